"""Refine the rig on the tracked dots of the capture itself (``spinemocap track --refine-rig``).

Every observed dot-frame is a 3D point seen by >= 2 cameras at known blobs: a bundle adjustment
over the camera poses (and optionally a focal-length scale and a clock offset per camera) and
those points, with the intrinsics' principal point and distortion held fixed.

- Solver: the rig adjustment (:class:`spinemocap.rig_adjust.RigAdjustment`, the dots as free
  points) by scipy's ``least_squares`` (trust-region reflective on the sparse Jacobian pattern,
  Huber loss of ``loss_scale_px`` after a first solve at the given rig's robust residual level);
  COLMAP's Ceres adjuster takes neither the priors nor the clock offsets.
- Gauge: the dots alone fix neither the world frame nor the scale (a similarity common to all
  cameras moves every triangulated dot and changes no residual). By default no camera is held;
  priors pull every camera's centre and rotation toward the given rig, so the correction is the
  smallest one in the gauge directions: the refined rig keeps the given rig's average frame and
  metric size (each camera's own error partly averages out, where fixing one ``reference``
  camera would carry that camera's whole error into every point). The widths (20 mm, 0.5 deg:
  a rotation and a shift that move the dots' images about as much at ~2 m) are wide against a
  calibration's real errors (~2-3 mm, ~0.05 deg at 2 px), so the data settle everything they
  can see and the priors only pick the gauge. Other gauges for the same refined geometry are
  options, none better on average at 1-2 px (``spinemocap bench gauge``): widths sized from
  each camera's own residual (:func:`residual_priors`, ``centre_prior_mm=None``), the
  similarity closest to the given cameras (:func:`closest_gauge`), and the similarity that fits
  the refined dots onto the given rig's own triangulation of them. The refined dots' shape is as
  good as the true rig's; the rest is the given rig's world frame.
  What the given rig's frame errs by cannot be removed by any choice of gauge: ``rig_refine.json``
  reports ``frame_uncertainty_mm``, the larger of two rough estimates: how far the given cameras
  disagree with the refined geometry (:func:`given_rig_disagreement_mm`,
  :func:`frame_uncertainty_mm`) and what the given rig's residuals imply for the frame it
  defines (:meth:`GivenRigError.frame_uncertainty_mm`; the disagreement alone under-reports
  once the priors hold the cameras near their calibration).
- Clock offsets (``sync=True``): camera ``c`` sees a dot at ``X + dt_c V`` where ``V`` is the
  dot's velocity along its tracked trajectory (mm/s, central differences) and ``dt_c`` the
  camera's offset (s) against the reference camera.

World frame from a reference object (``control``, :class:`ControlPoints`): markers at known
world positions (a lab's L-frame, :mod:`spinemocap.reference`) seen at known blobs add their
reprojection errors to the problem (weighted by ``reference_weight``), with the known positions
held fixed. They see what the dots cannot: the world frame. The solve starts from the given rig
shifted onto the reference (the mean offset of its triangulation of the markers). The report's
``world_frame`` says where the frame came from (``reference`` or ``given rig``) and, with a
reference, the fit: each marker's reprojection error
(px) under the refined rig and its re-triangulated distance from the design (mm); markers the
refined rig cannot fit (beyond ``reference_limit_px``) make :class:`ReferenceFitError` (a wrong
design or pose in ``reference.toml``, or a marker mistaken), never a quietly bent rig. A pose
shifted as a whole fits perfectly and moves the world with it; what shows it is the size of the
move against the given rig's own frame (``given_frame_offset_mm``, warned about by the caller).

The residual reported before/after is the RMS reprojection error (distorted px) of the
observations kept (before: points triangulated from their blobs with the given rig). Now and then
a blob was paired with a neighbouring dot's point (a few px off whatever the rig): after a first
solve, observations beyond ``outlier_factor`` x the robust RMS (at least 1 px) are dropped and
the problem solved again (``outliers_dropped`` in the report).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from ..camera import Rig
from ..geometry import triangulate_dlt
from ..markers import OBSERVED
from ..rig_adjust import AdjustmentSettings, CameraPriors, FixedPoints, FreePoints, RigAdjustment
from .candidates import reprojection_errors
from .rig_check import robust_rms


@dataclass
class RigRefineConfig:
    """``max_frames``: frames used (evenly spread); ``focal``: refine a focal scale per camera;
    ``sync``: refine a clock offset per camera; ``reference``: a camera whose pose is held (None:
    the priors pick the gauge); ``max_nfev``: the solver's residual evaluations per solve;
    ``outlier_factor``: see module.
    Priors toward the given cameras (see module): ``centre_prior_mm`` / ``rotation_prior_deg``
    fixed widths for every camera (default 20 mm, 0.5 deg), or None: each camera's widths from
    its own residual on the capture's dots, ``prior_scale`` x that residual (at least
    ``min_prior_px``) turned into an angle (/ focal length) and a centre shift (x the camera's
    distance to the dots), see :func:`residual_priors` and the module docstring. With a reference
    object: ``reference_weight`` scales its markers' residuals (each is a median over frames,
    ~0.05 px against ~0.13 px for a dot), ``reference_limit_px`` the least fit
    beyond which a marker makes :class:`ReferenceFitError`."""

    max_frames: int = 120
    focal: bool = True
    sync: bool = False
    reference: int | None = None
    loss_scale_px: float = 1.0
    centre_prior_mm: float | None = 20.0
    rotation_prior_deg: float | None = 0.5
    prior_scale: float = 2.0
    min_prior_px: float = 0.2
    max_nfev: int = 100
    outlier_factor: float = 4.0
    reference_limit_px: float = 1.0
    reference_weight: float = 3.0


@dataclass
class ControlPoints:
    """A reference object's markers as control points: ``world_mm`` (N, 3) their known world
    positions, ``pixels`` (C, N, 2) distorted px where each camera sees them (NaN: not seen),
    ``labels`` (N,), ``name`` the object's (for messages)."""

    labels: list[str]
    world_mm: np.ndarray
    pixels: np.ndarray
    name: str = "reference"

    def observations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cam (M,), marker (M,), uv (M, 2)) of every finite observation."""
        seen = np.isfinite(self.pixels).all(axis=2)
        cam, marker = np.nonzero(seen)
        return cam, marker, self.pixels[cam, marker]

    def problems(self) -> list[str]:
        """Why these control points cannot fix a world frame (empty when they can): at least 3
        markers not on one line each seen by >= 2 cameras."""
        seen = np.isfinite(self.pixels).all(axis=2).sum(axis=0)
        usable = seen >= 2
        if usable.sum() < 3:
            return [f"{self.name}: only {int(usable.sum())} markers seen by >= 2 cameras (need 3 not on one line; "
                    "per marker: " + ", ".join(f"{lb} {int(n)}" for lb, n in zip(self.labels, seen)) + " cameras)"]
        pts = self.world_mm[usable] - self.world_mm[usable].mean(axis=0)
        spread = np.linalg.svd(pts, compute_uv=False)
        if spread[1] < 1e-3 * spread[0]:
            return [f"{self.name}: the markers seen by >= 2 cameras lie on one line"]
        return []


class ReferenceFitError(ValueError):
    """The refined rig cannot fit the reference object's markers where their design puts them."""


@dataclass
class ReferenceFrame:
    """The world frame a reference object's markers fixed (:func:`reference_fit`): the object's
    ``name``, the markers used and the cameras that saw each, the observations, each marker's
    reprojection RMS under the refined rig (px) and its re-triangulated distance from the design
    (mm), their overall RMS (``fit_rms_px``, ``fit_rms_mm``), the limit (px) and the markers beyond
    it (``bad_markers``), ``given_frame_offset_mm``: how far the given rig's own triangulation of
    the markers lies from the design (mean, mm), and ``pose_warning``: the caller's doubt about the
    reference's pose (None: none)."""

    name: str
    markers_used: list[str]
    cameras_per_marker: dict[str, int]
    observations: int
    marker_rms_px: dict[str, float]
    marker_error_mm: dict[str, float]
    fit_rms_px: float
    fit_rms_mm: float
    limit_px: float
    bad_markers: list[str]
    given_frame_offset_mm: float
    pose_warning: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The report's ``world_frame`` object: ``source`` ``reference``, the fields in order
        (``pose_warning`` only when there is one)."""
        data = dataclasses.asdict(self)
        warning = data.pop("pose_warning")
        return {"source": "reference", **data, **({"pose_warning": warning} if warning is not None else {})}


@dataclass
class RigRefinement:
    """The refined rig with the residuals (distorted px RMS, per camera and ``all``) before and
    after, the clock offsets (ms, per camera; zeros without ``sync``), the problem size (points,
    observations, frames used, outliers dropped) and the solver; per camera the distance (mm)
    between the refined and the given rig once the gauge is removed, the priors that held the
    cameras near their calibration (centre mm, rotation deg), the focal scale and how far the
    camera moved (mm). ``reference``: the world frame a reference object fixed (None: the given
    rig's). ``frame_uncertainty_mm``: the world-frame error the refined rig keeps (mm; from the
    reference's fit, else the larger of the estimates from the disagreement and from the given
    rig's residuals, both kept)."""

    rig: Rig
    before_px: dict[str, float]
    after_px: dict[str, float]
    sync_offsets_ms: dict[str, float]
    n_points: int
    n_observations: int
    frames_used: int
    solver: str
    outliers_dropped: int
    given_rig_disagreement_mm: dict[str, float]
    reference: ReferenceFrame | None
    frame_uncertainty_mm: float
    frame_uncertainty_from_disagreement_mm: float
    frame_uncertainty_from_residuals_mm: float
    centre_prior_mm: dict[str, float]
    rotation_prior_deg: dict[str, float]
    focal_scale: dict[str, float]
    camera_moved_mm: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """``rig_refine.json``'s object (``world_frame``: the reference's, or ``{"source": "given rig"}``)."""
        return {"before_px": self.before_px, "after_px": self.after_px, "sync_offsets_ms": self.sync_offsets_ms,
                "n_points": self.n_points, "n_observations": self.n_observations, "frames_used": self.frames_used,
                "solver": self.solver, "outliers_dropped": self.outliers_dropped,
                "given_rig_disagreement_mm": self.given_rig_disagreement_mm,
                "world_frame": self.reference.to_dict() if self.reference is not None else {"source": "given rig"},
                "frame_uncertainty_mm": self.frame_uncertainty_mm,
                "frame_uncertainty_from_disagreement_mm": self.frame_uncertainty_from_disagreement_mm,
                "frame_uncertainty_from_residuals_mm": self.frame_uncertainty_from_residuals_mm,
                "centre_prior_mm": self.centre_prior_mm, "rotation_prior_deg": self.rotation_prior_deg,
                "focal_scale": self.focal_scale, "camera_moved_mm": self.camera_moved_mm}


@dataclass
class _Problem:
    cam: np.ndarray  # (M,) camera of each observation
    point: np.ndarray  # (M,) point of each observation
    uv: np.ndarray  # (M, 2) distorted px
    velocity: np.ndarray  # (P, 3) mm/s per point
    start: np.ndarray  # (P, 3) initial points (mm)


def _observations(pixels: np.ndarray, positions: np.ndarray, fps: float, rig: Rig, frames: np.ndarray) -> _Problem:
    """Observations of the dot-frames seen by >= 2 cameras in ``frames`` (indices into the
    (F, D, C, 2) ``pixels`` and (F, D, 3) ``positions``)."""
    F = len(positions)
    velocity = np.zeros_like(positions)
    if F > 2:
        velocity[1:-1] = (positions[2:] - positions[:-2]) * fps / 2
    velocity = np.nan_to_num(velocity)
    seen = np.isfinite(pixels).all(axis=3)  # (F, D, C)
    cams: list[int] = []
    pts: list[int] = []
    uvs: list[np.ndarray] = []
    vel: list[np.ndarray] = []
    start: list[np.ndarray] = []
    P = np.stack([c.projection_matrix for c in rig])
    for f in frames:
        undist = _undistorted(rig, pixels[f], seen[f])
        for d in np.flatnonzero(seen[f].sum(axis=1) >= 2):
            used = seen[f, d]
            X = triangulate_dlt(P, undist[d][None], used[None])[0]
            if not np.isfinite(X).all():
                continue
            p = len(start)
            start.append(X)
            vel.append(velocity[f, d])
            for c in np.flatnonzero(used):
                cams.append(int(c))
                pts.append(p)
                uvs.append(pixels[f, d, c])
    return _Problem(np.asarray(cams, np.int64), np.asarray(pts, np.int64), np.asarray(uvs, float).reshape(-1, 2),
                    np.asarray(vel, float).reshape(-1, 3), np.asarray(start, float).reshape(-1, 3))


def _per_camera_rms(errors: np.ndarray, cam: np.ndarray, rig: Rig) -> dict[str, float]:
    out = {name: float(np.sqrt(np.mean(errors[cam == c] ** 2))) if (cam == c).any() else float("nan")
           for c, name in enumerate(rig.names)}
    out["all"] = float(np.sqrt(np.mean(errors**2))) if len(errors) else float("nan")
    return out


def refine_rig(rig: Rig, pixels: np.ndarray, positions: np.ndarray, fps: float,
               config: RigRefineConfig | None = None, control: ControlPoints | None = None) -> RigRefinement:
    """Bundle-adjust ``rig`` on tracked dots: ``pixels`` (F, D, C, 2) distorted blob centres of
    the observed dots (NaN elsewhere), ``positions`` (F, D, 3) mm their tracked trajectories
    (velocities for the clock offsets), ``fps`` frames per second; ``control``: a reference
    object's markers (fix the world frame; :class:`ReferenceFitError` when they do not fit). See
    module."""
    config = config or RigRefineConfig()
    if control is None:
        return _refine(rig, pixels, positions, fps, config)
    problems = control.problems()
    if problems:
        raise ReferenceFitError("; ".join(problems))
    # the solve starts with the given rig (and its dots) shifted onto the reference: the mean
    # offset of the given rig's triangulation of the markers from their known places. From the
    # given frame itself the solver's sparse steps creep along the dots' flat gauge directions
    # and stop short of a frame some mm away; a start rotated by the similarity fitted on the
    # markers (or on a dots-only refinement) converges worse than a shift
    seen = _triangulate_markers(rig, control)
    ok = np.isfinite(seen).all(axis=1)
    shift = (control.world_mm[ok] - seen[ok]).mean(axis=0)
    return _refine(rig, pixels, positions, fps, config, control, (np.eye(3), shift, 1.0))


def _refine(rig: Rig, pixels: np.ndarray, positions: np.ndarray, fps: float, config: RigRefineConfig,
            control: ControlPoints | None = None,
            start: tuple[np.ndarray, np.ndarray, float] | None = None) -> RigRefinement:
    """:func:`refine_rig`'s bundle adjustment; ``start``: a world similarity applied to the given
    rig and the dots before solving (the priors then hold the cameras near the moved rig)."""
    outlier_factor = config.outlier_factor
    F = len(positions)
    frames = np.unique(np.linspace(0, F - 1, min(config.max_frames, F)).round().astype(int)) if F else np.zeros(0, int)
    prob = _observations(pixels, positions, fps, rig, frames)
    if len(prob.start) < 10:
        raise ValueError(f"only {len(prob.start)} dot-frames seen by >= 2 cameras; cannot refine the rig")
    P, M = len(prob.start), len(prob.cam)
    ctrl_cam, ctrl_marker, ctrl_uv = control.observations() if control is not None else (np.zeros(0, int),) * 2 + (
        np.zeros((0, 2)),)
    ctrl_world = control.world_mm[ctrl_marker] if control is not None else np.zeros((0, 3))
    given_error = GivenRigError.measure(rig, prob)  # before any move: the given rig's own residuals
    start_rig = rig
    if start is not None:
        start_rig, prob = _moved(rig, prob, start)
    sigma_centre, sigma_rotation = residual_priors(given_error, config)
    adjustment = RigAdjustment(
        start_rig,
        points=FreePoints(prob.cam, prob.point, prob.uv, prob.start, prob.velocity),
        control=FixedPoints(ctrl_world, ctrl_cam, ctrl_uv, config.reference_weight) if control is not None else None,
        settings=AdjustmentSettings(intrinsics="focal" if config.focal else "fixed", clock_offsets=config.sync,
                                    reference=config.reference, priors=CameraPriors(sigma_centre, sigma_rotation),
                                    loss_scale_px=config.loss_scale_px, max_evaluations=config.max_nfev,
                                    # with a reference, inexact lsmr steps along the dots' flat gauge
                                    # directions stop short of the markers
                                    exact_steps=control is not None, backend="scipy"))
    before = adjustment.initial().point_errors_px
    # the Huber scale starts at the given rig's own residual level: with every residual far in
    # the loss's linear part (a 3 px rig against a 1 px scale) the solver stalls on its first
    # steps and returns the given rig unchanged
    fit = adjustment.solve(loss_scale_px=max(config.loss_scale_px, robust_rms(before)))
    # a blob paired with the wrong dot now and then (a few px off whatever the rig): drop the
    # observations far beyond the fitted residuals' spread and solve again
    after = fit.point_errors_px
    limit = max(outlier_factor * robust_rms(after), 1.0)
    keep = after < limit
    if not keep.all():
        fit = adjustment.solve(fit, weights=keep.astype(float))
        after = fit.point_errors_px
    before, after, obs_cam = before[keep], after[keep], prob.cam[keep]
    refined = Rig([dataclasses.replace(c, K=adjusted.K, R=adjusted.R, t=adjusted.t) for c, adjusted in zip(rig, fit.rig)])
    disagreement = given_rig_disagreement_mm(refined, rig, sigma_centre, np.degrees(sigma_rotation))
    frame_uncertainty = max(frame_uncertainty_mm(disagreement), given_error.frame_uncertainty_mm())
    world_frame: ReferenceFrame | None = None
    if control is not None:
        limit = max(config.reference_limit_px, outlier_factor * robust_rms(after))
        world_frame = reference_fit(refined, rig, control, limit)
        if world_frame.bad_markers:
            raise ReferenceFitError(
                f"{control.name}: the refined rig cannot fit markers {world_frame.bad_markers} where the reference's "
                f"design and pose put them (reprojection RMS per marker, px: "
                + ", ".join(f"{k} {v:.2f}" for k, v in world_frame.marker_rms_px.items())
                + f"; limit {limit:.2f} px): check the design (marker positions, mm) and pose in the reference file, "
                "or that nothing else was taken for these markers")
        frame_uncertainty = world_frame.fit_rms_mm
    return RigRefinement(
        rig=refined, before_px=_per_camera_rms(before, obs_cam, rig), after_px=_per_camera_rms(after, obs_cam, rig),
        sync_offsets_ms={n: float(1000 * fit.clock_offsets_s[i]) for i, n in enumerate(rig.names)}, n_points=P,
        n_observations=M, frames_used=int(len(frames)), solver="scipy least_squares (trf, huber)",
        outliers_dropped=int(M - keep.sum()),
        given_rig_disagreement_mm=dict(zip(rig.names, disagreement.tolist())),
        reference=world_frame,
        frame_uncertainty_mm=frame_uncertainty,
        frame_uncertainty_from_disagreement_mm=frame_uncertainty_mm(disagreement),
        frame_uncertainty_from_residuals_mm=given_error.frame_uncertainty_mm(),
        centre_prior_mm=dict(zip(rig.names, sigma_centre.tolist())),
        rotation_prior_deg=dict(zip(rig.names, np.degrees(sigma_rotation).tolist())),
        focal_scale={n: float(fit.focal_scale[i]) for i, n in enumerate(rig.names)},
        camera_moved_mm={n: float(np.linalg.norm(refined[i].center - rig[i].center)) for i, n in enumerate(rig.names)},
    )


def _moved(rig: Rig, prob: _Problem, similarity: tuple[np.ndarray, np.ndarray, float]) -> tuple[Rig, _Problem]:
    """``rig`` and the problem's start points (and velocities) moved by a world similarity (the
    reprojections are unchanged)."""
    R, t, s = similarity
    moved = dataclasses.replace(prob, start=s * prob.start @ R.T + t, velocity=s * prob.velocity @ R.T)
    return rig.transformed(R, t, s), moved


def _triangulate_markers(rig: Rig, control: ControlPoints) -> np.ndarray:
    """(N, 3) mm: each marker triangulated from its blobs with ``rig`` (NaN where < 2 cameras)."""
    P = np.stack([c.projection_matrix for c in rig])
    pixels = control.pixels.transpose(1, 0, 2)  # (N, C, 2)
    seen = np.isfinite(pixels).all(axis=2)
    out = triangulate_dlt(P, _undistorted(rig, pixels, seen), seen)
    out[seen.sum(axis=1) < 2] = np.nan
    return out


def _undistorted(rig: Rig, pixels: np.ndarray, used: np.ndarray) -> np.ndarray:
    """(N, C, 2) undistorted px of the distorted ``pixels`` (N, C, 2) where ``used`` (N, C); 0 elsewhere."""
    out = np.zeros(pixels.shape)
    for c, cam in enumerate(rig):
        if used[:, c].any():
            out[used[:, c], c] = cam.undistort_points(pixels[used[:, c], c])
    return out


def reference_fit(refined: Rig, given: Rig, control: ControlPoints, limit_px: float) -> ReferenceFrame:
    """How well ``refined`` fits the reference's markers (the report's ``world_frame``,
    :class:`ReferenceFrame`): per-marker reprojection RMS (px) and re-triangulated distance from
    the design (mm), their overall RMS, the markers beyond ``limit_px``, and how far the given
    rig's own triangulation of the markers lies from the design (the given rig's world-frame
    error at the reference, or a reference pose shifted as a whole)."""
    cam, marker, uv = control.observations()
    errors = np.array([float(np.linalg.norm(refined[c].project(control.world_mm[m][None])[0] - p))
                       for c, m, p in zip(cam, marker, uv)])
    per_marker_px = {control.labels[m]: float(np.sqrt(np.mean(errors[marker == m] ** 2)))
                     for m in np.unique(marker)}
    refined_xyz = _triangulate_markers(refined, control)
    given_xyz = _triangulate_markers(given, control)
    miss = np.linalg.norm(refined_xyz - control.world_mm, axis=1)
    given_miss = np.linalg.norm(given_xyz - control.world_mm, axis=1)
    seen = np.isfinite(control.pixels).all(axis=2)
    return ReferenceFrame(
        name=control.name,
        markers_used=[control.labels[m] for m in np.unique(marker)],
        cameras_per_marker=dict(zip(control.labels, seen.sum(axis=0).tolist())),
        observations=int(len(cam)),
        marker_rms_px=per_marker_px,
        marker_error_mm={lb: float(d) for lb, d in zip(control.labels, miss) if np.isfinite(d)},
        fit_rms_px=float(np.sqrt(np.mean(errors**2))),
        fit_rms_mm=float(np.sqrt(np.nanmean(miss**2))) if np.isfinite(miss).any() else float("nan"),
        limit_px=float(limit_px),
        bad_markers=[lb for lb, v in per_marker_px.items() if v > limit_px],
        given_frame_offset_mm=float(np.nanmean(given_miss)) if np.isfinite(given_miss).any() else float("nan"),
    )


@dataclass
class GivenRigError:
    """What the capture's own dots say of each given camera's calibration error: its residual
    (robust RMS, distorted px) against the dots triangulated with the given rig, its focal length
    (px) and its distance to the dots (median, mm). ``shift_mm``: that residual as a shift at
    the dots (residual x distance / focal)."""

    residual_px: np.ndarray  # (C,)
    focal_px: np.ndarray  # (C,)
    distance_mm: np.ndarray  # (C,)

    @property
    def shift_mm(self) -> np.ndarray:
        return self.residual_px * self.distance_mm / self.focal_px

    @classmethod
    def measure(cls, rig: Rig, prob: _Problem) -> GivenRigError:
        residual, distance = np.full(len(rig), np.nan), np.full(len(rig), np.nan)
        for c, cam in enumerate(rig):
            rows = prob.cam == c
            if rows.any():
                points = prob.start[prob.point[rows]]
                residual[c] = robust_rms(np.linalg.norm(cam.project(points) - prob.uv[rows], axis=1))
                distance[c] = float(np.median(np.linalg.norm(points - cam.center, axis=1)))
        seen = np.isfinite(distance)
        distance[~seen] = np.median(distance[seen]) if seen.any() else 1000.0
        residual[~seen] = np.median(residual[seen]) if seen.any() else 0.0
        return cls(residual, np.array([0.5 * (cam.K[0, 0] + cam.K[1, 1]) for cam in rig]), distance)

    def frame_uncertainty_mm(self) -> float:
        """A rough uncertainty (mm, mean 3D) of the world frame the given rig defines, as if each
        camera's error acted on the frame as independent noise of its measured size: ``rho`` =
        RMS of ``shift_mm`` (2D, per camera) triangulated from C views, 3 rho / (2 sqrt(C)) RMS in
        3D, x 0.92 for the mean of a 3D norm."""
        rho = float(np.sqrt(np.mean(self.shift_mm**2)))
        return 0.92 * 3 * rho / (2 * np.sqrt(len(self.shift_mm)))


def residual_priors(error: GivenRigError, config: RigRefineConfig) -> tuple[np.ndarray, np.ndarray]:
    """(C,) centre prior widths (mm) and (C,) rotation prior widths (rad) of the cameras.

    Fixed widths where ``config`` gives them; otherwise from what each given camera's residual
    on the capture's dots (:class:`GivenRigError`) says of its calibration error:
    ``prior_scale`` x that residual (at least ``min_prior_px``) is an angle of residual / focal
    length (rad) and, at the camera's distance to the dots, a centre shift of that angle x
    distance: a rotation and a shift that move the dots' images as much. A calibration's errors
    are of that size (the rig reprojects its own calibration volume with about that residual),
    so the priors let the data correct them where it can and hold each camera near its
    calibration where the dots say little: the world frame, and the directions a shallow tape
    hardly constrains (a camera's distance traded against its focal length)."""
    C = len(error.residual_px)
    angle = config.prior_scale * np.maximum(error.residual_px, config.min_prior_px) / error.focal_px
    rotation = np.full(C, np.radians(config.rotation_prior_deg)) if config.rotation_prior_deg is not None else angle
    centre = (np.full(C, float(config.centre_prior_mm)) if config.centre_prior_mm is not None
              else angle * error.distance_mm)
    return centre, rotation


def closest_gauge(refined: Rig, given: Rig, centre_sigma_mm: float | np.ndarray,
                  rotation_sigma_deg: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The similarity ``(R, t, s)`` (``x -> s R x + t``, mm) that moves ``refined`` closest to
    ``given``: least squares over the cameras of the centre differences / ``centre_sigma_mm`` and
    the orientation differences (rotation vectors) / ``rotation_sigma_deg`` (either: one width
    or one per camera). Under a world
    similarity the cameras' relative geometry is unchanged, so the refined rig's fit to the dots
    is kept; only where the world sits (position, orientation, metric scale) is chosen, from
    all cameras together. Starts from the centres' Umeyama fit."""
    from ..geometry import umeyama

    c_ref = np.stack([c.center for c in refined])
    c_given = np.stack([c.center for c in given])
    R_ref = np.stack([c.R for c in refined])
    R_given = np.stack([c.R for c in given])
    sigma_c = np.broadcast_to(np.asarray(centre_sigma_mm, float), (len(refined),))[:, None]
    sigma_r = np.broadcast_to(np.radians(np.asarray(rotation_sigma_deg, float)), (len(refined),))[:, None]
    if len(refined) >= 3:
        R0, t0, s0 = umeyama(c_ref, c_given, with_scale=True)
    else:
        R0, t0, s0 = np.eye(3), np.zeros(3), 1.0

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        return cv2.Rodrigues(x[:3])[0] @ R0, x[3:6] + t0, float(s0 * np.exp(x[6]))

    def residuals(x: np.ndarray) -> np.ndarray:
        R, t, s = unpack(x)
        centre = ((s * c_ref @ R.T + t - c_given) / sigma_c).ravel()
        turn = np.array([cv2.Rodrigues(Rg @ (Rr @ R.T).T)[0].ravel() for Rr, Rg in zip(R_ref, R_given)])
        return np.concatenate([centre, (turn / sigma_r).ravel()])

    fit = least_squares(residuals, np.zeros(7), method="lm")
    return unpack(fit.x)


def given_rig_disagreement_mm(refined: Rig, given: Rig, centre_sigma_mm: float | np.ndarray,
                              rotation_sigma_deg: float | np.ndarray) -> np.ndarray:
    """(C,) mm: how far each given camera's centre lies from the refined rig moved onto the given
    one by :func:`closest_gauge`, i.e. the given rig's per-camera errors the dots reveal."""
    moved = refined.transformed(*closest_gauge(refined, given, centre_sigma_mm, rotation_sigma_deg))
    return np.array([float(np.linalg.norm(a.center - b.center)) for a, b in zip(moved, given)])


def frame_uncertainty_mm(disagreement: np.ndarray) -> float:
    """A rough uncertainty (mm) of the world frame left in absolute positions after refinement:
    the given cameras' centre error estimated from their disagreement (RMS, corrected for the 7
    parameters of the fitted similarity among the 3 x cameras centre coordinates) and averaged
    over the cameras (/ sqrt(cameras)). NaN with fewer than 3 cameras."""
    d = np.asarray(disagreement, float)
    n = 3 * len(d)
    if len(d) < 3:
        return float("nan")
    per_camera = np.sqrt(np.mean(d**2) * n / (n - 7))
    return float(per_camera / np.sqrt(len(d)))


def retriangulate(rig: Rig, pixels: np.ndarray, positions: np.ndarray, status: np.ndarray,
                  thickness_mm: float = 0.0, normals: np.ndarray | None = None,
                  max_reprojection_px: float = 3.0) -> np.ndarray:
    """Positions (F, D, 3) mm under a refined rig, labels unchanged: observed dots re-triangulated
    from their blobs (moved in by ``thickness_mm`` along ``normals`` (F, D, 3) as the tracker
    does), the other finite dots moved with the observed ones by a per-frame similarity fit.

    A re-triangulated point that misses one of its own blobs by more than ``max_reprojection_px``
    (undistorted px), or that lies behind a camera that saw it, is not taken: the linear triangulation can land 15-25 mm off although the
    blobs agree with the refined rig to ~1 px (seen on 3-camera dots, 24-27 px from their
    blobs); such a dot moves with the frame's similarity like an inferred one."""
    from ..geometry import umeyama

    out = positions.copy()
    P = np.stack([c.projection_matrix for c in rig])
    for f in range(len(positions)):
        used = np.isfinite(pixels[f]).all(axis=2)  # (D, C)
        obs = (status[f] == OBSERVED) & (used.sum(axis=1) >= 2)
        if not obs.any():
            continue
        undist = _undistorted(rig, pixels[f], used & obs[:, None])
        new = triangulate_dlt(P, undist[obs], used[obs])
        errors = reprojection_errors(P, new, undist[obs], used[obs])  # NaN: unused, or behind the camera
        fits = (np.isfinite(errors) == used[obs]).all(axis=1) & (np.nan_to_num(errors) <= max_reprojection_px).all(axis=1)
        if thickness_mm and normals is not None:
            new = new - thickness_mm * normals[f, obs]
        old = positions[f, obs]
        taken = np.flatnonzero(obs)[fits]
        out[f, taken] = new[fits]
        rest = np.isfinite(positions[f]).all(axis=1)
        rest[taken] = False
        good = fits & np.isfinite(new).all(axis=1) & np.isfinite(old).all(axis=1)
        if rest.any() and good.sum() >= 3:
            Rm, tm, s = umeyama(old[good], new[good], with_scale=True)
            out[f, rest] = s * positions[f, rest] @ Rm.T + tm
    return out

