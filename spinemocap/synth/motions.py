"""Spine motions: commanded [flexion, lateral bending, axial rotation] in degrees over time.

Signs (see :func:`spinemocap.synth.body.rotation_from_spine_angles`): flexion positive = bending
forward, lateral bending positive = toward the subject's right, axial rotation positive = to the
subject's left (counter-clockwise seen from above). Every motion starts in the neutral pose at
``t = 0`` and is a smooth function of time, so any frame rate (and sub-frame instants for motion
blur) can be sampled.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from .skin_strain import FULL_FLEXION_DEG

TAU = 2 * np.pi


def _flexion(t: np.ndarray) -> np.ndarray:
    # forward bend to full flexion (toe touch: FULL_FLEXION_DEG of the spine, the pelvis stays
    # upright so the cameras behind keep the back in view) and back, 3 s period
    f = 0.5 * FULL_FLEXION_DEG * (1 - np.cos(TAU * t / 3.0))
    return np.column_stack([f, 0 * t, 0 * t])


def _lateral(t: np.ndarray) -> np.ndarray:
    return np.column_stack([0 * t, 30.0 * np.sin(TAU * t / 2.5), 0 * t])


def _rotation(t: np.ndarray) -> np.ndarray:
    return np.column_stack([0 * t, 0 * t, 35.0 * np.sin(TAU * t / 2.5)])


def _mixed(t: np.ndarray) -> np.ndarray:
    # hip circling with trunk twist, like Dynamic FAUST's "hips": flexion and lateral bending in
    # quadrature (the trunk traces a cone) plus axial rotation at another rate; large amplitudes.
    ramp = np.clip(t / 0.5, 0, 1) ** 2 * (3 - 2 * np.clip(t / 0.5, 0, 1))  # smooth start
    w = TAU / 2.2
    flex = ramp * (10.0 + 22.0 * np.sin(w * t))
    lat = ramp * 28.0 * np.cos(w * t)
    rot = ramp * 25.0 * np.sin(TAU * t / 3.1)
    return np.column_stack([flex, lat, rot])


def _forehand(t: np.ndarray) -> np.ndarray:
    # tennis forehand every 1.2 s: back-swing to 40 deg right rotation (0.35 s), fast swing to
    # 55 deg left in 0.15 s (~950 deg/s peak) between 0.35 and 0.5 s -- inside the first 50
    # frames at 100 fps and inside every preset's default frame count -- follow-through, recovery.
    period = 1.2
    phase = np.mod(t, period)
    knots_t = np.array([0.0, 0.35, 0.5, 0.7, 1.2])
    knots_r = np.array([0.0, -40.0, 55.0, 60.0, 0.0])
    rot = _smooth_interp(phase, knots_t, knots_r)
    flex = 0.2 * np.abs(rot)
    lat = -0.15 * rot
    return np.column_stack([flex, lat, rot])


def _neutral(t: np.ndarray) -> np.ndarray:
    return np.zeros((len(t), 3))


def _smooth_interp(x: np.ndarray, xk: np.ndarray, yk: np.ndarray) -> np.ndarray:
    """Piecewise smoothstep interpolation through knots (zero velocity at each knot)."""
    i = np.clip(np.searchsorted(xk, x, side="right") - 1, 0, len(xk) - 2)
    s = (x - xk[i]) / (xk[i + 1] - xk[i])
    s = s * s * (3 - 2 * s)
    return yk[i] + s * (yk[i + 1] - yk[i])


MOTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "flexion": _flexion,
    "lateral": _lateral,
    "rotation": _rotation,
    "mixed": _mixed,
    "forehand": _forehand,
    "neutral": _neutral,
}


def spine_motion(name: str, times_s: npt.ArrayLike) -> np.ndarray:
    """(T, 3) commanded [flexion, lateral bending, axial rotation] (degrees) at ``times_s``."""
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; choose from {sorted(MOTIONS)}")
    return MOTIONS[name](np.asarray(times_s, float).reshape(-1))
