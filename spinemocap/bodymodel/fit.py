"""MoSh-like fit of a body model to sparse skin markers (Loper et al. 2014, simplified).

Unknowns: the body's shape, one offset per marker (mm, in the rest pose, from the marker's skin
vertex: the marker's height above the skin plus its misplacement) and one pose per frame.

1. Shape stage, on a few key frames (the static trial when given, else frames spread over the
   trial): alternately the key frames' poses and (shape, offsets) by Levenberg-Marquardt. The
   offsets have a prior: ``marker_height_mm`` along the skin normal, deviations weighted as
   ``offset_sigma_mm`` against a ``marker_sigma_mm`` marker residual.
2. Pose stage: every frame by Levenberg-Marquardt, warm-started from the previous frame, shape
   and offsets fixed. Markers missing in a frame simply have no residual (gaps); a frame with
   fewer than ``min_markers`` markers keeps the previous pose and is flagged.

Jacobians come from torch autograd (forward mode, vectorised) through the backend's sparse path.
LBFGS stalls on this problem's ill-conditioning; LM does not. Units: mm, radians.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..geometry import umeyama
from .base import GLOBAL_ROTATION, TRANSLATION, BodyModel, PoseKernel, SurfaceAnchors, batched_jacobian

log = logging.getLogger(__name__)


@dataclass
class FitOptions:
    marker_height_mm: float = 9.5  # 14 mm marker: 7 mm radius + 2.5 mm base
    marker_sigma_mm: float = 5.0
    offset_sigma_mm: float = 10.0
    pose_sigma_rad: float = 1.0  # weak prior pulling joints toward the rest pose
    shape_sigma: float = 1.0  # prior on shape (anny phenotype units / SMPL betas)
    n_key_frames: int = 5
    shape_rounds: int = 2
    shape_iterations: int = 5
    pose_iterations: int = 12  # cold start (first frame, key frames)
    warm_iterations: int = 4  # a frame warm-started from the previous one (more changed nothing measurable)
    min_markers: int = 4
    fit_offsets: bool = True
    # per-frame pose Jacobian: "kernel" = the backend's pose kernel (anny: analytic, numpy, the
    # posed bones only); "autodiff" = one batched forward-mode pass through the whole torch
    # skeleton (the benchmark's peer)
    pose_jacobian: str = "kernel"


@dataclass
class BodyFit:
    """Result: ``shape`` (S,), ``offsets`` (M, 3) mm, ``poses`` (F, P), ``vertices`` (M,) skin
    vertices of the markers, ``residual_mm`` (F, M) marker distances (NaN where missing),
    ``flagged`` (F,) frames whose pose could not be fitted (too few markers)."""

    model_name: str
    labels: list[str]
    vertices: np.ndarray
    shape: np.ndarray
    offsets: np.ndarray
    poses: np.ndarray
    residual_mm: np.ndarray
    flagged: np.ndarray
    timings_s: dict[str, float] = field(default_factory=dict)

    def anchors(self) -> SurfaceAnchors:
        return SurfaceAnchors(self.vertices, self.offsets)


def levenberg_marquardt(residuals: Callable, x0: np.ndarray, iterations: int = 10,
                        bounds: tuple[np.ndarray, np.ndarray] | None = None, tol: float = 1e-6,
                        jac: Callable[[np.ndarray], np.ndarray] | None = None,
                        max_iterations: int | None = None) -> tuple[np.ndarray, float]:
    """:func:`solve_lm` for ``residuals``, a torch function of a float64 vector; Jacobian by
    forward-mode autograd (:func:`jacobian`) unless ``jac(x)`` is given. Returns (x, final cost)."""
    import torch

    def evaluate(v: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return residuals(torch.as_tensor(v)).numpy()

    return solve_lm(evaluate, jac or (lambda v: jacobian(residuals, v)), x0, iterations, bounds, tol, max_iterations)


def solve_lm(evaluate: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
             iterations: int = 10, bounds: tuple[np.ndarray, np.ndarray] | None = None, tol: float = 1e-6,
             max_iterations: int | None = None) -> tuple[np.ndarray, float]:
    """Minimise ``|evaluate(x)|^2`` (numpy residuals (R,), Jacobian ``jac(x)`` (R, N)) from
    ``x0`` by Levenberg-Marquardt. Stops when a step gains less than ``tol`` (relative), or after
    ``iterations`` once a step gains less than 1 %; at most ``max_iterations`` (default
    ``iterations``). Returns (x, final cost)."""
    x = np.asarray(x0, float).copy()
    lam = 1e-3
    r = evaluate(x)
    cost = float(r @ r)
    for iteration in range(max(iterations, max_iterations or 0)):
        J = jac(x)
        JtJ, g = J.T @ J, J.T @ r
        diag = np.maximum(np.diag(JtJ), 1e-9)
        improved = False
        for _ in range(8):
            step = np.linalg.solve(JtJ + lam * np.diag(diag), -g)
            candidate = x + step
            if bounds is not None:
                candidate = np.clip(candidate, *bounds)
            r_new = evaluate(candidate)
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        gain = (cost - cost_new) / max(cost, 1e-12)
        x, r, cost = candidate, r_new, cost_new
        lam = max(lam / 3, 1e-7)
        if gain < tol or (iteration + 1 >= iterations and gain < 1e-2):
            break
    return x, cost


def jacobian(residuals: Callable, x: np.ndarray) -> np.ndarray:
    """(R, N) Jacobian of a torch function of a float64 vector by forward-mode autograd:
    vectorised over the N tangents, or one tangent at a time for the few parameters (shape)
    whose path through anny has no batching rule."""
    import torch
    import torch.autograd.forward_ad as fwAD

    x_t = torch.as_tensor(x, dtype=torch.float64)
    if len(x) > 12:
        return torch.autograd.functional.jacobian(residuals, x_t, vectorize=True, strategy="forward-mode").numpy()
    columns = []
    with torch.no_grad(), fwAD.dual_level():
        for i in range(len(x)):
            tangent = torch.zeros_like(x_t)
            tangent[i] = 1.0
            columns.append(fwAD.unpack_dual(residuals(fwAD.make_dual(x_t, tangent))).tangent.numpy())
    return np.stack(columns, axis=1)


class MarkerFitter:
    """Fits a :class:`~spinemocap.bodymodel.base.BodyModel` to (F, M, 3) mm marker positions
    whose skin vertices (M,) on the model's rest mesh are known (see
    :func:`~spinemocap.bodymodel.markersets.place_markers`)."""

    def __init__(self, model: BodyModel, vertices: np.ndarray, options: FitOptions | None = None):
        self.model = model
        self.vertices = np.asarray(vertices, np.int64)
        self.options = options or FitOptions()
        rest = model.rest()
        self.rest = rest
        self.offset_prior = rest.normals[self.vertices] * self.options.marker_height_mm

    # ------------------------------------------------------------------ residual pieces
    def _marker_residual(self, pose, shape, offsets, observed: np.ndarray):
        """Flattened (model - observed) / marker_sigma over finite markers; pose (F, P)."""
        import torch

        ok = np.isfinite(observed).all(axis=-1)
        pred = self.model.points(pose, shape, SurfaceAnchors(self.vertices, offsets))
        target = torch.as_tensor(np.nan_to_num(observed))
        return (pred - target)[torch.as_tensor(ok)].reshape(-1) / self.options.marker_sigma_mm

    def _frame_residuals(self, poses, shape: np.ndarray, offsets, observed: np.ndarray):
        """(B, R) residuals of B candidate poses (B, P) of one frame's markers (M, 3)."""
        import torch

        ok = torch.as_tensor(np.isfinite(observed).all(axis=-1))
        pred = self.model.points(poses, shape, SurfaceAnchors(self.vertices, offsets))
        target = torch.as_tensor(np.nan_to_num(observed))
        markers = (pred - target)[:, ok].reshape(len(poses), -1) / self.options.marker_sigma_mm
        return torch.cat([markers, poses[:, 6:] / self.options.pose_sigma_rad], dim=1)

    def initial_pose(self, observed: np.ndarray, shape: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Global rigid alignment of the rest model's markers to one frame's markers (F=1)."""
        import torch

        pose = self.model.zero_pose(1)
        ok = np.isfinite(observed).all(axis=-1)
        with torch.no_grad():
            rest_points = self.model.points(torch.as_tensor(pose), np.asarray(shape, float),
                                            SurfaceAnchors(self.vertices, offsets))[0].numpy()
        R, t, _ = umeyama(rest_points[ok], observed[ok], with_scale=False)
        from scipy.spatial.transform import Rotation

        pose[0, GLOBAL_ROTATION] = Rotation.from_matrix(R).as_rotvec()
        # R about the pelvis c: R (x - c) + c + T = R x + t  =>  T = t - c + R c
        c = self.rest.pelvis
        pose[0, TRANSLATION] = t - c + R @ c
        return pose[0]

    def fit_pose(self, observed: np.ndarray, shape: np.ndarray, offsets: np.ndarray, x0: np.ndarray,
                 iterations: int | None = None) -> tuple[np.ndarray, float]:
        """One frame's pose (P,) for (M, 3) observed markers, from ``x0``: ``iterations`` LM
        steps, more (up to ``pose_iterations``) while steps still gain over 1 %."""
        if self.options.pose_jacobian == "autodiff":
            return self._fit_pose_autodiff(observed, shape, offsets, x0, iterations)
        o = self.options
        kernel = self._kernel(shape, offsets)
        ok = np.isfinite(observed).all(axis=-1)
        target = observed[ok]
        n_joint = len(x0) - 6
        prior_jac = np.zeros((n_joint, len(x0)))
        prior_jac[:, 6:] = np.eye(n_joint) / o.pose_sigma_rad
        last: dict[str, np.ndarray] = {}

        def evaluate(x: np.ndarray) -> np.ndarray:
            points, jac = kernel(x)
            last["x"], last["jac"] = x, jac[ok].reshape(-1, len(x)) / o.marker_sigma_mm
            return np.concatenate([((points[ok] - target) / o.marker_sigma_mm).ravel(), x[6:] / o.pose_sigma_rad])

        def jacobian_at(x: np.ndarray) -> np.ndarray:
            if last.get("x") is not x:
                evaluate(x)
            return np.concatenate([last["jac"], prior_jac])

        return solve_lm(evaluate, jacobian_at, x0, iterations or o.pose_iterations, max_iterations=o.pose_iterations)

    def _kernel(self, shape: np.ndarray, offsets: np.ndarray) -> PoseKernel:
        """The model's pose kernel for this shape and these offsets (the last one is kept)."""
        key = (np.asarray(shape, float).tobytes(), np.asarray(offsets, float).tobytes())
        if getattr(self, "_kernel_key", None) != key:
            self._kernel_key = key
            self._cached_kernel = self.model.pose_kernel(np.asarray(shape, float),
                                                         SurfaceAnchors(self.vertices, np.asarray(offsets, float)))
        return self._cached_kernel

    def _fit_pose_autodiff(self, observed: np.ndarray, shape: np.ndarray, offsets: np.ndarray, x0: np.ndarray,
                           iterations: int | None = None) -> tuple[np.ndarray, float]:
        """:meth:`fit_pose` with the autograd Jacobian: one batched forward-mode autograd pass
        through the backend's torch path (all of anny's 104 bones)."""
        import torch

        offsets_t = torch.as_tensor(offsets, dtype=torch.float64)
        shape = np.asarray(shape, float)

        def batch(X):
            return self._frame_residuals(X, shape, offsets_t, observed)

        def residuals(x):
            return batch(x[None])[0]

        return levenberg_marquardt(residuals, x0, iterations or self.options.pose_iterations,
                                   jac=lambda x: batched_jacobian(batch, x),
                                   max_iterations=self.options.pose_iterations)

    def fit_offsets(self, observed: np.ndarray, poses: np.ndarray, shape: np.ndarray) -> np.ndarray:
        """Offsets (M, 3) mm for fixed poses (K, P) and shape: per marker a 3 x 3 linear least
        squares (a skinned point is affine in its rest position) with the offset prior."""
        import torch

        o = self.options
        M = len(self.vertices)
        basis = [np.zeros((M, 3))] + [np.tile(np.eye(3)[i], (M, 1)) for i in range(3)]
        with torch.no_grad():
            p = [self.model.points(torch.as_tensor(poses), np.asarray(shape, float),
                                   SurfaceAnchors(self.vertices, b)).numpy() for b in basis]
        b0 = p[0]  # (K, M, 3) marker positions with zero offset
        A = np.stack([p[i + 1] - b0 for i in range(3)], axis=-1)  # (K, M, 3, 3): d position / d offset
        offsets = np.empty((M, 3))
        w_prior = (o.marker_sigma_mm / o.offset_sigma_mm) ** 2
        for m in range(M):
            ok = np.isfinite(observed[:, m]).all(axis=1)
            lhs = w_prior * np.eye(3) + sum((A[k, m].T @ A[k, m] for k in np.flatnonzero(ok)), np.zeros((3, 3)))
            rhs = w_prior * self.offset_prior[m] + sum(
                (A[k, m].T @ (observed[k, m] - b0[k, m]) for k in np.flatnonzero(ok)), np.zeros(3))
            offsets[m] = np.linalg.solve(lhs, rhs)
        return offsets

    def fit_shape(self, observed: np.ndarray, poses: np.ndarray, shape: np.ndarray, offsets: np.ndarray
                  ) -> np.ndarray:
        """Shape (S,) for fixed key-frame poses (K, P), offsets and markers (K, M, 3)."""
        import torch

        o = self.options
        poses_t = torch.as_tensor(poses)
        offsets_t = torch.as_tensor(offsets)
        shape0 = torch.as_tensor(self.model.default_shape())

        def residuals(x):
            return torch.cat([self._marker_residual(poses_t, x, offsets_t, observed), (x - shape0) / o.shape_sigma])

        bounds = None
        if self.model.shape_bounds is not None:
            bounds = (np.full(len(shape), self.model.shape_bounds[0]), np.full(len(shape), self.model.shape_bounds[1]))
        x, _ = levenberg_marquardt(residuals, np.asarray(shape, float), o.shape_iterations, bounds)
        return x

    # ------------------------------------------------------------------ whole fit
    def fit(self, markers: np.ndarray, static: np.ndarray | None = None, progress: bool = True,
            labels: list[str] | None = None) -> BodyFit:
        """Fit (F, M, 3) mm markers (NaN gaps); ``static`` (K, M, 3) frames of a static trial for
        the shape stage (default: key frames of ``markers``). Runs with one BLAS thread: its
        matrices are small (~180 x 70), and threads fighting over a loaded machine made the
        per-frame pose stage ~4x slower."""
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return self._fit(markers, static, progress, labels)

    def _fit(self, markers: np.ndarray, static: np.ndarray | None, progress: bool, labels: list[str] | None
             ) -> BodyFit:
        import time

        from tqdm import tqdm

        o = self.options
        markers = np.asarray(markers, float)
        F, M = markers.shape[:2]
        shape = self.model.default_shape()
        offsets = self.offset_prior.copy()
        times = {}
        t0 = time.perf_counter()
        key = self._key_frames(static if static is not None else markers)
        log.info("shape stage on %d key frames", len(key))
        key_poses = np.array([self.initial_pose(k, shape, offsets) for k in key])
        for _ in range(o.shape_rounds):
            key_poses = np.array([self.fit_pose(k, shape, offsets, p)[0] for k, p in zip(key, key_poses)])
            shape = self.fit_shape(key, key_poses, shape, offsets)
        if o.fit_offsets:  # offsets last: fitted earlier, they would absorb the shape
            for _ in range(2):
                key_poses = np.array([self.fit_pose(k, shape, offsets, p)[0] for k, p in zip(key, key_poses)])
                offsets = self.fit_offsets(key, key_poses, shape)
        times["shape_stage"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        poses = np.zeros((F, self.model.pose_size))
        flagged = np.zeros(F, bool)
        previous = None
        for f in tqdm(range(F), desc="body fit", unit="frame", disable=not progress):
            ok = np.isfinite(markers[f]).all(axis=1)
            if ok.sum() < o.min_markers:
                flagged[f] = True
                poses[f] = previous if previous is not None else self.model.zero_pose(1)[0]
                continue
            if previous is None:
                poses[f], _ = self.fit_pose(markers[f], shape, offsets, self.initial_pose(markers[f], shape, offsets))
            else:
                poses[f], _ = self.fit_pose(markers[f], shape, offsets, previous, o.warm_iterations)
            previous = poses[f]
        times["pose_stage"] = time.perf_counter() - t0
        residual = self.marker_residuals(markers, poses, shape, offsets)
        return BodyFit(self.model.name, list(labels or [f"M{i}" for i in range(M)]), self.vertices, shape,
                       offsets, poses, residual, flagged, times)

    def _key_frames(self, markers: np.ndarray) -> np.ndarray:
        """Up to ``n_key_frames`` frames spread over ``markers``, preferring complete frames."""
        complete = np.isfinite(markers).all(axis=(1, 2))
        pool = np.flatnonzero(complete) if complete.sum() >= self.options.n_key_frames else \
            np.argsort(-np.isfinite(markers).all(axis=2).sum(axis=1))[: max(self.options.n_key_frames, 1) * 4]
        pool = np.sort(pool)
        pick = np.linspace(0, len(pool) - 1, min(self.options.n_key_frames, len(pool))).round().astype(int)
        return markers[pool[pick]]

    def marker_residuals(self, markers: np.ndarray, poses: np.ndarray, shape: np.ndarray, offsets: np.ndarray
                         ) -> np.ndarray:
        """(F, M) distances (mm) between fitted and observed markers; NaN where missing."""
        import torch

        with torch.no_grad():
            pred = self.model.points(torch.as_tensor(poses), np.asarray(shape, float),
                                     SurfaceAnchors(self.vertices, offsets)).numpy()
        return np.linalg.norm(pred - markers, axis=2)
