"""Dot errors against the studio's truth with and without the world frame (``bench gauge``,
``bench realism``): a refined rig's geometry can be exact while its world frame (a similarity
common to all cameras, which no residual sees) is off; :func:`shape_error_mm` separates the two."""

from __future__ import annotations

import numpy as np

from ..geometry import umeyama
from ..markers import MISSING, MarkerTable


def truth_of(table: MarkerTable, groundtruth: dict) -> np.ndarray:
    """(F, D, 3) mm: the studio's true dots for the table's frames, in the table's label order."""
    gt_labels = [str(x) for x in groundtruth.get("labels", table.labels)]
    order = [gt_labels.index(label) for label in table.labels]
    return np.asarray(groundtruth["dots"], float)[table.frames][:, order]


def cloud_gauge(points: np.ndarray, target: np.ndarray, with_scale: bool = True,
                rounds: int = 3) -> tuple[np.ndarray, np.ndarray, float]:
    """The similarity ``(R, t, s)`` (``x -> s R x + t``, mm) that best fits ``points`` (N, 3) onto
    ``target`` (N, 3), rows with NaN ignored; robust: after each fit the pairs beyond 3x the
    median distance (at least 0.5 mm) are left out of the next."""
    ok = np.isfinite(points).all(axis=1) & np.isfinite(target).all(axis=1)
    src, dst = points[ok], target[ok]
    if len(src) < 3:
        raise ValueError(f"only {len(src)} point pairs; a similarity needs 3")
    keep = np.ones(len(src), bool)
    for _ in range(rounds):
        R, t, s = umeyama(src[keep], dst[keep], with_scale=with_scale)
        distance = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
        keep = distance <= max(3.0 * float(np.median(distance)), 0.5)
    return R, t, s


def shape_error_mm(table: MarkerTable, truth: np.ndarray) -> float:
    """Mean error (mm) of the tracked dots after the best similarity onto the truth: what is left
    once the world frame (position, orientation, scale) is taken out."""
    positions, status = table.positions(), table.to_arrays().status
    tracked = status != MISSING
    R, t, s = cloud_gauge(positions[tracked], truth[tracked])
    moved = s * positions[tracked] @ R.T + t
    return float(np.nanmean(np.linalg.norm(moved - truth[tracked], axis=1)))


def mean_error_mm(table: MarkerTable, truth: np.ndarray) -> float:
    """Mean error (mm) over the tracked dot-frames."""
    tracked = table.to_arrays().status != MISSING
    return float(np.nanmean(np.linalg.norm(table.positions()[tracked] - truth[tracked], axis=1)))
