"""The tape template that MRF1 starts from (paper Sec. 3.2), and local tape frames of labelled dots.

A cubic polynomial (in the feasible set's principal-direction coordinate) approximates the
tape's midline; the normal field orients the tape around it; the flat tape layout
(``TapeGraph.uv_mm``) is then laid along the curve by arc length: dot ``(u, v)`` goes to
``curve(s0 + o * v) + u * across``, with ``across = along x normal`` (the subject's right when the
normal points out of the back). Two choices remain and decide the labels:

- the orientation ``o`` (which end of the curve is the sacral row 1; left/right follows from the
  normal, so there are only two): on a first frame, row 1 is the lower end along the subject's
  ``up``; later, the orientation whose dots lie closest to the ``previous`` frame's labelled dots
  (so identity survives handstands: it is carried, not re-derived from "lower end = sacral");
- the offset ``s0``: the one whose dots best match the feasible points (symmetric capped chamfer).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy.spatial import cKDTree

from ..geometry import umeyama
from ..tape import TapeGraph
from .normals import NormalField, _unit


class SpineCurve:
    """A cubic through (K, 3) points (mm), parameterised by arc length ``s`` (mm).

    The polynomial's parameter is the coordinate along the points' principal direction; beyond
    the points' range the curve continues straight along its end tangents (a cubic extrapolates
    wildly), so the template can cover rows with no feasible point."""

    def __init__(self, points: np.ndarray, extension_mm: float = 0.0, samples: int = 400):
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(pts) < 2:
            raise ValueError(f"cannot fit the tape curve to {len(pts)} point(s); need at least 2")
        centre = pts.mean(axis=0)
        axis = np.linalg.svd(pts - centre, full_matrices=False)[2][0]
        t = (pts - centre) @ axis
        degree = int(min(3, len(pts) - 1))
        coef = npoly.polyfit(t, pts, degree)  # (degree + 1, 3)
        t_lo, t_hi = float(t.min()), float(t.max())
        span = max(t_hi - t_lo, 1e-6)
        grid = np.linspace(t_lo - extension_mm, t_hi + extension_mm, samples + int(2 * extension_mm / span * samples))
        inside = npoly.polyval(np.clip(grid, t_lo, t_hi), coef).T
        slope = npoly.polyval(np.clip(grid, t_lo, t_hi), npoly.polyder(coef)).T
        beyond = grid - np.clip(grid, t_lo, t_hi)
        self.dense = inside + beyond[:, None] * slope  # (M, 3)
        step = np.linalg.norm(np.diff(self.dense, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(step)])
        self.axis = axis
        self._tangents: np.ndarray | None = None  # unit tangents at the samples, when first asked for
        self._tree = cKDTree(self.dense)

    @property
    def length(self) -> float:
        return float(self.arc[-1])

    def point(self, s: np.ndarray) -> np.ndarray:
        """(N, 3) curve points at arc lengths ``s`` (N,) mm."""
        s = np.asarray(s, dtype=float)
        return np.column_stack([np.interp(s, self.arc, self.dense[:, i]) for i in range(3)])

    def tangent(self, s: np.ndarray) -> np.ndarray:
        """(N, 3) unit tangents (direction of increasing s)."""
        s = np.asarray(s, dtype=float)
        return _unit(np.column_stack([np.interp(s, self.arc, self._tangent[:, i]) for i in range(3)]))

    @property
    def _tangent(self) -> np.ndarray:
        if self._tangents is None:  # not needed for arc coordinates (the spacing estimate, every frame)
            self._tangents = _unit(np.gradient(self.dense, axis=0))
        return self._tangents

    def arc_of(self, points: np.ndarray) -> np.ndarray:
        """(N,) arc length of the curve sample nearest to each of (N, 3) points."""
        return self.arc[self._tree.query(np.asarray(points, dtype=float).reshape(-1, 3))[1]]


@dataclass
class Template:
    """Template dot positions (D, 3) mm in label order, with its outward normals (D, 3), the
    curve, the orientation (+1: row 1 at the curve's low-arc end; 0: carried from a complete
    previous frame without a curve) and the offset ``s0`` (mm)."""

    positions: np.ndarray
    normals: np.ndarray
    curve: SpineCurve | None
    orientation: int
    offset_mm: float


def lay_along(
    curve: SpineCurve, field: NormalField, tape: TapeGraph, orientation: int, offset_mm: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and normals of the flat tape laid along ``curve``: (D, 3) each for a scalar
    ``offset_mm``, (C, D, 3) for C offsets at once."""
    u, v = tape.uv_mm[:, 0], tape.uv_mm[:, 1]
    offsets = np.atleast_1d(np.asarray(offset_mm, dtype=float))
    s = (offsets[:, None] + orientation * v[None, :]).ravel()
    centre = curve.point(s)
    along = orientation * curve.tangent(s)
    normal = field.at(centre)
    normal = _unit(normal - (normal * along).sum(axis=1, keepdims=True) * along)
    across = _unit(np.cross(along, normal))
    pos = (centre + np.tile(u, len(offsets))[:, None] * across).reshape(len(offsets), -1, 3)
    normal = normal.reshape(len(offsets), -1, 3)
    if np.ndim(offset_mm) == 0:
        return pos[0], normal[0]
    return pos, normal


def _chamfer(templates: np.ndarray, points: np.ndarray, cap_mm: float) -> np.ndarray:
    """Symmetric capped chamfer distance (mm) between each of C templates (C, D, 3) and the
    feasible points (K, 3): (C,)."""
    # |template dot - point| (C, D, K) by components: the same sums as np.linalg.norm(..., axis=3)
    # without its strided reduction
    dx, dy, dz = (templates[:, :, None, i] - points[None, None, :, i] for i in range(3))
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    dots_to_points = np.minimum(dist.min(axis=2), cap_mm).mean(axis=1)
    points_to_dots = np.minimum(dist.min(axis=1), cap_mm).mean(axis=1)
    return dots_to_points + points_to_dots


def _best_offset(curve, field, tape, orientation, points, cap_mm, step_mm, score_fn=None,
                 ambiguity_mm: float = 1.5, score_weight_mm: float = 5.0) -> float:
    """Offset s0 with the best chamfer match. Several offsets can tie when only part of the tape
    was triangulated (the 2/3-dot pattern repeats every two rows); ``score_fn`` (templates
    (C, D, 3) -> (C,) extra cost, e.g. image evidence) then decides among the chamfer's local
    minima within ``ambiguity_mm`` of the best, weighted by ``score_weight_mm`` per unit."""
    span = float(tape.uv_mm[:, 1].max())
    s_data = curve.arc_of(points)
    lo, hi = s_data.min(), s_data.max()
    if orientation > 0:
        candidates = np.arange(lo - span, hi + step_mm, step_mm)
    else:
        candidates = np.arange(lo, hi + span + step_mm, step_mm)
    templates = lay_along(curve, field, tape, orientation, candidates)[0]
    scores = _chamfer(templates, points, cap_mm)
    best = int(np.argmin(scores))
    if score_fn is None or len(scores) < 3:
        return float(candidates[best])
    padded = np.concatenate([[np.inf], scores, [np.inf]])
    local_min = (scores <= padded[:-2]) & (scores <= padded[2:])
    tied = np.flatnonzero(local_min & (scores <= scores[best] + ambiguity_mm))
    if len(tied) < 2:
        return float(candidates[best])
    total = scores[tied] + score_weight_mm * np.asarray(score_fn(templates[tied]), dtype=float)
    return float(candidates[tied[int(np.argmin(total))]])


def build_template(
    points: np.ndarray,
    normals: np.ndarray,
    tape: TapeGraph,
    up: np.ndarray | None = None,
    previous: np.ndarray | None = None,
    warm_start: bool = False,
    field: NormalField | None = None,
    cap_mm: float = 15.0,
    step_mm: float = 2.5,
    template_score: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Template:
    """Initial template for MRF1 from the feasible points (K, 3) and their normals (K, 3).

    ``up`` (3,): the subject's up direction (used when ``previous`` is None; default world +Z).
    ``previous`` (D, 3): the last frame's labelled dots (NaN rows allowed); it fixes the
    orientation, and with ``warm_start`` its finite rows, rigidly aligned to the points
    (:func:`align_rigidly`), are the template. ``template_score``: optional callable scoring
    candidate templates (C, D, 3) -> (C,) (lower is better, e.g. image evidence) that breaks ties
    between offsets along the tape (see :func:`_best_offset`)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if warm_start and previous is not None and np.isfinite(previous).all():
        # identity and shape are carried whole: no curve needed (orientation 0 = carried)
        positions = align_rigidly(np.asarray(previous, dtype=float), points)
        return Template(positions, tape_frames(positions, tape)[0], None, 0, float("nan"))
    field = field if field is not None else NormalField(points, normals)
    span = float(tape.uv_mm[:, 1].max())
    curve = SpineCurve(points, extension_mm=span + 50.0)
    options = {}
    for o in (+1, -1):
        s0 = _best_offset(curve, field, tape, o, points, cap_mm, step_mm, score_fn=template_score)
        options[o] = (*lay_along(curve, field, tape, o, s0), s0)

    # the last frame's dots orient (and warm-start) this one when at least 3 of them are finite
    if previous is not None and np.isfinite(previous).all(axis=1).sum() < 3:
        previous = None
    if previous is not None:
        finite = np.isfinite(previous).all(axis=1)
        dist = {o: np.linalg.norm(options[o][0][finite] - previous[finite], axis=1).mean() for o in options}
        orientation = min(dist, key=lambda o: dist[o])
    else:
        up_dir = np.asarray(up if up is not None else (0.0, 0.0, 1.0), dtype=float)
        first, last = tape.row == 0, tape.row == tape.row.max()
        # rise from row 1 to the last row along up: positive when row 1 is the lower end
        rise = {o: float((options[o][0][last].mean(0) - options[o][0][first].mean(0)) @ up_dir) for o in options}
        orientation = +1 if rise[+1] >= rise[-1] else -1
    positions, node_normals, s0 = options[orientation]
    if previous is not None and warm_start:
        finite = np.isfinite(previous).all(axis=1)
        positions = positions.copy()
        positions[finite] = align_rigidly(previous[finite], points)
        node_normals = tape_frames(positions, tape)[0]
    return Template(positions=positions, normals=node_normals, curve=curve, orientation=orientation, offset_mm=s0)


def align_rigidly(dots: np.ndarray, points: np.ndarray, iterations: int = 12, inlier_mm: float = 12.0) -> np.ndarray:
    """Move labelled dots (N, 3) rigidly onto the feasible points (K, 3) by trimmed ICP: each
    iteration pairs every dot with its nearest point, keeps pairs closer than a threshold that
    shrinks to ``inlier_mm``, and solves the rigid fit (translation only with < 3 pairs). The
    last frame's dots thus follow the body's motion before MRF1 refines them."""
    tree = cKDTree(points)
    rot, shift = np.eye(3), np.zeros(3)
    for it in range(iterations):
        moved = dots @ rot.T + shift
        dist, idx = tree.query(moved)
        limit = max(inlier_mm, 4 * inlier_mm * (1 - it / max(iterations - 1, 1)))
        pairs = dist < limit
        if pairs.sum() == 0:
            break
        if pairs.sum() < 3:
            shift = shift + (points[idx[pairs]] - moved[pairs]).mean(axis=0)
            continue
        rot, shift, _ = umeyama(dots[pairs], points[idx[pairs]], with_scale=False)
    return dots @ rot.T + shift


def tape_frames(positions: np.ndarray, tape: TapeGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local frames of labelled dots (D, 3): (normal, across, along), unit vectors.

    ``across`` runs from the row's L dot to its R dot, ``along`` from the previous row's centre to
    the next row's (one-sided at the ends), ``normal = across x along`` points out of the back.
    Because labels fix handedness, this needs no external normal."""
    pos = np.asarray(positions, dtype=float)
    rows = tape.row_index
    n_rows = len(rows.count)
    if (rows.left < 0).any() or (rows.right < 0).any():
        raise IndexError("every row of the tape needs an L and an R dot")
    row_centre = rows.sums(pos) / rows.count[:, None]  # each row's mean, its members added in order
    row_across = pos[rows.right] - pos[rows.left]
    # a single row has no longitudinal direction: any perpendicular
    row_along = _row_gradient(row_centre) if n_rows > 1 else _cross3(row_across, np.array([[0.0, 0.0, 1.0]]))
    # every dot takes its row's frame, so the frames are made per row and then handed to the dots
    # (the same element-by-element operations as per dot: the same values)
    across = _unit(row_across)
    along = _unit(row_along)
    normal = _unit(_cross3(across, along))
    along = _unit(_cross3(normal, across))  # re-orthogonalised
    return normal[tape.row], across[tape.row], along[tape.row]


def _row_gradient(f: np.ndarray) -> np.ndarray:
    """``np.gradient(f, axis=0)`` of (R >= 2, K) rows at unit spacing, without its overhead: the
    central difference over 2 inside, one-sided differences at the ends (the same operations)."""
    out = np.empty_like(f)
    np.subtract(f[2:], f[:-2], out=out[1:-1])
    out[1:-1] /= 2.0
    out[0] = f[1] - f[0]
    out[-1] = f[-1] - f[-2]
    return out


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of (N, 3) rows, without its overhead (its operations: ``a1 b2 - a2 b1`` ...)."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    out = np.empty((len(a), 3), dtype=np.result_type(a, b))
    out[:, 0] = a1 * b2 - a2 * b1
    out[:, 1] = a2 * b0 - a0 * b2
    out[:, 2] = a0 * b1 - a1 * b0
    return out
