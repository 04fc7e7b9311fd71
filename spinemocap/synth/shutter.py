"""Global and rolling shutters: which instants a frame's rows see, and where a dot lands.

A global shutter exposes every row at once (over the exposure, for motion blur); a rolling
shutter reads the rows out one after the other, the top row ``readout / 2`` before the frame's
instant and the bottom row as long after it (:meth:`spinemocap.synth.appearance.CameraLook.row_times`),
so a moving subject is sheared. The studio renders a few instants over the readout and gives each
image row its own blend of them (:func:`row_weights`, :func:`exposed`); a dot's true image position
is where the dot was when its own row was read (:func:`rolling_shutter_uv`).
"""

from __future__ import annotations

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


def rolling_shutter_uv(instants: np.ndarray, uv_at_instants: np.ndarray, row_times: np.ndarray,
                       iterations: int = 8) -> np.ndarray:
    """(D, 2) image positions (px) of D points seen by a rolling shutter: each where it was when
    its own row was read. ``uv_at_instants`` (N, D, 2) their projections at the rendered
    ``instants`` (N,) s (increasing), between which they move linearly (as the rows' blend of the
    instants' images does, :func:`row_weights`); ``row_times`` (H,) when each row is read, s.
    Fixed-point iteration from the projection at the middle row's time."""
    instants, uv_at_instants = np.asarray(instants, float), np.asarray(uv_at_instants, float)
    rows = np.arange(len(row_times), dtype=float)

    def at(times: np.ndarray) -> np.ndarray:
        position = np.interp(times, instants, np.arange(len(instants), dtype=float))
        lower = np.minimum(np.floor(position).astype(int), len(instants) - 2) if len(instants) > 1 else np.zeros(len(times), int)
        frac = (position - lower)[:, None] if len(instants) > 1 else np.zeros((len(times), 1))
        upper = np.minimum(lower + 1, len(instants) - 1)
        points = np.arange(uv_at_instants.shape[1])
        return (1 - frac) * uv_at_instants[lower, points] + frac * uv_at_instants[upper, points]

    uv = at(np.full(uv_at_instants.shape[1], float(np.interp((len(rows) - 1) / 2, rows, row_times))))
    for _ in range(iterations):
        uv = at(np.interp(np.nan_to_num(uv[:, 1], nan=(len(rows) - 1) / 2), rows, row_times))
    return uv
