"""Split a tape mask into instances (separate stripes, or pieces of one stripe cut by an occluder)."""

from __future__ import annotations

import cv2
import numpy as np

from .blobs import labelled_components, mask_box


def _kept_components(mask: np.ndarray, min_area_px: float, min_share: float):
    """The box holding ``mask``'s pixels, its component labels there (:func:`labelled_components`)
    and the kept labels, largest first (None when the mask is empty). Only the box is labelled: a
    full-frame labelling costs more than the rest."""
    box = mask_box(mask)
    if box is None:
        return None
    _, labels, areas = labelled_components(mask[box])
    areas = areas[1:]  # int32 as OpenCV's statistics: argsort orders ties as before
    floor = max(min_area_px, min_share * areas.max())
    order = np.argsort(-areas)
    kept = [int(i) + 1 for i in order[areas[order] >= floor]]
    return box, labels, kept


def split_instances(mask: np.ndarray, min_area_px: float = 0.0, min_share: float = 0.02) -> list[np.ndarray]:
    """Connected components of ``mask`` (H, W) bool as separate bool masks, largest first.

    Components smaller than ``min_area_px`` or than ``min_share`` of the largest one are dropped
    (specks of false positives)."""
    mask = np.asarray(mask, bool)
    found = _kept_components(mask, min_area_px, min_share)
    if found is None:
        return []
    box, labels, kept = found
    out = []
    for i in kept:
        instance = np.zeros(mask.shape, bool)
        instance[box] = labels == i
        out.append(instance)
    return out


def kept_instances(mask: np.ndarray, min_area_px: float = 0.0, min_share: float = 0.02) -> np.ndarray:
    """``union(split_instances(mask, ...), mask.shape)`` without a full-frame mask per instance."""
    mask = np.asarray(mask, bool)
    out = np.zeros(mask.shape, bool)
    found = _kept_components(mask, min_area_px, min_share)
    if found is not None:
        box, labels, kept = found
        n = int(labels.max()) + 1
        if len(kept) == n - 1:  # every component kept (the usual case): the mask itself
            out[box] = mask[box]
        else:
            table = np.zeros(max(n, 256), bool)
            table[kept] = True
            if n <= 256:  # OpenCV's table lookup on bytes: several times faster than indexing by labels
                out[box] = cv2.LUT(labels.astype(np.uint8), table[:256].view(np.uint8)).view(bool)
            else:
                out[box] = table[labels]
    return out


def union(instances: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """The union of instance masks; an all-False (H, W) mask when there are none."""
    out = np.zeros(shape, bool)
    for m in instances:
        out |= m
    return out
