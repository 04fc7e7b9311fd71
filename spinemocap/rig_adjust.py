"""The one sparse adjustment of a camera rig (bundle adjustment), for calibration and the tracker.

What is seen (all pixels distorted, world mm, camera poses world -> camera):

- :class:`FreePoints`: 3D points solved for together with the rig (the tracker's dots), each
  seen by several cameras; with clock offsets camera ``c`` sees point ``X`` at
  ``X + dt_c V`` (``V`` its velocity, mm/s; ``dt_c`` s against camera 0);
- :class:`RigidTarget`: a rigid object of known shape (board corners, wand markers) whose pose
  in each frame is solved for (calibration);
- :class:`FixedPoints`: points at known world positions (a reference object's markers:
  control points), weighted against the rest.

What is solved for (:class:`AdjustmentSettings`): every camera's pose; its intrinsics
(``"fixed"``, ``"focal"``: one focal-length scale, or ``"full"``: fx fy cx cy k1 k2 p1 p2, k3
held); optionally a clock offset per camera; the free points and the target poses. The gauge is
fixed by a ``reference`` camera whose pose is held, or by :class:`CameraPriors` pulling every
camera's centre and rotation toward the given rig. Every observation's residual goes through a
Huber loss of ``loss_scale_px``.

Solvers: Ceres through pycolmap (COLMAP's bundle adjuster: sparse Schur complement, analytic
Jacobians) where the problem fits it (a rigid target only, a reference camera, no priors, no
clock offsets, fixed or full intrinsics, no k3), and ``scipy.optimize.least_squares`` (trust
region reflective on the sparse Jacobian pattern) for everything, and as the peer. The Ceres
mapping swaps the roles of the objects: the world of the COLMAP reconstruction is the target's
frame, so the target's points are the same constant 3D points in every frame; each capture frame
is a COLMAP frame whose ``rig_from_world`` is the target's pose in the reference camera's frame;
each camera is a sensor of one COLMAP rig, ``sensor_from_rig`` its pose relative to the reference
camera (the reference sensor is the identity: the gauge). COLMAP's ``OPENCV`` model (fx fy cx cy
k1 k2 p1 p2) is OpenCV's projection with k3 = 0.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csr_matrix
from tqdm import tqdm

from .camera import Camera, Rig
from .fileio import InputError
from .geometry import distort, rotation_matrices

log = logging.getLogger(__name__)

Pose = tuple[np.ndarray, np.ndarray]
#: ``fixed``: intrinsics held; ``focal``: one focal-length scale per camera (fx and fy together);
#: ``full``: fx fy cx cy k1 k2 p1 p2 per camera (k3 and skew held)
IntrinsicsMode = Literal["fixed", "focal", "full"]
#: ``ceres``: Ceres through pycolmap where the problem fits it, scipy otherwise; ``scipy``: scipy
Backend = Literal["ceres", "scipy"]
BACKENDS: tuple[Backend, ...] = ("ceres", "scipy")
#: the solver that produced an :class:`AdjustedRig` (``start``: the unsolved start)
SolvedBy = Literal["start", "ceres", "scipy"]
INTRINSIC_COUNTS: dict[IntrinsicsMode, int] = {"fixed": 0, "focal": 1, "full": 8}
CERES_MAX_ITERATIONS = 100


@dataclass
class FreePoints:
    """3D points solved for with the rig. ``cam`` (M,) camera index and ``point`` (M,) point
    index of each observation, ``uv`` (M, 2) its distorted px; ``start`` (P, 3) mm the points'
    start positions; ``velocity`` (P, 3) mm/s (needed for clock offsets; None: static)."""

    cam: np.ndarray
    point: np.ndarray
    uv: np.ndarray
    start: np.ndarray
    velocity: np.ndarray | None = None


@dataclass
class RigidTarget:
    """A rigid object of known shape seen in several frames. ``model`` (N, 3) mm its points in
    its own frame; ``poses`` its start pose per frame (R (3, 3), t (3,): target -> world);
    observation k is model point ``corner[k]`` in frame ``frame[k]`` seen by camera ``cam[k]``
    at distorted px ``uv[k]``."""

    model: np.ndarray
    poses: list[Pose]
    cam: np.ndarray
    frame: np.ndarray
    corner: np.ndarray
    uv: np.ndarray


@dataclass
class FixedPoints:
    """Points at known world positions (control points): observation k is world point
    ``world_mm[k]`` (mm) seen by camera ``cam[k]`` at distorted px ``uv[k]``; ``weight``
    multiplies their residuals."""

    world_mm: np.ndarray
    cam: np.ndarray
    uv: np.ndarray
    weight: float = 1.0


@dataclass
class CameraPriors:
    """Widths of the priors pulling each camera toward the given rig: ``centre_mm`` (C,) on its
    centre, ``rotation_rad`` (C,) on its rotation vector."""

    centre_mm: np.ndarray
    rotation_rad: np.ndarray


@dataclass
class AdjustmentSettings:
    """What the adjustment solves for and how. ``reference``: the camera whose pose is held (the
    gauge; None: the priors pick it); ``max_evaluations`` bounds scipy's residual evaluations;
    ``tolerance``: scipy's ``xtol`` and ``ftol`` (None: scipy's defaults); ``exact_steps``: tight
    lsmr tolerances for scipy's trust-region steps (steps along nearly flat gauge directions);
    ``progress``: a progress bar of scipy's evaluations."""

    intrinsics: IntrinsicsMode = "fixed"
    clock_offsets: bool = False
    reference: int | None = 0
    priors: CameraPriors | None = None
    loss_scale_px: float = 1.0
    max_evaluations: int = 100
    tolerance: float | None = None
    exact_steps: bool = False
    backend: Backend = "ceres"
    progress: bool = False


@dataclass
class AdjustedRig:
    """A state of the adjustment: the ``rig``, the target's ``target_poses`` (target -> world),
    the free ``points`` (P, 3) mm, per camera ``focal_scale`` (C,) against the given rig and
    ``clock_offsets_s`` (C,), and each observation's reprojection error (px, unweighted):
    ``point_errors_px`` (M,) of the free points, ``target_errors_px`` of the target,
    ``control_errors_px`` of the fixed points. ``backend``: the solver that produced it
    (``"start"`` for the unsolved start)."""

    rig: Rig
    target_poses: list[Pose]
    points: np.ndarray
    focal_scale: np.ndarray
    clock_offsets_s: np.ndarray
    point_errors_px: np.ndarray
    target_errors_px: np.ndarray
    control_errors_px: np.ndarray
    backend: SolvedBy
    vector: np.ndarray = field(repr=False)  # the solver's parameters, to start another solve from


def project_batch(fx: np.ndarray, fy: np.ndarray, cx: np.ndarray, cy: np.ndarray, skew: np.ndarray,
                  dist: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """(N, 2) distorted px of (N, 3) camera-frame points, one camera per row: focal lengths,
    principal point and skew (N,) px, ``dist`` (N, 5) OpenCV k1 k2 p1 p2 k3."""
    xd, yd = distort(points_cam[:, :2] / points_cam[:, 2:3], dist).T
    return np.column_stack([fx * xd + skew * yd + cx, fy * yd + cy])


class RigAdjustment:
    """One bundle adjustment problem over ``rig`` (start values; the priors' centre) and what
    its cameras see; :meth:`solve` runs it, :meth:`initial` is the unsolved start.

    Raises :class:`~spinemocap.fileio.InputError` naming the parameter for an inconsistent
    problem (nothing seen, an unknown backend or intrinsics mode, a reference camera out of
    range, clock offsets without point velocities, priors of the wrong length)."""

    def __init__(self, rig: Rig, points: FreePoints | None = None, target: RigidTarget | None = None,
                 control: FixedPoints | None = None, settings: AdjustmentSettings | None = None) -> None:
        self.rig, self.settings = rig, settings or AdjustmentSettings()
        s = self.settings
        if s.backend not in BACKENDS:
            raise InputError("backend", f"unknown bundle adjustment backend {s.backend!r}; choose one of {BACKENDS}")
        if s.intrinsics not in INTRINSIC_COUNTS:
            raise InputError("intrinsics", f"unknown intrinsics mode {s.intrinsics!r}; choose one of "
                             f"{tuple(INTRINSIC_COUNTS)}")
        if points is None and target is None:
            raise InputError("observations", "nothing to adjust on: give free points or a rigid target")
        if s.reference is not None and not 0 <= s.reference < len(rig):
            raise InputError("reference", f"reference camera {s.reference} is not one of the rig's {len(rig)} cameras")
        if s.clock_offsets and (points is None or points.velocity is None):
            raise InputError("clock_offsets", "clock offsets need free points with velocities")
        if s.priors is not None and (len(s.priors.centre_mm) != len(rig) or len(s.priors.rotation_rad) != len(rig)):
            raise InputError("priors", f"priors need one centre and one rotation width per camera ({len(rig)})")
        self.points = points or FreePoints(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3)))
        self.target = target or RigidTarget(np.zeros((0, 3)), [], np.zeros(0, int), np.zeros(0, int),
                                            np.zeros(0, int), np.zeros((0, 2)))
        self.control = control or FixedPoints(np.zeros((0, 3)), np.zeros(0, int), np.zeros((0, 2)))
        self.n_intrinsics = INTRINSIC_COUNTS[s.intrinsics]
        self.n_camera = 6 + self.n_intrinsics + int(s.clock_offsets)
        self._rvec0 = np.stack([cam.rvec for cam in rig])
        self._centres0 = np.stack([cam.center for cam in rig])
        self._K = np.stack([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], c.K[0, 1]] for c in rig])
        self._dist = np.stack([cam.dist for cam in rig])
        self._x0 = self._pack(rig, self.target.poses, self.points.start, np.ones(len(rig)), np.zeros(len(rig)))
        self._reference_pose = (self._x0[s.reference * self.n_camera: s.reference * self.n_camera + 6].copy()
                                if s.reference is not None else None)

    # ------------------------------------------------------------------ parameters

    def _pack(self, rig: Rig, poses: list[Pose], points: np.ndarray, focal_scale: np.ndarray,
              clock_s: np.ndarray) -> np.ndarray:
        """The parameter vector: camera blocks (rvec, t, intrinsics, clock), target poses (rvec, t), points."""
        cams = []
        for c, cam in enumerate(rig):
            block = [cam.rvec, cam.t]
            if self.settings.intrinsics == "full":
                block.append(np.array([cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], *cam.dist[:4]]))
            elif self.settings.intrinsics == "focal":
                block.append(np.array([focal_scale[c]]))
            if self.settings.clock_offsets:
                block.append(np.array([clock_s[c]]))
            cams.append(np.concatenate(block))
        targets = [np.concatenate([cv2.Rodrigues(np.asarray(R, float))[0].ravel(), t]) for R, t in poses]
        return np.concatenate(cams + targets + [np.asarray(points, float).ravel()])

    def _unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(camera blocks (C, n_camera), target poses (F, 6), points (P, 3)); the gauge's held values put back."""
        C, F = len(self.rig), len(self.target.poses)
        cams = x[: C * self.n_camera].reshape(C, self.n_camera).copy()
        if self._reference_pose is not None:
            cams[self.settings.reference, :6] = self._reference_pose
        if self.settings.clock_offsets:
            cams[0, -1] = 0.0  # clocks against camera 0 (a common offset is a gauge)
        targets = x[C * self.n_camera: C * self.n_camera + 6 * F].reshape(F, 6)
        return cams, targets, x[C * self.n_camera + 6 * F:].reshape(-1, 3)

    def _intrinsics(self, cams: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(K (C, 5) fx fy cx cy skew, dist (C, 5), focal scale (C,)) of the camera blocks."""
        if self.settings.intrinsics == "full":
            K = np.column_stack([cams[:, 6:10], self._K[:, 4]])
            return K, np.column_stack([cams[:, 10:14], self._dist[:, 4]]), np.ones(len(cams))
        if self.settings.intrinsics == "focal":
            K = self._K.copy()
            K[:, 0] *= cams[:, 6]
            K[:, 1] *= cams[:, 6]
            return K, self._dist, cams[:, 6].copy()
        return self._K, self._dist, np.ones(len(cams))

    # ------------------------------------------------------------------ residuals
    def _errors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Unweighted residuals: free points (M, 2), target (N, 2), priors (6C,), control (Q, 2)."""
        cams, targets, X = self._unpack(x)
        R, t = rotation_matrices(cams[:, :3]), cams[:, 3:6]
        K, dist, _ = self._intrinsics(cams)

        def pixels(cam: np.ndarray, world: np.ndarray) -> np.ndarray:
            pc = np.einsum("nij,nj->ni", R[cam], world) + t[cam]
            k = K[cam]
            return project_batch(k[:, 0], k[:, 1], k[:, 2], k[:, 3], k[:, 4], dist[cam], pc)

        pts, tgt, ctrl = self.points, self.target, self.control
        world = X[pts.point]
        if self.settings.clock_offsets and pts.velocity is not None:
            world = world + cams[pts.cam, -1, None] * pts.velocity[pts.point]
        point_res = pixels(pts.cam, world) - pts.uv
        Rb = rotation_matrices(targets[:, :3])[tgt.frame]
        on_target = np.einsum("nij,nj->ni", Rb, tgt.model[tgt.corner]) + targets[tgt.frame, 3:]
        target_res = pixels(tgt.cam, on_target) - tgt.uv
        priors = np.zeros(0)
        if self.settings.priors is not None:
            centres = -np.einsum("cji,cj->ci", R, t)
            priors = np.concatenate([((centres - self._centres0) / self.settings.priors.centre_mm[:, None]).ravel(),
                                     ((cams[:, :3] - self._rvec0) / self.settings.priors.rotation_rad[:, None]).ravel()])
        control_res = pixels(ctrl.cam, ctrl.world_mm) - ctrl.uv
        return point_res, target_res, priors, control_res

    def _residuals(self, x: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
        point_res, target_res, priors, control_res = self._errors(x)
        if weights is not None:
            point_res = point_res * weights[:, None]
        return np.concatenate([point_res.ravel(), target_res.ravel(), priors, self.control.weight * control_res.ravel()])

    def _sparsity(self) -> csr_matrix:
        """Which parameters each residual depends on."""
        C, F, n = len(self.rig), len(self.target.poses), self.n_camera
        targets0, points0 = C * n, C * n + 6 * F
        pose_intr = np.arange(6 + self.n_intrinsics)
        rows: list[np.ndarray] = []
        cols: list[np.ndarray] = []

        def add(row: np.ndarray, col: np.ndarray) -> None:  # every row of ``row`` on every column of ``col``
            r, c = np.broadcast_arrays(row[:, None], col)
            rows.append(r.ravel())
            cols.append(c.ravel())

        def observed(start: int, cam: np.ndarray, own: np.ndarray, camera_columns: np.ndarray) -> int:
            """Rows of observations (two each) on their camera's columns and their own ``own`` (M, k) columns."""
            for axis in (0, 1):
                row = start + 2 * np.arange(len(cam)) + axis
                r, c = np.broadcast_arrays(row[:, None], cam[:, None] * n + camera_columns[None])
                rows.append(r.ravel())
                cols.append(c.ravel())
                r, c = np.broadcast_arrays(row[:, None], own)
                rows.append(r.ravel())
                cols.append(c.ravel())
            return start + 2 * len(cam)

        pts, tgt = self.points, self.target
        row = observed(0, pts.cam, points0 + 3 * pts.point[:, None] + np.arange(3), np.arange(n))
        row = observed(row, tgt.cam, targets0 + 6 * tgt.frame[:, None] + np.arange(6), pose_intr)
        if self.settings.priors is not None:
            for c in range(C):
                add(row + 3 * c + np.arange(3), c * n + np.arange(6))
                add(row + 3 * C + 3 * c + np.arange(3), c * n + np.arange(3))
            row += 6 * C
        row = observed(row, self.control.cam, np.zeros((len(self.control.cam), 0), int), pose_intr)
        held = np.zeros(len(self._x0), bool)  # the gauge's held parameters: structurally zero columns
        if self.settings.reference is not None:
            held[self.settings.reference * n: self.settings.reference * n + 6] = True
        if self.settings.clock_offsets:
            held[n - 1] = True
        all_rows, all_cols = np.concatenate(rows), np.concatenate(cols)
        free = ~held[all_cols]
        return coo_matrix((np.ones(int(free.sum()), int), (all_rows[free], all_cols[free])),
                          shape=(row, len(self._x0))).tocsr()

    # ------------------------------------------------------------------ solving
    def _state(self, x: np.ndarray, backend: SolvedBy) -> AdjustedRig:
        cams, targets, X = self._unpack(x)
        K, dist, focal = self._intrinsics(cams)
        rig = Rig([Camera(cam.name, np.array([[K[c, 0], K[c, 4], K[c, 2]], [0.0, K[c, 1], K[c, 3]], [0.0, 0.0, 1.0]]),
                          dist[c].copy(), cv2.Rodrigues(cams[c, :3])[0], cams[c, 3:6].copy(), cam.size)
                   for c, cam in enumerate(self.rig)])
        poses = [(cv2.Rodrigues(p[:3])[0], p[3:].copy()) for p in targets]
        point_res, target_res, _, control_res = self._errors(x)
        clock = cams[:, -1].copy() if self.settings.clock_offsets else np.zeros(len(self.rig))
        return AdjustedRig(rig, poses, X.copy(), focal, clock, np.linalg.norm(point_res, axis=1),
                           np.linalg.norm(target_res, axis=1), np.linalg.norm(control_res, axis=1), backend, x.copy())

    def initial(self) -> AdjustedRig:
        """The unsolved start: the given rig, target poses and points."""
        return self._state(self._x0, "start")

    def ceres_unfit(self) -> str | None:
        """Why Ceres (through pycolmap) cannot take this problem; None when it can."""
        s = self.settings
        reasons = [(len(self.points.cam) > 0, "free points"), (len(self.control.cam) > 0, "control points"),
                   (s.priors is not None, "camera priors"), (s.clock_offsets, "clock offsets"),
                   (s.reference is None, "no reference camera"), (s.intrinsics == "focal", "a focal scale"),
                   (any(abs(cam.dist[4]) > 0 for cam in self.rig), "a camera with a k3 radial term")]
        found = [why for present, why in reasons if present]
        return f"COLMAP's adjuster takes no {', '.join(found)}" if found else None

    def solve(self, start: AdjustedRig | None = None, weights: np.ndarray | None = None,
              loss_scale_px: float | None = None) -> AdjustedRig:
        """The adjusted state from ``start`` (default: :meth:`initial`). ``weights`` (M,)
        multiply the free points' residuals (0 leaves an observation out); ``loss_scale_px``
        overrides the settings' Huber scale. Ceres where the problem fits and the backend is
        ``"ceres"`` (without weights), scipy otherwise (the reason logged)."""
        s = self.settings
        scale = s.loss_scale_px if loss_scale_px is None else loss_scale_px
        x = self._x0 if start is None else start.vector
        if s.backend == "ceres":
            why_not = self.ceres_unfit() or ("per-observation weights" if weights is not None else None)
            if why_not is None:
                rig, poses = (self.rig, self.target.poses) if start is None else (start.rig, start.target_poses)
                rig, poses = self._solve_ceres(rig, poses, scale)
                state = self._state(self._pack(rig, poses, self.points.start, np.ones(len(rig)), np.zeros(len(rig))),
                                    "ceres")
                state.rig, state.target_poses = rig, poses  # Ceres's own values, not through rotation vectors
                return state
            log.info("bundle adjustment with scipy: %s", why_not)
        return self._state(self._solve_scipy(x, weights, scale), "scipy")

    def _solve_scipy(self, x0: np.ndarray, weights: np.ndarray | None, scale: float) -> np.ndarray:
        s = self.settings
        options: dict[str, Any] = {}
        if s.tolerance is not None:
            options.update(xtol=s.tolerance, ftol=s.tolerance)
        if s.exact_steps:
            options["tr_options"] = {"atol": 1e-12, "btol": 1e-12}
        bar = tqdm(desc="bundle adjustment", unit=" evals", disable=not s.progress, leave=False)

        def residuals(x: np.ndarray) -> np.ndarray:
            bar.update()
            return self._residuals(x, weights)

        try:
            fit = least_squares(residuals, x0, jac_sparsity=self._sparsity(), loss="huber", f_scale=scale,
                                x_scale="jac", method="trf", max_nfev=s.max_evaluations, **options)
        finally:
            bar.close()
        return fit.x

    def _solve_ceres(self, rig: Rig, targets: list[Pose], scale: float) -> tuple[Rig, list[Pose]]:
        """Ceres through pycolmap (see module): the adjusted rig and target poses."""
        import pycolmap

        tgt, reference = self.target, int(self.settings.reference or 0)
        refine = self.settings.intrinsics == "full"

        def sensor(c: int) -> Any:
            return pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=c + 1)

        def rigid(R: np.ndarray, t: np.ndarray) -> Any:
            return pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(R, float)), np.asarray(t, float))

        rec = pycolmap.Reconstruction()
        R_ref, t_ref = rig[reference].R, rig[reference].t
        colmap_rig = pycolmap.Rig(rig_id=1)
        for c, cam in enumerate(rig):
            params = [cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], *cam.dist[:4]]
            rec.add_camera(pycolmap.Camera(camera_id=c + 1, model="OPENCV", width=cam.size[0], height=cam.size[1],
                                           params=params))
            if c == reference:
                colmap_rig.add_ref_sensor(sensor(c))
            else:  # camera pose relative to the reference camera
                colmap_rig.add_sensor(sensor(c), rigid(cam.R @ R_ref.T, cam.t - cam.R @ R_ref.T @ t_ref))
        rec.add_rig(colmap_rig)
        point_ids = [rec.add_point3D(p, pycolmap.Track()) for p in np.asarray(tgt.model, float)]
        config = pycolmap.BundleAdjustmentConfig()
        image_id = 0
        for f, (R_t, t_t) in enumerate(targets):
            in_frame = np.flatnonzero(tgt.frame == f)
            cams = np.unique(tgt.cam[in_frame])
            if not len(cams):
                continue
            frame = pycolmap.Frame(frame_id=f + 1, rig_id=1)
            frame.rig_from_world = rigid(R_ref @ R_t, R_ref @ t_t + t_ref)  # target -> reference camera
            images = []
            for c in cams:
                image_id += 1
                frame.add_data_id(pycolmap.data_t(sensor_id=sensor(int(c)), id=image_id))
                images.append((image_id, in_frame[tgt.cam[in_frame] == c]))
            rec.add_frame(frame)
            for iid, rows in images:
                image = pycolmap.Image(name=f"{f}_{iid}", keypoints=tgt.uv[rows], camera_id=int(tgt.cam[rows[0]]) + 1,
                                       image_id=iid)
                image.frame_id = f + 1
                rec.add_image(image)
            rec.register_frame(f + 1)
            for iid, rows in images:
                config.add_image(iid)
                for k, row in enumerate(rows):
                    rec.add_observation(point_ids[tgt.corner[row]], pycolmap.TrackElement(iid, k))
        for pid in point_ids:
            config.add_constant_point(pid)
        if not refine:
            for c in range(len(rig)):
                config.set_constant_cam_intrinsics(c + 1)
        options = pycolmap.BundleAdjustmentOptions()
        options.refine_focal_length = options.refine_principal_point = options.refine_extra_params = refine
        options.print_summary = False
        options.ceres.loss_function_type = pycolmap.LossFunctionType.HUBER
        options.ceres.loss_function_scale = scale
        options.ceres.solver_options.max_num_iterations = CERES_MAX_ITERATIONS
        options.ceres.solver_options.function_tolerance = 1e-12
        options.ceres.solver_options.gradient_tolerance = 1e-10
        options.ceres.solver_options.parameter_tolerance = 1e-12
        pycolmap.create_default_bundle_adjuster(options, config, rec).solve()

        solved = rec.rig(1)
        cameras = []
        for c, cam in enumerate(rig):
            if c == reference:
                R_c, t_c = R_ref, t_ref
            else:
                rel = solved.sensor_from_rig(sensor(c))
                if rel is None:
                    raise RuntimeError(f"the adjustment dropped camera {cam.name!r} from the rig")
                R_rel, t_rel = rel.rotation.matrix(), np.asarray(rel.translation)
                R_c, t_c = R_rel @ R_ref, R_rel @ t_ref + t_rel
            fx, fy, cx, cy, *dist4 = rec.camera(c + 1).params
            K = np.array([[fx, cam.K[0, 1], cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            cameras.append(Camera(cam.name, K, np.array([*dist4, cam.dist[4]]), R_c, t_c, cam.size))
        refined = []
        for f, pose in enumerate(targets):
            world = rec.frame(f + 1).rig_from_world if rec.exists_frame(f + 1) else None
            if world is None:  # a target the adjustment did not pose keeps its start
                refined.append(pose)
                continue
            R_f, t_f = world.rotation.matrix(), np.asarray(world.translation)
            refined.append((R_ref.T @ R_f, R_ref.T @ (t_f - t_ref)))
        return Rig(cameras), refined
