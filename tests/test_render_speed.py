"""The fast studio renderer (threaded developing, mask resampled around the tape, in-place
sensor noise) gives the pixels of the renderer as first written (its reference
path, kept as the peer of ``spinemocap bench render``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spinemocap.camera import Camera
from spinemocap.synth import SynthConfig, build_scene
from spinemocap.synth.render import Appearance, CameraRenderer


@pytest.fixture(scope="module")
def lab_scene():
    """Tiny rig at the lab level (noise, sync offsets), a band and falling balls."""
    config = SynthConfig.preset("tiny", frames=3, rows=7, band=True, band_level="T12", balls=2500, seed=5,
                                realism="lab")
    scene = build_scene(config)
    yield scene
    scene.close()


def assert_same_frames(fast, reference) -> None:
    for c, (image, expected) in enumerate(zip(fast.images, reference.images)):
        assert image.dtype == np.uint8 and image.shape == expected.shape
        np.testing.assert_array_equal(image, expected, err_msg=f"camera {c}")
    for mask, expected in zip(fast.masks, reference.masks):
        assert expected.sum() > 100  # the tape is in view: the comparison means something
        np.testing.assert_array_equal(mask, expected)


def test_fast_render_equals_reference_render(lab_scene):
    """Images (with sensor noise) and tape masks are identical, pixel for pixel."""
    for frame in (0, 2):
        fast = lab_scene.render(frame)
        assert_same_frames(fast, lab_scene.render(frame, reference=True))
    images_only = lab_scene.render(1, with_masks=False)
    assert images_only.masks == [None] * len(lab_scene.rig)
    np.testing.assert_array_equal(images_only.images[1], lab_scene.render(1, reference=True).images[1])


def test_fast_render_with_motion_blur_equals_reference_render(lab_scene, monkeypatch):
    monkeypatch.setattr(lab_scene.config, "blur", 0.5)  # seven instants averaged per image
    assert_same_frames(lab_scene.render(1), lab_scene.render(1, reference=True))


def test_sensor_without_noise_equals_reference(lab_scene, monkeypatch):
    monkeypatch.setattr(lab_scene.config, "noise", 0.0)
    rgb = np.random.default_rng(1).uniform(0, 255, (40, 50, 3)).astype(np.float32)
    np.testing.assert_array_equal(lab_scene._sensor(rgb, 0, 1), lab_scene._sensor_reference(rgb, 0, 1))


@pytest.fixture(scope="module")
def distorted_renderer():
    cam = Camera.look_at("c", (300, 2000, 1300), (0, 0, 1100), (320, 240), 450.0,
                         dist=(-0.25, 0.08, 0.001, -0.0008, 0), principal_point=(165.3, 114.6))
    tri = np.array([[0, 1, 2]])
    renderer = CameraRenderer(cam, tri, tri, tri, Appearance(skin_rgb=(0.8, 0.6, 0.5)))
    yield renderer
    renderer.close()


@pytest.mark.parametrize("corner", ["inside", "top_left", "bottom_right", "whole"])
def test_window_resampling_equals_whole_canvas_resampling(distorted_renderer, corner):
    """A window pasted on a black canvas: resampling only the block that can see it gives the
    pixels of resampling the whole canvas, also where the window touches the canvas' border."""
    renderer = distorted_renderer
    W, H = renderer.canvas_size
    cw, ch = {"whole": (W, H)}.get(corner, (37, 53))
    wx, wy = {"inside": (101, 62), "top_left": (0, 0), "bottom_right": (W - cw, H - ch), "whole": (0, 0)}[corner]
    window = np.random.default_rng(3).integers(1, 256, (ch, cw), dtype=np.uint8)
    canvas = np.zeros((H, W), np.uint8)
    canvas[wy : wy + ch, wx : wx + cw] = window
    expected = cv2.remap(canvas, renderer.map_x, renderer.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    got = renderer._through_lens_window(window, wx, wy)
    assert expected.any()
    np.testing.assert_array_equal(got, expected)
