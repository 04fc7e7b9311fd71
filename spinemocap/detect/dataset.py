"""Training data for the tape segmentation network: synthetic-studio renders and labelled lab images.

Every labelled image (BGR + bool tape mask at full resolution) becomes two *views* at working
resolution, the two inputs the detector feeds its network (see :mod:`spinemocap.detect.detector`):

- the whole frame reduced to ``WORK_WIDTH`` px wide (stage 1: where is the tape?);
- a crop around the tape, padded and reduced so its longer side is ``WORK_WIDTH`` px (stage 2:
  the tape's exact outline).

Views are stored as ``.npz`` shards (``image_###`` uint8 (h, w, 3), ``mask_###`` bool (h, w),
``split`` 'train'/'val'), one shard per synthetic scene or per lab image batch, so generation
is resumable shard by shard.

Lab data, as in the paper's 1988/631 train/val split idea: a folder ``images/`` with masks either
as PNGs in ``masks/`` (same file stem, any non-zero pixel is tape) or as a COCO JSON with polygon
segmentations. Each image goes to validation when a hash of its stem falls below
``val_fraction`` (stable when images are added later).
"""

from __future__ import annotations

import json
import logging
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..capture import read_image
from ..fileio import InputError, atomic_path
from ..media import IMAGE_SUFFIXES

log = logging.getLogger(__name__)

WORK_WIDTH = 256          # stage-1 frame width and stage-2 crop long side, px
CROP_PAD = 0.5            # stage-2 crop: tape box grown by this fraction of its size on each side
AREA_PRESTEP = 2          # frame_view's integer area step before the final area resize (1: none)


# ---------------------------------------------------------------------------------- views
def area_reduced(image: np.ndarray, size: tuple[int, int], prestep: int | None = None) -> np.ndarray:
    """``image`` reduced to ``size`` (w, h) px by area averaging, first by the integer factor
    ``prestep`` (default :data:`AREA_PRESTEP`; OpenCV's fast integer area path) where both sides
    divide by it and the image is at least twice ``prestep`` times ``size``, then by OpenCV's
    general area resize to ``size``. On a 2448x1600 studio image to 256 px wide, prestep 2 took
    ~6 ms instead of ~16 ms; its levels differ from the one-step area average by at most a few
    (the pre-step's rounding to uint8 and the destination cells' edges falling on half a source
    pixel). 1: the one-step area average."""
    k = AREA_PRESTEP if prestep is None else prestep
    h, w = image.shape[:2]
    if k > 1 and h % k == 0 and w % k == 0 and w >= 2 * k * size[0] and h >= 2 * k * size[1]:
        image = cv2.resize(image, (w // k, h // k), interpolation=cv2.INTER_AREA)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def frame_view(image: np.ndarray, mask: np.ndarray | None = None, width: int = WORK_WIDTH):
    """The whole frame at ``width`` px wide (area averaging, :func:`area_reduced`: the network's
    stage-1 input in training and detection alike); mask reduced by majority."""
    h, w = image.shape[:2]
    size = (width, max(8, int(round(h * width / w))))
    small = area_reduced(image, size)
    if mask is None:
        return small, None
    return small, cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5


def crop_box(mask: np.ndarray, pad: float = CROP_PAD, min_side: int = 32) -> tuple[slice, slice] | None:
    """Box around a mask's pixels grown by ``pad`` x its size per side (at least ``min_side``)."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return None
    h, w = mask.shape
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    py = max(pad * (y1 - y0), (min_side - (y1 - y0)) / 2, 4)
    px = max(pad * (x1 - x0), (min_side - (x1 - x0)) / 2, 4)
    return (slice(max(0, int(y0 - py)), min(h, int(np.ceil(y1 + py)))),
            slice(max(0, int(x0 - px)), min(w, int(np.ceil(x1 + px)))))


def crop_scale(box: tuple[slice, slice], long_side: int = WORK_WIDTH) -> float:
    """Factor that brings a box's longer side to ``long_side`` (never enlarges)."""
    ys, xs = box
    return min(1.0, long_side / max(ys.stop - ys.start, xs.stop - xs.start))


def crop_view(image: np.ndarray, mask: np.ndarray, box: tuple[slice, slice], long_side: int = WORK_WIDTH):
    """The crop ``box`` of image and mask, reduced so its longer side is at most ``long_side``."""
    s = crop_scale(box, long_side)
    img, m = image[box], mask[box].astype(np.float32)
    size = (max(8, int(round(img.shape[1] * s))), max(8, int(round(img.shape[0] * s))))
    return (cv2.resize(img, size, interpolation=cv2.INTER_AREA),
            cv2.resize(m, size, interpolation=cv2.INTER_AREA) >= 0.5)


def views_of(image: np.ndarray, mask: np.ndarray, rng: np.random.Generator | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """The stage-1 and (if the tape is visible) stage-2 views of one labelled image. With ``rng``
    the crop padding varies, so the network does not learn one fixed framing."""
    views = [frame_view(image, mask)]
    pad = CROP_PAD if rng is None else float(rng.uniform(0.2, 0.9))
    box = crop_box(mask, pad)
    if box is not None:
        views.append(crop_view(image, mask, box))
    return views


# ---------------------------------------------------------------------------------- shards
def save_shard(path: Path, views: list[tuple[np.ndarray, np.ndarray]], split: str, info: dict) -> None:
    arrays = {}
    for i, (img, m) in enumerate(views):
        arrays[f"image_{i:03d}"] = img
        arrays[f"mask_{i:03d}"] = m
    arrays["split"] = np.array(split)
    arrays["info"] = np.array(json.dumps(info))
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, allow_pickle=False, **arrays)


@dataclass
class ViewSet:
    """Views in memory: lists of uint8 BGR images and bool masks at working resolution."""

    images: list[np.ndarray]
    masks: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.images)

    def extend(self, other: "ViewSet") -> None:
        self.images += other.images
        self.masks += other.masks


def load_shards(folder: Path) -> tuple[ViewSet, ViewSet]:
    """All shards of a folder, split into (train, val)."""
    folder = Path(folder)
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise InputError(folder, "no training data shards (*.npz) found")
    train, val = ViewSet([], []), ViewSet([], [])
    for f in files:
        try:
            with np.load(f) as data:
                target = val if str(data["split"]) == "val" else train
                n = sum(1 for k in data.files if k.startswith("image_"))
                for i in range(n):
                    target.images.append(data[f"image_{i:03d}"])
                    target.masks.append(data[f"mask_{i:03d}"].astype(bool))
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f, f"damaged training data shard ({exc})") from exc
    return train, val


# ---------------------------------------------------------------------------------- synthetic
def split_of(stem: str, val_fraction: float) -> str:
    """'val' or 'train', stable per file stem (crc32 hash)."""
    return "val" if (zlib.crc32(stem.encode()) % 10_000) < val_fraction * 10_000 else "train"


def _images_in(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise InputError(folder, "image folder not found")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(folder, "no images (png/jpg/bmp/tif) in folder")
    return files


def read_mask_png(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """A label PNG: any non-zero pixel is tape. Must match the image size."""
    if not path.is_file():
        raise InputError(path, "mask file not found (expected the image's stem with .png in the masks folder)")
    m = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if m is None:
        raise InputError(path, "mask file is corrupt or not an image")
    if m.ndim == 3:
        m = m.max(axis=2)
    if m.shape != shape:
        raise InputError(path, f"mask size {m.shape[::-1]} differs from its image {shape[::-1]}")
    return m > 0


def read_coco_masks(path: Path) -> dict[str, list[list[np.ndarray]]]:
    """COCO JSON -> {file name: [polygons per annotation]} (polygons (K, 2) px). Only polygon
    segmentations are read; RLE annotations raise an InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "COCO annotation file not found")
    try:
        data = json.loads(path.read_text())
        names = {img["id"]: img["file_name"] for img in data["images"]}
        out: dict[str, list[list[np.ndarray]]] = {Path(n).name: [] for n in names.values()}
        for ann in data.get("annotations", []):
            seg = ann["segmentation"]
            if isinstance(seg, dict):
                raise InputError(path, f"annotation {ann.get('id')} uses RLE; export polygons instead")
            polys = [np.asarray(p, float).reshape(-1, 2) for p in seg if len(p) >= 6]
            out[Path(names[ann["image_id"]]).name].append(polys)
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(path, f"not a COCO annotation file ({exc.__class__.__name__}: {exc})") from exc
    return out


def rasterize_polygons(polygons: list[list[np.ndarray]], shape: tuple[int, int]) -> np.ndarray:
    """Fill every polygon of every annotation into one bool mask (H, W)."""
    m = np.zeros(shape, np.uint8)
    for polys in polygons:
        for p in polys:
            cv2.fillPoly(m, [np.round(p * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    return m.astype(bool)


def labelled_images(images: Path, masks: Path | None = None, coco: Path | None = None):
    """Yield (stem, image BGR, mask bool) for a lab data set (PNG masks or COCO polygons)."""
    if (masks is None) == (coco is None):
        raise ValueError("give exactly one of masks (PNG folder) or coco (JSON file)")
    polygons = read_coco_masks(coco) if coco is not None else None
    for path in _images_in(Path(images)):
        image = read_image(path)
        if polygons is not None:
            if path.name not in polygons:
                log.warning("%s: not in %s, skipped", path, coco)
                continue
            mask = rasterize_polygons(polygons[path.name], image.shape[:2])
        else:
            assert masks is not None  # exactly one of masks and coco, checked above
            mask = read_mask_png(Path(masks) / f"{path.stem}.png", image.shape[:2])
        yield path.stem, image, mask


def import_labelled(out: Path, images: Path, masks: Path | None = None, coco: Path | None = None,
                    val_fraction: float = 0.24, seed: int = 0) -> tuple[int, int]:
    """Turn a lab data set into shards under ``out`` (one per image). The default split, 24 % to
    validation, is the paper's 631 of 2619. Returns (n_train, n_val) images."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    counts = {"train": 0, "val": 0}
    for stem, image, mask in labelled_images(images, masks, coco):
        split = split_of(stem, val_fraction)
        rng = np.random.default_rng([seed, zlib.crc32(stem.encode())])
        save_shard(out / f"lab_{stem}.npz", views_of(image, mask, rng), split, {"source": stem})
        counts[split] += 1
    if counts["train"] == 0:
        raise InputError(images, "no labelled image landed in the training split (too few images?)")
    return counts["train"], counts["val"]
