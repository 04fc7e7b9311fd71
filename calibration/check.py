"""Quality check of a rig: per-camera table and reprojection-error plot, and its agreement with
another calibration of the same cameras (:func:`compare_rigs`).

Residuals come either from the bundle adjustment (saved beside the rig as
``<rig>.residuals.npz`` by ``spinemocap calibrate extrinsics``) or from fresh synchronized board
views: each frame's board pose is fitted to all cameras at once (robust least squares on
reprojection error), so every camera is judged against the others.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Hashable

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from spinemocap.camera import Rig
from spinemocap.fileio import InputError, atomic_path, atomic_write

from .boards import BoardDetection, BoardSpec

Residuals = dict[str, np.ndarray]  # camera -> (N, 4): observed u v, residual du dv (px)


def residuals_path(rig_path: str | os.PathLike) -> Path:
    return Path(str(rig_path) + ".residuals.npz")


def save_residuals(rig_path: str | os.PathLike, residuals: Residuals) -> Path:
    path = residuals_path(rig_path)
    with atomic_write(path, "wb") as handle:
        np.savez_compressed(handle, allow_pickle=False, **residuals)
    return path


def load_residuals(rig_path: str | os.PathLike) -> Residuals | None:
    path = residuals_path(rig_path)
    if not path.is_file():
        return None
    with np.load(path) as data:
        return {name: data[name] for name in data.files}


def residuals_from_views(rig: Rig, board: BoardSpec, views: dict[str, dict[Hashable, BoardDetection]]) -> Residuals:
    """Fit each frame's board pose to all cameras that see it; return every corner's residual."""
    model = board.object_points()
    frames: dict[Hashable, dict[str, BoardDetection]] = {}
    for name, per_frame in views.items():
        for f, det in per_frame.items():
            frames.setdefault(f, {})[name] = det
    out: dict[str, list[np.ndarray]] = {cam.name: [] for cam in rig}
    for dets in frames.values():
        start = max(dets, key=lambda n: len(dets[n]))
        cam0, det0 = rig[start], dets[start]
        ok, rvec, tvec = cv2.solvePnP(model[det0.ids], det0.pixels, cam0.K, cam0.dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            continue
        R0 = cam0.R.T @ cv2.Rodrigues(rvec)[0]  # board -> world
        x0 = np.concatenate([cv2.Rodrigues(R0)[0].ravel(), cam0.R.T @ (tvec.ravel() - cam0.t)])

        def res(x: np.ndarray, dets: dict = dets) -> np.ndarray:
            R = cv2.Rodrigues(x[:3])[0]
            return np.concatenate([(rig[n].project(model[d.ids] @ R.T + x[3:]) - d.pixels).ravel()
                                   for n, d in dets.items()])

        fit = least_squares(res, x0, loss="huber", f_scale=1.0)
        R, t = cv2.Rodrigues(fit.x[:3])[0], fit.x[3:]
        for n, d in dets.items():
            out[n].append(np.column_stack([d.pixels, rig[n].project(model[d.ids] @ R.T + t) - d.pixels]))
    return {n: np.concatenate(v) if v else np.zeros((0, 4)) for n, v in out.items()}


def camera_table(rig: Rig, residuals: Residuals | None = None, observed: str = "board corners") -> str:
    """Per-camera text table: intrinsics, centre (mm), viewing direction and residual stats (px)
    of the ``observed`` points (named in the table's last line)."""
    head = f"{'camera':<10}{'size':>11}{'fx':>9}{'fy':>9}{'cx':>8}{'cy':>8}{'k1':>8}{'centre x,y,z (mm)':>25}{'looks along':>20}"
    if residuals is not None:
        head += f"{'obs':>6}{'RMS':>7}{'p95':>7}{'max':>7}"
    lines = [head]
    for cam in rig:
        c, d = cam.center, cam.R[2]
        row = (f"{cam.name:<10}{f'{cam.size[0]}x{cam.size[1]}':>11}{cam.K[0, 0]:>9.1f}{cam.K[1, 1]:>9.1f}"
               f"{cam.K[0, 2]:>8.1f}{cam.K[1, 2]:>8.1f}{cam.dist[0]:>8.4f}"
               f"{f'{c[0]:.0f},{c[1]:.0f},{c[2]:.0f}':>25}{f'{d[0]:+.2f},{d[1]:+.2f},{d[2]:+.2f}':>20}")
        if residuals is not None:
            r = residuals.get(cam.name, np.zeros((0, 4)))
            norm = np.linalg.norm(r[:, 2:], axis=1)
            if len(norm):
                row += f"{len(norm):>6}{np.sqrt(np.mean(norm ** 2)):>7.3f}{np.percentile(norm, 95):>7.3f}{norm.max():>7.3f}"
            else:
                row += f"{0:>6}{'-':>7}{'-':>7}{'-':>7}"
        lines.append(row)
    if residuals is not None:
        lines.append(f"residuals in px (reprojection error of {observed})")
    return "\n".join(lines)


def plot_residuals(rig: Rig, residuals: Residuals, path: str | os.PathLike, arrow_gain: float | None = None) -> None:
    """PNG: per camera, residual vectors over the image (magnified ``arrow_gain`` times; by
    default so that the 95th-percentile residual spans 4 % of the image width) and a histogram
    of residual lengths (px)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rig)
    if arrow_gain is None:
        lengths = np.concatenate([np.linalg.norm(r[:, 2:], axis=1) for r in residuals.values()] + [np.zeros(1)])
        arrow_gain = float(0.04 * max(c.size[0] for c in rig) / max(np.percentile(lengths, 95), 1e-6))
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.6), squeeze=False)
    for k, cam in enumerate(rig):
        r = residuals.get(cam.name, np.zeros((0, 4)))
        ax = axes[0, k]
        ax.set_title(cam.name, fontsize=9)
        ax.set_xlim(0, cam.size[0])
        ax.set_ylim(cam.size[1], 0)
        ax.set_aspect("equal")
        if len(r):
            ax.quiver(r[:, 0], r[:, 1], r[:, 2] * arrow_gain, -r[:, 3] * arrow_gain, np.linalg.norm(r[:, 2:], axis=1),
                      angles="xy", scale_units="xy", scale=1, width=0.006, cmap="viridis")
        ax.tick_params(labelsize=6)
        hist = axes[1, k]
        norm = np.linalg.norm(r[:, 2:], axis=1)
        if len(norm):
            hist.hist(norm, bins=30, color="tab:blue")
            hist.set_title(f"RMS {np.sqrt(np.mean(norm ** 2)):.3f} px", fontsize=8)
        hist.set_xlabel("reprojection error (px)", fontsize=7)
        hist.tick_params(labelsize=6)
    axes[0, 0].set_ylabel(f"residuals x{arrow_gain:.0f}", fontsize=8)
    fig.suptitle("Reprojection error per camera", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------- against another calibration
@dataclass
class PairAgreement:
    """Two cameras as two calibrations see them: baselines (mm) and the angle (deg) between the
    two calibrations' relative rotations of the pair."""

    a: str
    b: str
    baseline_mm: float
    other_baseline_mm: float
    rotation_diff_deg: float

    @property
    def baseline_ratio(self) -> float:
        return self.baseline_mm / self.other_baseline_mm


@dataclass
class RigComparison:
    """Every camera pair of a rig compared with another calibration of the same cameras; frame-
    and origin-free (baselines and relative rotations only). ``matched_by``: "name" or "order"."""

    pairs: list[PairAgreement]
    matched_by: str
    max_baseline_error: float = 0.02
    max_rotation_deg: float = 1.0

    @property
    def worst_baseline_error(self) -> float:
        return max(abs(p.baseline_ratio - 1) for p in self.pairs)

    @property
    def worst_rotation_deg(self) -> float:
        return max(p.rotation_diff_deg for p in self.pairs)

    @property
    def agrees(self) -> bool:
        return self.worst_baseline_error <= self.max_baseline_error and self.worst_rotation_deg <= self.max_rotation_deg

    def summary(self) -> str:
        lines = [f"{'pair':<24}{'baseline':>10}{'other':>10}{'ratio':>9}{'rot diff':>10}",
                 *(f"{p.a + ' - ' + p.b:<24}{p.baseline_mm:>10.1f}{p.other_baseline_mm:>10.1f}{p.baseline_ratio:>9.4f}"
                   f"{p.rotation_diff_deg:>9.3f}d" + ("  !" if abs(p.baseline_ratio - 1) > self.max_baseline_error
                                                       or p.rotation_diff_deg > self.max_rotation_deg else "")
                   for p in self.pairs)]
        verdict = "agree" if self.agrees else "DISAGREE"
        lines.append(f"cameras matched by {self.matched_by}; worst baseline {100 * self.worst_baseline_error:.2f} % "
                     f"(limit {100 * self.max_baseline_error:g} %), worst relative rotation {self.worst_rotation_deg:.3f} "
                     f"deg (limit {self.max_rotation_deg:g}): the calibrations {verdict}")
        return "\n".join(lines)


def compare_rigs(rig: Rig, other: Rig, max_baseline_error: float = 0.02, max_rotation_deg: float = 1.0) -> RigComparison:
    """Compare ``rig`` with ``other`` (mm both): cameras matched by name, or by order when the
    names differ but the counts agree. Raises :class:`InputError` when they cannot be matched."""
    if sorted(rig.names) == sorted(other.names):
        matched_by, pairs_of = "name", [(cam, other[cam.name]) for cam in rig]
    elif len(rig) == len(other):
        matched_by, pairs_of = "order", list(zip(rig, other))
    else:
        raise InputError("against", f"the rigs have different cameras ({rig.names} vs {other.names}); "
                         "compare calibrations of the same cameras")
    if len(pairs_of) < 2:
        raise InputError("against", "a comparison needs at least two cameras")
    pairs = []
    for i in range(len(pairs_of)):
        for j in range(i + 1, len(pairs_of)):
            (a, a2), (b, b2) = pairs_of[i], pairs_of[j]
            difference = (b.R @ a.R.T) @ (b2.R @ a2.R.T).T  # the two relative rotations' difference
            pairs.append(PairAgreement(a.name, b.name, float(np.linalg.norm(a.center - b.center)),
                                       float(np.linalg.norm(a2.center - b2.center)),
                                       float(np.degrees(Rotation.from_matrix(difference).magnitude()))))
    return RigComparison(pairs, matched_by, max_baseline_error, max_rotation_deg)
