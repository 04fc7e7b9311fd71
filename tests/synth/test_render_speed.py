"""The fast studio renderer (only the scene's rectangle rasterised, developing on worker threads,
mask resampled around the tape, in-place sensor noise) gives the ground truth and the masks of
the renderer as first written (its reference path, kept as the peer of ``spinemocap bench
render``), and its images up to rounding on a few anti-aliased edge pixels."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.camera import Camera
from spinemocap.synth import SynthConfig, build_scene
from spinemocap.synth.render import Appearance, CameraRenderer


@pytest.fixture(scope="module")
def lab_scene():
    """The studio's wide layout, small images, at the lab level (noise, sync offsets), with a band:
    the body covers a third to a half of each view, so the rasterised window is smaller."""
    config = SynthConfig.preset("studio", cameras=3, size=(640, 420), frames=3, band=True, seed=5, realism="lab")
    scene = build_scene(config)
    yield scene
    scene.close()


def assert_same_frames(fast, reference) -> None:
    """Masks identical; images identical but for rare edge pixels where the window's shifted
    projection rounds an anti-aliasing sample the other way (<= 3.4e-5 of the values)."""
    for c, (image, expected) in enumerate(zip(fast.images, reference.images)):
        assert image.dtype == np.uint8 and image.shape == expected.shape
        diff = np.abs(image.astype(int) - expected.astype(int))
        assert (diff > 0).mean() < 1e-3 and diff.mean() < 0.01, (c, (diff > 0).mean(), diff.mean())
    assert sum(int(m.sum()) for m in reference.masks) > 500  # the tape is in view
    for mask, expected in zip(fast.masks, reference.masks):
        np.testing.assert_array_equal(mask, expected)


def test_fast_render_matches_reference_render_and_keeps_the_ground_truth(lab_scene):
    before = {key: value.copy() for key, value in lab_scene.frame_groundtruth(2).items()}
    for frame in (0, 2):
        assert_same_frames(lab_scene.render(frame), lab_scene.render(frame, reference=True))
    for renderer in lab_scene.renderers:  # the fast path really rasterised a smaller window
        assert renderer._scene_window_size[0] < 0.7 * renderer.canvas_size[0]
    after = lab_scene.frame_groundtruth(2)
    for key, value in before.items():
        np.testing.assert_array_equal(after[key], value, err_msg=key)
    images_only = lab_scene.render(1, with_masks=False)
    assert images_only.masks == [None] * len(lab_scene.rig)
    reference = lab_scene.render(1, reference=True)
    assert np.abs(images_only.images[1].astype(int) - reference.images[1]).mean() < 0.01


def test_fast_render_with_motion_blur_equals_reference_render(lab_scene, monkeypatch):
    monkeypatch.setattr(lab_scene.config, "blur", 0.5)  # seven instants averaged per image
    assert_same_frames(lab_scene.render(1), lab_scene.render(1, reference=True))


def test_fast_render_with_a_rolling_shutter_equals_reference_render(lab_scene, monkeypatch):
    from spinemocap.synth.appearance import CameraLook

    cameras = len(lab_scene.rig)
    monkeypatch.setattr(lab_scene, "camera_looks", [CameraLook(readout_ms=80.0)] * cameras)
    monkeypatch.setattr(lab_scene, "readout_s", np.full(cameras, 0.08))
    rolling = [lab_scene._shutter(c, float(lab_scene.times[1]), lab_scene.fps).row_weights is not None
               for c in range(cameras)]
    assert any(rolling)  # the rows blend several instants
    assert_same_frames(lab_scene.render(1), lab_scene.render(1, reference=True))


@pytest.mark.parametrize("noise", [0.0, 3.0])
@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_sensor_equals_reference_byte_for_byte(lab_scene, monkeypatch, noise, dtype):
    """Same normal draws, same float32 sums: the in-place sensor gives the reference's bytes for
    sharp (uint8) and motion-blurred (float32) images."""
    monkeypatch.setattr(lab_scene.config, "noise", noise)
    rgb = np.random.default_rng(1).uniform(0, 255, (40, 50, 3)).astype(dtype)
    np.testing.assert_array_equal(lab_scene._sensor(rgb, 7, 1), lab_scene._sensor_reference(rgb, 7, 1))


@pytest.fixture(scope="module")
def distorted_renderer():
    cam = Camera.look_at("c", (300, 2000, 1300), (0, 0, 1100), (320, 240), 450.0,
                         dist=(-0.25, 0.08, 0.001, -0.0008, 0), principal_point=(165.3, 114.6))
    tri = np.array([[0, 1, 2]])
    renderer = CameraRenderer(cam, tri, tri, tri, Appearance(skin_rgb=(0.8, 0.6, 0.5)))
    yield renderer
    renderer.close()


@pytest.mark.parametrize("corner", ["inside", "top_left", "bottom_right", "whole"])
@pytest.mark.parametrize("channels", [1, 3])
def test_window_resampling_equals_whole_canvas_resampling(distorted_renderer, corner, channels):
    """A window pasted on a uniform canvas (black, or the background colour): resampling only the
    block that can see it gives the pixels of resampling the whole canvas, also where the window
    touches the canvas' border."""
    renderer = distorted_renderer
    W, H = renderer.canvas_size
    cw, ch = {"whole": (W, H)}.get(corner, (37, 53))
    wx, wy = {"inside": (101, 62), "top_left": (0, 0), "bottom_right": (W - cw, H - ch), "whole": (0, 0)}[corner]
    shape = (ch, cw) if channels == 1 else (ch, cw, 3)
    fill = np.uint8(0) if channels == 1 else np.array([89, 92, 97], np.uint8)
    window = np.random.default_rng(3).integers(1, 256, shape, dtype=np.uint8)
    canvas = np.empty((H, W, *shape[2:]), np.uint8)
    canvas[...] = fill
    canvas[wy : wy + ch, wx : wx + cw] = window
    expected = renderer.through_lens(canvas)
    got = renderer._through_lens_window(window, wx, wy, fill=fill)
    assert expected.any()
    np.testing.assert_array_equal(got, expected)



def test_bench_render_refuses_unknown_presets_and_empty_runs(tmp_path, capsys):
    from spinemocap.cli import main

    assert main(["bench", "render", "--presets", "artificial,nope", "--out", str(tmp_path)]) == 2
    assert "unknown preset 'nope'" in capsys.readouterr().err
    assert main(["bench", "render", "--frames", "0", "--out", str(tmp_path)]) == 2
    assert "--frames >= 1" in capsys.readouterr().err
