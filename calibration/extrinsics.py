"""Multi-camera extrinsics from a ChArUco board seen by several cameras at once.

Pipeline:
1. per (camera, frame) board pose by PnP (IPPE, planar) with each camera's intrinsics;
2. relative pose of every camera pair from their shared frames: both IPPE solutions of an
   ambiguous (small or grazing) view are candidates, the relative pose most frames agree with
   wins (rotation chordal mean, translation median over the agreeing frames); a maximum
   spanning tree over pairs weighted by shared frames (the :class:`PoseGraph`), and the chained
   poses of every camera in the reference camera's frame; each frame's board pose is the
   candidate that reprojects best into all cameras reading it;
3. bundle adjustment over all camera poses, all board poses and (optionally) each camera's
   fx fy cx cy k1 k2 p1 p2, Huber loss of 1 px, by the rig adjustment
   (:class:`spinemocap.rig_adjust.RigAdjustment`, the board a rigid target): by default Ceres
   through pycolmap, or ``scipy.optimize.least_squares`` (``backend="scipy"``, the peer in
   ``bench calibration``); the reference camera's pose fixes the gauge and the board's square size
   fixes the scale; then each frame's other planar solutions compete again with the adjusted
   pose through the adjusted rig (:func:`choose_board_poses`), and a switch adjusts again;
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
from typing import Hashable, Sequence, cast

import cv2
import numpy as np
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError
from spinemocap.rig_adjust import BACKENDS, AdjustmentSettings, Backend, RigAdjustment, RigidTarget

from .boards import BoardDetection, BoardSpec, is_half_turn_symmetric
from .check import camera_table
from .geometry import rigid_fit, triangulate

log = logging.getLogger(__name__)

Detections = dict[str, dict[Hashable, BoardDetection]]  # camera name -> frame -> detection
MAX_POSE_SWITCH_ROUNDS = 3


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
    #: which cameras read the board together and how the initial poses were chained
    pose_graph: "PoseGraph | None" = None

    @property
    def board_rms_mm(self) -> float:
        v = np.array(list(self.board_error_mm.values()))
        return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")

    def summary(self) -> str:
        lines = [camera_table(self.rig, self.residuals, "board corners")]
        lines.append(f"board geometry from triangulated corners: RMS {self.board_rms_mm:.3f} mm over "
                     f"{len(self.board_error_mm)} multi-camera frames")
        lines += [f"left out {name} frame {frame}: {why}" for (name, frame), why in self.rejected.items()]
        if self.pose_graph is not None:
            lines.append(self.pose_graph.summary())
        return "\n".join(lines)


# ---------------------------------------------------------------------- step 1-2: initial poses
Pose = tuple[np.ndarray, np.ndarray]
#: A planar view's second PnP solution is kept as a candidate while its RMS is at most
#: ``AMBIGUOUS_FACTOR`` times the best one's plus ``AMBIGUOUS_MARGIN_PX``.
AMBIGUOUS_FACTOR, AMBIGUOUS_MARGIN_PX = 2.0, 0.5
#: Per-frame relative poses agreeing with a pair hypothesis within these bounds support it.
AGREE_DEG, AGREE_FRACTION = 2.0, 0.05


def _pnp_candidates(cam: Camera, board: BoardSpec, det: BoardDetection) -> list[Pose]:
    """Board -> camera poses that fit one view (PnP by IPPE, both of its solutions refined):
    the best, and the other where the view is ambiguous (a small or grazing board fits two
    poses almost equally, mirror images about the line of sight). Empty when PnP fails."""
    if len(det) < 6:
        return []
    obj = board.object_points()[det.ids]
    try:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, det.pixels, cam.K, cam.dist, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return []
    fits = []
    for rvec, tvec in zip(rvecs[:n], tvecs[:n]):
        rvec, tvec = cv2.solvePnPRefineLM(obj, det.pixels, cam.K, cam.dist, rvec.copy(), tvec.copy())
        pred = cv2.projectPoints(obj, rvec, tvec, cam.K, cam.dist)[0].reshape(-1, 2)
        rms = float(np.sqrt(np.mean(np.sum((pred - det.pixels) ** 2, axis=1))))
        if tvec.ravel()[2] > 0:
            fits.append((rms, cv2.Rodrigues(rvec)[0], tvec.ravel()))
    fits.sort(key=lambda fit: fit[0])
    return [(R, t) for rms, R, t in fits if rms <= AMBIGUOUS_FACTOR * fits[0][0] + AMBIGUOUS_MARGIN_PX]


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


@dataclass
class PoseGraph:
    """Which cameras see the board together: ``shared[i][j]`` frames both cameras i and j read
    the board in, the spanning tree's ``edges`` (parent, child, frames that agree with the chosen
    relative pose / shared frames) the initial poses were chained along."""

    names: list[str]
    shared: np.ndarray
    edges: list[tuple[str, str, int, int]]

    def summary(self) -> str:
        lines = ["pose graph (frames both cameras read the board in):"]
        width = max(len(n) for n in self.names) + 2
        lines.append(" " * width + "".join(f"{n:>{width}}" for n in self.names))
        for i, name in enumerate(self.names):
            lines.append(f"{name:<{width}}" + "".join(f"{'-' if i == j else int(self.shared[i, j]):>{width}}"
                                                       for j in range(len(self.names))))
        lines.append("chained along: " + ", ".join(f"{a} -> {b} ({agree}/{n} frames agree)"
                                                   for a, b, agree, n in self.edges))
        weak = [f"{a} -> {b}" for a, b, agree, n in self.edges if agree < 3 or agree < 0.5 * n]
        if weak:
            lines.append(f"! weak links ({', '.join(weak)}): few shared frames agree on these cameras' relative pose; "
                         "capture more frames where both see the board")
        return "\n".join(lines)


def _relative_pose(views_p: dict[Hashable, list[Pose]], views_c: dict[Hashable, list[Pose]],
                   shared: list[Hashable]) -> tuple[Pose, int]:
    """Parent camera -> camera c from their shared frames: every frame proposes one relative
    pose per pair of its candidate board poses; the proposal most others agree with (within
    :data:`AGREE_DEG` and :data:`AGREE_FRACTION` of the baseline) wins, and its agreeing
    proposals (one per frame, the closest) are averaged. Returns (pose, frames that agree)."""
    frames, rotations, translations = [], [], []
    for k, f in enumerate(shared):
        for Rp, tp in views_p[f]:
            for Rc, tc in views_c[f]:
                R = Rc @ Rp.T
                frames.append(k)
                rotations.append(R)
                translations.append(tc - R @ tp)
    frame, Rs, ts = np.asarray(frames), np.asarray(rotations), np.asarray(translations)
    cos = np.clip((np.einsum("aij,bij->ab", Rs, Rs) - 1) / 2, -1.0, 1.0)  # cos of the angle between proposals
    angle = np.degrees(np.arccos(cos))
    distance = np.linalg.norm(ts[:, None] - ts[None], axis=2)
    agree = (angle <= AGREE_DEG) & (distance <= AGREE_FRACTION * np.maximum(np.linalg.norm(ts, axis=1), 1e-9)[:, None])
    support = [len(np.unique(frame[row])) for row in agree]
    best = int(np.argmax(support))
    chosen = []  # per agreeing frame, its proposal closest to the winner
    for k in np.unique(frame[agree[best]]):
        members = np.flatnonzero(agree[best] & (frame == k))
        chosen.append(members[np.argmin(angle[best, members])])
    return (_mean_rotation(list(Rs[chosen])), np.median(ts[chosen], axis=0)), len(chosen)


def initial_poses(intrinsics: Rig, board: BoardSpec, detections: Detections, reference: int = 0
                  ) -> tuple[list[Pose], dict[Hashable, Pose]]:
    """Camera poses (R, t: reference frame -> camera) by a spanning tree over camera pairs, and
    board poses (R, t: board -> reference frame) for every frame; see :func:`initial_pose_graph`."""
    poses, boards, _, _ = initial_pose_graph(intrinsics, board, detections, reference)
    return poses, boards


def initial_pose_graph(intrinsics: Rig, board: BoardSpec, detections: Detections, reference: int = 0
                       ) -> tuple[list[Pose], dict[Hashable, Pose], dict[Hashable, list[Pose]], PoseGraph]:
    """Camera poses by a spanning tree over camera pairs (each pair's relative pose by consensus
    over its shared frames' candidate board poses, :func:`_relative_pose`), every frame's board
    pose (the candidate from any camera that reprojects best into all cameras seeing the frame),
    every frame's candidate board poses in the reference frame (for :func:`choose_board_poses`
    after the adjustment) and the :class:`PoseGraph`."""
    names = intrinsics.names
    pnp = {c: {f: cands for f, d in detections.get(name, {}).items() if (cands := _pnp_candidates(intrinsics[c], board, d))}
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
    poses: list[Pose | None] = [None] * n
    poses[reference] = (np.eye(3), np.zeros(3))
    edges = []
    for c in order[1:]:
        p = parents[c]
        shared = pair_frames[min(p, c), max(p, c)]
        (R_pc, t_pc), agree = _relative_pose(pnp[p], pnp[c], shared)
        edges.append((names[p], names[c], agree, len(shared)))
        Rp_ref, tp_ref = poses[p]
        poses[c] = (R_pc @ Rp_ref, R_pc @ tp_ref + t_pc)
    rig_poses = cast(list[Pose], poses)  # the spanning tree reached every camera
    placed = Rig([Camera(cam.name, cam.K, cam.dist, R, t, cam.size) for cam, (R, t) in zip(intrinsics, rig_poses)])
    candidates = _candidates_in_world(placed, pnp)
    boards = choose_board_poses(placed, board, detections, candidates)
    return rig_poses, boards, candidates, PoseGraph(names, weights, edges)


def _candidates_in_world(rig: Rig, pnp: dict[int, dict[Hashable, list[Pose]]]) -> dict[Hashable, list[Pose]]:
    """Per frame, every camera's candidate board poses (board -> camera) taken to ``rig``'s world."""
    candidates: dict[Hashable, list[Pose]] = defaultdict(list)
    for c, cam in enumerate(rig):
        for f, cands in pnp.get(c, {}).items():
            candidates[f] += [(cam.R.T @ Rb, cam.R.T @ (tb - cam.t)) for Rb, tb in cands]
    return dict(candidates)


def board_pose_candidates(rig: Rig, board: BoardSpec, detections: Detections) -> dict[Hashable, list[Pose]]:
    """Per frame, the candidate board poses (board -> world) of every camera that reads it
    (:func:`_pnp_candidates` with the rig's intrinsics, through its camera poses)."""
    pnp = {c: {f: cands for f, d in detections.get(cam.name, {}).items() if (cands := _pnp_candidates(cam, board, d))}
           for c, cam in enumerate(rig)}
    return _candidates_in_world(rig, pnp)


def choose_board_poses(rig: Rig, board: BoardSpec, detections: Detections,
                       candidates: dict[Hashable, list[Pose]], keep_first_within: float = 0.0) -> dict[Hashable, Pose]:
    """Per frame, the candidate board pose (board -> ``rig``'s world) with the least robust
    reprojection error (Huber, 1 px) summed over every camera that reads the board in it. With
    ``keep_first_within`` > 0 a frame's first candidate stays unless another costs less than
    ``(1 - keep_first_within)`` times its cost (no flip-flopping between near-equal solutions)."""
    model = board.object_points()
    chosen = {}
    for f, cands in candidates.items():
        views = [(cam, detections[cam.name][f]) for cam in rig if f in detections.get(cam.name, {})]

        def cost(pose: Pose, views=views) -> float:
            R, t = pose
            total = 0.0
            for cam, det in views:
                points = model[det.ids] @ R.T + t
                if np.any(cam.depth(points) <= 0):
                    return np.inf
                e = np.linalg.norm(cam.project(points) - det.pixels, axis=1)
                total += float(np.sum(np.where(e <= 1.0, 0.5 * e ** 2, e - 0.5)))
            return total

        best = min(cands, key=cost)
        if keep_first_within > 0 and cost(best) >= (1 - keep_first_within) * cost(cands[0]):
            best = cands[0]
        chosen[f] = best
    return chosen


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


def bundle_adjust(intrinsics: Rig, board: BoardSpec | np.ndarray, detections: Detections,
                  poses: list[tuple[np.ndarray, np.ndarray]], boards: dict[Hashable, tuple[np.ndarray, np.ndarray]],
                  reference: int = 0, refine_intrinsics: bool = True, loss_scale_px: float = 1.0,
                  progress: bool = True, backend: Backend = "ceres"
                  ) -> tuple[Rig, dict[Hashable, tuple[np.ndarray, np.ndarray]], Observations]:
    """Refine all camera poses, board poses and (optionally) intrinsics with the rig adjustment
    (:class:`spinemocap.rig_adjust.RigAdjustment`, the board a rigid target); see module doc.
    ``board`` may also be the (N, 3) model points of any rigid target (e.g. the Vicon wand),
    indexed by the detections' ids. ``backend``: ``"ceres"`` (pycolmap; scipy, with a log line,
    for cameras with a k3 term) or ``"scipy"``. Returns the rig, the board poses and the
    observations used; :class:`InputError` for an unknown backend."""
    if backend not in BACKENDS:
        raise InputError("backend", f"unknown bundle adjustment backend {backend!r}; choose one of {BACKENDS}")
    frames = list(boards)
    obs = _observations(intrinsics.names, detections, frames)
    model = board.object_points() if isinstance(board, BoardSpec) else np.asarray(board, float)
    start = Rig([Camera(cam.name, cam.K, cam.dist, R, t, cam.size) for cam, (R, t) in zip(intrinsics, poses)])
    target = RigidTarget(model, [boards[f] for f in frames], obs.cam, obs.frame, obs.corner, obs.pixels)
    settings = AdjustmentSettings(intrinsics="full" if refine_intrinsics else "fixed", reference=reference,
                                  loss_scale_px=loss_scale_px, max_evaluations=200, tolerance=1e-12,
                                  backend=backend, progress=progress)
    adjusted = RigAdjustment(start, target=target, settings=settings).solve()
    return adjusted.rig, dict(zip(frames, adjusted.target_poses)), obs


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
                         floor_frame: Hashable | Sequence[Hashable] | None = None, reference: int = 0,
                         refine_intrinsics: bool = True, progress: bool = True,
                         backend: Backend = "ceres") -> ExtrinsicsResult:
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
    poses, boards, _, graph = initial_pose_graph(intrinsics, board, detections, reference)
    rig, board_poses, obs = bundle_adjust(intrinsics, board, detections, poses, boards, reference,
                                          refine_intrinsics, progress=progress, backend=backend)
    # Planar ambiguity: each frame's other PnP solutions, seen through the adjusted rig, compete
    # with the adjusted pose; where one fits all cameras better the adjustment runs again from it.
    for _ in range(MAX_POSE_SWITCH_ROUNDS):
        candidates = board_pose_candidates(rig, board, detections)
        for f, pose in board_poses.items():
            candidates.setdefault(f, []).insert(0, pose)
        chosen = choose_board_poses(rig, board, detections, candidates, keep_first_within=0.2)
        switched = [f for f in chosen if chosen[f] is not candidates[f][0]]
        if not switched:
            break
        log.info("bundle adjustment: %d board poses switched to their other planar solution, adjusting again",
                 len(switched))
        rig, board_poses, obs = bundle_adjust(rig, board, detections, [(c.R, c.t) for c in rig], chosen,
                                              reference, refine_intrinsics, progress=progress, backend=backend)
    # Drop corners whose residual is far beyond the typical one (mis-refined corners), then
    # adjust again from the refined state.
    detections, n_dropped = drop_outlier_corners(rig, board, detections, board_poses)
    if n_dropped:
        log.info("bundle adjustment: dropped %d outlier corners, adjusting again", n_dropped)
        rig, board_poses, obs = bundle_adjust(rig, board, detections, [(c.R, c.t) for c in rig], board_poses,
                                              reference, refine_intrinsics, progress=progress, backend=backend)
    if floor_frame is not None:
        R, t = floor_world_transform(board, board_poses, floor_frame)
        rig = rig.transformed(R, t)
        board_poses = {f: (R @ Rb, R @ tb + t) for f, (Rb, tb) in board_poses.items()}
    else:
        log.warning("no floor frame given: the world frame is camera %s's frame, not Z up", rig[reference].name)
    result = _report(rig, board, detections, board_poses, obs)
    result.rejected = rejected
    result.pose_graph = graph
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
    frames: defaultdict[Hashable, dict[str, BoardDetection]] = defaultdict(dict)
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
