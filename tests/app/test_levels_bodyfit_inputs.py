"""Where a capture's level map comes from (the trial's file first, the ground truth last); a body
fit's marker arrays and frame selection; a wand wave written as C3D and read back as Nexus's."""

from __future__ import annotations

import numpy as np
import pytest

import exporters
from calibration.wand import WandSpec
from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.app.bodyfit import frame_step, marker_arrays
from spinemocap.app.c3d_inputs import read_vicon_wand, write_vicon_wand_c3d
from spinemocap.app.levels import find_level_map
from spinemocap.capture import Capture
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec


def test_the_level_map_is_looked_up_in_order(tmp_path):
    trial = tmp_path / "S01" / "pre" / "trial01"
    write_bent_capture(trial, TapeSpec(n_rows=9), 10.0, n_frames=3)
    capture = Capture.open(trial)
    with pytest.raises(InputError, match="no row-to-level map"):
        find_level_map(capture)
    (tmp_path / "S01" / "levels.toml").write_text('[levels]\nS1 = 1\n"T12/L1" = 7\n')
    levels, source = find_level_map(capture)
    assert source.endswith("S01/levels.toml") and levels.rows["T12/L1"] == 7
    (trial / "levels.toml").write_text('[levels]\nS1 = 2\n"T12/L1" = 8\n')
    levels, source = find_level_map(capture)
    assert source == str(trial / "levels.toml") and levels.rows["S1"] == 2
    given = tmp_path / "given.toml"
    given.write_text('[levels]\nS1 = 1\nL3 = 4\n')
    levels, source = find_level_map(capture, trial_file=given)
    assert source == str(given) and "L3" in levels.rows


def test_marker_arrays_keep_the_selected_frames_and_markers_only(tmp_path):
    positions = np.random.default_rng(0).normal(size=(10, 3, 3)) * 100 + [0, 0, 1000]
    exporters.write(MarkerTable.from_arrays(["LASI", "RASI", "C7"], positions, fps=100.0), tmp_path / "m.trc")
    labels, frames, kept, fps = marker_arrays(tmp_path / "m.trc", frames="2:10:3")
    assert labels == ["LASI", "RASI", "C7"] and frames.tolist() == [2, 5, 8] and fps == 100.0
    np.testing.assert_allclose(kept, positions[[2, 5, 8]], atol=1e-3)
    assert frame_step(frames) == 3 and frame_step(frames[:1]) == 1
    with pytest.raises(ValueError, match="not evenly spaced"):
        frame_step(np.array([0, 1, 3]))
    with pytest.raises(InputError, match="frames: .*step 0"):
        marker_arrays(tmp_path / "m.trc", frames="0:5:0")


def test_a_wand_wave_written_as_c3d_is_read_back(tmp_path):
    wand = WandSpec()
    points = np.random.default_rng(1).uniform(-500, 500, (60, 5, 3)) + [0, 0, 1000]
    points[4, 2] = np.nan  # a marker the Vicon lost for a frame
    write_vicon_wand_c3d(tmp_path / "wand.c3d", points, 100.0, wand)
    back = read_vicon_wand(tmp_path / "wand.c3d", wand)
    assert back.rate == 100.0 and back.points_mm.shape == (60, 5, 3) and np.isnan(back.points_mm[4, 2]).all()
    finite = np.isfinite(points)
    np.testing.assert_allclose(back.points_mm[finite], points[finite], atol=1e-2)
