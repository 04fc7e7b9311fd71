"""The detector run on files: every frame asked of a video named by its frame, each image's dots
written as CSV (the detector's dots, in order) with an overlay beside it, nothing written without
an output folder, and a folder that is not a capture refused."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spinemocap.app.detector_run import detect_inputs, input_images
from spinemocap.detect import Detector
from spinemocap.detect.drawn import draw_sample
from spinemocap.fileio import InputError
from spinemocap.media import VideoWriter, read_image


def _images(n: int) -> list[np.ndarray]:
    return [draw_sample(np.random.default_rng(20 + k), size=(480, 360), px_per_mm=1.2).image for k in range(n)]


def test_a_video_gives_the_frames_asked_for_by_name(tmp_path):
    images = _images(3)
    writer = VideoWriter(tmp_path / "cam.avi", 30.0, (480, 360))
    for image in images:
        writer.write(image)
    writer.close()
    got = list(input_images(tmp_path / "cam.avi", "1:3"))
    assert [name for name, _ in got] == ["cam_f000001", "cam_f000002"]
    for (_, image), expected in zip(got, images[1:]):
        np.testing.assert_array_equal(image, expected)  # lossless


def test_each_image_detected_and_written(tmp_path):
    image = _images(1)[0]
    cv2.imwrite(str(tmp_path / "a.png"), image)
    detector = Detector("classical")
    assert [f.name for f in detect_inputs(detector, [tmp_path / "a.png"])] == ["a"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]  # nothing written without ``out``
    out = tmp_path / "o"
    (found,) = detect_inputs(detector, [tmp_path / "a.png"], out=out)
    expected = detector.detect(image)
    np.testing.assert_array_equal(found.dots.uv, expected.uv)
    assert found.tape_px == int(expected.tape_mask.sum()) > 0
    assert found.tape_share == pytest.approx(100.0 * found.tape_px / (480 * 360))
    rows = (out / "a_dots.csv").read_text().splitlines()
    assert rows[0] == "u_px,v_px,confidence" and len(rows) - 1 == len(expected.uv) > 0
    np.testing.assert_allclose(np.loadtxt(out / "a_dots.csv", delimiter=",", skiprows=1)[:, :2], expected.uv, atol=5e-4)
    overlay = read_image(out / "a_overlay.png")
    assert overlay.shape == image.shape and np.any(overlay != image)


def test_a_folder_that_is_not_a_capture_is_refused(tmp_path):
    (tmp_path / "plain").mkdir()
    with pytest.raises(InputError, match="must be a capture"):
        list(input_images(tmp_path / "plain", "0:1"))
