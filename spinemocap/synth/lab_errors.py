"""A lab's set-up errors in the studio: an imperfect calibration and unsynchronised camera clocks.

Calibration error: the rig written to ``rig.toml`` (what the lab's calibration delivered) differs
from the rig that rendered the images (the truth, kept in the ground truth). Each camera is
perturbed along a seeded direction in (rotation, centre, focal length) space: a rotation about a
random axis, a shift of the centre in a random direction and a common change of fx and fy, in the
fixed proportions of :data:`PERTURBATION_UNIT` (at the ``artificial`` preset one unit moves the
true dots by roughly 1-2 px each). The length of that step is then solved per camera so that the
true dots reproject through the written camera with the requested RMS against where the images
show them (a 1-D root find: the RMS grows monotonically with the step).

For reference: good optical studios calibrate to ~0.2-0.5 px RMS, video
set-ups accept 1-3 px; 0.05 deg of camera rotation is about 1.7 px on the artificial preset.

Sync error: each camera's clock runs ahead of or behind the nominal frame times by a constant
offset; offsets are seeded, zero-mean over the rig (the ground truth's frame times are the mean
clock) and scaled so that their RMS is exactly the requested value.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera, Rig

# One unit of perturbation: (rotation deg, centre shift mm, relative focal change).
PERTURBATION_UNIT = (0.02, 1.0, 0.001)


def reprojection_rms_px(true_camera: Camera, camera: Camera, points_mm: np.ndarray) -> float:
    """RMS distance (px) between the projections of ``points_mm`` (N, 3) through ``camera`` and
    through ``true_camera``, over the points the true camera sees inside its image."""
    truth = true_camera.project(points_mm)
    inside = true_camera.in_image(truth) & (true_camera.depth(points_mm) > 0)
    if not inside.any():
        return 0.0
    error = camera.project(points_mm[inside]) - truth[inside]
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def _perturbed(camera: Camera, direction: tuple[np.ndarray, np.ndarray, float], step: float) -> Camera:
    """``camera`` moved ``step`` units along a perturbation ``direction`` (axis, shift, focal sign)."""
    axis, shift, focal_sign = direction
    rot_deg, shift_mm, focal_rel = PERTURBATION_UNIT
    R = cv2.Rodrigues(axis * np.radians(step * rot_deg))[0] @ camera.R
    centre = camera.center + step * shift_mm * shift
    K = camera.K.copy()
    K[0, 0] *= 1 + step * focal_rel * focal_sign
    K[1, 1] *= 1 + step * focal_rel * focal_sign
    return Camera(camera.name, K, camera.dist.copy(), R, -R @ centre, camera.size)


def perturb_rig(rig: Rig, points_mm: np.ndarray, target_rms_px: float,
                rng: np.random.Generator) -> tuple[Rig, np.ndarray]:
    """A copy of ``rig`` whose cameras reproject ``points_mm`` (N, 3; the true dots over a few
    frames) with ``target_rms_px`` RMS each (see the module docstring). Returns the perturbed rig
    and the (C,) RMS actually reached (px)."""
    if target_rms_px <= 0:
        return rig, np.zeros(len(rig))
    cameras, reached = [], []
    for camera in rig:
        axis = rng.normal(size=3)
        shift = rng.normal(size=3)
        direction = (axis / np.linalg.norm(axis), shift / np.linalg.norm(shift), float(rng.choice([-1.0, 1.0])))

        def rms(step: float, camera: Camera = camera, direction=direction) -> float:
            return reprojection_rms_px(camera, _perturbed(camera, direction, step), points_mm)

        lo, hi = 0.0, 1.0
        while rms(hi) < target_rms_px and hi < 1e6:
            lo, hi = hi, 2 * hi
        for _ in range(40):  # bisection: the RMS grows monotonically with the step
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if rms(mid) < target_rms_px else (lo, mid)
        step = 0.5 * (lo + hi)
        cameras.append(_perturbed(camera, direction, step))
        reached.append(rms(step))
    return Rig(cameras), np.array(reached)


def clock_offsets_s(n_cameras: int, rms_ms: float, rng: np.random.Generator) -> np.ndarray:
    """(C,) per-camera clock offsets (s): zero-mean, RMS exactly ``rms_ms`` milliseconds (all zero
    for one camera or ``rms_ms == 0``)."""
    if rms_ms <= 0 or n_cameras < 2:
        return np.zeros(n_cameras)
    offsets = rng.normal(size=n_cameras)
    offsets -= offsets.mean()
    return offsets / np.sqrt(np.mean(offsets**2)) * rms_ms / 1000.0
