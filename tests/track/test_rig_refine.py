"""The refinement's report (``rig_refine.json``): where the world frame came from, the
reference's fit with the caller's doubt about its pose last."""

from __future__ import annotations

import json

from spinemocap.camera import Rig
from spinemocap.track.rig_refine import ReferenceFrame, RigRefinement


def _frame() -> ReferenceFrame:
    return ReferenceFrame(name="L-frame", markers_used=["REF1", "REF2", "REF3"],
                          cameras_per_marker={"REF1": 3, "REF2": 2, "REF3": 3}, observations=8,
                          marker_rms_px={"REF1": 0.1, "REF2": 0.2, "REF3": 0.1},
                          marker_error_mm={"REF1": 0.05, "REF2": 0.1, "REF3": 0.05}, fit_rms_px=0.14,
                          fit_rms_mm=0.07, limit_px=1.0, bad_markers=[], given_frame_offset_mm=12.0)


def _refinement(reference: ReferenceFrame | None) -> RigRefinement:
    per_camera = {"cam1": 0.5, "cam2": 0.4}
    return RigRefinement(Rig([]), {**per_camera, "all": 0.45}, {**per_camera, "all": 0.1}, {"cam1": 0.0, "cam2": 0.0},
                         n_points=20, n_observations=40, frames_used=5, solver="scipy least_squares (trf, huber)",
                         outliers_dropped=1, given_rig_disagreement_mm=per_camera, reference=reference,
                         frame_uncertainty_mm=0.3, frame_uncertainty_from_disagreement_mm=0.3,
                         frame_uncertainty_from_residuals_mm=0.2, centre_prior_mm=per_camera,
                         rotation_prior_deg=per_camera, focal_scale=per_camera, camera_moved_mm=per_camera)


def test_the_report_names_the_given_rig_as_the_world_frame_without_a_reference():
    report = json.loads(json.dumps(_refinement(None).to_dict()))
    assert report["world_frame"] == {"source": "given rig"}
    assert list(report)[:6] == ["before_px", "after_px", "sync_offsets_ms", "n_points", "n_observations", "frames_used"]
    assert list(report).index("world_frame") == list(report).index("given_rig_disagreement_mm") + 1


def test_the_reference_frame_is_reported_with_its_fit_and_the_pose_doubt_last():
    frame = _frame()
    assert list(frame.to_dict())[:2] == ["source", "name"] and frame.to_dict()["source"] == "reference"
    assert "pose_warning" not in frame.to_dict()
    frame.pose_warning = "L-frame: the given rig places the reference's markers 12.0 mm from ..."
    world = json.loads(json.dumps(_refinement(frame).to_dict()))["world_frame"]
    assert list(world)[-2:] == ["given_frame_offset_mm", "pose_warning"] and world["observations"] == 8
