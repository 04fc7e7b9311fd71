"""Training data (PNG masks, COCO polygons, shards) and the training loop, on drawn images."""

import json

import cv2
import numpy as np
import pytest

from spinemocap.detect.dataset import ViewSet, import_labelled, load_shards, read_coco_masks, split_of, views_of
from spinemocap.detect.detector import shipped_weights_path
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.segnet import load_weights
from spinemocap.detect.train import TrainSettings, train
from spinemocap.fileio import InputError


def _lab_folder(tmp_path, n=8):
    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir()
    masks.mkdir()
    coco = {"images": [], "annotations": [], "categories": [{"id": 1, "name": "tape"}]}
    truth = {}
    for i in range(n):
        s = draw_sample(np.random.default_rng(i), size=(200, 160), px_per_mm=0.7, supersample=2)
        name = f"img{i:02d}.png"
        cv2.imwrite(str(images / name), s.image)
        cv2.imwrite(str(masks / name), s.mask.astype(np.uint8) * 255)
        truth[name] = s.mask
        contours, _ = cv2.findContours(s.mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        coco["images"].append({"id": i, "file_name": name, "width": 200, "height": 160})
        for c in contours:
            coco["annotations"].append({"id": len(coco["annotations"]), "image_id": i, "category_id": 1,
                                        "segmentation": [c.reshape(-1).astype(float).tolist()]})
    (tmp_path / "tape.json").write_text(json.dumps(coco))
    return images, masks, tmp_path / "tape.json", truth


def test_png_and_coco_labels_give_the_same_views(tmp_path):
    images, masks, coco, truth = _lab_folder(tmp_path)
    n_png = import_labelled(tmp_path / "png", images, masks=masks, val_fraction=0.3)
    n_coco = import_labelled(tmp_path / "coco", images, coco=coco, val_fraction=0.3)
    assert n_png == n_coco and sum(n_png) == 8 and n_png[1] == sum(split_of(f"img{i:02d}", 0.3) == "val" for i in range(8))
    png_train, png_val = load_shards(tmp_path / "png")
    coco_train, coco_val = load_shards(tmp_path / "coco")
    assert len(png_train) == 2 * n_png[0] and len(png_val) == 2 * n_png[1]  # frame view + crop view each
    for a, b in zip(png_train.masks, coco_train.masks):
        iou = (a & b).sum() / (a | b).sum()
        assert iou > 0.9  # polygon outline vs pixel mask: differ by the boundary pixels only


def test_bad_labels_name_the_file(tmp_path):
    images, masks, coco, _ = _lab_folder(tmp_path, n=2)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match="bad.json"):
        read_coco_masks(tmp_path / "bad.json")
    cv2.imwrite(str(masks / "img00.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError, match="img00.png.*differs"):
        import_labelled(tmp_path / "out", images, masks=masks)
    (images / "img01.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="img01.png"):
        import_labelled(tmp_path / "out2", images, coco=coco)


def test_training_loop_learns_resumes_and_exports(tmp_path):
    rng = np.random.default_rng(0)
    train_views, val_views = ViewSet([], []), ViewSet([], [])
    for i in range(10):
        s = draw_sample(rng, size=(192, 144), px_per_mm=0.6, supersample=2)
        target = val_views if i >= 8 else train_views
        for img, m in views_of(s.image, s.mask, rng):
            target.images.append(img)
            target.masks.append(m)
    settings = TrainSettings(epochs=2, steps=12, batch=6, crop=64, lr=1e-2, channels=(8, 12, 16), threads=1)
    out = tmp_path / "run"
    meta = train(train_views, val_views, out, dataclass_replace(settings, epochs=1), provenance={"command": "test"}, progress=False)
    assert len(meta["history"]) == 1
    meta = train(train_views, val_views, out, settings, provenance={"command": "test"}, progress=False)
    assert [h["epoch"] for h in meta["history"]] == [1, 2]  # resumed, not restarted
    assert meta["history"][1]["loss"] < meta["history"][0]["loss"]
    assert meta["val_iou"] > 0.5  # a dark stripe on skin is learnt within two tiny epochs
    model, stored = load_weights(out / "weights.pt")
    assert stored["command"] == "test" and json.loads((out / "weights.json").read_text())["best_epoch"] in (1, 2)
    assert (out / "training.png").is_file()


def dataclass_replace(obj, **changes):
    import dataclasses

    return dataclasses.replace(obj, **changes)


def test_damaged_weights_file_is_named(tmp_path):
    bad = tmp_path / "w.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(InputError, match="w.pt"):
        load_weights(bad)
    with pytest.raises(InputError, match="not found"):
        load_weights(tmp_path / "missing.pt")


def test_cli_finetune_from_shipped_weights_on_coco_labels(tmp_path, capsys):
    from spinemocap.cli import main
    from spinemocap.detect import Detector

    images, _, coco, truth = _lab_folder(tmp_path, n=6)
    out = tmp_path / "lab"
    assert main(["detector", "finetune", "--images", str(images), "--coco", str(coco), "--out", str(out),
                 "--epochs", "1", "--steps", "2", "--batch", "2", "--crop", "64", "--val-fraction", "0.3"]) == 0
    assert "validation IoU" in capsys.readouterr().out
    meta = json.loads((out / "weights.json").read_text())
    assert meta["init_weights"].endswith(shipped_weights_path().name) and meta["data"]["kind"] == "lab"
    assert meta["command"].startswith("spinemocap detector finetune") and "--epochs 1" in meta["command"]
    det = Detector("net", weights=out / "weights.pt")
    assert det.segment(cv2.imread(str(images / "img00.png"))).shape == truth["img00.png"].shape


def _exact_area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in): destination cell j's share of source pixel i (the overlap of
    [j, j + 1) * n_in / n_out with [i, i + 1), over the cell's length)."""
    scale = n_in / n_out
    lo, hi = np.arange(n_out)[:, None] * scale, (np.arange(n_out)[:, None] + 1) * scale
    px = np.arange(n_in)[None, :]
    return np.clip(np.minimum(hi, px + 1) - np.maximum(lo, px), 0, None) / scale


def _exact_area_average(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (H, W, 3) averaged over the destination cells of ``size`` (w, h), float."""
    wy, wx = _exact_area_weights(image.shape[0], size[1]), _exact_area_weights(image.shape[1], size[0])
    return np.stack([wy @ image[..., c].astype(np.float64) @ wx.T for c in range(3)], axis=-1)


def test_stage1_area_resize_is_close_to_the_exact_area_average_on_a_random_image():
    from spinemocap.detect.dataset import AREA_PRESTEP, area_reduced, frame_view

    assert AREA_PRESTEP > 1
    k = AREA_PRESTEP
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (800, 1224, 3), dtype=np.uint8)   # the studio's aspect, a quarter of the pixels
    small, _ = frame_view(image, width=128)
    h, w = small.shape[:2]
    exact = _exact_area_average(image, (w, h))
    # the one-step area resize is the exact average up to rounding
    assert np.abs(area_reduced(image, (w, h), prestep=1) - exact).max() <= 0.5 + 1e-3
    # with the pre-step a cell's edge that falls inside a block of k source px shares the block
    # evenly: the weights move by at most 2 (k - 1) / k px (L1) at each of the cell's two edges
    # per axis, over the cell's scale px; the levels by half the L1 times 255, plus the
    # pre-step's and the final rounding
    scale = 1224 / w
    assert np.abs(small - exact).max() <= 0.5 * 255 * (2 * 2 * 2 * (k - 1) / k) / scale + 1.0
    # an image constant over k x k blocks loses nothing in the pre-step: the exact average
    blocks = np.repeat(np.repeat(image[: 800 // k, : 1224 // k], k, axis=0), k, axis=1)
    assert np.abs(frame_view(blocks, width=128)[0] - _exact_area_average(blocks, (w, h))).max() <= 0.5 + 1e-3
