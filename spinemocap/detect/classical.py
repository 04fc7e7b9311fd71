"""Classical tape segmentation (baseline and fallback): darkness + morphology + perforation test.

The tape is darker than the skin around it and perforated: a dark region with several small
bright holes. Steps, on the frame reduced to at most ``work_width`` px wide:

1. dark pixels: grey below Otsu's threshold (whole frame), and below Otsu's threshold of the
   darker class (a second, darker level);
2. open lightly (noise), then fill each dark component's holes: the dots join their tape;
3. keep components that look perforated: at least ``min_holes`` enclosed bright holes making up
   a plausible share (``hole_share``) of the filled area; a plain dark background, hair or a
   dark garment has no such regular holes;
4. scale back to full resolution (bilinear on the 0/1 mask, threshold 0.5).

No training, no weights; it fails where the background itself is dark and perforated, and it
needs the holes to be resolved at ``work_width``.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..capture import to_grey


def _dark_thresholds(grey: np.ndarray, levels: int = 2) -> list[float]:
    """Otsu's threshold, then Otsu again on the darker class, and so on: the tape is the darkest
    large region, but a dark background or a mid-grey skin may sit between it and the rest."""
    out, pixels = [], grey.reshape(-1, 1)
    for _ in range(levels):
        if len(pixels) < 64 or pixels.min() == pixels.max():
            break
        t, _ = cv2.threshold(pixels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        out.append(t)
        pixels = pixels[pixels < t].reshape(-1, 1)
    return out


def _keep_perforated(dark: np.ndarray, keep: np.ndarray, min_holes: int, hole_share: tuple[float, float]) -> None:
    """Fill into ``keep`` the components of ``dark`` that have tape-like holes."""
    dark = cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))
    contours, hierarchy = cv2.findContours(dark, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return
    hierarchy = hierarchy[0]
    for i, (_next, _prev, child, parent) in enumerate(hierarchy):
        if parent != -1:
            continue
        outer = cv2.contourArea(contours[i])
        hole_areas = []
        c = child
        while c != -1:
            hole_areas.append(cv2.contourArea(contours[c]))
            c = hierarchy[c][0]
        holes = np.asarray([a for a in hole_areas if a >= 1.0])
        if len(holes) < min_holes or outer <= 0:
            continue
        # Dots are alike: count holes within a factor 3 of the median hole.
        median = np.median(holes)
        alike = holes[(holes > median / 3) & (holes < median * 3)]
        share = alike.sum() / outer
        if len(alike) >= min_holes and hole_share[0] <= share <= hole_share[1]:
            cv2.drawContours(keep, contours, i, 1, thickness=cv2.FILLED)


def segment_classical(
    image: np.ndarray,
    work_width: int = 1600,
    min_holes: int = 3,
    hole_share: tuple[float, float] = (0.03, 0.45),
) -> np.ndarray:
    """Tape mask (H, W) bool of a BGR/grey uint8 image."""
    grey = to_grey(image)
    h, w = grey.shape
    s = min(1.0, work_width / w)
    small = cv2.resize(grey, (max(8, int(w * s)), max(8, int(h * s))), interpolation=cv2.INTER_AREA) if s < 1 else grey
    small = cv2.GaussianBlur(small, (3, 3), 0)
    keep = np.zeros(small.shape, np.uint8)
    for threshold in _dark_thresholds(small):
        _keep_perforated((small < threshold).astype(np.uint8), keep, min_holes, hole_share)
    if s < 1:
        keep = cv2.resize(keep.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR) >= 0.5
    return keep.astype(bool)
