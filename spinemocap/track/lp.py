"""Stage 3: the binary edge-selection program (paper section 3.1).

Variables ``x_e`` in {0, 1} per edge of the edge cloud, ``y_p`` in {0, 1} per candidate point
("point used"). Model::

    min   sum_e c_e x_e                      c_e = 1 / |Omega_e|   (Omega_e: cloud edges sharing
                                                                    an endpoint with e)
    s.t.  sum_e x_e = n                      n = Eq. 1's n_e, lowered while infeasible
          6 x_e <= sum_{f in Omega_e} x_f <= 12 + M_e (1 - x_e)     (bounds bind on selected edges
                                                                     only; M_e = |Omega_e| - 12)
          x_e <= y_i,  x_e <= y_j            for e = (i, j)
          sum_{p uses blob b of camera c} y_p <= 1    for every blob used by >= 2 points
          sum_{e touches p} x_e >= k y_p     (k = min_point_degree, default 3)

Deviations from the paper's literal text (degenerate: with ``sum x <= n`` no edge is cheapest): ``sum x = n``
instead of ``<= n``; neighbour bounds only on selected edges. The ghost rule is written per blob
(a clique over all points triangulated from that blob) instead of per edge pair: it implies the
paper's "two edges whose endpoints come from the same blobs of one camera cannot both be
selected" and is much smaller. The point-degree rule is ours: the paper's model lets a
clutter point hang on the tape by a single edge (a pendant edge at a well-connected dot is even
cheap, its Omega being large); every dot of a tape has >= 4 tape edges (>= 3 with one neighbour
occluded), so requiring 3 removes such pendants. ``min_point_degree = 0`` restores the paper's
model. The bounds 6 and 12 are checked against the tape's solid graph
by :func:`neighbour_bounds` (min 6 at the end rows, max 12 in the middle).

Relaxation: when the program is infeasible (occluded dots, missed blobs) ``n`` is lowered by one
and re-solved, as the paper says; after ``max_step_relaxations`` unit steps the largest feasible
``n`` is found by one cardinality solve instead, so heavy occlusion does not cost dozens of
solves. Every relaxation is logged.

Time limit: a solve that reaches ``LPConfig.time_limit_s`` ends with the best selection found in
that time, not one proven optimal, and a solve that found none by then counts as infeasible (``n``
is lowered). Both depend on the machine's speed and load, so the frame says so
(``FeasibleSet.time_limited``, the quality flag ``lp_time_limited``).
"""

from __future__ import annotations

import contextlib
import logging

import numpy as np
import pyomo.environ as pyo
from pyomo.opt import TerminationCondition

from ..tape import TapeSpec, edge_neighbour_sets
from .config import LPConfig
from .types import CandidateCloud, EdgeCloud, FeasibleSet

log = logging.getLogger(__name__)
# HiGHS' own progress log is forwarded at INFO level; keep it out of the tracker's log.
logging.getLogger("pyomo.contrib.appsi.solvers.highs").setLevel(logging.WARNING)


def neighbour_bounds(tape: TapeSpec) -> tuple[int, int]:
    """(min, max) of |Omega_e| over the tape's solid edges: the Eq. 4-5 bounds (6, 12)."""
    counts = [len(n) for n in tape.graph.edge_neighbours()]
    return min(counts), max(counts)


class EdgeSelectionProgram:
    """The binary program for one frame's edge cloud; :meth:`solve` returns the feasible set."""

    def __init__(self, cloud: CandidateCloud, edge_cloud: EdgeCloud, tape: TapeSpec, config: LPConfig):
        self.cloud, self.edge_cloud, self.tape, self.config = cloud, edge_cloud, tape, config
        lo, hi = neighbour_bounds(tape)
        self.lo = config.min_neighbours if config.min_neighbours is not None else lo
        self.hi = config.max_neighbours if config.max_neighbours is not None else hi
        self.n_initial = tape.n_target_edges
        self.time_limited = False  # a solve stopped at the time limit (see module)
        self.model = self._build()
        self.solver = pyo.SolverFactory(config.solver)
        if not self.solver.available():
            raise RuntimeError(f"LP solver {config.solver!r} is not available (install highspy)")

    # ------------------------------------------------------------------ model
    def _build(self) -> pyo.ConcreteModel:
        edges = self.edge_cloud.edges
        E = len(edges)
        omega = edge_neighbour_sets(edges)
        self.omega = omega
        points = np.unique(edges.ravel()) if E else np.zeros(0, np.int64)
        m = pyo.ConcreteModel("edge_selection")
        m.E = pyo.RangeSet(0, E - 1) if E else pyo.Set(initialize=[])
        m.P = pyo.Set(initialize=points.tolist())
        m.x = pyo.Var(m.E, domain=pyo.Binary)
        m.y = pyo.Var(m.P, domain=pyo.Binary)
        m.n = pyo.Param(mutable=True, initialize=self.n_initial)
        cost = [1.0 / max(len(o), 1) for o in omega]
        m.cost = pyo.Objective(expr=sum(cost[e] * m.x[e] for e in range(E)), sense=pyo.minimize)
        m.count = pyo.Constraint(expr=sum(m.x[e] for e in range(E)) == m.n)
        lo, hi = self.lo, self.hi
        m.min_nb = pyo.Constraint(m.E, rule=lambda m, e: sum(m.x[f] for f in omega[e]) >= lo * m.x[e])
        big_m = [max(len(o) - hi, 0) for o in omega]
        m.max_nb = pyo.Constraint(
            m.E, rule=lambda m, e: pyo.Constraint.Skip if big_m[e] == 0
            else sum(m.x[f] for f in omega[e]) <= hi + big_m[e] * (1 - m.x[e])
        )
        m.use_i = pyo.Constraint(m.E, rule=lambda m, e: m.x[e] <= m.y[int(edges[e, 0])])
        m.use_j = pyo.Constraint(m.E, rule=lambda m, e: m.x[e] <= m.y[int(edges[e, 1])])
        k = self.config.min_point_degree
        if k > 0:
            incident: dict[int, list[int]] = {}
            for e, (i, j) in enumerate(edges.tolist()):
                incident.setdefault(i, []).append(e)
                incident.setdefault(j, []).append(e)
            m.degree = pyo.Constraint(m.P, rule=lambda m, p: sum(m.x[e] for e in incident[p]) >= k * m.y[p])
        if self.config.limit_points:
            m.points = pyo.Constraint(expr=sum(m.y[p] for p in m.P) <= self.tape.n_dots)
        cliques = self._blob_cliques(points)
        m.ghost = pyo.ConstraintList()
        for members in cliques:
            m.ghost.add(sum(m.y[int(p)] for p in members) <= 1)
        return m

    def _blob_cliques(self, points: np.ndarray) -> list[np.ndarray]:
        """Groups (>= 2) of edge-cloud points triangulated from the same blob of one camera."""
        ids = self.cloud.blob_ids[points] if len(points) else np.zeros((0, 1), np.int64)
        groups = []
        for c in range(ids.shape[1]):
            used = ids[:, c] >= 0
            blobs, inverse, counts = np.unique(ids[used, c], return_inverse=True, return_counts=True)
            owners = points[used]
            for b in np.nonzero(counts >= 2)[0]:
                groups.append(owners[inverse == b])
        return groups

    # ------------------------------------------------------------------ solving
    def _solve_at(self, n: int) -> bool:
        self.model.n.set_value(n)
        result = self.solver.solve(self.model, load_solutions=False, **self._time_limit_kwargs())
        term = result.solver.termination_condition
        timed_out = self._note_time_limit(term)
        if term == TerminationCondition.optimal or (timed_out and len(result.solution) > 0):
            self._load(result)
            self.termination = str(term)
            return True
        return False

    def _note_time_limit(self, term: TerminationCondition) -> bool:
        """Whether a solve ended at the time limit; remembered in :attr:`time_limited`."""
        timed_out = term == TerminationCondition.maxTimeLimit
        if timed_out:
            log.debug("LP stopped at its %.1f s time limit", self.config.time_limit_s)
        self.time_limited |= timed_out
        return timed_out

    def _load(self, result) -> None:
        """Load a solve's solution; a time-limited one is flagged on the frame instead of Pyomo's
        warning about loading an aborted solve."""
        with _quiet_pyomo_load():
            self.model.solutions.load_from(result)

    def _time_limit_kwargs(self) -> dict:
        return {"timelimit": self.config.time_limit_s,
                "options": {"mip_rel_gap": self.config.mip_rel_gap}}

    def _largest_feasible_n(self, upper: int) -> int:
        """One cardinality solve: the most edges selectable under the neighbour/ghost rules."""
        m = self.model
        m.cost.deactivate()
        m.count.deactivate()
        m.card_cap = pyo.Constraint(expr=sum(m.x[e] for e in m.E) <= upper)
        m.card = pyo.Objective(expr=sum(m.x[e] for e in m.E), sense=pyo.maximize)
        try:
            result = self.solver.solve(m, load_solutions=False, **self._time_limit_kwargs())
            self._note_time_limit(result.solver.termination_condition)
            if len(result.solution) == 0:
                return 0
            self._load(result)
            return int(round(sum(pyo.value(m.x[e]) for e in m.E)))
        finally:
            m.del_component(m.card)
            m.del_component(m.card_cap)
            m.cost.activate()
            m.count.activate()

    def solve(self) -> FeasibleSet | None:
        """Solve with n = Eq. 1, relaxing while infeasible. None when no tape-like set exists."""
        E = len(self.edge_cloud)
        n = min(self.n_initial, E)
        if n < self.n_initial:
            log.debug("LP: only %d candidate edges; target lowered from %d to %d", E, self.n_initial, n)
        steps = 0
        while n >= self.config.min_target:
            if self._solve_at(n):
                return self._feasible_set(n)
            steps += 1
            if steps <= self.config.max_step_relaxations:
                log.debug("LP infeasible with %d edges; relaxing to %d", n, n - 1)
                n -= 1
                continue
            best = self._largest_feasible_n(n - 1)
            log.debug("LP infeasible with %d edges; largest feasible selection has %d edges", n, best)
            if best < self.config.min_target or best >= n:
                break
            n = best
            steps = -10**9  # the cardinality bound is exact: no more unit steps needed
        log.debug("LP found no tape-like edge set (%d candidate edges)", E)
        return None

    def _feasible_set(self, n: int) -> FeasibleSet:
        x = np.array([pyo.value(self.model.x[e]) for e in range(len(self.edge_cloud))])
        chosen = self.edge_cloud.edges[x > 0.5]
        source, local = np.unique(chosen.ravel(), return_inverse=True)
        return FeasibleSet(
            points=self.cloud.points[source],
            normals=self.cloud.normals[source],
            edges=local.reshape(-1, 2),
            source_index=source,
            n_target=n,
            n_target_initial=self.n_initial,
            status="optimal" if n == self.n_initial else "relaxed",
            time_limited=self.time_limited,
        )


@contextlib.contextmanager
def _quiet_pyomo_load():
    """Pyomo's ``pyomo.core`` logger at ERROR for the duration (it warns on every time-limited load)."""
    logger = logging.getLogger("pyomo.core")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def select_edges(cloud: CandidateCloud, edge_cloud: EdgeCloud, tape: TapeSpec,
                 config: LPConfig | None = None) -> FeasibleSet | None:
    """Solve the edge-selection program of one frame (None: no tape found)."""
    config = config or LPConfig()
    if len(edge_cloud) < config.min_target:
        log.debug("LP skipped: %d candidate edges, fewer than %d", len(edge_cloud), config.min_target)
        return None
    return EdgeSelectionProgram(cloud, edge_cloud, tape, config).solve()
