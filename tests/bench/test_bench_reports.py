"""The sync and Vicon-wand benchmarks' tables: the goal's verdict from the worst error on 100 fps
cameras, a method that failed shown with its reason; the body-fit benchmark's error statistics."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.bench.bodyfit import _stats
from spinemocap.bench.sync import CaptureSync, OffsetErrors, SyncNumbers
from spinemocap.bench.sync import format_table as sync_table
from spinemocap.bench.vicon_wand import format_table as wand_table


def _method(worst: float) -> OffsetErrors:
    return OffsetErrors(offset_ms=[0.0, 12.5 + worst], error_ms=[0.0, worst], stderr_ms=[0.0, 0.01],
                        max_abs_error_100fps_ms=worst, max_abs_error_ms=worst, found=[True, True], pairs_as_truth=1.0)


def test_the_sync_verdict_follows_the_worst_error_on_100_fps_cameras():
    scenario = CaptureSync(cameras=["cam1", "cam2"], camera_fps=[100, 100], true_offset_ms=[0.0, 12.5], audio_s=0.1,
                           detect_s=1.0, motion_s=0.5,
                           methods={"motion": _method(0.4), "motion_no_bias_term": _method(7.0)},
                           dropped_rendered=[], dropped_found=[])
    text = sync_table(SyncNumbers(1.0, "classical", "lab", {"s": scenario}))
    assert "motion: worst |error| on 100 fps cameras 0.400 ms (goal met)" in text
    assert "motion_no_bias_term: worst |error| on 100 fps cameras 7.000 ms (goal NOT met)" in text
    assert "audio:" not in text  # a method not run is not reported
    assert list(scenario.to_dict()) == ["cameras", "camera_fps", "true_offset_ms", "audio_s", "detect_s", "motion_s",
                                        "motion", "motion_no_bias_term", "dropped_rendered", "dropped_found", "render_s"]


def test_the_wand_table_shows_a_failed_method_with_its_reason():
    ok = {"offset_error_ms": -0.067, "rotation_error_deg": 0.025, "point_error_mean_mm": 0.24,
          "point_error_max_mm": 0.32, "angles": {"lumbar_flexion": {"rmse_deg": 1.0, "icc": 0.9}}}
    text = wand_table([{"realism": "lab", "vicon_occluded_share": 0.1, "wand": ok, "crossval_rig_vicon": ok,
                        "crossval_markers": "failed: too few markers"}])
    assert "lab    wand" in text and "-0.067" in text and "lumbar_flexion 1.00 / 0.900" in text
    assert "crossval_markers          failed: too few markers" in text


def test_body_fit_error_statistics_skip_missing_dots():
    errors = np.array([1.0, 2.0, np.nan, 3.0, 4.0])
    stats = _stats(errors, "tracker")
    assert stats["tracker_dot_frames"] == 4 and stats["tracker_dot_error_mean_mm"] == 2.5
    assert stats["tracker_dot_error_p95_mm"] == pytest.approx(np.percentile([1, 2, 3, 4], 95))
