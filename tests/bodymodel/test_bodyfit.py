"""Body fit: anny recovers a known pose from synthetic markers; a tape laid on the fitted body
reproduces the studio's dots; the real Nexus files fit (skipped when ../shared is absent)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from repo_paths import SHARED

from spinemocap.tape import TapeSpec

VICON = SHARED / "data" / "vicon"


@pytest.fixture(scope="module")
def anny():
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from spinemocap.bodymodel.anny_body import AnnyModel

    return AnnyModel()


def spine_pose(model, angles_deg: np.ndarray) -> np.ndarray:
    """Pose vectors bending the five spine bones like the studio (one fifth of the angles each)."""
    from scipy.spatial.transform import Rotation

    from spinemocap.synth.body import SPINE_BONES, rotation_from_spine_angles

    pose = np.zeros((len(angles_deg), model.pose_size))
    for f, angles in enumerate(angles_deg):
        rotvec = Rotation.from_matrix(rotation_from_spine_angles(np.asarray(angles) / 5)).as_rotvec()
        for bone in SPINE_BONES:
            pose[f, model.joint_index(bone) : model.joint_index(bone) + 3] = rotvec
    return pose


def test_tape_on_the_studio_body_reproduces_the_studio_dots(anny):
    from spinemocap.bodymodel.tape import lay_tape
    from spinemocap.synth.body import Body
    from spinemocap.synth.tape_on_skin import TapeOnSkin

    spec = TapeSpec(n_rows=9)
    body = Body()
    studio = TapeOnSkin(body, spec, "L4")
    # one level table: the body model places the vertebral levels from its hip and neck joints as
    # the studio does from anny's (S2 at the PSIS, C7 at the neck; anny's own frame: soles not on z = 0)
    from spinemocap.bodymodel.markersets import level_heights

    ours_levels = level_heights(anny.rest())
    studio_levels = body.level_heights()
    assert list(ours_levels) == list(studio_levels)
    np.testing.assert_allclose([ours_levels[n] + body.floor_offset[2] for n in ours_levels],
                               list(studio_levels.values()), atol=1e-6)
    # so on the studio's own body the body-model tape, laid from its own levels, is the studio's
    # (no tension, no skin strain)
    laid = lay_tape(anny.rest(), spec, "L4")
    assert laid.row_levels == studio.row_levels
    angles = np.array([[20.0, 5.0, -10.0], [-10.0, 0.0, 15.0]])
    studio_vertices, _ = body.pose(angles)
    ours = anny.vertices(spine_pose(anny, angles)) + body.floor_offset  # studio frame: soles on z = 0
    for f in range(len(angles)):
        np.testing.assert_allclose(laid.dot_positions(ours[f]), studio.dot_positions(studio_vertices[f]), atol=0.01)
    # the other reference: bind to the (here: exact) tracked dots of frame 0, read them off frame 1
    from spinemocap.bodymodel.tape import bind_to_tracked, dots_over_frames

    tracked = studio.dot_positions(studio_vertices[0])
    tracked[3] = np.nan  # a dot not seen in the reference frame stays NaN
    binding, present = bind_to_tracked(ours[0], anny.faces, tracked)
    dots = dots_over_frames(binding, ours, anny.faces, len(tracked), present)
    assert np.isnan(dots[:, 3]).all()
    np.testing.assert_allclose(dots[0, present], tracked[present], atol=0.1)  # offsets in the triangles' frames
    error = np.linalg.norm(dots[1, present] - studio.dot_positions(studio_vertices[1])[present], axis=1)
    assert error.max() < 0.5


def test_anny_fit_recovers_a_known_pose_and_the_tape_on_it(anny):
    import torch

    from spinemocap.bodymodel.base import SurfaceAnchors
    from spinemocap.bodymodel.fit import FitOptions, MarkerFitter
    from spinemocap.bodymodel.markersets import (
        PLUG_IN_GAIT,
        SPINE_MARKERS,
        place_markers,
    )
    from spinemocap.bodymodel.tape import lay_tape

    rest = anny.rest()
    labels, vertices = place_markers(rest, list(PLUG_IN_GAIT) + ["T4", "T8", "L1", "L3", "S1"])
    assert len(labels) == len(PLUG_IN_GAIT) + 5 and set(SPINE_MARKERS) <= set(labels)
    truth = spine_pose(anny, np.array([[25.0, 5.0, -10.0], [10.0, -8.0, 12.0], [0.0, 0.0, 0.0]]))
    truth[:, :3] = [30.0, -20.0, 15.0]
    truth[:, 3:6] = [0.0, 0.0, 0.3]
    with torch.no_grad():
        markers = anny.points(torch.tensor(truth), anny.default_shape(),
                              SurfaceAnchors(vertices, rest.normals[vertices] * 9.5)).numpy()
    markers += np.random.default_rng(0).normal(0.0, 0.3, markers.shape)
    markers[1, 3] = np.nan  # a gap
    fit = MarkerFitter(anny, vertices, FitOptions(n_key_frames=2, shape_rounds=1, shape_iterations=3)).fit(
        markers, labels=labels, progress=False)
    assert np.isnan(fit.residual_mm[1, 3]) and not fit.flagged.any()
    assert np.sqrt(np.nanmean(fit.residual_mm ** 2)) < 0.6  # noise is 0.3 mm per axis (0.52 mm 3D)
    assert np.abs(fit.poses[:, 6:] - truth[:, 6:]).max() < 0.1  # rad
    spec = TapeSpec(n_rows=9)
    true_dots = lay_tape(rest, spec, "L4").dots.sequence(anny.vertices(truth), anny.faces)
    fitted = lay_tape(anny.rest(fit.shape), spec, "L4").dots.sequence(anny.vertices(fit.poses, fit.shape), anny.faces)
    assert np.linalg.norm(fitted - true_dots, axis=2).mean() < 2.0  # mm


def test_anny_pose_kernel_matches_autograd_through_the_whole_skeleton(anny):
    """The fast per-frame path (numpy, posed bones only, analytic Jacobian) gives the torch
    sparse path's points and its forward-mode Jacobian, at a non-zero pose and shape; so does
    the shape stage's sparse rest model."""
    from spinemocap.bodymodel.base import AutodiffPoseKernel, SurfaceAnchors
    from spinemocap.bodymodel.markersets import PLUG_IN_GAIT, place_markers

    shape = np.array([0.3, 0.6, 0.5, 0.4, 0.7, 0.5])
    rest = anny.rest(shape)
    _, vertices = place_markers(rest, list(PLUG_IN_GAIT) + ["T8", "L3"])
    rng = np.random.default_rng(1)
    anchors = SurfaceAnchors(vertices, rest.normals[vertices] * 9.5 + rng.normal(0.0, 5.0, (len(vertices), 3)))
    pose = rng.normal(0.0, 0.3, anny.pose_size)
    pose[:3] = [10.0, -30.0, 40.0]
    points, jac = anny.pose_kernel(shape, anchors)(pose)
    ref_points, ref_jac = AutodiffPoseKernel(anny, shape, anchors)(pose)
    assert jac.shape == (len(vertices), 3, anny.pose_size)
    np.testing.assert_allclose(points, ref_points, atol=1e-8)  # mm
    np.testing.assert_allclose(jac, ref_jac, atol=1e-8 * np.abs(ref_jac).max())
    # the shape stage's path (torch shape: the rest model blended at the anchors' vertices only)
    import torch

    with torch.no_grad():
        shaped = anny.points(torch.tensor(pose[None]), torch.tensor(shape), anchors)[0].numpy()
    np.testing.assert_allclose(shaped, ref_points, atol=1e-8)


def _run_bodyfit(tmp_path, name: str, frames: str, *extra: str) -> dict:
    from spinemocap.cli import main

    path = VICON / name
    if not path.is_file():
        pytest.skip(f"{path} absent")
    out = tmp_path / name
    assert main(["bodyfit", str(path), "--out", str(out), "--frames", frames, "--key-frames", "1",
                 "--no-progress", *extra]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert np.isfinite(summary["marker_rms_mm"]) and summary["marker_rms_mm"] < 30
    for name_ in ("body.npz", "residuals.csv", "residuals.png"):
        assert (out / name_).is_file()
    return summary


def test_real_plug_in_gait_trial_fits_with_trunk_rms(tmp_path, anny):
    import exporters

    TapeSpec(n_rows=9).to_toml(tmp_path / "tape.toml")
    summary = _run_bodyfit(tmp_path, "golf_static.c3d", "0:1", "--tape", str(tmp_path / "tape.toml"))
    tape = exporters.read(summary["tape_dots"])
    assert tape.labels == TapeSpec(n_rows=9).labels and np.isfinite(tape.positions()).all()
    assert {"C7", "T10", "CLAV", "STRN", "RBAK"} <= set(summary["trunk_markers"])
    # one key frame of a static trial fits to ~7 mm (trunk ~10 mm) with free per-marker offsets
    assert summary["marker_rms_mm"] < 10 and summary["trunk_marker_rms_mm"] < 15
    assert len(summary["markers"]) >= 35


@pytest.mark.slow
@pytest.mark.parametrize("name,frames", [("running_cluster01.c3d", "0:400:40"),
                                         ("walking01_plugin_gait_lower.c3d", "::40")])  # the latter starts at 198
def test_other_real_nexus_files_fit(tmp_path, anny, name, frames):
    _run_bodyfit(tmp_path, name, frames)


def test_bodyfit_refuses_a_file_without_known_markers(tmp_path):
    import exporters
    from spinemocap.cli import main
    from spinemocap.markers import MarkerTable

    table = MarkerTable.from_arrays(["A", "B", "C"], np.zeros((2, 3, 3)), fps=100.0)
    exporters.write(table, tmp_path / "m.trc")
    assert main(["bodyfit", str(tmp_path / "m.trc"), "--out", str(tmp_path / "out")]) == 2


def test_marker_frames_use_the_common_selection_syntax_on_the_files_frame_numbers(tmp_path):
    import exporters
    from spinemocap.app.bodyfit import frame_step, marker_arrays
    from spinemocap.fileio import InputError
    from spinemocap.markers import MarkerTable

    positions = np.arange(20 * 2 * 3, dtype=float).reshape(20, 2, 3)
    table = MarkerTable.from_arrays(["A", "B"], positions, fps=100.0)
    exporters.write(table, tmp_path / "m.trc")
    _, frames, kept, fps = marker_arrays(tmp_path / "m.trc", "2:12:5")
    assert fps == 100.0 and frames.tolist() == [2, 7] and frame_step(frames) == 5
    np.testing.assert_allclose(kept, positions[[2, 7]], atol=1e-3)
    _, frames, _, _ = marker_arrays(tmp_path / "m.trc", "15:")
    assert frames.tolist() == list(range(15, 20))
    with pytest.raises(InputError, match="frames"):
        marker_arrays(tmp_path / "m.trc", "3-9")
    _, frames, _, _ = marker_arrays(tmp_path / "m.trc", "0,1,5")
    with pytest.raises(ValueError, match="not evenly spaced"):
        frame_step(frames)
