"""The angles of one marker file: the tape read from its labels, the table and its plot written
(beside the markers by default), zero at the trial's first frames or at a static trial's median."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import exporters
from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.app.angles import marker_file_angles, tape_of_labels
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

LEVELS_TOML = '[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n'


def _marker_file(folder, peak_flexion: float, n_frames: int = 20):
    write_bent_capture(folder / "capture", TapeSpec(n_rows=9), peak_flexion, n_frames, fps=50.0)
    with np.load(folder / "capture" / "groundtruth.npz") as data:
        table = MarkerTable.from_arrays(list(data["labels"]), data["dots"], fps=50.0)
    path = folder / f"flexion_{peak_flexion:g}.trc"
    exporters.write(table, path)
    return path


def test_the_tape_is_read_from_the_labels():
    assert tape_of_labels(["R01L", "R01R", "R09C", "pelvis"], "m.trc").n_rows == 9
    assert tape_of_labels(["R01L", "R08R"], "m.trc").n_rows == 9  # rounded up to an odd count
    with pytest.raises(InputError, match="m.trc: no tape labels"):
        tape_of_labels(["LASI", "RASI"], "m.trc")


def test_angles_written_beside_the_markers_zero_at_the_first_frames(tmp_path):
    markers = _marker_file(tmp_path, 20.0)
    (tmp_path / "levels.toml").write_text(LEVELS_TOML)
    found = marker_file_angles(markers, tmp_path / "levels.toml")
    assert found.table_path == tmp_path / "flexion_20_angles.csv" and found.plot_path == found.table_path.with_suffix(".png")
    written = pd.read_csv(found.table_path)
    assert len(written) == 20 and found.plot_path.stat().st_size > 1000
    np.testing.assert_allclose(written["lumbar_flexion"], found.angles.table["lumbar_flexion"], atol=1e-4)
    assert found.angles.completeness == 1.0
    rom = found.from_neutral["lumbar_flexion_rom"]
    assert rom == pytest.approx(np.ptp(found.angles.table["lumbar_flexion"]))
    assert 15 < rom < 25  # the rod's applied 20 deg, read on the tape


def test_a_static_trial_sets_zero(tmp_path):
    markers = _marker_file(tmp_path, 20.0)
    static = _marker_file(tmp_path, 10.0)  # "static": its median is well into a flexion
    (tmp_path / "levels.toml").write_text(LEVELS_TOML)
    out = tmp_path / "out" / "angles.csv"
    out.parent.mkdir()
    found = marker_file_angles(markers, tmp_path / "levels.toml", out, neutral=static)
    assert found.table_path == out and "static trial flexion_10.trc" in found.neutral.source
    first = marker_file_angles(markers, tmp_path / "levels.toml", tmp_path / "first.csv")
    moved = found.from_neutral["lumbar_flexion_neutral"] - first.from_neutral["lumbar_flexion_neutral"]
    assert moved > 3  # zero is the static trial's median, not the first frame
    assert found.from_neutral["lumbar_flexion_pos_from_neutral"] == pytest.approx(
        first.from_neutral["lumbar_flexion_pos_from_neutral"] - moved, abs=0.01)
    assert found.from_neutral["lumbar_flexion_rom"] == pytest.approx(first.from_neutral["lumbar_flexion_rom"])
