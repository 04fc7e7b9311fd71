"""``spinemocap detector run`` on each kind of input: image files, videos and capture folders,
with the overlay of what it found."""

import cv2
import numpy as np

from spinemocap.capture import VideoWriter
from spinemocap.cli import main
from spinemocap.detect import Detector
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.overlay import DOT_COLOUR, MASK_COLOUR, draw_detections


def drawn(seed: int):
    return draw_sample(np.random.default_rng(seed), size=(480, 360), px_per_mm=1.2)


def dots_rows(path) -> int:
    rows = path.read_text().splitlines()
    assert rows[0] == "u_px,v_px,confidence"
    return len(rows) - 1


def test_overlay_outlines_the_mask_marks_the_dots_and_counts_them():
    sample = drawn(1)
    out = draw_detections(sample.image, sample.mask, sample.uv, np.ones(len(sample.uv)), "cam1")
    assert out.shape == sample.image.shape and out is not sample.image
    changed = np.any(out != sample.image, axis=2)
    # the outline: green pixels on the mask's edge; the dots: red at their centres
    edge = sample.mask & ~cv2.erode(sample.mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert (out[edge] == MASK_COLOUR).all(axis=1).mean() > 0.5
    for u, v in np.round(sample.uv).astype(int):
        assert tuple(out[v, u]) == DOT_COLOUR
    # the banner holds the counts; away from the drawing the image is unchanged
    assert changed[:12].any() and not changed[-20:, :20].any()
    empty = draw_detections(sample.image, np.zeros_like(sample.mask), np.zeros((0, 2)))
    assert not np.any(empty[60:] != sample.image[60:])


def test_run_on_images_and_a_video(tmp_path, capsys):
    samples = [drawn(3), drawn(4)]
    cv2.imwrite(str(tmp_path / "a.png"), samples[0].image)
    video = VideoWriter(tmp_path / "cam.avi", 50.0, (480, 360))
    for s in samples:
        video.write(s.image)
    video.close()
    out = tmp_path / "o"
    assert main(["detector", "run", str(tmp_path / "a.png"), str(tmp_path / "cam.avi"), "--frames", "0:2",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    expected = {"a": samples[0], "cam_f000000": samples[0], "cam_f000001": samples[1]}
    detector = Detector("net")
    for name, sample in expected.items():
        assert f"{name}: " in printed
        found = detector.detect(sample.image)  # the video is lossless: the same dots as the image
        assert dots_rows(out / f"{name}_dots.csv") == len(found.uv) >= len(sample.uv) - 1
        overlay = cv2.imread(str(out / f"{name}_overlay.png"))
        assert overlay.shape == sample.image.shape and np.any(overlay != sample.image)


def test_run_on_a_capture_folder_reads_every_camera(tmp_path, capsys):
    from spinemocap.synth import SynthConfig
    from spinemocap.synth.writer import write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=2, seed=11), tmp_path / "cap", progress=False)
    out = tmp_path / "o"
    assert main(["detector", "run", str(root), "--frames", "1:2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    overlays = sorted(p.name for p in out.glob("*_overlay.png"))
    assert len(overlays) == 3 and all("_f000001_" in name for name in overlays)
    assert sum(dots_rows(p) for p in out.glob("*_dots.csv")) > 10  # the tape's dots, seen by the cameras
    assert printed.count(" dots, tape mask ") == 3


def test_run_names_a_folder_that_is_not_a_capture(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["detector", "run", str(tmp_path / "empty")]) == 2
    assert "capture.toml" in capsys.readouterr().err
