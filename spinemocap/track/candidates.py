"""Stage 1: 3D candidate points from per-view blobs (paper section 3, the point cloud P).

Blobs of every camera pair are matched along epipolar lines (fundamental matrices on undistorted
pixels), triangulated, and kept when their reprojection error is below ``th1`` px in both views.
Points closer than ``th2`` mm are then merged, round after round, when the merged point (re-
triangulated from the union of their blobs) still reprojects below ``th1`` in every camera; this
repeats until nothing merges. A dot seen by k cameras thus ends as one point with k views, while
ghost points (wrong blob pairings along an epipolar line) usually keep only two.

Deviation from the paper: a merged point is re-triangulated from all its blobs instead of taking
the midpoint ``(p1 + p2) / 2``; with three or more views this is the more accurate estimate.
Two points whose blobs differ in a camera they share are never merged (one blob is one dot).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..camera import Rig
from ..geometry import triangulate_dlt
from ..views import ViewDots
from .config import CandidateConfig
from .lattice import inverse_sym3
from .types import CandidateCloud


def fundamental_matrix(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """F with ``x2^T F x1 = 0`` for (3, 4) projection matrices on undistorted pixels."""
    _, _, vt = np.linalg.svd(P1)
    c1 = vt[-1]  # camera-1 centre, homogeneous (null vector of P1)
    e2 = P2 @ c1
    e2x = np.array([[0, -e2[2], e2[1]], [e2[2], 0, -e2[0]], [-e2[1], e2[0], 0]])
    return e2x @ P2 @ np.linalg.pinv(P1)


@lru_cache(maxsize=256)
def _fundamental_cached(P1: bytes, P2: bytes) -> np.ndarray:
    """:func:`fundamental_matrix` of two (3, 4) float64 matrices given as bytes, remembered (a
    rig's cameras are the same from frame to frame)."""
    F = fundamental_matrix(np.frombuffer(P1).reshape(3, 4), np.frombuffer(P2).reshape(3, 4))
    F.flags.writeable = False
    return F


_RIGS: dict[bytes, tuple[np.ndarray, np.ndarray, dict]] = {}


def _rig_constants(rig: Rig) -> tuple[np.ndarray, np.ndarray, dict]:
    """The rig's stacked projection matrices (C, 3, 4), camera centres (C, 3) and its fundamental
    matrices found so far, remembered by the cameras' K, R and t (a rig is the same from frame to
    frame; one changed in place has other values, so other constants)."""
    key = b"".join(a.dtype.str.encode() + np.ascontiguousarray(a).tobytes() for cam in rig for a in (cam.K, cam.R, cam.t))
    got = _RIGS.get(key)
    if got is None:
        P = np.stack([cam.projection_matrix for cam in rig])
        centers = np.stack([cam.center for cam in rig])
        P.flags.writeable = centers.flags.writeable = False
        if len(_RIGS) >= 16:
            _RIGS.clear()
        got = _RIGS[key] = (P, centers, {})
    return got


def epipolar_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray,
                      h1: np.ndarray | None = None, h2: np.ndarray | None = None) -> np.ndarray:
    """(N1, N2) symmetric epipolar distance (px, the larger of both directions) between undistorted
    pixels ``x1`` (N1, 2) of camera 1 and ``x2`` (N2, 2) of camera 2 (``h1``, ``h2``: the same
    pixels homogeneous, (N, 3) with a last column of ones, when the caller has them)."""
    h1 = np.column_stack([x1, np.ones(len(x1))]) if h1 is None else h1
    h2 = np.column_stack([x2, np.ones(len(x2))]) if h2 is None else h2
    lines2 = h1 @ F.T  # (N1, 3) epipolar lines in image 2
    lines1 = h2 @ F  # (N2, 3) epipolar lines in image 1
    algebraic = np.abs(lines2 @ h2.T)  # (N1, N2) |x2^T F x1|
    d2 = algebraic / np.linalg.norm(lines2[:, :2], axis=1, keepdims=True)
    d1 = algebraic / np.linalg.norm(lines1[:, :2], axis=1)[None, :]
    return np.maximum(d1, d2)


def reprojection_errors(P: np.ndarray, points: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    """(N, C) reprojection error in undistorted px (NaN where unused or behind the camera)."""
    Xh = np.column_stack([points, np.ones(len(points))])
    proj = np.einsum("cij,nj->nci", P, Xh)  # (N, C, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = proj[:, :, :2] / proj[:, :, 2:3]
        err = np.linalg.norm(px - uv, axis=2)
    err[(proj[:, :, 2] <= 0) | ~used] = np.nan
    return err


class _Views:
    """Undistorted blobs of all cameras of one frame, addressable by (camera, blob id).

    :meth:`solve` remembers every row of blob ids it has triangulated in this frame: the merge
    rounds ask again for the rows they keep, and for the same merged unions round after round
    (triangulation is per row, so a remembered result is bit for bit the one a new call gives)."""

    def __init__(self, rig: Rig, views: Sequence[ViewDots], record_gate_range: bool = False):
        self.P, self.centers, self._fundamental = _rig_constants(rig)
        self.uv = [cam.undistort_points(v.uv) if len(v) else np.zeros((0, 2)) for cam, v in zip(rig, views)]
        self.homogeneous = [np.column_stack([uv, np.ones(len(uv))]) for uv in self.uv]  # for the epipolar search
        self.n_cameras = len(rig)
        # each row of blob ids (-1 .. n-1 per camera) as one integer: digits of base n + 1
        base = max([len(uv) for uv in self.uv] + [1]) + 1
        if self.n_cameras * np.log2(base) >= 62:  # pragma: no cover - thousands of blobs per camera
            raise ValueError(f"too many blobs for the candidate search ({base - 1} in one camera)")
        self._digits = base ** np.arange(self.n_cameras, dtype=np.int64)
        self._keys = np.zeros(0, np.int64)     # rows triangulated so far (sorted keys) ...
        self._where = np.zeros(0, np.int64)    # ... and their index in the arrays below
        self._points = np.zeros((0, 3))
        self._rms = np.zeros(0)
        self._ok = np.zeros(0, bool)
        self._th1: float | None = None
        # (lo, hi]: the th1 values that decide every test made so far alike (one th1 per build),
        # kept only when asked for (:func:`candidates_and_gate_range`)
        self.record_gate_range = record_gate_range
        self.th1_range = (-np.inf, np.inf)

    def fundamental(self, a: int, b: int) -> np.ndarray:
        """The fundamental matrix of cameras a and b (:func:`fundamental_matrix`), remembered per rig."""
        F = self._fundamental.get((a, b))
        if F is None:
            F = self._fundamental[(a, b)] = _fundamental_cached(self.P[a].tobytes(), self.P[b].tobytes())
        return F

    def gather(self, blob_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, C) blob ids -> undistorted pixels (N, C, 2) and the used mask (N, C)."""
        used = blob_ids >= 0
        uv = np.zeros(blob_ids.shape + (2,))
        for c in range(self.n_cameras):
            rows = used[:, c]
            if rows.any():
                uv[rows, c] = self.uv[c][blob_ids[rows, c]]
        return uv, used

    def keys(self, blob_ids: np.ndarray) -> np.ndarray:
        """(N,) int64: each row of blob ids as one integer (equal rows, equal keys)."""
        return (np.asarray(blob_ids, np.int64) + 1) @ self._digits

    def solve(self, blob_ids: np.ndarray, th1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Triangulate each row of blob ids; returns points (N, 3), RMS residual (N,) and a
        validity mask (N,) = finite, in front of all used cameras, max error below th1."""
        if th1 != self._th1:
            self._forget(th1)
        keys = self.keys(blob_ids)
        pos = np.minimum(np.searchsorted(self._keys, keys), max(len(self._keys) - 1, 0))
        known = (self._keys[pos] == keys) if len(self._keys) else np.zeros(len(keys), bool)
        if not known.all():
            new_keys, first = np.unique(keys[~known], return_index=True)
            points, rms, ok = self._triangulate(blob_ids[np.flatnonzero(~known)[first]], th1)
            where = np.concatenate([self._where, len(self._points) + np.arange(len(new_keys))])
            all_keys = np.concatenate([self._keys, new_keys])
            order = np.argsort(all_keys, kind="stable")
            self._keys, self._where = all_keys[order], where[order]
            self._points = np.concatenate([self._points, points])
            self._rms = np.concatenate([self._rms, rms])
            self._ok = np.concatenate([self._ok, ok])
            pos = np.searchsorted(self._keys, keys)
        index = self._where[pos]
        return self._points[index], self._rms[index], self._ok[index]

    def _forget(self, th1: float) -> None:
        self._keys, self._where = np.zeros(0, np.int64), np.zeros(0, np.int64)
        self._points, self._rms, self._ok = np.zeros((0, 3)), np.zeros(0), np.zeros(0, bool)
        self._th1 = th1

    def decided(self, values: np.ndarray, th1: float) -> None:
        """Narrow :attr:`th1_range` by tests ``value < th1`` just made on ``values`` (any shape;
        NaN values, whose test fails for every th1, are ignored): the range keeps only the th1
        values that decide each of them as ``th1`` did. Nothing is kept unless ``record_gate_range``."""
        if not self.record_gate_range:
            return
        values = np.asarray(values, float).ravel()
        below = values[values < th1]
        above = values[values >= th1]
        lo, hi = self.th1_range
        self.th1_range = (max(lo, float(below.max())) if len(below) else lo,
                          min(hi, float(above.min())) if len(above) else hi)

    def _triangulate(self, blob_ids: np.ndarray, th1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        uv, used = self.gather(blob_ids)
        points = _triangulate_compact(self.P, uv, used)
        err = reprojection_errors(self.P, points, uv, used)
        seen = used & ~np.isnan(err)  # the used views with a reprojection (in front of the camera)
        with np.errstate(invalid="ignore", divide="ignore"):
            valid = np.isfinite(points).all(axis=1) & ~(used & ~seen).any(axis=1)
            # np.nanmax / np.nanmean over the used views, without the nan-functions' overhead (same sums)
            worst = np.where(seen, err, 0.0).max(axis=1)
            ok = valid & (worst < th1)
            rms = np.sqrt(np.where(seen, err**2, 0.0).sum(axis=1) / seen.sum(axis=1))
        # rows failing for another reason (not finite, behind a camera) fail for every th1
        self.decided(np.where(valid, worst, np.nan), th1)
        return points, rms, ok

    def normals(self, points: np.ndarray, blob_ids: np.ndarray) -> np.ndarray:
        """Negative mean viewing direction of the contributing cameras (unit, toward them)."""
        to_point = points[:, None, :] - self.centers[None, :, :]
        to_point /= np.linalg.norm(to_point, axis=2, keepdims=True)
        mean = -(to_point * (blob_ids >= 0)[:, :, None]).sum(axis=1)
        return mean / np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)


def _triangulate_compact(P: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    """:func:`~spinemocap.geometry.triangulate_dlt` of each row on its used cameras, without an SVD
    per row: the DLT's null vector ``(X, 1)`` is the smallest eigenvector of ``A^T A``, found by a
    few Newton steps on ``A^T A v = lambda v`` whose residuals are computed from ``A`` itself (not
    from the squared matrix), so the same points to rounding (<= 1e-9 mm against LAPACK's SVD on
    the studio's frames) in a fraction of the time (LAPACK's per-matrix SVD cost ~6 us a row).
    Rows with fewer than two cameras, or whose steps have not settled, take the SVD."""
    n = len(uv)
    points = np.full((n, 3), np.nan)
    n_used = used.sum(axis=1)
    fast = n_used >= 2
    if fast.any():
        cams = used[fast].any(axis=0)  # cameras no row uses add only zero rows: leave them out
        points[fast] = _dlt_newton(P[cams], uv[fast][:, cams], used[fast][:, cams])
        unsettled = fast & ~np.isfinite(points).all(axis=1)
        fast &= ~unsettled
    rest = np.flatnonzero(~fast & (n_used > 0))
    if len(rest):
        points[rest] = _dlt_svd(P, uv[rest], used[rest])
    return points


def _dlt_newton(P: np.ndarray, uv: np.ndarray, used: np.ndarray, steps: int = 4) -> np.ndarray:
    """(N, 3) DLT points of rows with >= 2 used cameras; NaN rows where the Newton steps did not
    settle to rounding (the caller takes the SVD there). ``A`` is built as
    :func:`~spinemocap.geometry.triangulate_dlt` builds it (row-normalised, zero rows for unused
    cameras); with ``v = (X, 1)`` the DLT solves ``G X + g = lambda X`` (``G``, ``g``: the blocks
    of ``A^T A``; ``lambda = |A v|^2 / |v|^2``, the smallest eigenvalue): started from the
    inhomogeneous least-squares point ``-G^-1 g``, each step corrects by ``(G - lambda_0 I)^-1``
    (``lambda_0``: the first eigenvalue estimate) times the stationarity residual
    ``A1^T A v - lambda X`` computed from ``A``. ``G`` only steers the steps; the point they
    settle at is set by the residuals, so it is as accurate as ``A`` allows (the eigenvector of
    ``A^T A`` itself carries the squared condition number)."""
    rows_u = uv[:, :, 0:1] * P[None, :, 2, :] - P[None, :, 0, :]  # (N, C, 4)
    rows_v = uv[:, :, 1:2] * P[None, :, 2, :] - P[None, :, 1, :]
    A = np.concatenate([rows_u, rows_v], axis=1) * np.tile(used, (1, 2))[:, :, None]
    A /= np.maximum(np.linalg.norm(A, axis=2, keepdims=True), 1e-12)
    A1, a4 = A[:, :, :3], A[:, :, 3:]
    At = A1.transpose(0, 2, 1)
    G = At @ A1  # (N, 3, 3)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        X = -(inverse_sym3(G) @ (At @ a4))  # (N, 3, 1)
        inv = None
        for _ in range(steps):
            r = A1 @ X + a4
            lam = (r * r).sum(axis=1, keepdims=True) / (1.0 + (X * X).sum(axis=1, keepdims=True))
            if inv is None:  # (G - lambda I)^-1 at the first eigenvalue estimate: the steps then converge fast
                inv = inverse_sym3(G - lam * np.eye(3))
            step = inv @ (At @ r - lam * X)
            X = X - step
        X, step = X[:, :, 0], step[:, :, 0]
        settled = np.abs(step).max(axis=1) <= 1e-12 * (1.0 + np.abs(X).max(axis=1))
    X[~settled] = np.nan
    return X


def _dlt_svd(P: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    """:func:`~spinemocap.geometry.triangulate_dlt` of each row on its used cameras only (rows
    grouped by their set of cameras): the same linear systems without their zero rows."""
    points = np.full((len(uv), 3), np.nan)
    camera_set = used @ (1 << np.arange(used.shape[1]))  # each row's cameras as bits
    order = np.argsort(camera_set, kind="stable")
    sets, starts = np.unique(camera_set[order], return_index=True)
    for bits, rows in zip(sets, np.split(order, starts[1:])):
        cameras = used[rows[0]]
        if bits:
            points[rows] = triangulate_dlt(P[cameras], uv[rows][:, cameras], np.ones((len(rows), int(cameras.sum())), bool))
    return points


def _pairwise_rows(views: _Views, config: CandidateConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blob-id rows (N, C) of all two-view triangulations passing epipolar and th1 checks, with
    their points (N, 3) and RMS residuals (N,)."""
    epi_tol = config.epipolar_px if config.epipolar_px is not None else 2.0 * config.th1_px
    rows = []
    C = views.n_cameras
    for a in range(C):
        for b in range(a + 1, C):
            if not len(views.uv[a]) or not len(views.uv[b]):
                continue
            F = views.fundamental(a, b)
            distance = epipolar_distance(F, views.uv[a], views.uv[b], views.homogeneous[a], views.homogeneous[b])
            ia, ib = np.nonzero(distance < epi_tol)
            if config.epipolar_px is None:  # d < 2 th1 exactly when d / 2 < th1 (halving is exact)
                views.decided(distance / 2.0, config.th1_px)
            ids = np.full((len(ia), C), -1, dtype=np.int64)
            ids[:, a], ids[:, b] = ia, ib
            rows.append(ids)
    if not rows:
        return np.zeros((0, C), dtype=np.int64), np.zeros((0, 3)), np.zeros(0)
    ids = np.concatenate(rows)
    points, rms, ok = views.solve(ids, config.th1_px)
    return ids[ok], points[ok], rms[ok]


def _merge_round(views: _Views, ids: np.ndarray, points: np.ndarray, config: CandidateConfig, rms: np.ndarray):
    """One merge round: among point pairs closer than th2 without conflicting blobs and whose
    merged point passes th1, merge every pair that is each endpoint's closest valid partner.
    ``rms``: the points' RMS residuals (px). Returns the new (ids, points), the number of merges
    and the new points' residuals."""
    pairs = cKDTree(points).query_pairs(config.th2_mm, output_type="ndarray")
    if not len(pairs):
        return ids, points, 0, rms
    bi, bj = ids[pairs[:, 0]], ids[pairs[:, 1]]
    conflict = ((bi >= 0) & (bj >= 0) & (bi != bj)).any(axis=1)
    pairs, bi, bj = pairs[~conflict], bi[~conflict], bj[~conflict]
    if not len(pairs):
        return ids, points, 0, rms
    union = np.where(bi >= 0, bi, bj)
    merged, merged_rms, ok = views.solve(union, config.th1_px)
    pairs, union, merged, merged_rms = pairs[ok], union[ok], merged[ok], merged_rms[ok]
    if not len(pairs):
        return ids, points, 0, rms
    # Mutual-best matching, vectorised: each point's closest valid partner.
    dist = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    n = len(points)
    best = np.full(n, np.inf)
    np.minimum.at(best, pairs[:, 0], dist)
    np.minimum.at(best, pairs[:, 1], dist)
    take = (dist <= best[pairs[:, 0]]) & (dist <= best[pairs[:, 1]])
    # Equal distances could let a point join two pairs; keep the first pair per point.
    chosen = np.nonzero(take)[0]
    endpoint_owner = np.full(n, len(pairs))  # the first chosen pair of each point
    np.minimum.at(endpoint_owner, pairs[chosen, 0], chosen)
    np.minimum.at(endpoint_owner, pairs[chosen, 1], chosen)
    chosen = chosen[(endpoint_owner[pairs[chosen, 0]] == chosen) & (endpoint_owner[pairs[chosen, 1]] == chosen)]
    keep = np.ones(n, dtype=bool)
    keep[pairs[chosen].ravel()] = False
    new_ids = np.concatenate([ids[keep], union[chosen]])
    new_points = np.concatenate([points[keep], merged[chosen]])
    return new_ids, new_points, len(chosen), np.concatenate([rms[keep], merged_rms[chosen]])


def _unique_row_index(ids: np.ndarray) -> np.ndarray:
    """Index of the first of each distinct row of ``ids``, the rows in lexicographic order
    (``np.unique(ids, axis=0, return_index=True)[1]``, faster): each row of ids >= -1 as one
    integer whose most significant digit is the first column (the same order), sorted stably."""
    if len(ids) < 2:
        return np.arange(len(ids))
    n_cols = ids.shape[1]
    base = int(ids.max()) + 2
    if ids.min() >= -1 and n_cols * np.log2(base) < 62:
        keys = (np.asarray(ids, np.int64) + 1) @ (base ** np.arange(n_cols - 1, -1, -1, dtype=np.int64))
        return np.unique(keys, return_index=True)[1]
    order = np.lexsort(ids.T[::-1])
    ordered = ids[order]
    distinct = np.ones(len(ordered), bool)
    distinct[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    return order[distinct]


def suppress_dominated(ids: np.ndarray) -> np.ndarray:
    """(N,) bool keep-mask: False for points sharing a blob with a point of more views.

    One blob images one dot, so of two points using the same blob at most one is real; the one
    confirmed by more cameras wins. This removes most two-view ghosts (wrong pairings along an
    epipolar line) before the LP, which then only arbitrates between equals. A dot seen by only
    two cameras keeps its point: its blobs belong to no better-supported point."""
    n_views = (ids >= 0).sum(axis=1)
    keep = np.ones(len(ids), dtype=bool)
    for c in range(ids.shape[1]):
        used = ids[:, c] >= 0
        if not used.any():
            continue
        best = np.zeros(ids[:, c].max() + 1, dtype=np.int64)
        np.maximum.at(best, ids[used, c], n_views[used])
        keep[used] &= n_views[used] >= best[ids[used, c]]
    return keep


def build_candidates(rig: Rig, views: Sequence[ViewDots], config: CandidateConfig | None = None) -> CandidateCloud:
    """The candidate cloud P of one frame: points (mm), normals, blob ids per camera, residuals."""
    return _build(_Views(rig, views), views, config or CandidateConfig())


def candidates_and_gate_range(rig: Rig, views: Sequence[ViewDots], config: CandidateConfig | None = None
                              ) -> tuple[CandidateCloud, tuple[float, float]]:
    """:func:`build_candidates`, and the gates (lo, hi] (px) that build the same cloud: every
    test against ``th1_px`` (and against the epipolar tolerance 2 * th1 when ``epipolar_px`` is
    None) comes out alike for any ``th1_px`` in that range, so the cloud is bit for bit the one
    that a call with such a gate returns. A cloud built ahead with one gate thus serves a frame
    whose gate is known only later."""
    v = _Views(rig, views, record_gate_range=True)
    return _build(v, views, config or CandidateConfig()), v.th1_range


def _build(v: _Views, views: Sequence[ViewDots], config: CandidateConfig) -> CandidateCloud:
    """The candidate search on ``v`` (the frame's undistorted blobs; ``views`` its views)."""
    if len(views) != v.n_cameras:
        raise ValueError(f"{len(views)} views for a rig of {v.n_cameras} cameras")
    # the rows carry their (remembered) points and residuals along: equal rows, equal values
    ids, points, residual = _pairwise_rows(v, config)
    distinct = _unique_row_index(ids)
    ids, points, residual = ids[distinct], points[distinct], residual[distinct]
    for _ in range(config.max_merge_rounds):
        ids, points, n_merged, residual = _merge_round(v, ids, points, config, residual)
        if n_merged == 0:
            break
        distinct = _unique_row_index(ids)
        ids, points, residual = ids[distinct], points[distinct], residual[distinct]
    if config.suppress_dominated and len(ids):
        keep = suppress_dominated(ids)
        ids, points, residual = ids[keep], points[keep], residual[keep]
    normals = v.normals(points, ids) if len(ids) else np.zeros((0, 3))
    return CandidateCloud(points=points.reshape(-1, 3), normals=normals, blob_ids=ids, residual=residual,
                          pixels=blob_pixels(views, ids))


def blob_pixels(views: Sequence[ViewDots], ids: np.ndarray) -> np.ndarray:
    """(N, C, 2) distorted pixel centres of the blobs in ``ids`` (N, C) (NaN where -1)."""
    out = np.full(ids.shape + (2,), np.nan)
    for c, view in enumerate(views):
        used = ids[:, c] >= 0
        if used.any():
            out[used, c] = np.asarray(view.uv, float)[ids[used, c]]
    return out
