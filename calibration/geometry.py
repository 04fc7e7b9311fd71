"""Small geometric tools shared by the calibration steps (mm, world -> camera poses)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from spinemocap.camera import Camera
from spinemocap.geometry import triangulate_rays, umeyama  # noqa: F401  (umeyama: re-exported)


def triangulate(cameras: Sequence[Camera], pixels: np.ndarray) -> np.ndarray:
    """One 3D point (mm) from its distorted pixels (C, 2) in ``cameras``: the least-squares point
    of the cameras' rays (the same in any world frame; the DLT's row-scaled homogeneous solution
    moves with the frame, by millimetres where the world is a camera's own frame)."""
    directions = np.stack([cam.R.T @ np.append(cam.undistort_points(px[None], normalized=True)[0], 1.0)
                           for cam, px in zip(cameras, pixels)])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    origins = np.stack([cam.center for cam in cameras])
    return triangulate_rays(origins, directions[None], np.ones((1, len(cameras))))[0]


def rigid_fit(model: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Kabsch: R, t minimizing |R model + t - observed|; returns (R, t, RMS distance)."""
    R, t, _ = umeyama(model, observed, with_scale=False)
    rms = float(np.sqrt(np.mean(np.sum((model @ R.T + t - observed) ** 2, axis=1))))
    return R, t, rms
