"""Global and rolling shutters: which instants a frame's rows see, and where a dot lands.

A global shutter exposes every row at once (over the exposure, for motion blur); a rolling
shutter reads the rows out one after the other, the top row ``readout / 2`` before the frame's
instant and the bottom row as long after it (:meth:`spinemocap.synth.appearance.CameraLook.row_times`),
so a moving subject is sheared. The studio renders a few instants over the readout and gives each
image row its own blend of them (:func:`row_weights`, :func:`exposed`); a dot's true image position
is where the dot was when its own row was read (:func:`rolling_shutter_uv`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Shutter:
    """The instants (s) a camera renders for one frame, the frame's own instant first; with a
    rolling shutter ``row_weights`` (H, instants): each image row's weights on them (rows sum to
    1); None: the instants are averaged (the first alone when there is one)."""

    instants: tuple[float, ...]
    row_weights: np.ndarray | None = None


def row_weights(instants: np.ndarray, row_times: np.ndarray, exposure_s: float) -> np.ndarray:
    """(H, N) weights of N rendered ``instants`` (s, increasing, evenly spaced) for rows exposed
    at ``row_times`` (H,) s: linear interpolation between the two instants around a row's time
    for a sharp exposure; for an exposure of ``exposure_s`` > 0, each instant weighs by how much
    of its share of time falls inside the row's exposure."""
    instants, row_times = np.asarray(instants, float), np.asarray(row_times, float)
    n = len(instants)
    if n == 1:
        return np.ones((len(row_times), 1))
    if exposure_s <= 0:
        position = np.interp(row_times, instants, np.arange(n, dtype=float))
        lower = np.minimum(np.floor(position).astype(int), n - 2)
        frac = position - lower
        weights = np.zeros((len(row_times), n))
        weights[np.arange(len(row_times)), lower] = 1 - frac
        weights[np.arange(len(row_times)), lower + 1] += frac
        return weights
    step = instants[1] - instants[0]
    lo = np.maximum(instants[None] - step / 2, (row_times - exposure_s / 2)[:, None])
    hi = np.minimum(instants[None] + step / 2, (row_times + exposure_s / 2)[:, None])
    weights = np.clip(hi - lo, 0.0, None)
    return weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-12)


def exposed(images: list[np.ndarray], masks: list[np.ndarray], weights: np.ndarray | None
            ) -> tuple[np.ndarray, np.ndarray | None]:
    """The frame a shutter makes of ``images`` (H, W, 3) rendered at its instants and their tape
    ``masks`` (H, W) bool (empty: none): without ``weights``, the images' average (the first
    image as it is when alone) and the first mask; with ``weights`` (H, instants), each row
    blended by its weights (float32), the mask where the blended masks reach one half."""
    if weights is None:
        rgb = images[0]
        if len(images) > 1:
            acc = rgb.astype(np.float32)
            for image in images[1:]:
                acc += image
            rgb = acc / len(images)
        return rgb, masks[0] if masks else None
    acc = np.zeros(images[0].shape, np.float32)
    for k, image in enumerate(images):
        acc += weights[:, k, None, None].astype(np.float32) * image
    if not masks:
        return acc, None
    cover = np.zeros(masks[0].shape, np.float32)
    for k, mask in enumerate(masks):
        cover += weights[:, k, None].astype(np.float32) * mask
    return acc, cover >= 0.5


def rolling_shutter_uv(project: Callable[[np.ndarray], np.ndarray], start_mm: np.ndarray, end_mm: np.ndarray,
                       height: int, iterations: int = 6) -> np.ndarray:
    """(D, 2) image positions (px) of D points seen by a rolling shutter whose top row is read
    when they are at ``start_mm`` (D, 3) and its bottom row (``height`` - 1) when at ``end_mm``
    (moving linearly in between): each point where it was when its own row was read (fixed-point
    iteration; ``project`` maps (D, 3) mm to (D, 2) px)."""
    start_mm, end_mm = np.asarray(start_mm, float), np.asarray(end_mm, float)
    uv = project(0.5 * (start_mm + end_mm))
    for _ in range(iterations):
        frac = np.clip(np.nan_to_num(uv[:, 1] / max(height - 1, 1), nan=0.5), 0.0, 1.0)
        uv = project(start_mm + frac[:, None] * (end_mm - start_mm))
    return uv
