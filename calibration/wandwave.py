"""All extrinsics from a wand wave alone (no board), as optical motion-capture systems calibrate.

Input: every camera's intrinsics and synchronized videos of a wand waved through the volume
(the 5-marker T-wand or a 2-/3-marker linear wand, :class:`calibration.wand.WandSpec`), the
first frames optionally with the wand lying on the floor. Pipeline:

1. markers per image (bright blobs) identified from the wand's layout
   (:func:`calibration.wand.identify_markers`);
2. per camera pair, the essential matrix from all markers of all frames both cameras see
   (RANSAC on undistorted normalized coordinates; a 2-marker wand enters both ways round and
   RANSAC keeps the consistent one), the relative pose, and a maximum spanning tree over pairs
   weighted by inliers;
3. metric scale per tree edge from the wand's known distances between the markers the pair
   triangulates (median over frames), chained poses from the reference camera;
4. wand pose per frame (markers triangulated from all cameras, rigid fit to the wand), then
   bundle adjustment of camera poses, wand poses and (by default) the intrinsics with the wand
   as a rigid target of known size (:func:`calibration.extrinsics.bundle_adjust`: Ceres by
   default), views that disagree left out and the adjustment repeated;
5. world frame from the wand on the floor (``floor_frames``): Z up is the normal of the plane
   through the floor markers (towards the cameras), the origin is below the wand's first
   ``x_axis`` marker, X points to its second. A T-wand is an L-frame by itself; a linear wand
   needs to lie on the floor in two directions (an L) across the floor frames;
6. report: per-camera reprojection residuals (px) and the wand-length error over the volume
   (each frame's markers triangulated with the final rig, distance between the wand's end
   markers minus the true length), the figure Vicon and Qualisys report after a wand wave.

Frames: the world is mm, Z up when floor frames are given, else the reference camera's frame.
"""

from __future__ import annotations

import logging
import os
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Hashable

import cv2
import numpy as np

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError, atomic_path
from spinemocap.rig_adjust import Backend

from .boards import BoardDetection
from .check import camera_table
from .extrinsics import bundle_adjust, spanning_tree
from .geometry import rigid_fit
from .wand import WandSpec, WandViews, triangulate_markers

log = logging.getLogger(__name__)

Pose = tuple[np.ndarray, np.ndarray]

#: Fewest frames a camera pair must share for an essential matrix.
MIN_SHARED_FRAMES = 12


@dataclass
class WandWaveResult:
    """Rig from a wand wave and its quality: per-camera reprojection RMS (px) and counts; per
    used frame the wand's centre (world mm) and its length error (mm: triangulated distance
    between the end markers minus the true length); views left out, with reasons."""

    rig: Rig
    rms_px: dict[str, float]
    n_observations: dict[str, int]
    frames: np.ndarray
    centres_mm: np.ndarray
    length_error_mm: np.ndarray
    wand: WandSpec
    floor: str
    residuals: dict[str, np.ndarray] = field(repr=False, default_factory=dict)  # cam -> (N, 4) u v du dv
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def length_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.length_error_mm ** 2))) if len(self.length_error_mm) else float("nan")

    def summary(self) -> str:
        i, j = self.wand.length_pair
        true = self.wand.distances[i, j]
        err = self.length_error_mm
        lines = [camera_table(self.rig, self.residuals, "wand markers")]
        lines.append(f"wand length {true:.1f} mm over {len(err)} frames in the volume: mean {true + err.mean():.2f} mm, "
                     f"error RMS {self.length_rms_mm:.3f} mm, SD {err.std():.3f} mm, max |error| "
                     f"{np.abs(err).max():.3f} mm")
        lines.append(f"world frame: {self.floor}")
        lines += [f"left out {n} {what}" for what, n in self.dropped.items() if n]
        return "\n".join(lines)


# ---------------------------------------------------------------------- step 2: pairs
def _normalized(intrinsics: Rig, views: WandViews) -> list[list[np.ndarray | None]]:
    return [[None if v is None else intrinsics[c].undistort_points(v, normalized=True) for c, v in enumerate(per)]
            for per in views]


def _pair_correspondences(norm, i: int, j: int, wand: WandSpec) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Markers of frames both cameras see; a 2-marker wand enters both ways round."""
    a, b, frames = [], [], []
    for f, per in enumerate(norm):
        if per[i] is None or per[j] is None:
            continue
        frames.append(f)
        a.append(per[i])
        b.append(per[j])
        if not wand.ordered:
            a.append(per[i])
            b.append(per[j][::-1])
    if not a:
        return np.zeros((0, 2)), np.zeros((0, 2)), []
    return np.concatenate(a), np.concatenate(b), frames


def _sampson(E: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distance (normalized units) of correspondences x1 <-> x2 under E (x2^T E x1 = 0)."""
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Ex1, Etx2 = h1 @ E.T, h2 @ E
    num = np.sum(h2 * Ex1, axis=1) ** 2
    return np.sqrt(num / (Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2))


def relative_pose(norm, i: int, j: int, wand: WandSpec, threshold: float) -> tuple[np.ndarray, np.ndarray, int] | None:
    """(R, t unit, inliers) with x_j = R x_i + t from the pair's wand markers, or None."""
    x1, x2, frames = _pair_correspondences(norm, i, j, wand)
    if len(frames) < MIN_SHARED_FRAMES:
        return None
    E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), method=cv2.RANSAC, prob=0.9999, threshold=threshold)
    if E is None or E.shape != (3, 3):
        return None
    n, R, t, mask = cv2.recoverPose(E, x1, x2, np.eye(3), mask=mask)
    return R, t.ravel(), int(n)


def _match(x_a: np.ndarray, x_b: np.ndarray, E: np.ndarray, wand: WandSpec) -> np.ndarray | None:
    """x_b in x_a's marker order: unchanged for an ordered wand; for a 2-marker wand the order
    with the smaller epipolar error, None when both orders fit about as well."""
    if wand.ordered:
        return x_b
    keep, swap = _sampson(E, x_a, x_b).max(), _sampson(E, x_a, x_b[::-1]).max()
    if max(keep, swap) < 3 * min(keep, swap):
        return None
    return x_b if keep < swap else x_b[::-1]


def _essential(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ R


def _pair_scale(norm, i: int, j: int, R: np.ndarray, t: np.ndarray, wand: WandSpec) -> float:
    """mm per unit of the pair's baseline: the wand's true end-to-end distance over the one the
    pair triangulates (median over shared frames)."""
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R, t[:, None]])
    E = _essential(R, t)
    a, b = wand.length_pair
    ratios = []
    for per in norm:
        if per[i] is None or per[j] is None:
            continue
        xj = _match(per[i], per[j], E, wand)
        if xj is None:
            continue
        X = cv2.triangulatePoints(P1, P2, per[i].T, xj.T)
        X = (X[:3] / X[3]).T
        length = np.linalg.norm(X[a] - X[b])
        if length > 0 and np.all(X[:, 2] > 0):
            ratios.append(wand.distances[a, b] / length)
    if not ratios:
        raise InputError("wand videos", "no frame gives the wand's length between two cameras")
    return float(np.median(ratios))


def initial_rig(intrinsics: Rig, views: WandViews, wand: WandSpec, reference: int = 0,
                threshold_px: float = 1.5) -> list[Pose]:
    """Camera poses (reference camera frame -> camera, mm) from essential matrices chained over
    a maximum spanning tree of camera pairs (weights: RANSAC inliers), scaled by the wand."""
    norm = _normalized(intrinsics, views)
    n = len(intrinsics)
    focal = float(np.mean([c.K[0, 0] for c in intrinsics]))
    pairs: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    weights = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            found = relative_pose(norm, i, j, wand, threshold_px / focal)
            if found is not None:
                R, t, inliers = found
                pairs[i, j] = (R, t)
                weights[i, j] = weights[j, i] = inliers
    order, parents = spanning_tree(weights, reference)
    unreached = [intrinsics[c].name for c in range(n) if c not in set(order.tolist())]
    if unreached:
        raise InputError("wand videos", f"cameras {unreached} never see the wand together with the cameras linked "
                         f"to {intrinsics[reference].name!r} in at least {MIN_SHARED_FRAMES} frames. Wave the wand "
                         "longer where each camera and a neighbour both see all its markers")
    poses: list[Pose | None] = [None] * n
    poses[reference] = (np.eye(3), np.zeros(3))
    for c in order[1:]:
        p = int(parents[c])
        R, t = pairs[min(p, c), max(p, c)]
        if p > c:  # stored as x_p = R x_c + t: invert to x_c = R' x_p + t'
            R, t = R.T, -R.T @ t
            scale = _pair_scale(norm, int(c), p, *pairs[c, p], wand)
        else:
            scale = _pair_scale(norm, p, int(c), R, t, wand)
        parent = poses[p]
        if parent is None:  # the spanning tree lists every parent before its children
            raise RuntimeError(f"camera {p} is not posed before camera {int(c)}")
        R_p, t_p = parent
        poses[c] = (R @ R_p, R @ t_p + scale * t)
    return [pose for pose in poses if pose is not None]


# ---------------------------------------------------------------------- step 4: wand poses + BA
def _with_poses(intrinsics: Rig, poses: list[Pose]) -> Rig:
    return Rig([Camera(c.name, c.K, c.dist, R, t, c.size) for c, (R, t) in zip(intrinsics, poses)])


def label_views(rig: Rig, views: WandViews, wand: WandSpec) -> WandViews:
    """Views with one marker order per frame across cameras: a 2-marker wand's views are put
    into the order of the frame's first camera (epipolar error; ambiguous views dropped)."""
    if wand.ordered:
        return views
    out: WandViews = []
    for per in views:
        seen = [(c, v) for c, v in enumerate(per) if v is not None]
        labelled: list[np.ndarray | None] = [None] * len(per)
        if seen:
            anchor, anchor_px = seen[0]
            labelled[anchor] = anchor_px
            xa = rig[anchor].undistort_points(anchor_px, normalized=True)
            for c, px in seen[1:]:
                R = rig[c].R @ rig[anchor].R.T
                t = rig[c].t - R @ rig[anchor].t
                xc = rig[c].undistort_points(px, normalized=True)
                matched = _match(xa, xc, _essential(R, t / max(np.linalg.norm(t), 1e-9)), wand)
                if matched is not None:
                    labelled[c] = px if matched is xc else px[::-1]
        out.append(labelled)
    return out


def wand_poses(rig: Rig, views: WandViews, wand: WandSpec, max_fit_mm: float) -> dict[int, Pose]:
    """Per frame seen by >= 2 cameras: the wand's pose (wand -> rig frame) fitted to its
    triangulated markers, kept when the fit is within ``max_fit_mm`` RMS."""
    poses = {}
    for f, per in enumerate(views):
        pts = triangulate_markers(rig, per)
        if pts is None:
            continue
        R, t, rms = rigid_fit(wand.points_mm, pts)
        if rms <= max_fit_mm:
            poses[f] = (R, t)
    return poses


def _detections(rig: Rig, views: WandViews, frames) -> dict:
    return {cam.name: {f: BoardDetection(np.arange(len(views[f][c])), views[f][c]) for f in frames
                       if views[f][c] is not None} for c, cam in enumerate(rig)}


def _view_errors(rig: Rig, views: WandViews, poses: dict[int, Pose], wand: WandSpec) -> dict[tuple[int, int], float]:
    """Largest reprojection error (px) of each (frame, camera) view under the fitted wand."""
    errors = {}
    for f, (R, t) in poses.items():
        markers = wand.points_mm @ R.T + t
        for c, v in enumerate(views[f]):
            if v is not None:
                errors[f, c] = float(np.linalg.norm(rig[c].project(markers) - v, axis=1).max())
    return errors


def adjust(intrinsics: Rig, poses: list[Pose], views: WandViews, wand: WandSpec, reference: int,
           backend: Backend, progress: bool, refine_intrinsics: bool = False
           ) -> tuple[Rig, dict[int, Pose], WandViews, dict[str, int]]:
    """Bundle adjustment with the wand as a rigid target (``refine_intrinsics``: also fx fy cx cy
    k1 k2 p1 p2); views more than ``max(5 x median, 1 px)`` off after the first pass are left
    out and the rig adjusted again."""
    rig = _with_poses(intrinsics, poses)
    views = label_views(rig, views, wand)
    targets = wand_poses(rig, views, wand, max_fit_mm=0.05 * wand.distances.max())
    if len(targets) < 20:
        raise InputError("wand videos", f"only {len(targets)} frames with the wand triangulated; wave it longer "
                         "and slower through the volume, all markers visible to at least two cameras")
    dropped = {"views whose markers disagree with the others": 0}
    for _ in range(2):
        boards: dict[Hashable, Pose] = dict(targets.items())
        rig, refined, _ = bundle_adjust(rig, wand.points_mm, _detections(rig, views, targets), [(c.R, c.t) for c in rig],
                                        boards, reference, refine_intrinsics=refine_intrinsics, progress=progress,
                                        backend=backend)
        targets = dict(zip(list(targets), refined.values()))  # same frames, same order
        errors = _view_errors(rig, views, targets, wand)
        limit = max(5 * float(np.median(list(errors.values()))), 1.0)
        bad = [key for key, e in errors.items() if e > limit]
        if not bad:
            break
        dropped["views whose markers disagree with the others"] += len(bad)
        views = [list(per) for per in views]
        for f, c in bad:
            views[f][c] = None
        targets = {f: pose for f, pose in targets.items() if sum(v is not None for v in views[f]) >= 2}
    return rig, targets, views, dropped


# ---------------------------------------------------------------------- step 5: floor
def floor_transform(rig: Rig, targets: dict[int, Pose], wand: WandSpec, floor_frames: list[int]) -> Pose:
    """(R, t) taking rig-frame points to the world (``X_w = R X + t``) from the wand lying on
    the floor in ``floor_frames`` (see module doc)."""
    usable = [f for f in floor_frames if f in targets]
    if not usable:
        raise InputError("floor_frames", f"no floor frame {floor_frames[:10]} has the wand triangulated; record the "
                         "wand lying on the floor, all markers seen by at least two cameras")
    markers = np.concatenate([wand.points_mm @ targets[f][0].T + targets[f][1] for f in usable])
    centred = markers - markers.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[1] < 0.1 * sv[0]:
        raise InputError("floor_frames", "the wand's markers on the floor lie on one line: lay a linear wand on "
                         "the floor in two directions (an L) within the floor frames, or use the T-wand")
    up = np.linalg.svd(centred)[2][2]
    cameras_above = np.mean([c.center for c in rig], axis=0) - markers.mean(axis=0)
    up = up if up @ cameras_above > 0 else -up
    R0, t0 = targets[usable[0]]
    first = wand.points_mm @ R0.T + t0
    x_axis = first[wand.x_axis[1]] - first[wand.x_axis[0]]
    x_axis -= (x_axis @ up) * up
    x_axis /= np.linalg.norm(x_axis)
    origin = first[wand.x_axis[0]] - wand.height_on_floor_mm * up
    R = np.column_stack([x_axis, np.cross(up, x_axis), up]).T
    return R, -R @ origin


# ---------------------------------------------------------------------- step 6: report
def length_errors(rig: Rig, views: WandViews, wand: WandSpec, frames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frames, wand centres mm, end-to-end length error mm) of the wand triangulated with
    ``rig`` from all its views (no wand model involved)."""
    a, b = wand.length_pair
    used, centres, errors = [], [], []
    for f in frames:
        pts = triangulate_markers(rig, views[f])
        if pts is None:
            continue
        used.append(f)
        centres.append(pts.mean(axis=0))
        errors.append(np.linalg.norm(pts[a] - pts[b]) - wand.distances[a, b])
    return np.asarray(used, int), np.asarray(centres).reshape(-1, 3), np.asarray(errors, float)


def _residuals(rig: Rig, views: WandViews, targets: dict[int, Pose], wand: WandSpec) -> dict[str, np.ndarray]:
    out: dict[str, list[np.ndarray]] = defaultdict(list)
    for f, (R, t) in targets.items():
        markers = wand.points_mm @ R.T + t
        for c, v in enumerate(views[f]):
            if v is not None:
                out[rig[c].name].append(np.column_stack([v, rig[c].project(markers) - v]))
    return {cam.name: np.concatenate(out[cam.name]) if out[cam.name] else np.zeros((0, 4)) for cam in rig}


def calibrate_wand_wave(intrinsics: Rig, views: WandViews, wand: WandSpec, floor_frames: list[int] | None = None,
                        reference: int = 0, backend: Backend = "ceres", progress: bool = True,
                        refine_intrinsics: bool = True) -> WandWaveResult:
    """Whole pipeline (module doc): ``intrinsics`` (poses ignored), ``views[frame][camera]``
    identified markers (:func:`calibration.wand.detect_wand_views`), ``floor_frames`` where
    the wand lies on the floor (None: the world is the reference camera's frame).
    ``refine_intrinsics``: the bundle adjustment also refines fx fy cx cy k1 k2 p1 p2 (as
    optical systems do in a wand wave; it takes the per-camera board intrinsics' errors out)."""
    poses = initial_rig(intrinsics, views, wand, reference)
    rig, targets, views, dropped = adjust(intrinsics, poses, views, wand, reference, backend, progress,
                                          refine_intrinsics)
    if floor_frames:
        R, t = floor_transform(rig, targets, wand, list(floor_frames))
        rig = rig.transformed(R, t)
        targets = {f: (R @ Rw, R @ tw + t) for f, (Rw, tw) in targets.items()}
        floor = f"wand on the floor in frames {_ranges(floor_frames)} (Z up, origin below {wand.labels[wand.x_axis[0]]})"
    else:
        floor = f"camera {rig[reference].name}'s frame (no floor frames: not Z up)"
        log.warning("no floor frames: the world frame is camera %s's frame, not Z up", rig[reference].name)
    wave = sorted(f for f in targets if not floor_frames or f not in set(floor_frames))
    frames, centres, errors = length_errors(rig, views, wand, wave)
    residuals = _residuals(rig, views, targets, wand)
    rms = {n: float(np.sqrt(np.mean(np.sum(r[:, 2:] ** 2, axis=1)))) if len(r) else float("nan")
           for n, r in residuals.items()}
    counts = {n: len(r) for n, r in residuals.items()}
    return WandWaveResult(rig, rms, counts, frames, centres, errors, wand, floor, residuals, dropped)


def _ranges(frames) -> str:
    frames = sorted(frames)
    return f"{frames[0]}-{frames[-1]}" if frames == list(range(frames[0], frames[-1] + 1)) else str(frames)


def plot_length_error(result: WandWaveResult, path: str | os.PathLike) -> None:
    """PNG: the wand-length error over the volume (top view and side view of the wand's centre,
    coloured by error) and its histogram."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    err, c = result.length_error_mm, result.centres_mm
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    lim = max(float(np.abs(err).max()), 1e-3)
    for ax, (i, j), title in zip(axes[:2], [(0, 1), (0, 2)], ["top view (x, y)", "side view (x, z)"]):
        sc = ax.scatter(c[:, i], c[:, j], c=err, cmap="coolwarm", vmin=-lim, vmax=lim, s=12)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=axes[1], label="wand length error (mm)")
    axes[2].hist(err, bins=30, color="tab:blue")
    axes[2].set_xlabel("wand length error (mm)")
    axes[2].set_title(f"RMS {result.length_rms_mm:.3f} mm over {len(err)} frames", fontsize=9)
    fig.suptitle("Wand length over the volume (triangulated end-to-end distance minus the true length)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
