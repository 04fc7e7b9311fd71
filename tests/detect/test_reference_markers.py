"""The reference object's markers in one image: each found near where the given camera predicts
it, its centre refined on the disc itself (a bright surround on one side does not pull it), and
a marker hidden, doubled or without an edge in the image left out (NaN)."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.camera import Camera
from spinemocap.detect.reference import disc_centre, faint_rim_share, find_reference_markers
from spinemocap.reference import ReferenceObject
from spinemocap.synth.reference import STUDIO_ROTATION
from spinemocap.synth.wand import render_wand_frame

REFERENCE = ReferenceObject.lframe(STUDIO_ROTATION, np.array([120.0, 800.0, 1000.0]))


def _disc(size: tuple[int, int], centre: tuple[float, float], radius: float, inside: float = 235.0,
          left: float = 30.0, right: float = 30.0) -> np.ndarray:
    """A grey image: a disc (8x8 supersampled coverage) on a surround of ``left`` / ``right``
    grey levels either side of the disc's centre."""
    w, h = size
    sub = (np.arange(8) + 0.5) / 8
    ys = (np.arange(h)[:, None] + sub[None]).ravel() - 0.5
    xs = (np.arange(w)[:, None] + sub[None]).ravel() - 0.5
    cover = ((ys[:, None] - centre[1]) ** 2 + (xs[None] - centre[0]) ** 2 <= radius**2)
    cover = cover.reshape(h, 8, w, 8).mean(axis=(1, 3))
    surround = np.where(np.arange(w)[None] < centre[0], left, right) * np.ones((h, 1))
    return np.round(surround * (1 - cover) + inside * cover).astype(np.uint8)


@pytest.mark.parametrize("left, right", [(30.0, 30.0), (30.0, 160.0)])
def test_the_disc_centre_is_sub_pixel_whatever_the_surround(left, right):
    truth = np.array([40.3, 37.6])
    grey = _disc((80, 72), tuple(truth), 6.0, left=left, right=right)
    found = disc_centre(grey, truth + [0.8, -0.6], 6.0)
    np.testing.assert_allclose(found, truth, atol=0.05)


def test_a_disc_without_an_edge_is_left_out_and_a_faint_one_kept_where_it_was():
    truth = (40.3, 37.6)
    no_edge = _disc((80, 72), truth, 6.0, left=30.0, right=225.0)  # one side as bright as the marker
    assert faint_rim_share(no_edge, np.array(truth), 6.0) > 0.1
    assert np.isnan(disc_centre(no_edge, np.array(truth), 6.0)).all()
    faint = _disc((80, 72), truth, 6.0, inside=40.0)  # not 15 grey levels above the surround
    np.testing.assert_array_equal(disc_centre(faint, np.array([41.0, 37.0]), 6.0), [41.0, 37.0])


def _given(camera: Camera, shift_px: float) -> Camera:
    """``camera`` with its principal point moved ``shift_px``: a calibration a few px off."""
    K = camera.K.copy()
    K[0, 2] += shift_px
    return Camera(camera.name, K, camera.dist, camera.R, camera.t, camera.size)


def test_markers_found_near_the_prediction_hidden_and_doubled_ones_nan():
    camera = Camera.look_at("cam1", (0.0, 2800.0, 1300.0), (0.0, 800.0, 1150.0), (1280, 800), 2000.0)
    world = REFERENCE.world_mm
    quiet = np.zeros((camera.size[1], camera.size[0]), np.float32)
    shown = [0, 1, 2, 4]  # REF4 hidden
    image = render_wand_frame(camera, world[shown], REFERENCE.marker_diameter_mm / 2, quiet)
    found = find_reference_markers(image, _given(camera, 4.0), REFERENCE)
    truth = camera.project(world)
    np.testing.assert_allclose(found[shown], truth[shown], atol=0.1)
    assert np.isnan(found[3]).all()
    # a second bright ball beside REF1, within the search radius: REF1 is no longer trusted
    beside = world[0] + 20.0 * camera.R[1]  # ~20 px below it in the image, apart from it
    doubled = render_wand_frame(camera, np.vstack([world[shown], beside]), REFERENCE.marker_diameter_mm / 2, quiet)
    again = find_reference_markers(doubled, _given(camera, 4.0), REFERENCE)
    assert np.isnan(again[0]).all() and np.isfinite(again[[1, 2, 4]]).all()
