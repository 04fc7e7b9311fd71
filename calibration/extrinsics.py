"""Multi-camera extrinsics from a ChArUco board seen by several cameras at once.

Pipeline:
1. per (camera, frame) board pose by PnP (IPPE, planar) with each camera's intrinsics;
2. relative pose of every camera pair from their shared frames (rotation chordal mean,
   translation median), a maximum spanning tree over pairs weighted by shared frames, and the
   chained poses of every camera in the reference camera's frame;
3. bundle adjustment over all camera poses, all board poses and (optionally) each camera's
   fx fy cx cy k1 k2 p1 p2, Huber loss of 1 px: by default Ceres through pycolmap
   (:mod:`calibration.ceres_ba`), or ``scipy.optimize.least_squares`` (trust region
   reflective, sparse Jacobian pattern; ``backend="scipy"``, the peer in ``bench
   calibration``); the reference camera's pose fixes the gauge and the board's square size
   fixes the scale;
4. world frame from the board lying face up on the floor in frame ``floor_frame``: origin at
   the pattern's top-left corner, X along the board's columns, Z up (board z is into the board,
   so world = diag(1, -1, -1) board). Several floor frames (the board laid at a few places)
   fix Z up better: it becomes the normal of the plane through all their corners.

Frames are any hashable keys; a frame seen by one camera only (e.g. that camera's intrinsic
views) still constrains that camera's intrinsics in the bundle adjustment.

Boards: ChArUco corners carry ids; checkerboard corners are put into one order by
:func:`calibration.boards.order_checkerboard`, and views whose order stays ambiguous are left
out of frames shared by several cameras (:func:`drop_ambiguous_views`, reasons in the result).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Hashable, cast

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree
from tqdm import tqdm

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError
from spinemocap.geometry import distort

from .boards import BoardDetection, BoardSpec, is_half_turn_symmetric
from .ceres_ba import bundle_adjust_ceres, ceres_unsupported
from .check import camera_table
from .geometry import rigid_fit, rodrigues, transform_rig, triangulate

log = logging.getLogger(__name__)

Detections = dict[str, dict[Hashable, BoardDetection]]  # camera name -> frame -> detection
N_INTRINSICS = 8  # fx fy cx cy k1 k2 p1 p2 (k3 stays as given)


@dataclass
class Observations:
    """All corner observations, flattened: camera index, frame index, board corner id, pixel."""

    cam: np.ndarray
    frame: np.ndarray
    corner: np.ndarray
    pixels: np.ndarray
    frames: list[Hashable]


@dataclass
class ExtrinsicsResult:
    """Calibrated rig (world mm, Z up when a floor frame was given) and its quality:
    per-camera reprojection RMS (px) and observation count, board geometry error (RMS mm of
    triangulated corners vs. the known board after a rigid fit, per multi-camera frame), and every
    observation's residual for plots."""

    rig: Rig
    rms_px: dict[str, float]
    n_observations: dict[str, int]
    board_error_mm: dict[Hashable, float]
    residuals: dict[str, np.ndarray] = field(repr=False, default_factory=dict)  # cam -> (N, 4) u v du dv
    board_poses: dict[Hashable, tuple[np.ndarray, np.ndarray]] = field(repr=False, default_factory=dict)
    #: (camera, frame) -> why that view was left out (e.g. a checkerboard's ambiguous corner order)
    rejected: dict[tuple[str, Hashable], str] = field(default_factory=dict)

    @property
    def board_rms_mm(self) -> float:
        v = np.array(list(self.board_error_mm.values()))
        return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")

    def summary(self) -> str:
        lines = [camera_table(self.rig, self.residuals, "board corners")]
        lines.append(f"board geometry from triangulated corners: RMS {self.board_rms_mm:.3f} mm over "
                     f"{len(self.board_error_mm)} multi-camera frames")
        lines += [f"left out {name} frame {frame}: {why}" for (name, frame), why in self.rejected.items()]
        return "\n".join(lines)


# ---------------------------------------------------------------------- step 1-2: initial poses
def _pnp(cam: Camera, board: BoardSpec, det: BoardDetection) -> tuple[np.ndarray, np.ndarray] | None:
    if len(det) < 6:
        return None
    obj = board.object_points()[det.ids]
    ok, rvec, tvec = cv2.solvePnP(obj, det.pixels, cam.K, cam.dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(obj, det.pixels, cam.K, cam.dist, rvec, tvec)
    return cv2.Rodrigues(rvec)[0], tvec.ravel()


def _mean_rotation(rotations: list[np.ndarray]) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.sum(rotations, axis=0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    return R


def spanning_tree(weights: np.ndarray, reference: int) -> tuple[np.ndarray, np.ndarray]:
    """Maximum spanning tree over cameras (``weights[i, j]``: how much cameras i and j share,
    0 = nothing), walked breadth first from ``reference``: (order of the reached cameras,
    parent of each camera; -9999 for the reference and unreached cameras)."""
    tree = minimum_spanning_tree(-weights).toarray()
    tree = (tree != 0) | (tree.T != 0)
    return breadth_first_order(tree, reference, directed=False)


def initial_poses(intrinsics: Rig, board: BoardSpec, detections: Detections, reference: int = 0
                  ) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict[Hashable, tuple[np.ndarray, np.ndarray]]]:
    """Camera poses (R, t: reference frame -> camera) by a spanning tree over camera pairs, and
    board poses (R, t: board -> reference frame) for every frame."""
    names = intrinsics.names
    pnp = {c: {f: p for f, d in detections.get(name, {}).items() if (p := _pnp(intrinsics[c], board, d))}
           for c, name in enumerate(names)}
    n = len(names)
    pair_frames = defaultdict(list)
    for i in range(n):
        for j in range(i + 1, n):
            shared = sorted(set(pnp[i]) & set(pnp[j]), key=str)
            if shared:
                pair_frames[i, j] = shared
    weights = np.zeros((n, n))
    for (i, j), shared in pair_frames.items():
        weights[i, j] = weights[j, i] = len(shared)
    order, parents = spanning_tree(weights, reference)
    unreached = [names[c] for c in range(n) if c not in set(order.tolist())]
    if unreached:
        seen = {names[c]: len(pnp[c]) for c in range(n)}
        raise InputError("board views", f"cameras {unreached} never see the board at the same time as the "
                         f"cameras connected to {names[reference]!r} (usable views per camera: {seen}). "
                         "Capture again with the board held where each of these cameras and a neighbour "
                         "both see it whole")
    poses: list[tuple[np.ndarray, np.ndarray] | None] = [None] * n
    poses[reference] = (np.eye(3), np.zeros(3))
    for c in order[1:]:
        p = parents[c]
        shared = pair_frames[min(p, c), max(p, c)]
        rel_R, rel_t = [], []  # parent camera -> camera c
        for f in shared:
            (Rp, tp), (Rc, tc) = pnp[p][f], pnp[c][f]
            R = Rc @ Rp.T
            rel_R.append(R)
            rel_t.append(tc - R @ tp)
        R_pc, t_pc = _mean_rotation(rel_R), np.median(rel_t, axis=0)
        Rp_ref, tp_ref = poses[p]
        poses[c] = (R_pc @ Rp_ref, R_pc @ tp_ref + t_pc)
    boards: dict[Hashable, tuple[np.ndarray, np.ndarray, int]] = {}  # pose and corners seen
    for c in range(n):
        Rc, tc = poses[c]
        for f, (Rb, tb) in pnp[c].items():
            if f not in boards or len(detections[names[c]][f]) > boards[f][2]:
                boards[f] = (Rc.T @ Rb, Rc.T @ (tb - tc), len(detections[names[c]][f]))
    # the spanning tree reached every camera: no pose is None any more
    return cast(list[tuple[np.ndarray, np.ndarray]], poses), {f: (R, t) for f, (R, t, _) in boards.items()}


# ---------------------------------------------------------------------- step 3: bundle adjustment
def _observations(names: list[str], detections: Detections, frames: list[Hashable]) -> Observations:
    index = {f: k for k, f in enumerate(frames)}
    cam, frame, corner, pixels = [], [], [], []
    for c, name in enumerate(names):
        for f, det in detections.get(name, {}).items():
            if f not in index:
                continue
            cam.append(np.full(len(det), c))
            frame.append(np.full(len(det), index[f]))
            corner.append(det.ids)
            pixels.append(det.pixels)
    return Observations(np.concatenate(cam), np.concatenate(frame), np.concatenate(corner),
                        np.concatenate(pixels), frames)


def project_batch(K: np.ndarray, dist: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """Distorted pixels of camera-frame points; K (N, 4) fx fy cx cy, dist (N, 5), points (N, 3)."""
    xd, yd = distort(points_cam[:, :2] / points_cam[:, 2:3], dist).T
    return np.column_stack([K[:, 0] * xd + K[:, 2], K[:, 1] * yd + K[:, 3]])


BACKENDS = ("ceres", "scipy")


def bundle_adjust(intrinsics: Rig, board: BoardSpec | np.ndarray, detections: Detections,
                  poses: list[tuple[np.ndarray, np.ndarray]], boards: dict[Hashable, tuple[np.ndarray, np.ndarray]],
                  reference: int = 0, refine_intrinsics: bool = True, loss_scale_px: float = 1.0,
                  progress: bool = True, backend: str = "ceres"
                  ) -> tuple[Rig, dict[Hashable, tuple[np.ndarray, np.ndarray]], Observations]:
    """Refine all camera poses, board poses and (optionally) intrinsics; see module doc.
    ``board`` may also be the (N, 3) model points of any rigid target (e.g. the Vicon wand),
    indexed by the detections' ids. ``backend``: ``"ceres"`` (pycolmap; falls back to scipy,
    with a log line, for cameras with a k3 term) or ``"scipy"``."""
    if backend not in BACKENDS:
        raise InputError("backend", f"unknown bundle adjustment backend {backend!r}; choose one of {BACKENDS}")
    names = intrinsics.names
    frames = list(boards)
    obs = _observations(names, detections, frames)
    model = board.object_points() if isinstance(board, BoardSpec) else np.asarray(board, float)
    if backend == "ceres":
        why_not = ceres_unsupported(intrinsics)
        if why_not is None:
            rig, targets = bundle_adjust_ceres(intrinsics, model, obs.cam, obs.frame, obs.corner, obs.pixels,
                                               poses, [boards[f] for f in frames], reference, refine_intrinsics,
                                               loss_scale_px)
            return rig, dict(zip(frames, targets)), obs
        log.info("bundle adjustment with scipy: %s", why_not)
    return _bundle_adjust_scipy(intrinsics, model, obs, poses, boards, reference, refine_intrinsics,
                                loss_scale_px, progress)


def _bundle_adjust_scipy(intrinsics: Rig, model: np.ndarray, obs: Observations,
                         poses: list[tuple[np.ndarray, np.ndarray]], boards: dict[Hashable, tuple[np.ndarray, np.ndarray]],
                         reference: int, refine_intrinsics: bool, loss_scale_px: float, progress: bool
                         ) -> tuple[Rig, dict[Hashable, tuple[np.ndarray, np.ndarray]], Observations]:
    """``scipy.optimize.least_squares`` path of :func:`bundle_adjust`."""
    n_cam = len(intrinsics)
    frames = list(boards)
    n_ci = 6 + (N_INTRINSICS if refine_intrinsics else 0)
    k3 = np.array([cam.dist[4] for cam in intrinsics])

    def pack() -> np.ndarray:
        cams = []
        for c, cam in enumerate(intrinsics):
            R, t = poses[c]
            block = [cv2.Rodrigues(R)[0].ravel(), t]
            if refine_intrinsics:
                block.append([cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], *cam.dist[:4]])
            cams.append(np.concatenate(block))
        bds = [np.concatenate([cv2.Rodrigues(R)[0].ravel(), t]) for R, t in (boards[f] for f in frames)]
        return np.concatenate(cams + bds)

    fixed_K = np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]] for c in intrinsics])
    fixed_d = np.array([c.dist for c in intrinsics])
    ref_pose = np.concatenate([cv2.Rodrigues(poses[reference][0])[0].ravel(), poses[reference][1]])

    def unpack(x: np.ndarray):
        cams = x[: n_cam * n_ci].reshape(n_cam, n_ci).copy()
        cams[reference, :6] = ref_pose  # gauge: the reference camera does not move
        bds = x[n_cam * n_ci:].reshape(len(frames), 6)
        if refine_intrinsics:
            Kp, dist = cams[:, 6:10], np.column_stack([cams[:, 10:14], k3])
        else:
            Kp, dist = fixed_K, fixed_d
        return cams, bds, Kp, dist

    bar = tqdm(desc="bundle adjustment", unit=" evals", disable=not progress, leave=False)

    def residuals(x: np.ndarray) -> np.ndarray:
        bar.update()
        cams, bds, Kp, dist = unpack(x)
        Rb = rodrigues(bds[:, :3])[obs.frame]
        Rc = rodrigues(cams[:, :3])[obs.cam]
        world = np.einsum("nij,nj->ni", Rb, model[obs.corner]) + bds[obs.frame, 3:]
        pc = np.einsum("nij,nj->ni", Rc, world) + cams[obs.cam, 3:6]
        return (project_batch(Kp[obs.cam], dist[obs.cam], pc) - obs.pixels).ravel()

    n_obs = len(obs.cam)
    sparsity = lil_matrix((2 * n_obs, n_cam * n_ci + 6 * len(frames)), dtype=int)
    rows = np.arange(n_obs)
    for k in range(n_ci):
        sparsity[2 * rows, obs.cam * n_ci + k] = 1
        sparsity[2 * rows + 1, obs.cam * n_ci + k] = 1
    for k in range(6):
        sparsity[2 * rows, n_cam * n_ci + obs.frame * 6 + k] = 1
        sparsity[2 * rows + 1, n_cam * n_ci + obs.frame * 6 + k] = 1
    sparsity[:, reference * n_ci: reference * n_ci + 6] = 0
    x0 = pack()
    try:
        fit = least_squares(residuals, x0, jac_sparsity=sparsity, loss="huber", f_scale=loss_scale_px,
                            x_scale="jac", method="trf", max_nfev=200, xtol=1e-12, ftol=1e-12)
    finally:
        bar.close()
    cams, bds, Kp, dist = unpack(fit.x)
    cameras = []
    for c, cam in enumerate(intrinsics):
        K = np.array([[Kp[c, 0], cam.K[0, 1], Kp[c, 2]], [0, Kp[c, 1], Kp[c, 3]], [0, 0, 1]])
        cameras.append(Camera(cam.name, K, dist[c], cv2.Rodrigues(cams[c, :3])[0], cams[c, 3:6], cam.size))
    board_poses = {f: (cv2.Rodrigues(bds[k, :3])[0], bds[k, 3:]) for k, f in enumerate(frames)}
    return Rig(cameras), board_poses, obs


# ---------------------------------------------------------------------- step 4 + report
def floor_world_transform(board: BoardSpec, board_poses: dict, floor_frame) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) taking reference-frame points to the world: ``X_w = R X_ref + t``. ``floor_frame``
    is a frame key or a list of them (the board lying on the floor at several places): Z up is
    the normal of a plane fitted to all their corners, the origin and X axis come from the first."""
    frames = list(floor_frame) if isinstance(floor_frame, (list, tuple)) else [floor_frame]
    missing = [f for f in frames if f not in board_poses]
    if missing:
        raise InputError("board views", f"floor frame(s) {missing} have no usable board view; capture the "
                         "board lying flat on the floor, seen whole by at least one camera")
    model = board.object_points()
    R0, t0 = board_poses[frames[0]]
    up = -R0[:, 2]  # board z points into the board, i.e. down into the floor
    if len(frames) > 1:
        corners = np.concatenate([model @ board_poses[f][0].T + board_poses[f][1] for f in frames])
        normal = np.linalg.svd(corners - corners.mean(axis=0))[2][2]
        up = normal if normal @ up > 0 else -normal
    x_axis = R0[:, 0] - (R0[:, 0] @ up) * up
    x_axis /= np.linalg.norm(x_axis)
    R_world_in_ref = np.column_stack([x_axis, np.cross(up, x_axis), up])  # world axes in the reference frame
    R = R_world_in_ref.T
    return R, -R @ t0


def calibrate_extrinsics(intrinsics: Rig, board: BoardSpec, detections: Detections,
                         floor_frame: Hashable | None = None, reference: int = 0,
                         refine_intrinsics: bool = True, progress: bool = True,
                         backend: str = "ceres") -> ExtrinsicsResult:
    """Whole pipeline (see module doc). ``intrinsics``: cameras with calibrated K/dist (poses
    ignored); ``detections[camera][frame]``; ``floor_frame``: the frame where the board lies
    face up on the floor (world Z up); None keeps the reference camera's frame as the world.
    ``backend``: bundle adjustment by ``"ceres"`` (pycolmap) or ``"scipy"``."""
    if is_half_turn_symmetric(board):
        raise InputError("board", f"checkerboard {board.cols}x{board.rows} looks the same after a half turn "
                         "(inner corners both odd or both even), so cameras cannot agree on its corner order. "
                         "Use a board with one odd and one even count of inner corners (e.g. 4x7) or ChArUco")
    _check_sizes(intrinsics)
    detections, rejected = drop_ambiguous_views(detections)
    for (name, frame), why in rejected.items():
        log.warning("left out %s frame %s: %s", name, frame, why)
    poses, boards = initial_poses(intrinsics, board, detections, reference)
    rig, board_poses, obs = bundle_adjust(intrinsics, board, detections, poses, boards, reference,
                                          refine_intrinsics, progress=progress, backend=backend)
    # Drop corners whose residual is far beyond the typical one (mis-refined corners), then
    # adjust again from the refined state.
    detections, n_dropped = drop_outlier_corners(rig, board, detections, board_poses)
    if n_dropped:
        log.info("bundle adjustment: dropped %d outlier corners, adjusting again", n_dropped)
        rig, board_poses, obs = bundle_adjust(rig, board, detections, [(c.R, c.t) for c in rig], board_poses,
                                              reference, refine_intrinsics, progress=progress, backend=backend)
    if floor_frame is not None:
        R, t = floor_world_transform(board, board_poses, floor_frame)
        rig = transform_rig(rig, R, t)
        board_poses = {f: (R @ Rb, R @ tb + t) for f, (Rb, tb) in board_poses.items()}
    else:
        log.warning("no floor frame given: the world frame is camera %s's frame, not Z up", rig[reference].name)
    result = _report(rig, board, detections, board_poses, obs)
    result.rejected = rejected
    return result


def drop_ambiguous_views(detections: Detections) -> tuple[Detections, dict[tuple[str, Hashable], str]]:
    """Leave out views whose corner order is not trusted (:attr:`BoardDetection.order_problem`)
    from frames that several cameras see; a frame one camera sees alone keeps its view (its
    board pose is that camera's own, so the order does not matter). Returns the kept views and
    (camera, frame) -> reason for the ones left out."""
    cameras_per_frame: dict[Hashable, int] = defaultdict(int)
    for views in detections.values():
        for f in views:
            cameras_per_frame[f] += 1
    kept: Detections = {}
    rejected: dict[tuple[str, Hashable], str] = {}
    for name, views in detections.items():
        kept[name] = {}
        for f, det in views.items():
            if det.order_problem and cameras_per_frame[f] > 1:
                rejected[name, f] = f"corner order ambiguous: {det.order_problem}"
            else:
                kept[name][f] = det
    return kept, rejected


def drop_outlier_corners(rig: Rig, board: BoardSpec, detections: Detections, board_poses,
                         factor: float = 5.0, floor_px: float = 0.2) -> tuple[Detections, int]:
    """Remove corners whose reprojection error exceeds ``max(factor * median error, floor_px)``;
    views left with fewer than 6 corners are removed."""
    model = board.object_points()
    errors = {}
    for cam in rig:
        for f, det in detections.get(cam.name, {}).items():
            if f in board_poses:
                R, t = board_poses[f]
                errors[cam.name, f] = np.linalg.norm(cam.project(model[det.ids] @ R.T + t) - det.pixels, axis=1)
    limit = max(factor * float(np.median(np.concatenate(list(errors.values())))), floor_px)
    kept: Detections = {}
    dropped = 0
    for name, views in detections.items():
        kept[name] = {}
        for f, det in views.items():
            good = errors[name, f] <= limit if (name, f) in errors else np.ones(len(det), bool)
            dropped += int((~good).sum())
            if good.sum() >= 6:
                kept[name][f] = BoardDetection(det.ids[good], det.pixels[good], det.blur_px, det.order_problem)
    return kept, dropped


def _check_sizes(rig: Rig) -> None:
    for cam in rig:
        if cam.size[0] <= 0 or cam.size[1] <= 0:
            raise InputError(cam.name, "camera has no image size")


def _report(rig: Rig, board: BoardSpec, detections: Detections, board_poses, obs: Observations) -> ExtrinsicsResult:
    model = board.object_points()
    residuals: dict[str, list] = defaultdict(list)
    for cam in rig:
        for f, det in detections.get(cam.name, {}).items():
            if f not in board_poses:
                continue
            R, t = board_poses[f]
            pred = cam.project(model[det.ids] @ R.T + t)
            residuals[cam.name].append(np.column_stack([det.pixels, pred - det.pixels]))
    res = {n: np.concatenate(v) if v else np.zeros((0, 4)) for n, v in residuals.items()}
    rms = {cam.name: float(np.sqrt(np.mean(np.sum(res[cam.name][:, 2:] ** 2, axis=1)))) if len(res.get(cam.name, []))
           else float("nan") for cam in rig}
    counts = {cam.name: int(len(res.get(cam.name, []))) for cam in rig}
    return ExtrinsicsResult(rig, rms, counts, board_geometry_error(rig, board, detections), res, board_poses)


def board_geometry_error(rig: Rig, board: BoardSpec, detections: Detections) -> dict[Hashable, float]:
    """Per frame seen by >= 2 cameras: RMS distance (mm) between the corners triangulated with
    ``rig`` and the known board geometry after a rigid fit."""
    model = board.object_points()
    frames = defaultdict(dict)
    for cam in rig:
        for f, det in detections.get(cam.name, {}).items():
            frames[f][cam.name] = det
    errors = {}
    for f, views in frames.items():
        if len(views) < 2:
            continue
        ids = sorted(set.intersection(*[set(d.ids.tolist()) for d in views.values()]))
        corner_ids, points = [], []
        for k in ids:
            pix = np.stack([d.pixels[list(d.ids).index(k)] for d in views.values()])
            points.append(triangulate([rig[n] for n in views], pix))
            corner_ids.append(k)
        if len(points) >= 4:
            errors[f] = rigid_fit(model[corner_ids], np.asarray(points))[2]
    return errors
