"""The smooth normal field N_f (paper Sec. 3.2) built from the feasible points' normal attributes.

Each feasible point carries a normal = negative mean viewing direction of the cameras that
triangulated it (world frame, unit, pointing from the skin toward the cameras). Those are noisy
and camera-biased, so the field smooths them with a Gaussian kernel over space, and answers
lookups at arbitrary 3D points (edge midpoints, curve points) with the same kernel.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


class NormalField:
    """Smooth unit normals over space from (K, 3) points (mm) and their (K, 3) normals.

    ``radius_mm`` is the Gaussian kernel's standard deviation; lookups average the ``k`` nearest
    smoothed normals. With no points the field is undefined and :meth:`at` raises."""

    def __init__(self, points: np.ndarray, normals: np.ndarray, radius_mm: float = 30.0, k: int = 8):
        self.points = np.asarray(points, dtype=float).reshape(-1, 3)
        raw = _unit(np.asarray(normals, dtype=float).reshape(-1, 3))
        if len(self.points) != len(raw):
            raise ValueError("points and normals differ in length")
        self.radius_mm = float(radius_mm)
        self.k = int(k)
        self._tree = cKDTree(self.points) if len(self.points) else None
        self.normals = self._smooth(raw) if len(raw) else raw

    def __len__(self) -> int:
        return len(self.points)

    @property
    def mean_normal(self) -> np.ndarray:
        """Unit mean of all smoothed normals (the dominant facing direction)."""
        if not len(self):
            raise ValueError("normal field has no points")
        return _unit(self.normals.sum(axis=0))

    def _kernel_average(self, queries: np.ndarray, values: np.ndarray) -> np.ndarray:
        if self._tree is None:
            raise ValueError("normal field has no points")
        k = min(self.k, len(self.points))
        dist, idx = self._tree.query(queries, k=k)
        dist, idx = dist.reshape(len(queries), k), idx.reshape(len(queries), k)
        w = np.exp(-0.5 * (dist / self.radius_mm) ** 2) + 1e-12
        return _unit((w[:, :, None] * values[idx]).sum(axis=1))

    def _smooth(self, raw: np.ndarray) -> np.ndarray:
        return self._kernel_average(self.points, raw)

    def at(self, queries: np.ndarray) -> np.ndarray:
        """(M, 3) unit normals at (M, 3) query points (mm)."""
        q = np.asarray(queries, dtype=float).reshape(-1, 3)
        return self._kernel_average(q, self.normals)

    def at_edges(self, positions: np.ndarray, edges: np.ndarray) -> np.ndarray:
        """(E, 3) normals at the midpoints of ``edges`` (E, 2) between ``positions`` (D, 3)."""
        mid = 0.5 * (positions[edges[:, 0]] + positions[edges[:, 1]])
        return self.at(mid)
