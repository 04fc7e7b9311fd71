"""Angles relative to standing (a neutral trial or the first frames), segmental angles and the
midline profiles, on the analytic bent tape. (A default studio capture's S1 -> T12/L1 angle over a
full flexion is tested with the studio: tests/synth/test_synth_realism.py.)"""

import re

import numpy as np
import pytest

from spinemocap.analysis.angles import ANGLE_COLUMNS, AngleSettings, compute_angles
from spinemocap.analysis.bent_tape import bent_tape_dots, uniform_bend
from spinemocap.analysis.levels import LevelMap
from spinemocap.analysis.neutral import (
    is_static_name,
    neutral_from_angles,
    neutral_summary,
    relative_to_neutral,
)
from spinemocap.analysis.shape import key_frames, midline_profiles, segmental_angles, segments_of, vertebrae_on_tape
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

TAPE = TapeSpec(n_rows=13)
LEVELS = LevelMap({"S1": 1, "L3": 5, "T12/L1": 9, "T7": 13}, 13)
NO_FILTER = AngleSettings(lowpass_hz=None)
LORDOSIS = np.array([-0.1, 0.0, 0.0])  # deg/mm: a standing lordotic back, lumbar angle ~ -20 deg


def _trial(flexion_per_frame, lateral=0.0) -> MarkerTable:
    """A bend spread evenly over the whole 300 mm tape, ``flexion_per_frame`` of it between S1
    (0 mm) and T12/L1 (200 mm): no curvature step for the spline to round off."""
    scale = TAPE.length_mm / 200.0
    dots = np.array([bent_tape_dots(TAPE, uniform_bend(0.0, TAPE.length_mm, scale * np.array([f, lateral, 0.0]),
                                                       LORDOSIS))
                     for f in flexion_per_frame])
    return MarkerTable.from_arrays(TAPE.labels, dots, fps=50.0)


def _angles(markers: MarkerTable):
    # no temporal low-pass: the test sequences jump between poses from frame to frame
    return compute_angles(markers, TAPE, LEVELS, settings=NO_FILTER).table


def test_angles_relative_to_a_neutral_trial_are_zero_at_neutral():
    static = _angles(_trial(np.zeros(10)))
    assert static["lumbar_flexion"].iloc[0] == pytest.approx(-20.0, abs=0.5)  # absolute: lordotic
    neutral = neutral_from_angles(static, first_s=None, source="static trial S01/static")
    # the static trial against itself, and the motion trial's neutral frames, read zero
    assert np.nanmax(np.abs(relative_to_neutral(static, neutral)[list(ANGLE_COLUMNS)].to_numpy(float))) < 1e-6
    motion = _angles(_trial([0.0, 0.0, 15.0, 40.0, 15.0, -10.0, 0.0]))
    relative = relative_to_neutral(motion, neutral)
    lumbar = ["lumbar_flexion", "lumbar_lateral", "lumbar_rotation"]
    assert np.abs(relative.loc[[0, 1, 6], lumbar].to_numpy(float)).max() < 1e-6
    assert relative["lumbar_flexion"].iloc[3] == pytest.approx(40.0, abs=0.2)
    # the words that read right: flexion 40 and extension 10 from neutral, ROM 50, absolute kept
    stats = neutral_summary(motion, neutral)
    assert stats["lumbar_flexion_pos_from_neutral"] == pytest.approx(40.0, abs=0.2)
    assert stats["lumbar_flexion_neg_from_neutral"] == pytest.approx(10.0, abs=0.2)
    assert stats["lumbar_flexion_rom"] == pytest.approx(50.0, abs=0.3)
    assert stats["lumbar_flexion_neutral"] == pytest.approx(-20.0, abs=0.5)
    assert stats["lumbar_flexion_max"] == pytest.approx(20.0, abs=0.5)  # absolute peak: -20 + 40


def test_first_frames_define_neutral_and_missing_angles_stay_unknown():
    table = _angles(_trial([0.0] * 11 + [30.0] * 5))  # 50 fps: the first 0.2 s are frames 0..10
    assert neutral_from_angles(table).source == "the trial's first frame"  # the default
    neutral = neutral_from_angles(table, first_s=0.2)
    assert neutral.source == "the first 0.2 s of the trial"
    assert relative_to_neutral(table, neutral)["lumbar_flexion"].iloc[:11].abs().max() < 1e-6
    table["lumbar_flexion"] = np.nan  # an angle never computed: unknown, never "0 from neutral"
    stats = neutral_summary(table, neutral_from_angles(table, first_s=0.2))
    assert np.isnan(stats["lumbar_flexion_pos_from_neutral"]) and np.isnan(stats["lumbar_flexion_rom"])
    assert is_static_name("Static01") and is_static_name("trial01", "neutral") and not is_static_name("flexion")


def test_segmental_angles_add_up_to_the_lumbar_angle_and_the_midline_bends_forward():
    markers = _trial([0.0, 20.0, 40.0], lateral=10.0)
    angles = _angles(markers)
    segments = segmental_angles(markers, TAPE, LEVELS, NO_FILTER)
    names = segments_of(segments)
    assert vertebrae_on_tape(LEVELS)[:2] == ["S1", "L5"] and names[0] == "L5-S1" and names[-1] == "T7-T8"
    lumbar = [n for n in names if n.split("-")[1] in ("S1", "L5", "L4", "L3", "L2")]  # S1 .. L1
    flexion_change = segments[[f"{n}_flexion" for n in lumbar]].to_numpy(float)
    flexion_change = flexion_change[2] - flexion_change[0]
    # S1 -> L1 (the segments) vs S1 -> T12/L1 (the lumbar angle): the bend is uniform along the
    # tape, so the segments carry the lumbar change in proportion of their length on the tape
    lumbar_change = angles["lumbar_flexion"].iloc[2] - angles["lumbar_flexion"].iloc[0]
    share = (LEVELS.row_of("L1") - 1) / (LEVELS.row_of("T12/L1") - 1)
    assert flexion_change.sum() == pytest.approx(lumbar_change * share, rel=0.03)
    assert np.all(flexion_change[:-1] > 0)
    frames = key_frames(angles)
    assert frames == {"neutral": 0, "peak flexion": 2, "peak extension": 0}
    profiles = midline_profiles(markers, TAPE, frames, settings=NO_FILTER)
    neutral, flexed = profiles["neutral"], profiles["peak flexion"]
    assert neutral["superior"][0] == 0 and neutral["anterior"][0] == 0  # origin at the sacral end
    assert max(neutral["superior"]) > 250  # the 300 mm tape stands up at neutral
    assert flexed["anterior"][-1] > neutral["anterior"][-1] + 50  # and leans forward at peak flexion
    assert neutral["right"][-1] > 20 and flexed["right"][-1] > 20  # the trial bends to the subject's right


def test_angles_command_reports_motion_from_a_static_trial(tmp_path, capsys):
    import exporters
    from spinemocap.cli import main

    exporters.write(_trial(np.zeros(20)), tmp_path / "static.trc")
    exporters.write(_trial(np.r_[np.zeros(10), np.linspace(0, 30, 30), np.linspace(30, -5, 30)]), tmp_path / "bend.trc")
    (tmp_path / "levels.toml").write_text('S1 = 1\nL3 = 5\n"T12/L1" = 9\nT7 = 13\n')
    assert main(["angles", str(tmp_path / "bend.trc"), "--levels", str(tmp_path / "levels.toml"),
                 "--neutral", str(tmp_path / "static.trc")]) == 0
    text = capsys.readouterr().out
    assert "neutral: the static trial static.trc" in text
    flexion, extension, rom = (float(x) for x in re.search(
        r"flexion from neutral ([\d.-]+) deg, extension from neutral ([\d.-]+) deg, ROM ([\d.-]+)", text).groups())
    assert flexion == pytest.approx(30.0, abs=0.6) and extension == pytest.approx(5.0, abs=0.6)
    assert rom == pytest.approx(35.0, abs=1.0)
