"""Split a tape mask into instances (separate stripes, or pieces of one stripe cut by an occluder)."""

from __future__ import annotations

import cv2
import numpy as np


def _kept_components(mask: np.ndarray, min_area_px: float, min_share: float):
    """The box holding ``mask``'s pixels, its component labels there and the kept labels,
    largest first (None when the mask is empty). Only the box is labelled: a full-frame
    labelling costs more than the rest."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return None
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask[box].view(np.uint8), connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
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
        table = np.zeros(labels.max() + 1, bool)
        table[kept] = True
        out[box] = table[labels]
    return out


def union(instances: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """The union of instance masks; an all-False (H, W) mask when there are none."""
    out = np.zeros(shape, bool)
    for m in instances:
        out |= m
    return out
