"""The waved wand: its markers keep their geometry along a smooth seeded motion, and each sphere
is drawn as a bright disc centred where the camera projects it; a sphere hidden behind a nearer one
or behind the camera adds nothing."""

from __future__ import annotations

import numpy as np
import pytest
from tape_scenes import rig_behind

from spinemocap.synth.wand import render_wand_frame, wand_trajectory

WAND = np.array([[0.0, 0.0, 0.0], [250.0, 0.0, 0.0], [500.0, 0.0, 0.0], [100.0, 300.0, 0.0]])


def test_the_wand_moves_rigidly_and_smoothly():
    times = np.arange(0, 2.0, 0.01)
    path = wand_trajectory(times, WAND, seed=4, centre_mm=(0.0, 800.0, 1150.0))
    assert path.shape == (len(times), len(WAND), 3)
    pairs = np.linalg.norm(path[:, :, None] - path[:, None], axis=3)
    np.testing.assert_allclose(pairs, np.broadcast_to(np.linalg.norm(WAND[:, None] - WAND[None], axis=2), pairs.shape),
                               atol=1e-9)
    np.testing.assert_allclose(path.mean(axis=1).mean(axis=0), (0.0, 800.0, 1150.0), atol=400)
    assert np.abs(np.diff(path, axis=0)).max() < 40  # mm per 10 ms: a hand's wave, no jumps
    np.testing.assert_array_equal(path, wand_trajectory(times, WAND, seed=4, centre_mm=(0.0, 800.0, 1150.0)))
    assert not np.allclose(path, wand_trajectory(times, WAND, seed=5, centre_mm=(0.0, 800.0, 1150.0)))


def _centroid(image: np.ndarray, centre: np.ndarray, reach: int) -> np.ndarray:
    u0, v0 = (np.round(centre) - reach).astype(int)
    patch = image[v0:v0 + 2 * reach + 1, u0:u0 + 2 * reach + 1].astype(float) - 25.0
    vv, uu = np.mgrid[v0:v0 + 2 * reach + 1, u0:u0 + 2 * reach + 1]
    weight = np.clip(patch, 0, None)
    return np.array([(uu * weight).sum(), (vv * weight).sum()]) / weight.sum()


def test_each_sphere_is_a_disc_at_its_projection():
    cam = rig_behind(1)[0]
    markers = np.array([[-150.0, 800.0, 1150.0], [150.0, 800.0, 1200.0]])
    image = render_wand_frame(cam, markers, radius_mm=7.0, noise=np.zeros((cam.size[1], cam.size[0]), np.float32))
    assert image.shape == (cam.size[1], cam.size[0]) and image.dtype == np.uint8
    for centre in cam.project(markers):
        np.testing.assert_allclose(_centroid(image, centre, 10), centre, atol=0.05)
        assert image[int(round(centre[1])), int(round(centre[0]))] > 200
    assert np.median(image) == 25


def test_hidden_spheres_and_spheres_behind_the_camera_add_nothing():
    cam = rig_behind(1)[0]
    near, far = cam.center + 0.3 * (np.array([0.0, 800.0, 1150.0]) - cam.center), np.array([0.0, 800.0, 1150.0])
    behind = cam.center - 500 * cam.R[2]  # behind the camera: not drawn
    quiet = np.zeros((cam.size[1], cam.size[0]), np.float32)
    alone = render_wand_frame(cam, np.array([near]), 7.0, quiet)
    both = render_wand_frame(cam, np.array([near, far, behind]), 7.0, quiet)
    np.testing.assert_array_equal(alone, both)  # the far sphere lies wholly behind the near one
    with pytest.raises(AssertionError):
        np.testing.assert_array_equal(alone, render_wand_frame(cam, np.array([far]), 7.0, quiet))
