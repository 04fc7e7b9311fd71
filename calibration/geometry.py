"""Small geometric tools shared by the calibration steps (mm, world -> camera poses)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from spinemocap.camera import Camera, Rig


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
    """One 3D point (mm) from its distorted pixels (C, 2) in ``cameras``: linear least squares
    (DLT) on undistorted normalized coordinates."""
    rows = []
    for cam, px in zip(cameras, pixels):
        x, y = cam.undistort_points(px[None], normalized=True)[0]
        P = np.hstack([cam.R, cam.t[:, None]])
        rows += [x * P[2] - P[0], y * P[2] - P[1]]
    A = np.asarray(rows)
    A /= np.linalg.norm(A[:, :3], axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(A)
    X = vt[-1]
    return X[:3] / X[3]


def rigid_fit(model: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Kabsch: R, t minimizing |R model + t - observed|; returns (R, t, RMS distance)."""
    R, t, _ = umeyama(model, observed, with_scale=False)
    rms = float(np.sqrt(np.mean(np.sum((model @ R.T + t - observed) ** 2, axis=1))))
    return R, t, rms


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
    """Similarity (R, t, s) minimizing |s R source + t - target|^2 (Umeyama 1991)."""
    source, target = np.asarray(source, float), np.asarray(target, float)
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    a, b = source - mu_s, target - mu_t
    U, S, Vt = np.linalg.svd(b.T @ a / len(a))
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.mean(np.sum(a * a, axis=1))) if with_scale else 1.0
    return R, mu_t - s * R @ mu_s, s


def transform_rig(rig: Rig, R: np.ndarray, t: np.ndarray, scale: float = 1.0) -> Rig:
    """The rig expressed in a new world frame ``X_new = scale R X_old + t``. Camera coordinates
    are scaled with the world so that projections are unchanged (and lengths become new-frame mm)."""
    cameras = []
    for cam in rig:
        R_new = cam.R @ R.T
        cameras.append(Camera(cam.name, cam.K.copy(), cam.dist.copy(), R_new,
                              scale * cam.t - R_new @ t, cam.size))
    return Rig(cameras)
