"""Observed dots' output points: the least-squares point of their blobs' rays (``StatusConfig.ray_points``).

The candidates' DLT, its rows normalised as 4-vectors in world mm, weights each camera by where
the world's origin lies rather than by its error, so a camera seeing the tape at a grazing angle
pulls its points off; a ray's distance does not depend on the world frame (the reasons and numbers:
``docs/decisions/0001-ray-points-for-observed-dots.md``)."""

from __future__ import annotations

import dataclasses

import numpy as np
from tape_scenes import SPEC, blobs, tape_on_back

from spinemocap.camera import Camera, Rig
from spinemocap.geometry import triangulate_rays
from spinemocap.track.config import StatusConfig, TrackerConfig
from spinemocap.track.pipeline import FrameTracker


def rig_behind(shift: np.ndarray, grazing: bool = True) -> Rig:
    """Four cameras on a 120 degree arc 2 m behind the back (as test_track_stages' rig) plus one
    78 deg off the back's normal, everything moved by ``shift`` (mm)."""
    angles = [*np.linspace(-60, 60, 4), *([78.0] if grazing else [])]
    cams = []
    for k, a in enumerate(np.deg2rad(angles)):
        pos = np.array((2000 * np.sin(a), 800 + 2000 * np.cos(a), 1300 + 150 * (k % 2))) + shift
        cams.append(Camera.look_at(f"cam{k + 1}", pos, np.array((0.0, 800.0, 1150.0)) + shift, (1280, 800), 1500.0))
    return Rig(cams)


def test_rays_meet_at_the_point_whatever_their_weights_and_a_zero_weight_drops_a_view():
    rig = rig_behind(np.zeros(3), grazing=False)
    centers = np.array([c.center for c in rig])
    point = np.array([[10.0, 780.0, 1020.0]])
    uv = np.stack([c.project(point) for c in rig], axis=1)  # (1, C, 2)

    def directions(pixels: np.ndarray) -> np.ndarray:
        return np.stack([c.rays(pixels[:, k])[1] for k, c in enumerate(rig)], axis=1)

    np.testing.assert_allclose(triangulate_rays(centers, directions(uv), np.array([[0.06, 0.6, 0.3, 0.1]])), point, atol=1e-6)
    off = uv.copy()
    off[0, 3] += 5.0  # camera 3's blob 5 px off
    assert np.linalg.norm(triangulate_rays(centers, directions(off), np.ones((1, 4))) - point) > 0.5
    np.testing.assert_allclose(triangulate_rays(centers, directions(off), np.array([[1.0, 1.0, 1.0, 0.0]])), point, atol=1e-6)
    assert np.isnan(triangulate_rays(centers, directions(uv), np.array([[1.0, 0.0, 0.0, 0.0]]))).all()


def test_observed_dots_stay_as_accurate_with_the_world_origin_far_away():
    """The same scene (cameras and back, the same 0.3 px blob noise) with the world's origin at
    the back and 7 m away: the rays' points stay within 0.45 mm on average, better than the DLT's
    points, which are 2x worse still with the origin far away (the candidates, DLT points, change
    with the origin too: the same blobs are not always grouped alike)."""
    errors = {}
    for ray_points in (True, False):
        config = TrackerConfig(status=dataclasses.replace(StatusConfig(), ray_points=ray_points))
        for shift in (0.0, 5000.0):
            rig, dots = rig_behind(np.array([shift, shift, 0.0])), tape_on_back(SPEC) + [shift, shift, 0.0]
            tracker = FrameTracker(rig, SPEC, config)
            result = tracker.assign_status(dots, tracker.candidates(blobs(rig, dots, noise_px=0.3, seed=2)))
            observed = result.status == "observed"
            assert observed.mean() > 0.9
            errors[ray_points, shift] = np.linalg.norm(result.positions - dots, axis=1)[observed].mean()
    assert StatusConfig().ray_points
    assert max(errors[True, 0.0], errors[True, 5000.0]) < 0.45, errors
    assert errors[False, 0.0] > errors[True, 0.0] and errors[False, 5000.0] > 2 * errors[True, 5000.0], errors
