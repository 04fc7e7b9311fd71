"""A tracked sequence's quality report (:meth:`TrackResult.quality`): which frames are vouched
for, the spacing measured on them, the gate, the cameras without images, and its JSON object."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spinemocap.app.run import TrackQuality, TrackResult
from spinemocap.app.streaming import DetectorInfo
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec
from spinemocap.track.pipeline import FrameResult
from spinemocap.track.stretch import StretchEstimate


def _solved(n_dots: int, along: float, gate_px: float, flags: list[str]) -> FrameResult:
    return FrameResult(np.zeros((n_dots, 3)), np.full(n_dots, "observed", dtype=object), np.full(n_dots, 3),
                       np.full(n_dots, 0.5), flags=flags, gate_px=gate_px,
                       stretch=StretchEstimate(along=along, across=0.98, source="data"))


def _result() -> TrackResult:
    """Frames 10-13: vouched for (spacing 1.10, gate 2 px), mildly flagged (1.20, 3 px), doubted
    (1.50, 4 px, never measured from), unsolved; camera cam2 without an image in frame 12."""
    tape = TapeSpec(n_rows=3)
    n = len(tape.labels)
    frames = [_solved(n, 1.10, 2.0, []), _solved(n, 1.20, 3.0, ["lp_relaxed"]),
              _solved(n, 1.50, 4.0, ["unlabelled_dots"]), FrameResult.missing(n, {}, "no dots")]
    table = MarkerTable.from_arrays(tape.labels, np.zeros((4, n, 3)), fps=50.0, first_frame=10)
    info = DetectorInfo("threads", 2, missing_frames={"cam2": [12], "cam1": []}, unreadable={"cam2": {12: "damaged"}})
    return TrackResult(table, frames, detector_info=info)


def test_quality_vouches_only_for_unflagged_frames_and_measures_on_them():
    quality = _result().quality()
    assert quality.flagged_frames == [12, 13]  # a doubting flag or unsolved; lp_relaxed is mild
    assert quality.flags == {"lp_relaxed": 1, "unlabelled_dots": 1, "tape not found": 1}
    assert quality.stretch_along == pytest.approx((1.10, 1.15, 1.20))  # min, median, max of the vouched-for frames
    assert quality.stretch_across == 0.98
    assert quality.gate_px == 3.0  # median over every frame that set a gate
    assert quality.rig_rms_px is None and quality.calibration_warning is None
    assert quality.missing_cameras == {"cam2": [12]}


def test_quality_json_keeps_its_keys_in_order_and_the_spacing_as_a_list():
    data = json.loads(json.dumps(_result().quality().to_dict()))
    assert list(data) == ["flagged_frames", "flags", "stretch_along", "stretch_across", "gate_px", "rig_rms_px",
                          "calibration_warning", "missing_cameras"]
    assert data["stretch_along"] == pytest.approx([1.10, 1.15, 1.20]) and data["missing_cameras"] == {"cam2": [12]}


def test_quality_without_measured_frames_says_none():
    quality = TrackResult(_result().table, [FrameResult.missing(3, {}, "")]).quality()
    assert quality == TrackQuality([10], {"tape not found": 1}, None, None, None, None, None, {})
    assert quality.to_dict()["stretch_along"] is None


def test_summary_reports_the_spacing_and_the_flagged_frames():
    summary = _result().summary()
    assert "+15 % along the tape vs the roll's spec (frames +10 .. +20 %), -2 % across" in summary
    assert "WARNING 2 of 4 frames flagged" in summary and "camera cam2 had no image in 1 of 4 frames (frame 12); the other cameras were used there: damaged" in summary
