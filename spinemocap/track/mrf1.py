"""MRF1: align the tape template to the LP's feasible set (paper Sec. 3.2, Eq. 6-9).

Nodes are the tape's dots in label order with state ``(x, y, z, d)``: position in mm and a local
stretch ``d``. The paper calls ``d`` "a local distance" that the edge length should match; since a
node's edges have different rest lengths (15 mm across, 25-29 mm between rows, 30-50 mm dashed),
we read it as a dimensionless local stretch: edge ``(s, t)`` should measure
``(d_s + d_t) / 2 * rest_length``. Energy (Eq. 6) = unaries + pairwise over solid and dashed edges:

- unary (Eq. 7): distance (mm) to the nearest feasible point, capped at ``unary_cap_mm`` (beyond
  the paper: an occluded dot then does not get dragged onto a neighbour's point);
- pairwise (Eq. 8) with ``p = x_s - x_t``, ``L`` the rest length, weights per edge kind
  (longitudinal / transverse, dashed edges scaled by ``dashed_weight``):
  ``theta1 (|p| - d L)^2 + theta2 <p, n_st>^2 + theta3 exp(d_min - |p|)^2 [|p| < d_min]
  + theta4 (|p| - L)^2`` where ``n_st`` is the normal field at the edge's midpoint.
The paper writes ``d_target`` for the fourth term: "measured tape distances", i.e. the rest length.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from ..tape import TapeGraph
from .config import MRF1Config
from .normals import NormalField
from .pbp import ParticleBP
from .template import build_template
from .types import FeasibleSet, MRFResult


class AlignmentMRF:
    """The MRF1 energy as a :class:`~spinemocap.track.pbp.PairwiseModel` (states (x, y, z, d))."""

    def __init__(self, feasible_points: np.ndarray, field: NormalField, tape: TapeGraph, config: MRF1Config):
        self.points = np.asarray(feasible_points, dtype=float).reshape(-1, 3)
        self.tree = cKDTree(self.points)
        self.field = field
        self.config = config
        self.edges = tape.edges
        self.rest = tape.rest_length_mm
        c = config
        kind_weight = np.where(tape.solid, 1.0, c.dashed_weight)
        self.w1 = kind_weight * np.where(tape.transverse, c.theta1_transverse, c.theta1_longitudinal)
        self.w4 = kind_weight * np.where(tape.transverse, c.theta4_transverse, c.theta4_longitudinal)
        self.w2 = kind_weight * c.theta2
        self.w3 = kind_weight * c.theta3
        self.edge_normals = np.zeros((len(self.edges), 3))

    def prepare(self, state: np.ndarray) -> None:
        self.edge_normals = self.field.at_edges(state[:, :3], self.edges)

    def unary(self, x: np.ndarray) -> np.ndarray:
        dist = self.tree.query(x[..., :3].reshape(-1, 3))[0].reshape(x.shape[:-1])
        d = x[..., 3]
        lo, hi = self.config.d_bounds
        out_of_bounds = 1e3 * (np.maximum(lo - d, 0) + np.maximum(d - hi, 0))  # keeps d plausible
        return np.minimum(dist, self.config.unary_cap_mm) + out_of_bounds

    def pairwise(self, xs: np.ndarray, xt: np.ndarray, edge_index: np.ndarray) -> np.ndarray:
        # p = xs - xt (M, Qs, Qt, 3) by components, the terms built in place (arrays of M Qs Qt
        # floats, a few MB: fresh ones cost page faults): the same values as |p| =
        # sqrt((p * p).sum(axis=3)), np.einsum("mabk,mk->mab", p, n) (whose terms numpy adds as
        # (x + z) + y) and the plain expression of Eq. 8
        dx = np.subtract(xs[:, :, None, 0], xt[:, None, :, 0])
        dy = np.subtract(xs[:, :, None, 1], xt[:, None, :, 1])
        dz = np.subtract(xs[:, :, None, 2], xt[:, None, :, 2])
        length = dx * dx
        tmp = np.multiply(dy, dy)
        length += tmp
        np.multiply(dz, dz, out=tmp)
        length += tmp
        np.sqrt(length, out=length)
        n = self.edge_normals[edge_index]
        normal_part = np.multiply(dx, n[:, 0, None, None], out=dx)
        normal_part += np.multiply(dz, n[:, 2, None, None], out=dz)
        normal_part += np.multiply(dy, n[:, 1, None, None], out=dy)
        rest = self.rest[edge_index][:, None, None]
        w = lambda arr: arr[edge_index][:, None, None]  # noqa: E731
        # w1 (|p| - d L)^2 with d the edge's mean stretch, 0.5 (d_s + d_t)
        out = np.add(xs[:, :, None, 3], xt[:, None, :, 3], out=dz)
        out *= 0.5
        out *= rest
        np.subtract(length, out, out=out)
        np.square(out, out=out)
        out *= w(self.w1)
        np.square(normal_part, out=normal_part)  # + w2 <p, n>^2
        normal_part *= w(self.w2)
        out += normal_part
        short = length < self.config.d_min_mm  # + w3 exp(d_min - |p|)^2 where |p| < d_min
        barrier = np.zeros_like(length)  # the exponential only where it applies (few entries): same values
        barrier[short] = np.exp(np.minimum(self.config.d_min_mm - length[short], 50.0)) ** 2
        barrier *= w(self.w3)
        out += barrier
        np.subtract(length, rest, out=length)  # + w4 (|p| - L)^2
        np.square(length, out=length)
        length *= w(self.w4)
        out += length
        return out

    def extra_proposals(self, state: np.ndarray) -> np.ndarray:
        """P_knn: the k nearest feasible points of each node, with the node's own d."""
        k = min(self.config.knn, len(self.points))
        if k == 0:
            return np.empty((len(state), 0, 4))
        idx = self.tree.query(state[:, :3], k=k)[1].reshape(len(state), k)
        prop = np.repeat(state[:, None, :], k, axis=1)
        prop[:, :, :3] = self.points[idx]
        return prop


def fit_mrf1(
    feasible: FeasibleSet,
    tape: TapeGraph,
    config: MRF1Config | None = None,
    up: np.ndarray | None = None,
    previous: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    template_score: Callable[[np.ndarray], np.ndarray] | None = None,
) -> MRFResult:
    """Align the tape template to ``feasible`` (world mm) by particle BP on the MRF1 energy.

    ``up`` (3,): the subject's up direction for the first frame (row 1 = lower end; default +Z).
    ``previous`` (D, 3): last frame's labelled dots (NaN rows allowed); it decides the orientation
    (identity carried through handstands) and, with ``config.warm_start``, the start positions.
    ``template_score`` (beyond the paper): scores candidate templates (C, D, 3) -> (C,), lower
    is better; it decides between offsets along the tape that fit a partial feasible set equally
    well (e.g. :class:`~spinemocap.track.mrf2.TemplateEvidenceScore` on the camera images).
    Returns positions (D, 3) in label order; ``extra``: ``d`` (D,), ``template`` (D, 3),
    ``normals`` (D, 3) at the template, ``orientation``, ``energy_baselines`` (see
    :class:`~spinemocap.track.pbp.PBPResult`). Raises ValueError for < 2 feasible points."""
    config = config or MRF1Config()
    points = np.asarray(feasible.points, dtype=float).reshape(-1, 3)
    if len(points) < 2:
        raise ValueError(f"MRF1 needs at least 2 feasible points; got {len(points)}")
    field = NormalField(points, feasible.normals, radius_mm=config.normal_radius_mm)
    template = build_template(
        points, feasible.normals, tape, up=up, previous=previous, warm_start=config.warm_start, field=field,
        template_score=template_score,
    )
    model = AlignmentMRF(points, field, tape, config)
    init = np.column_stack([template.positions, np.ones(tape.n_dots)])
    result = ParticleBP(model, config.pbp(), rng).run(init)
    return MRFResult(
        positions=result.state[:, :3].copy(),
        energy_history=result.energy_history,
        extra={
            "d": result.state[:, 3].copy(),
            "template": template.positions,
            "normals": template.normals,
            "orientation": template.orientation,
            "energy_baselines": result.baselines,
        },
    )
