"""Bring a tape capture and a Vicon recording into one frame and clock from markers both
systems see (points at known places on the tape, see :mod:`.tape_markers`).

Convention (as the wand co-registration's): a rig-frame point ``X`` is ``R X + t`` in the Vicon
frame (mm) and a rig instant ``t_rgb`` is Vicon time ``t_rgb + offset_s``. The offset is found
coarsely by correlating the markers' speed (invariant to the unknown transform), then offset,
rotation and translation are refined together by least squares against a cubic spline of the
Vicon trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..fileio import InputError
from ..geometry import umeyama

#: A rig -> Vicon similarity (R (3, 3), t (3,) mm, scale): ``X_vicon = scale R X_rig + t``.
RigToVicon = tuple[np.ndarray, np.ndarray, float]


@dataclass
class Alignment:
    """Rig -> Vicon: ``X_vicon = scale R X_rig + t`` (``R`` (3, 3), ``t`` (3,) mm; ``scale`` is 1
    unless a wand co-registration measured the rig's scale against the Vicon's), ``offset_s``;
    ``residual_mm`` RMS over ``n_frames`` matched frames; ``estimated`` says which of
    transform/offset were estimated."""

    R: np.ndarray
    t: np.ndarray
    offset_s: float
    residual_mm: float
    n_frames: int
    estimated: str
    scale: float = 1.0

    def to_vicon(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points) @ self.R.T + self.t

    def to_rig(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points) - self.t) @ self.R / self.scale

    def to_dict(self) -> dict:
        return {"clock_offset_s": self.offset_s, "clock_offset_ms": 1000 * self.offset_s,
                "rotation": self.R.tolist(), "translation_mm": self.t.tolist(),
                "rotation_xyz_deg": Rotation.from_matrix(self.R).as_euler("xyz", degrees=True).tolist(),
                "scale": self.scale, "residual_mm": self.residual_mm, "n_frames": self.n_frames,
                "estimated": self.estimated,
                "convention": "X_vicon = scale R X_rig + t; t_vicon = t_rgb + clock_offset_s"}


def vicon_spline(time_s: np.ndarray, points: np.ndarray) -> tuple[CubicSpline, float, float]:
    """Cubic spline over the Vicon frames where all (N, K, 3) markers are present."""
    ok = np.isfinite(points).all(axis=(1, 2))
    if ok.sum() < 4:
        raise InputError("vicon", "fewer than 4 Vicon frames with all the shared markers")
    return CubicSpline(time_s[ok], points[ok].reshape(ok.sum(), -1), axis=0), float(time_s[ok][0]), float(time_s[ok][-1])


def _speed(points: np.ndarray, time_s: np.ndarray) -> np.ndarray:
    centroid = np.nanmean(points, axis=1)
    v = np.full(len(points), np.nan)
    v[1:-1] = np.linalg.norm(centroid[2:] - centroid[:-2], axis=1) / (time_s[2:] - time_s[:-2])
    return v


def coarse_offset(rig_time: np.ndarray, rig_points: np.ndarray, vicon_time: np.ndarray, vicon_points: np.ndarray,
                  max_offset_s: float, step_s: float = 0.002) -> float:
    """Offset maximising the correlation of the markers' centroid speed in both systems."""
    s_rig, s_vic = _speed(rig_points, rig_time), _speed(vicon_points, vicon_time)
    ok = np.isfinite(s_vic)
    best, best_r = 0.0, -np.inf
    for tau in np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s):
        query = rig_time + tau
        inside = np.isfinite(s_rig) & (query >= vicon_time[ok][0]) & (query <= vicon_time[ok][-1])
        if inside.sum() < 8:
            continue
        other = np.interp(query[inside], vicon_time[ok], s_vic[ok])
        r = np.corrcoef(s_rig[inside], other)[0, 1]
        if np.isfinite(r) and r > best_r:
            best, best_r = float(tau), float(r)
    if not np.isfinite(best_r):
        raise InputError("vicon", f"the tape and Vicon recordings do not overlap within +-{max_offset_s} s")
    return best


def estimate_alignment(rig_time: np.ndarray, rig_points: np.ndarray, vicon_time: np.ndarray,
                       vicon_points: np.ndarray, max_offset_s: float = 1.0,
                       transform: RigToVicon | None = None) -> Alignment:
    """Align (F, K, 3) rig-frame points at ``rig_time`` with the same K markers (N, K, 3) in the
    Vicon frame at ``vicon_time``. ``transform`` (R, t, scale) known (e.g. from the wand
    calibration: :func:`transform_between_rigs`) leaves only the clock offset to estimate; else
    a rigid transform is estimated with it."""
    spline, t_lo, t_hi = vicon_spline(vicon_time, vicon_points)
    tau0 = coarse_offset(rig_time, rig_points, vicon_time, vicon_points, max_offset_s)
    ok = np.isfinite(rig_points).all(axis=(1, 2)) & (rig_time + tau0 >= t_lo + 0.02) & (rig_time + tau0 <= t_hi - 0.02)
    if ok.sum() < 3:
        raise InputError("vicon", f"only {int(ok.sum())} tape frames overlap the Vicon recording with all shared "
                                  "markers seen")
    source = rig_points[ok].reshape(-1, 3)
    times = rig_time[ok]
    scale = 1.0
    if transform is None:
        R0, t0, _ = umeyama(source, spline(times + tau0).reshape(-1, 3), with_scale=False)
    else:
        R0, t0, scale = np.asarray(transform[0], float), np.asarray(transform[1], float), float(transform[2])
    fixed = transform is not None

    def unpack(x: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        if fixed:
            return x[0], R0, t0
        return x[0], Rotation.from_rotvec(x[1:4]).as_matrix(), x[4:7]

    def residuals(x: np.ndarray) -> np.ndarray:
        tau, R, t = unpack(x)
        return (scale * source @ R.T + t - spline(times + tau0 + tau).reshape(-1, 3)).ravel()

    x0 = np.zeros(1) if fixed else np.concatenate([[0.0], Rotation.from_matrix(R0).as_rotvec(), t0])
    x_scale = [1e-3] if fixed else [1e-3, 1e-3, 1e-3, 1e-3, 1.0, 1.0, 1.0]
    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=3.0, x_scale=x_scale)
    tau, R, t = unpack(fit.x)
    err = np.linalg.norm(residuals(fit.x).reshape(-1, 3), axis=1)
    return Alignment(R, np.asarray(t, float), float(tau0 + tau), float(np.sqrt(np.mean(err ** 2))), int(ok.sum()),
                     "offset" if fixed else "offset+transform", scale)


def transform_between_rigs(rig_R: list[np.ndarray], rig_t: list[np.ndarray], vicon_R: list[np.ndarray],
                           vicon_t: list[np.ndarray]) -> RigToVicon:
    """Rig -> Vicon similarity ``X_v = scale R X + t`` from the same cameras' extrinsics in both
    frames (``x_c = R x + t``; the Vicon-frame rig as ``spinemocap calibrate wand`` writes it,
    camera coordinates in Vicon mm). ``R``: the mean of the per-camera ``R_v^T R_c``; ``scale`` and
    ``t``: least squares on the camera centres given ``R`` (the wand measures the rig's scale
    against the Vicon's: a rigid transform would drop it; scale 1 with fewer than two cameras)."""
    R = Rotation.from_matrix(np.array([Rv.T @ Rc for Rc, Rv in zip(rig_R, vicon_R)])).mean().as_matrix()
    centres = np.array([-Rc.T @ tc for Rc, tc in zip(rig_R, rig_t)])
    vicon_centres = np.array([-Rv.T @ tv for Rv, tv in zip(vicon_R, vicon_t)])
    spread = (centres - centres.mean(axis=0)) @ R.T
    scale = 1.0
    if len(centres) >= 2 and np.sum(spread ** 2) > 1e-6:
        scale = float(np.sum((vicon_centres - vicon_centres.mean(axis=0)) * spread) / np.sum(spread ** 2))
    t = vicon_centres.mean(axis=0) - scale * centres.mean(axis=0) @ R.T
    return R, t, scale
