"""Drawn 2D tape images with exact answers, for unit tests and quick smoke training.

A drawn sample is a background, a skin-coloured back, and one or more dark tape stripes whose
dots are holes showing the skin. Everything is drawn ``supersample`` times larger and reduced
with area averaging, so dot edges are anti-aliased and dot centres sit at known sub-pixel
positions. This is no substitute for the synthetic studio (no body, no perspective); it checks
the detector's geometry where the answer is known to the last bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

SHIFT = 4  # cv2 drawing fixed-point bits


@dataclass
class DrawnSample:
    """``image`` BGR uint8 (H, W, 3); ``mask`` (H, W) bool stripes with their dots filled;
    ``uv`` (N, 2) px dot centres; ``dot_px`` dot diameter in px; ``stripe_masks`` one per stripe."""

    image: np.ndarray
    mask: np.ndarray
    uv: np.ndarray
    dot_px: float
    stripe_masks: list[np.ndarray]


def _pts(xy: npt.ArrayLike, s: int) -> np.ndarray:
    """Low-res px -> fixed-point high-res coordinates (pixel i covers [i s, (i+1) s))."""
    return np.round((np.asarray(xy, float) * s + (s - 1) / 2.0) * (1 << SHIFT)).astype(np.int32)


def _stripe(rng: np.random.Generator, size: tuple[int, int], px_per_mm: float, n_rows: int, x_frac: float):
    """Centre line, unit tangents and normals of a gently curved stripe, in low-res px."""
    w, h = size
    length = (n_rows - 1) * 25.0 * px_per_mm + 25.0 * px_per_mm
    t = np.linspace(-0.5, 0.5, 200)
    angle = rng.uniform(-0.3, 0.3)
    bend = rng.uniform(-0.15, 0.15) * length
    direction = np.array([np.sin(angle), np.cos(angle)])
    normal = np.array([direction[1], -direction[0]])
    centre = np.array([x_frac * w, h / 2 + rng.uniform(-0.05, 0.05) * h])
    line = centre + np.outer(t * length, direction) + np.outer(bend * (1 - 4 * t * t), normal)
    tangent = np.gradient(line, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normals = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    return line, tangent, normals, length


def draw_sample(
    rng: np.random.Generator,
    size: tuple[int, int] = (320, 240),
    px_per_mm: float = 0.9,
    n_rows: int = 7,
    n_stripes: int = 1,
    supersample: int = 8,
    noise: float = 0.0,
    blur: float = 0.0,
) -> DrawnSample:
    """Draw one sample of ``size`` (width, height) px; tape 50 mm wide, 10 mm dots, 25 mm rows."""
    w, h = size
    s = supersample
    hi = np.empty((h * s, w * s, 3), np.uint8)
    hi[:] = rng.integers(20, 235, 3)
    skin = np.array([rng.uniform(60, 200), rng.uniform(90, 215), rng.uniform(120, 240)])
    cv2.ellipse(hi, _pts((w / 2, h / 2), s), (int(w * 0.45 * s) << SHIFT, int(h * 0.6 * s) << SHIFT),
                0, 0, 360, skin.tolist(), -1, cv2.LINE_8, SHIFT)
    tape_colour = rng.uniform(10, 70, 3).tolist()
    stripe_masks, centres = [], []
    dot_px = 10.0 * px_per_mm
    for k in range(n_stripes):
        x_frac = (k + 1) / (n_stripes + 1)
        line, tangent, normals, length = _stripe(rng, size, px_per_mm, n_rows, x_frac)
        half = 25.0 * px_per_mm
        outline = np.concatenate([line + half * normals, (line - half * normals)[::-1]])
        stripe_hi = np.zeros((h * s, w * s), np.uint8)
        cv2.fillPoly(stripe_hi, [_pts(outline, s)], 1, cv2.LINE_8, SHIFT)
        hi[stripe_hi.astype(bool)] = tape_colour
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
        for row in range(n_rows):
            a = (12.5 + row * 25.0) * px_per_mm
            j = int(np.clip(np.searchsorted(arc, a), 0, len(line) - 1))
            columns = (-7.5, 7.5) if row % 2 == 0 else (-15.0, 0.0, 15.0)
            for u in columns:
                p = line[j] + u * px_per_mm * normals[j]
                centres.append(p)
                radius = int(round(dot_px / 2 * s * (1 << SHIFT)))
                cv2.circle(hi, tuple(_pts(p, s)), radius, skin.tolist(), -1, cv2.LINE_8, SHIFT)
        stripe_masks.append(cv2.resize(stripe_hi, (w, h), interpolation=cv2.INTER_AREA) >= 0.5)
    image = cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    if blur > 0:
        image = cv2.GaussianBlur(image, (0, 0), blur)
    if noise > 0:
        image += rng.normal(0, noise, image.shape).astype(np.float32)
    image = np.clip(image + 0.5, 0, 255).astype(np.uint8)
    mask = np.zeros((h, w), bool)
    for m in stripe_masks:
        mask |= m
    uv = np.asarray(centres, float).reshape(-1, 2)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    return DrawnSample(image, mask, uv[inside], dot_px, stripe_masks)
