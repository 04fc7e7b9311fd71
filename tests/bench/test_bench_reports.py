"""The sync and Vicon-wand benchmarks' tables: the goal's verdict from the worst error on 100 fps
cameras, a method that failed shown with its reason; the body-fit benchmark's error statistics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from spinemocap.app.wand_wave import RegistrationErrors
from spinemocap.bench.bodyfit import BodyFitBenchmark, BodyFitRun, CrossValNumbers, DotErrors, dot_errors, format_report
from spinemocap.bench.sync import CaptureSync, OffsetErrors, SyncNumbers
from spinemocap.bench.sync import format_table as sync_table
from spinemocap.bench.vicon_wand import NOT_FILMABLE, CrossValRegistration, WandLevel, WandRegistration
from spinemocap.bench.vicon_wand import format_table as wand_table
from spinemocap.crossval.agreement import Agreement


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


def _wand_level(**methods) -> WandLevel:
    return WandLevel(realism="lab", preset="artificial", motion="mixed", frames=10, fps=30.0, size=[480, 360],
                     cameras=4, record_and_wand_s=4.5, vicon_occluded_share=0.1, vicon_markers_with_gaps=["VT_R07"],
                     **methods)


def test_the_wand_table_shows_a_failed_method_with_its_reason_and_the_json_keeps_its_keys():
    errors = RegistrationErrors(rotation_error_deg=0.025, point_error_mean_mm=0.24, point_error_max_mm=0.32,
                                offset_error_ms=-0.067)
    wand = WandRegistration(errors, n_frames=79, scale=1.0, residual_rms_mm=0.33)
    crossval = CrossValRegistration(errors, estimated="offset", scale=1.0,
                                    angles={"lumbar_flexion": {"rmse_deg": 1.0, "bias_deg": 0.1, "icc": 0.9, "cmc": 0.95}})
    row = _wand_level(wand=wand, coregister_s=1.9, crossval_rig_vicon=crossval,
                      crossval_markers="failed: too few markers")
    text = wand_table([row])
    assert "lab    wand" in text and "-0.067" in text and "lumbar_flexion 1.00 / 0.900" in text
    assert "crossval_markers          failed: too few markers" in text
    assert list(row.to_dict()) == ["realism", "preset", "motion", "frames", "fps", "size", "cameras", "record_and_wand_s",
                                   "vicon_occluded_share", "vicon_markers_with_gaps", "coregister_s", "wand",
                                   "crossval_rig_vicon", "crossval_markers"]
    assert list(row.to_dict()["wand"]) == ["rotation_error_deg", "point_error_mean_mm", "point_error_max_mm",
                                           "offset_error_ms", "n_frames", "scale", "residual_rms_mm"]
    unfilmed = _wand_level(wand=NOT_FILMABLE).to_dict()
    assert list(unfilmed)[-2:] == ["vicon_markers_with_gaps", "wand"] and unfilmed["wand"] == NOT_FILMABLE


def test_body_fit_error_statistics_skip_missing_dots():
    errors = np.array([1.0, 2.0, np.nan, 3.0, 4.0])
    stats = dot_errors(errors)
    assert stats.dot_frames == 4 and stats.mean_mm == 2.5
    assert stats.p95_mm == pytest.approx(np.percentile([1, 2, 3, 4], 95))
    assert stats.keyed("tracker") == {"tracker_dot_error_mean_mm": 2.5, "tracker_dot_error_median_mm": 2.5,
                                      "tracker_dot_error_p95_mm": stats.p95_mm, "tracker_dot_frames": 4}


def _fit(jacobian: str, ms: float) -> BodyFitRun:
    return BodyFitRun(vicon_frames=50, vicon_markers_fitted=["C7", "T10"], marker_rms_mm=3.0, fit_s=2.0,
                      fit_ms_per_vicon_frame=ms, shape_stage_s=1.5, misplacement_mm=10.0, pose_jacobian=jacobian)


def test_the_body_fit_benchmark_writes_its_keys_in_order_and_reports_the_peer():
    crossval = CrossValNumbers(frames=60, fps=30.0, rows=9, dot_noise_mm=0.3, clock_offset_true_ms=12.0,
                               clock_offset_error_ms=0.02, transform_error_max_mm=0.1,
                               angles={"lumbar_flexion": Agreement(1.0, 0.5, -1.0, 2.0, 0.9, 0.95, 60)},
                               angle_convention={"definition": "each minus its neutral value"})
    numbers = BodyFitBenchmark(preset="tiny", frames=3, seed=0, bodyfit_errors=DotErrors(20.0, 19.0, 30.0, 90),
                               tracker_errors=DotErrors(4.0, 3.5, 8.0, 90), bodyfit=_fit("kernel", 10.0),
                               peer=_fit("autodiff", 40.0), peer_errors=DotErrors(21.0, 20.0, 31.0, 90),
                               crossval=crossval)
    data = numbers.to_dict()
    assert list(data) == ["preset", "frames", "seed", "paper_studio_mm",
                          "bodyfit_dot_error_mean_mm", "bodyfit_dot_error_median_mm", "bodyfit_dot_error_p95_mm",
                          "bodyfit_dot_frames", "tracker_dot_error_mean_mm", "tracker_dot_error_median_mm",
                          "tracker_dot_error_p95_mm", "tracker_dot_frames", "bodyfit_over_tracker", "bodyfit",
                          "bodyfit_peer_autodiff", "crossval"]
    assert data["bodyfit_over_tracker"] == 5.0
    assert list(data["bodyfit_peer_autodiff"])[-4:] == ["bodyfit_dot_error_mean_mm", "bodyfit_dot_error_median_mm",
                                                       "bodyfit_dot_error_p95_mm", "bodyfit_dot_frames"]
    assert list(data["crossval"]) == ["frames", "fps", "rows", "dot_noise_mm", "clock_offset_true_ms",
                                      "clock_offset_error_ms", "transform_error_max_mm", "angles", "angle_convention"]
    assert data["crossval"]["angles"]["lumbar_flexion"]["rmse_deg"] == 1.0
    report = format_report(numbers)
    assert "(4.0x ours)" in report and "lumbar_flexion             RMSE 1.00 deg" in report
    no_peer = dataclasses.replace(numbers, peer=None, peer_errors=None)
    assert no_peer.to_dict()["bodyfit_peer_autodiff"] == {} and "peer" not in format_report(no_peer)
