"""Split a tape mask into instances (separate stripes, or pieces of one stripe cut by an occluder)."""

from __future__ import annotations

import cv2
import numpy as np


def split_instances(mask: np.ndarray, min_area_px: float = 0.0, min_share: float = 0.02) -> list[np.ndarray]:
    """Connected components of ``mask`` (H, W) bool as separate bool masks, largest first.

    Components smaller than ``min_area_px`` or than ``min_share`` of the largest one are dropped
    (specks of false positives)."""
    mask = np.asarray(mask, bool)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return []
    # Label only the box holding the tape: a full-frame labelling costs more than the rest.
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask[box].view(np.uint8), connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    floor = max(min_area_px, min_share * areas.max())
    out = []
    for i in np.argsort(-areas):
        if areas[i] < floor:
            break
        instance = np.zeros(mask.shape, bool)
        instance[box] = labels == i + 1
        out.append(instance)
    return out


def union(instances: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """The union of instance masks; an all-False (H, W) mask when there are none."""
    out = np.zeros(shape, bool)
    for m in instances:
        out |= m
    return out
