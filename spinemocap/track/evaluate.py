"""Tracking accuracy against ground truth (synthetic studio), and the paper's plane baselines.

Errors are Euclidean distances (mm) between tracked and true dot centres, split by status
(``observed`` / ``inferred``). A *label swap* is a tracked dot-frame that lies nearer another
dot's true position than its own (and more than half the smallest dot spacing from its own):
its label is wrong, whatever the geometry. *Frames without a solution* have every dot missing.

Plane baselines (paper experiment 1, Table 1): planes fitted (least squares) to skin keypoints
that a keypoint tracker (pose-estimator style) follows left and right of the spine. The 8
keypoints (see :data:`spinemocap.synth.tape_on_skin.KEYPOINT_NAMES`) are ordered from the
sacral end, left before right: hips (posterior pelvis) 0-1, waist (lower ribs, L1) 2-3,
shoulder-blade angles (T7) 4-5, shoulders (scapulae) 6-7. As in the paper, 1 plane uses 4
keypoints, 2 planes 6 and 3 planes 8:

- 1 plane: hips + shoulders (0, 1, 6, 7);
- 2 planes: hips + waist (0-3) and waist + shoulders (2, 3, 6, 7);
- 3 planes: hips + waist, waist + shoulder-blade angles, shoulder-blade angles + shoulders.

Each true dot is measured to the plane of its segment along the back: dots and keypoints are
projected on the hip-to-shoulder axis (midpoints of the left/right pairs); a plane's span is the
interval its keypoints cover there and a dot goes to the plane whose span contains it (or lies
nearest). The distance is point-to-plane; the mean over dot-frames is the one-sided Hausdorff
distance the paper reports.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..markers import INFERRED, MISSING, OBSERVED, STATUSES, MarkerStatus, MarkerTable

PLANE_GROUPS = {
    1: [[0, 1, 6, 7]],
    2: [[0, 1, 2, 3], [2, 3, 6, 7]],
    3: [[0, 1, 2, 3], [2, 3, 4, 5], [4, 5, 6, 7]],
}


@dataclass
class ErrorStats:
    """Summary of a set of errors (mm): their number and mean, median, 95th percentile and
    largest value (NaN when there are none)."""

    n: int
    mean: float
    median: float
    p95: float
    max: float

    @classmethod
    def of(cls, values: np.ndarray) -> ErrorStats:
        """The finite ``values``' statistics."""
        values = values[np.isfinite(values)]
        if not len(values):
            return cls(0, float("nan"), float("nan"), float("nan"), float("nan"))
        return cls(int(len(values)), float(values.mean()), float(np.median(values)),
                   float(np.percentile(values, 95)), float(values.max()))


def label_swaps(positions: np.ndarray, truth: np.ndarray, min_spacing_mm: float) -> np.ndarray:
    """(F, D) bool: tracked dot nearer another true dot than its own and > spacing/2 from it."""
    d = np.linalg.norm(positions[:, :, None, :] - truth[:, None, :, :], axis=3)  # (F, D, D)
    own = np.einsum("fdd->fd", d)
    d_other = d.copy()
    idx = np.arange(d.shape[1])
    d_other[:, idx, idx] = np.inf
    with np.errstate(invalid="ignore"):
        return (np.nanmin(np.where(np.isfinite(d_other), d_other, np.inf), axis=2) < own) & (own > min_spacing_mm / 2)


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane through (N, 3) points: (centroid, unit normal)."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c)
    return c, vt[-1]


def plane_segments(dots: np.ndarray, keypoints: np.ndarray, groups: list[list[int]]) -> np.ndarray:
    """(D,) index of the plane group each dot (D, 3) belongs to along the back, for one frame's
    keypoints (8, 3): see module."""
    bottom, top = keypoints[0:2].mean(axis=0), keypoints[-2:].mean(axis=0)
    axis = (top - bottom) / np.linalg.norm(top - bottom)
    t_dots = (dots - bottom) @ axis
    t_kp = (keypoints - bottom) @ axis
    lo = np.array([t_kp[g].min() for g in groups])
    hi = np.array([t_kp[g].max() for g in groups])
    outside = np.maximum(lo[None] - t_dots[:, None], 0.0) + np.maximum(t_dots[:, None] - hi[None], 0.0)
    return np.argmin(outside, axis=1)


def plane_baseline(dots: np.ndarray, keypoints: np.ndarray, n_planes: int) -> np.ndarray:
    """(F, D) distances (mm) of the dots (F, D, 3) to the ``n_planes`` planes fitted to the
    keypoints (F, 8, 3) (see module)."""
    groups = PLANE_GROUPS[n_planes]
    F, D = dots.shape[:2]
    out = np.full((F, D), np.nan)
    for f in range(F):
        seg = plane_segments(dots[f], keypoints[f], groups)
        for k, g in enumerate(groups):
            c, n = fit_plane(keypoints[f, g])
            on = seg == k
            out[f, on] = np.abs((dots[f, on] - c) @ n)
    return out


def plane_baselines(dots: np.ndarray, keypoints: np.ndarray) -> dict[str, float]:
    """Mean dot-to-plane distance (mm) of the 1-, 2- and 3-plane baselines: ``{"1-plane": ...}``."""
    return {f"{n}-plane": float(np.nanmean(plane_baseline(dots, keypoints, n))) for n in PLANE_GROUPS}


def views_histogram(visible: np.ndarray) -> dict[str, int]:
    """(F, C, D) visibility -> dot-frames seen by exactly C, C-1, ..., 0 cameras."""
    count = visible.sum(axis=1)
    C = visible.shape[1]
    return {f"{k} cameras": int((count == k).sum()) for k in range(C, -1, -1)}


@dataclass
class TrackingAccuracy:
    """Accuracy of a tracked sequence against the ground truth (errors in mm). ``observed`` /
    ``inferred``: :class:`ErrorStats` over dots of that status; optional parts are
    None when the ground truth (or the caller) lacks them. :meth:`to_dict` gives the JSON of
    ``spinemocap bench track``."""

    frames: int
    dots: int
    mean_error_mm: float
    median_error_mm: float
    p95_error_mm: float
    max_error_mm: float
    observed: ErrorStats
    inferred: ErrorStats
    status_counts: dict[MarkerStatus, int]
    label_swaps: int
    frames_with_swaps: int
    frames_without_solution: int
    visibility_histogram: dict[str, int] | None = None
    plane_baselines_mm: dict[str, float] | None = None
    stage_ms: dict[str, float] | None = None
    total_ms_per_frame: float | None = None

    def to_dict(self) -> dict:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


def evaluate_tracking(table: MarkerTable, groundtruth: dict, tape_min_spacing_mm: float,
                      stage_ms: dict[str, float] | None = None) -> TrackingAccuracy:
    """All accuracy numbers of a tracked sequence vs the ground truth dict of the synthetic
    studio (``dots`` (F, D, 3), ``visible`` (F, C, D), optional ``keypoints`` (F, 8, 3)); the
    table's frames index the ground truth."""
    arrays = table.to_arrays()
    frames = arrays.frames
    labels = list(arrays.labels)
    gt_labels = [str(x) for x in groundtruth.get("labels", labels)]
    order = [gt_labels.index(lab) for lab in labels]
    truth = np.asarray(groundtruth["dots"], float)[frames][:, order]
    pos, status = arrays.positions, arrays.status
    err = np.linalg.norm(pos - truth, axis=2)
    tracked = status != MISSING
    swaps = label_swaps(pos, truth, tape_min_spacing_mm) & tracked
    overall = ErrorStats.of(err[tracked])
    result = TrackingAccuracy(
        frames=int(len(frames)),
        dots=int(len(labels)),
        mean_error_mm=overall.mean,
        median_error_mm=overall.median,
        p95_error_mm=overall.p95,
        max_error_mm=overall.max,
        observed=ErrorStats.of(err[status == OBSERVED]),
        inferred=ErrorStats.of(err[status == INFERRED]),
        status_counts={s: int((status == s).sum()) for s in STATUSES},
        label_swaps=int(swaps.sum()),
        frames_with_swaps=int(swaps.any(axis=1).sum()),
        frames_without_solution=int((~tracked).all(axis=1).sum()),
    )
    if "visible" in groundtruth:
        result.visibility_histogram = views_histogram(np.asarray(groundtruth["visible"])[frames][:, :, order])
    if "keypoints" in groundtruth:
        kp = np.asarray(groundtruth["keypoints"], float)[frames]
        result.plane_baselines_mm = plane_baselines(truth, kp)
    if stage_ms is not None:
        result.stage_ms = {k: float(v) for k, v in stage_ms.items()}
        result.total_ms_per_frame = float(sum(stage_ms.values()))
    return result
