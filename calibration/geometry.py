"""Small geometric tools shared by the calibration steps (mm, world -> camera poses)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from spinemocap.camera import Camera, Rig
from spinemocap.geometry import triangulate_rays, umeyama  # noqa: F401  (umeyama: re-exported)


def rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors -> (N, 3, 3) rotation matrices (vectorized Rodrigues)."""
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    k = rvecs / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(rvecs), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    R[small] = np.eye(3) + _skew(rvecs[small])
    return R


def _skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


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


def transform_rig(rig: Rig, R: np.ndarray, t: np.ndarray, scale: float = 1.0) -> Rig:
    """The rig expressed in a new world frame ``X_new = scale R X_old + t``. Camera coordinates
    are scaled with the world so that projections are unchanged (and lengths become new-frame mm)."""
    cameras = []
    for cam in rig:
        R_new = cam.R @ R.T
        cameras.append(Camera(cam.name, cam.K.copy(), cam.dist.copy(), R_new,
                              scale * cam.t - R_new @ t, cam.size))
    return Rig(cameras)
