"""The shipped network on a freshly rendered capture, the Detector API, and bad image files."""

import json

import numpy as np
import pytest

from spinemocap.cli import main
from spinemocap.detect import Detector, shipped_weights_path
from spinemocap.detect.drawn import draw_sample
from spinemocap.fileio import InputError


@pytest.fixture(scope="module")
def tiny_render():
    """A tiny studio capture with a body, seed and lighting never used for training."""
    from spinemocap.app.training_data import HELD_OUT_SEED_BASE
    from spinemocap.bench.detect import surface_uv
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("tiny", frames=1, seed=HELD_OUT_SEED_BASE + 7,
                                           phenotype={"weight": 0.7, "gender": 0.2}, skin_tone=0.5))
    rendered = scene.render(0)
    uv, visible, dot_px = surface_uv(scene, 0)
    scene.close()
    return rendered, uv, visible


def test_shipped_weights_load_with_their_provenance():
    path = shipped_weights_path()
    assert path.is_file() and path.stat().st_size < 5e6
    info = json.loads(path.with_suffix(".json").read_text())
    assert info["command"].startswith("spinemocap detector train") and "seed" in info["train_settings"]
    assert Detector("net").segment(np.zeros((120, 160, 3), np.uint8)).shape == (120, 160)


def test_shipped_network_segments_a_fresh_render(tiny_render):
    rendered, uv, visible = tiny_render
    det = Detector("net")
    for c, (image, truth) in enumerate(zip(rendered.images, rendered.masks)):
        mask = det.segment(image)
        iou = (mask & truth).sum() / (mask | truth).sum()
        assert iou > 0.85, f"camera {c}: IoU {iou:.3f}"
        dots = det.detect(image, camera=c)
        gt = uv[c][visible[c]]
        d = np.linalg.norm(dots.uv[:, None] - gt[None], axis=2)
        assert len(dots) == len(gt)
        assert np.all(d.min(axis=0) < 1.0)                       # every visible dot found ...
        assert np.sqrt(np.mean(d.min(axis=0) ** 2)) < 0.3        # ... at sub-pixel accuracy
        assert dots.image.shape == truth.shape and dots.mask.dtype == bool


def test_blob_centres_in_exact_mask_match_ground_truth(tiny_render):
    from spinemocap.detect.blobs import find_dots

    rendered, uv, visible = tiny_render
    errors = []
    for c, (image, truth) in enumerate(zip(rendered.images, rendered.masks)):
        found, _ = find_dots(image, truth)
        gt = uv[c][visible[c]]
        d = np.linalg.norm(found[:, None] - gt[None], axis=2)
        assert len(found) == len(gt)
        errors += list(d.min(axis=0))
    assert max(errors) < 0.6 and np.sqrt(np.mean(np.square(errors))) < 0.25


def test_frame_without_tape_gives_no_dots():
    rng = np.random.default_rng(0)
    image = np.clip(rng.normal(128, 20, (360, 480, 3)), 0, 255).astype(np.uint8)
    for name in ("net", "classical"):
        dots = Detector(name).detect(image, camera=2)
        assert len(dots) == 0 and dots.camera == 2 and dots.uv.shape == (0, 2)


def test_classical_detector_on_drawn_tape():
    sample = draw_sample(np.random.default_rng(2), size=(480, 360), px_per_mm=1.2, noise=2)
    det = Detector("classical")
    mask = det.segment(sample.image)
    assert (mask & sample.mask).sum() / (mask | sample.mask).sum() > 0.9
    assert len(det.instances(sample.image)) == 1


def test_two_stripes_are_two_instances():
    sample = draw_sample(np.random.default_rng(4), size=(480, 360), px_per_mm=0.9, n_stripes=2, n_rows=5)
    instances = Detector("classical").instances(sample.image)
    assert len(instances) == 2


def test_missing_or_corrupt_image_file_is_named(tmp_path, capsys):
    bad = tmp_path / "cam1_000.png"
    bad.write_bytes(b"\x89PNG garbage")
    det = Detector("classical")
    with pytest.raises(InputError, match="cam1_000.png.*corrupt"):
        det.detect_file(bad)
    with pytest.raises(InputError, match="nothere.png.*not found"):
        det.detect_file(tmp_path / "nothere.png")
    assert main(["detector", "run", str(bad), "--name", "classical"]) == 2
    assert "cam1_000.png" in capsys.readouterr().err


def test_cli_run_writes_dots_and_overlay(tmp_path):
    import cv2

    sample = draw_sample(np.random.default_rng(3), size=(480, 360), px_per_mm=1.2)
    cv2.imwrite(str(tmp_path / "a.png"), sample.image)
    assert main(["detector", "run", str(tmp_path / "a.png"), "--name", "classical", "--out", str(tmp_path / "o")]) == 0
    rows = (tmp_path / "o" / "a_dots.csv").read_text().splitlines()
    assert rows[0] == "u_px,v_px,confidence" and len(rows) - 1 == len(sample.uv)
    assert (tmp_path / "o" / "a_overlay.png").is_file()


def test_unknown_detector_name():
    with pytest.raises(ValueError, match="unknown detector"):
        Detector("maskrcnn-please")


def test_growing_stage2_box_pastes_the_mask_of_the_final_box(monkeypatch):
    """A tape running out of every box makes the box grow max_grow times; the mask pasted into
    the frame must be the one computed for the final box, not an earlier box's (a broadcast
    error on bent tapes)."""
    from spinemocap.detect.detector import NetSegmenter

    seg = NetSegmenter(max_grow=1)

    def coarse_logits(views):  # stage 1 (batched): one small tape component in the middle of each view
        logits = np.full(views.shape[:3], -5.0, np.float32)
        h, w = logits.shape[1:]
        logits[:, h // 2 - 2: h // 2 + 2, w // 2 - 2: w // 2 + 2] = 5.0
        return logits

    refined_boxes = []

    def net_says_everything(image, box):  # stage 2 says: tape everywhere in the box (touches its edges)
        refined_boxes.append(box)
        return np.ones((box[0].stop - box[0].start, box[1].stop - box[1].start), bool)

    monkeypatch.setattr(seg, "_logits_batch", coarse_logits)
    monkeypatch.setattr(seg, "_net_mask", net_says_everything)
    mask = seg(np.zeros((960, 1280, 3), np.uint8))
    final = refined_boxes[-1]
    assert len(refined_boxes) == 2  # the first box, then one growth
    assert mask[final].all() and mask.sum() == mask[final].size
