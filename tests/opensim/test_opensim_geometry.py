"""The OpenSim model's static tape rows (no OpenSim needed): row centres on the tape's midline."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.analysis.bent_tape import bent_tape_dots, uniform_bend
from spinemocap.opensim.geometry import row_frames
from spinemocap.tape import TapeSpec

TAPE = TapeSpec(n_rows=13)


def _anterior_per_dot(dots: np.ndarray) -> np.ndarray:
    """(D, 3) unit normal of each dot's row on a clean tape: the tangent from the neighbouring
    rows' L-R midpoints x the L -> R axis."""
    graph = TAPE.graph
    side = {c: np.array([graph.labels.index(f"R{r + 1:02d}{c}") for r in range(TAPE.n_rows)]) for c in "LR"}
    tangent = np.gradient(0.5 * (dots[side["L"]] + dots[side["R"]]), axis=0)
    normal = np.cross(tangent, dots[side["R"]] - dots[side["L"]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return normal[graph.row]


@pytest.mark.xfail(strict=True, reason="known gap: row_frames keeps the L-R midpoints. With the "
                   "midline centres (tape.row_midline_points) the OpenSim benchmark did not improve and IK "
                   "on a model turned 30 deg differed by up to 2.1 deg (test_opensim.py)")
def test_static_rows_do_not_zig_zag_when_dots_read_deeper_toward_the_midline():
    # Tracked dots read deeper toward the tape's midline (studio, lab: C ~0.7 mm, +-7.5 mm ~0.5 mm,
    # +-15 mm ~0.2 mm). Rows alternate dots at +-7.5 mm and at -15/0/+15 mm, so the L-R midpoints
    # of 2-dot rows sink 3/4 of the midline's depth and those of 3-dot rows none of it: a zig-zag
    # between rows. The model's row centres must follow the midline, the same depth on every row.
    clean = bent_tape_dots(TAPE, uniform_bend(0, 300, np.array([25.0, 8.0, 0.0])))
    depth_mm = 1.0 * (1 - (TAPE.graph.uv_mm[:, 0] / 15.0) ** 2)
    normal = _anterior_per_dot(clean)
    deeper = clean + depth_mm[:, None] * normal

    shift = row_frames(deeper, TAPE).centre - row_frames(clean, TAPE).centre
    row_normal = normal[[TAPE.graph.labels.index(f"R{r + 1:02d}L") for r in range(TAPE.n_rows)]]
    along_normal = np.einsum("rk,rk->r", shift, row_normal)
    np.testing.assert_allclose(along_normal, 1.0, atol=0.02)  # L-R midpoints: 0.75 / 0.0 alternating
    assert np.abs(np.diff(along_normal, 2)).max() < 0.02


def test_a_row_without_a_side_dot_stays_unseen():
    static = bent_tape_dots(TAPE, uniform_bend(0, 300, np.array([25.0, 0.0, 0.0])))
    static[TAPE.graph.labels.index("R04R")] = np.nan  # a 3-dot row: its C dot alone gives no L->R axis
    rows = row_frames(static, TAPE)
    assert not rows.seen[3] and rows.seen[[2, 4]].all()
    assert np.isfinite(rows.arc).all()
