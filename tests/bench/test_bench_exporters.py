"""The export benchmark's input and its C3D peer: trajectories with the asked share of gaps,
ezc3d's file of them read back by our reader sample for sample."""

from __future__ import annotations

import numpy as np
import pytest

import exporters
from spinemocap.bench.exporters import _ezc3d_peer, synthetic_table


def test_the_synthetic_table_has_its_gaps_and_the_peer_writes_what_we_read(tmp_path):
    pytest.importorskip("ezc3d")
    table = synthetic_table(200, 9, gap_share=0.1, seed=3)
    positions = table.positions()
    assert positions.shape == (200, 9, 3) and table.labels[:3] == ["R01L", "R01C", "R01R"]
    assert np.isnan(positions[..., 0]).mean() == pytest.approx(0.1, abs=0.03)
    times = _ezc3d_peer(table, tmp_path, repeat=1)
    assert times.write_ms > 0 and times.read_ms > 0 and list(times.to_dict()) == ["write_ms", "read_ms"]
    back = exporters.read(tmp_path / "peer.c3d")
    assert back.labels == table.labels and back.fps == table.fps
    finite = np.isfinite(positions)
    np.testing.assert_allclose(back.positions()[finite], positions[finite], atol=1e-3)
