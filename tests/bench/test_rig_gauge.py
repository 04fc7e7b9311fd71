"""``--refine-rig``'s world frame: the refined geometry is the true rig's up to one
similarity, priors sized by the given rig's own residuals (an option), and the cloud gauge of
``bench gauge``.

Pixels are projections of dots laid on a curved back (see test_track_stages), the given rigs the
studio's own calibration error (:func:`spinemocap.synth.lab_errors.perturb_rig`), so the truth is
exact and no rendering is needed."""

from __future__ import annotations

import cv2
import numpy as np
from tape_scenes import SPEC, pixels_of, rig_behind, sequence, triangulated

from spinemocap.bench.frame_error import cloud_gauge
from spinemocap.synth.lab_errors import perturb_rig
from spinemocap.track.rig_refine import RigRefineConfig, refine_rig


def test_cloud_gauge_recovers_a_known_similarity_despite_outliers():
    rng = np.random.default_rng(3)
    points = rng.uniform(-200, 200, (400, 3)) + [0.0, 800.0, 1100.0]
    R = cv2.Rodrigues(np.array([0.02, -0.01, 0.03]))[0]
    t, s = np.array([12.0, -7.0, 4.0]), 1.003
    target = s * points @ R.T + t
    target[::20] += rng.normal(0, 30.0, (20, 3))  # 5 % wrong pairings
    target[5] = np.nan
    R_fit, t_fit, s_fit = cloud_gauge(points, target)
    assert np.allclose(R_fit, R, atol=1e-9) and np.allclose(t_fit, t, atol=1e-6) and abs(s_fit - s) < 1e-9


def test_the_priors_follow_the_given_rigs_calibration_error():
    """A rig calibrated to 3 px gets ~6x wider priors than one calibrated to 0.5 px, and every
    camera's centre width is its angle width at its distance to the dots; fixed widths stay."""
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    widths = {}
    for level in (0.5, 3.0):
        given = perturb_rig(true_rig, poses.reshape(-1, 3), level, np.random.default_rng(1))[0]
        refinement = refine_rig(given, pixels, poses, 100.0, RigRefineConfig(centre_prior_mm=None, rotation_prior_deg=None))
        centre = np.array(list(refinement.centre_prior_mm.values()))
        rotation = np.radians(list(refinement.rotation_prior_deg.values()))
        distance = np.array([np.linalg.norm(cam.center - poses.reshape(-1, 3).mean(axis=0)) for cam in given])
        assert np.allclose(centre / (rotation * distance), 1.0, atol=0.1)
        widths[level] = rotation
    assert 3.0 < np.median(widths[3.0] / widths[0.5]) < 10.0
    fixed = refine_rig(given, pixels, poses, 100.0, RigRefineConfig())  # the default: fixed widths
    assert set(fixed.centre_prior_mm.values()) == {20.0}


def test_refinement_leaves_only_the_world_frame():
    """Over seeded 2 px studio calibrations, after --refine-rig the dots are the true rig's up to
    one similarity (their shape error is the true rig's own), where the given rig's are not. The
    similarity left (the world frame) is not asserted: no residual sees it."""
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    truth = poses.reshape(-1, 3)

    def shape_error(points: np.ndarray) -> float:
        R, t, s = cloud_gauge(points, truth)
        return float(np.linalg.norm(s * points @ R.T + t - truth, axis=1).mean())

    floor = shape_error(triangulated(true_rig, pixels).reshape(-1, 3))  # the pixels' noise
    for seed in range(3):
        given = perturb_rig(true_rig, truth, 2.0, np.random.default_rng([seed, 3]))[0]
        refinement = refine_rig(given, pixels, triangulated(given, pixels), 100.0, RigRefineConfig())
        assert shape_error(triangulated(given, pixels).reshape(-1, 3)) > 1.8 * floor
        assert shape_error(triangulated(refinement.rig, pixels).reshape(-1, 3)) < 1.05 * floor


def test_shape_error_takes_the_world_frame_out_of_a_tracked_table():
    from spinemocap.bench.frame_error import mean_error_mm, shape_error_mm
    from spinemocap.markers import MarkerTable

    truth = sequence(4)
    turn = cv2.Rodrigues(np.array([0.004, 0.0, -0.003]))[0]
    tracked = 1.002 * truth @ turn.T + [1.5, -0.8, 2.0]  # a world frame off by a similarity, shape exact
    status = np.full(truth.shape[:2], "observed", dtype=object)
    status[1, :3] = "missing"
    tracked[1, :3] = np.nan
    table = MarkerTable.from_arrays(SPEC.labels, tracked, 100.0, status=status)
    assert mean_error_mm(table, truth) > 1.5
    assert shape_error_mm(table, truth) < 1e-6


def test_bench_gauge_refuses_a_bad_sweep_before_rendering(tmp_path, capsys):
    from spinemocap.cli import main

    code = main(["bench", "gauge", "--json", str(tmp_path / "g.json"), "--levels", "2", "25", "--no-progress"])
    assert code != 0 and "every level in (0, 20] px" in capsys.readouterr().err
    assert not (tmp_path / "g.json").exists()
