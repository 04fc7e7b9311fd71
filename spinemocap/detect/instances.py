"""Split a tape mask into instances (separate stripes, or pieces of one stripe cut by an occluder)."""

from __future__ import annotations

import cv2
import numpy as np


def split_instances(mask: np.ndarray, min_area_px: float = 0.0, min_share: float = 0.02) -> list[np.ndarray]:
    """Connected components of ``mask`` (H, W) bool as separate bool masks, largest first.

    Components smaller than ``min_area_px`` or than ``min_share`` of the largest one are dropped
    (specks of false positives)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(np.asarray(mask, np.uint8), connectivity=8)
    if n <= 1:
        return []
    areas = stats[1:, cv2.CC_STAT_AREA]
    floor = max(min_area_px, min_share * areas.max())
    order = [i + 1 for i in np.argsort(-areas) if areas[i] >= floor]
    return [labels == k for k in order]


def union(instances: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """The union of instance masks; an all-False (H, W) mask when there are none."""
    out = np.zeros(shape, bool)
    for m in instances:
        out |= m
    return out
