"""Geometry shared by the tracker and the calibration package: the lens distortion model, batched
rotation vectors, linear triangulation and the least-squares similarity between point sets. Millimetres in, millimetres out.
The one implementation of each (``Camera.distort`` and the rig adjustment use
:func:`distort`; the tracker's candidates and calibration's ``triangulate`` use :func:`triangulate_dlt`;
the tracker's output points, their views weighted, :func:`triangulate_rays`)."""

from __future__ import annotations

import numpy as np


def distort(normalized: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's 5-parameter distortion (k1, k2, p1, p2, k3) applied to (N, 2) normalized image
    coordinates. ``dist``: (5,) for one camera or (N, 5), one row per point (batched cameras)."""
    x, y = normalized[:, 0], normalized[:, 1]
    k1, k2, p1, p2, k3 = np.asarray(dist).T
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([xd, yd])


def rotation_matrices(rvecs: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors (rad) -> (N, 3, 3) rotation matrices (Rodrigues' formula, batched)."""
    rvecs = np.asarray(rvecs, float).reshape(-1, 3)
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    k = rvecs / np.where(small, 1.0, theta)[:, None]
    K = _skew(k)
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    R[small] = np.eye(3) + _skew(rvecs[small])
    return R


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def triangulate_dlt(P: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Batched linear (DLT) triangulation.

    ``P`` (C, 3, 4) projection matrices; ``uv`` (N, C, 2) undistorted pixels; ``used`` (N, C) bool.
    Returns (N, 3) world points (mm). Unused cameras contribute zero rows."""
    rows_u = uv[:, :, 0:1] * P[None, :, 2, :] - P[None, :, 0, :]  # (N, C, 4)
    rows_v = uv[:, :, 1:2] * P[None, :, 2, :] - P[None, :, 1, :]
    A = np.concatenate([rows_u, rows_v], axis=1) * np.tile(used, (1, 2))[:, :, None]
    # Scale rows for conditioning: world mm and pixels differ by orders of magnitude.
    A /= np.maximum(np.linalg.norm(A, axis=2, keepdims=True), 1e-12)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        return X[:, :3] / X[:, 3:4]


def triangulate_rays(origins: np.ndarray, directions: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Batched weighted least-squares point of rays: minimises ``sum_c (w_c d_c)^2``, ``d_c`` the
    point's distance (mm) from ray ``c``, so a weight is the inverse of its ray's expected error.

    ``origins`` (C, 3) mm (the cameras' centres); ``directions`` (N, C, 3) unit; ``weights``
    (N, C) >= 0, 0 where a camera is not used. Returns (N, 3) mm; NaN for rows with fewer than
    two weighted rays. (The DLT's homogeneous least squares is no place for weights: scaled
    rows bias its null vector, 18 mm on a studio dot.)"""
    w2 = weights**2
    across = np.eye(3) - directions[..., :, None] * directions[..., None, :]  # (N, C, 3, 3): off-ray part
    A = np.einsum("nc,ncij->nij", w2, across)
    b = np.einsum("nc,ncij,cj->ni", w2, across, origins)
    points = np.full((len(weights), 3), np.nan)
    ok = (weights > 0).sum(axis=1) >= 2
    if ok.any():
        points[ok] = np.linalg.solve(A[ok], b[ok][:, :, None])[:, :, 0]
    return points


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
