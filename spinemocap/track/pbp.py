"""Max-product particle belief propagation (min-sum form) for pairwise MRFs with continuous states.

Used by both tracker MRFs (paper Sec. 3.2-3.3, after Pacheco et al. and Hachmann et al.). Each node
``s`` holds a set of particles (candidate states); one outer iteration

1. proposes new particles per node by slice sampling its current belief (Mueller et al.), starting
   from the node's best particles;
2. augments the set (paper Eq. 9): ``P_aug = P_kept U P_slice U P_mobility U P_extra``, where
   ``P_mobility`` copies the neighbours' current positions and ``P_extra`` is model-supplied
   (MRF1: the k nearest feasible points);
3. evaluates all unary costs ``(D, Pa)`` and pairwise costs ``(E, Pa, Pa)`` in one batch and runs a
   few flooding sweeps of min-sum messages on the augmented sets;
4. picks a joint labelling on the augmented sets: the belief minimisers, improved by
   iterated conditional modes (ICM: each node in turn takes its best particle given its
   neighbours; nodes of one graph colour at once); the same ICM from the current estimate is the
   fallback, so a step never raises the energy (loopy-BP belief minimisers alone are often
   mutually inconsistent on the tape's triangle-rich graph);
5. keeps the ``P`` lowest-belief distinct particles per node for the next iteration.

Everything is vectorised over nodes, edges and particles; Python loops run over iterations,
sweeps, state dimensions and slice-shrink steps only. Energies are costs (lower is better); the
slice sampler targets ``exp(-belief / temperature)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


class PairwiseModel(Protocol):
    """What the engine needs from an MRF. States are rows of ``S`` floats.

    ``edges``: (E, 2) node indices. ``unary(x)``: x (D, Q, S) -> (D, Q) costs.
    ``pairwise(xs, xt, edge_index)``: xs (M, Qs, S) states of the edges' first nodes, xt (M, Qt, S)
    of their second nodes, for the M edges ``edge_index`` -> (M, Qs, Qt) costs.
    ``prepare(state)``: refresh state-dependent parameters (normals, directions) from the current
    estimate (D, S) before an iteration. ``extra_proposals(state)``: (D, K, S) or None.
    Optional ``unary_rows(nodes, x)``: nodes (K,), x (K, S) -> (K,), the unary cost of node
    ``nodes[k]`` at ``x[k]`` (the same values as ``unary``); with it the slice sampler evaluates
    beliefs only for its chains still open, and repeated particles share their pairwise costs.
    Optional ``symmetric_pairwise = True``: ``pairwise(xs, xt, i)`` is ``pairwise(xt, xs, i)``
    transposed, bit for bit (beliefs then evaluate both message directions in one call).
    Optional ``prepared_parameters()``: the objects ``prepare`` sets; when ``prepare`` sets none
    again, the first iteration's slice sampler reads its start beliefs from the costs already
    evaluated for the kept particles."""

    edges: np.ndarray

    def unary(self, x: np.ndarray) -> np.ndarray: ...

    def pairwise(self, xs: np.ndarray, xt: np.ndarray, edge_index: np.ndarray) -> np.ndarray: ...

    def prepare(self, state: np.ndarray) -> None: ...

    def extra_proposals(self, state: np.ndarray) -> np.ndarray | None: ...


@runtime_checkable
class RowUnaryModel(Protocol):
    """A :class:`PairwiseModel` with the optional ``unary_rows``."""

    def unary_rows(self, nodes: np.ndarray, x: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class PreparedParametersModel(Protocol):
    """A :class:`PairwiseModel` with the optional ``prepared_parameters``."""

    def prepared_parameters(self) -> tuple: ...


@dataclass
class PBPConfig:
    """Engine settings. ``slice_width`` (S,) is the slice sampler's initial bracket per state
    dimension (state units, e.g. mm); ``width_decay`` shrinks it each iteration (1 = constant);
    ``mobility_dims`` are the state dimensions copied from neighbours for ``P_mobility`` (the others
    keep the node's own value); ``init_spread`` (S,) is the std of the initial particle cloud."""

    n_particles: int = 8
    n_slice: int = 8
    iterations: int = 15
    sweeps: int = 6
    damping: float = 0.3
    slice_width: tuple[float, ...] = (4.0, 4.0, 4.0)
    slice_steps: int = 5
    width_decay: float = 1.0
    temperature: float = 1.0
    mobility: bool = True
    mobility_dims: tuple[int, ...] = (0, 1, 2)
    init_spread: tuple[float, ...] = (2.0, 2.0, 2.0)


def pbp_config(settings, slice_width: tuple[float, ...], init_spread: tuple[float, ...]) -> PBPConfig:
    """Engine settings from an MRF's config (MRF1Config / MRF2Config: ``particles``,
    ``slice_particles``, ``iterations``, ``sweeps``, ``slice_steps``, ``damping``, ``width_decay``,
    ``temperature``, ``mobility``); the MRFs differ only in their state's brackets and spreads."""
    return PBPConfig(
        n_particles=settings.particles, n_slice=settings.slice_particles, iterations=settings.iterations,
        sweeps=settings.sweeps, slice_steps=settings.slice_steps, damping=settings.damping,
        slice_width=slice_width, width_decay=settings.width_decay, temperature=settings.temperature,
        mobility=settings.mobility, mobility_dims=(0, 1, 2), init_spread=init_spread,
    )


@dataclass
class PBPResult:
    """``state`` (D, S) the final estimate; ``energy_history`` its energy after each iteration
    (index 0: the initial state); ``baselines[i]``: the energy before step i under that
    iteration's prepared parameters (``energy_history[i + 1] <= baselines[i]`` always; the two
    differ from ``energy_history[i]`` only when ``prepare`` moved state-dependent parameters);
    ``particles`` (D, P, S) and ``beliefs`` (D, P) at the end."""

    state: np.ndarray
    energy_history: list[float]
    particles: np.ndarray
    beliefs: np.ndarray
    accepted: list[bool] = field(default_factory=list)
    baselines: list[float] = field(default_factory=list)


def mrf_energy(model: PairwiseModel, state: np.ndarray) -> float:
    """Eq. 6: sum of unary costs plus the pairwise cost of every edge, at one state (D, S)."""
    edges = model.edges
    unary = model.unary(state[:, None, :]).sum()
    if len(edges) == 0:
        return float(unary)
    pair = model.pairwise(state[edges[:, 0], None, :], state[edges[:, 1], None, :], np.arange(len(edges)))
    return float(unary + pair.sum())


class _Graph:
    """Directed-edge bookkeeping: message i runs src[i] -> dst[i]; rev[i] is its opposite."""

    def __init__(self, edges: np.ndarray, n_nodes: int):
        e = len(edges)
        self.n_edges = e
        self.src = np.concatenate([edges[:, 0], edges[:, 1]])
        self.dst = np.concatenate([edges[:, 1], edges[:, 0]])
        self.rev = np.concatenate([np.arange(e, 2 * e), np.arange(e)])
        self.incidence = np.zeros((n_nodes, 2 * e))  # sums incoming messages per node
        self.incidence[self.dst, np.arange(2 * e)] = 1.0
        self.colours = _greedy_colouring(edges, n_nodes)
        degree = np.bincount(self.dst, minlength=n_nodes)
        self.max_degree = int(degree.max()) if n_nodes else 0
        # neighbour table (D, max_degree), padded with the node itself
        self.neighbours = np.tile(np.arange(n_nodes)[:, None], (1, max(self.max_degree, 1)))
        slot = np.zeros(n_nodes, dtype=int)
        for s, t in zip(self.src, self.dst):
            self.neighbours[t, slot[t]] = s
            slot[t] += 1


def _greedy_colouring(edges: np.ndarray, n_nodes: int) -> list[np.ndarray]:
    """Node groups with no edge inside a group (greedy, highest degree first)."""
    adjacency: list[set[int]] = [set() for _ in range(n_nodes)]
    for a, b in edges:
        adjacency[a].add(int(b))
        adjacency[b].add(int(a))
    colour = np.full(n_nodes, -1)
    for node in sorted(range(n_nodes), key=lambda i: -len(adjacency[i])):
        used = {colour[j] for j in adjacency[node]}
        colour[node] = next(c for c in range(n_nodes + 1) if c not in used)
    return [np.flatnonzero(colour == c) for c in range(colour.max() + 1)] if n_nodes else []


def _labelling_energy(graph: _Graph, unary: np.ndarray, cost_dir: np.ndarray, labels: np.ndarray) -> float:
    """Energy of choosing particle labels[s] at every node, from the precomputed tables."""
    e = graph.n_edges
    pair = cost_dir[np.arange(e), labels[graph.src[:e]], labels[graph.dst[:e]]].sum()
    return float(unary[np.arange(len(labels)), labels].sum() + pair)


def _icm(graph: _Graph, unary: np.ndarray, cost_dir: np.ndarray, labels: np.ndarray, max_sweeps: int = 10) -> np.ndarray:
    """Iterated conditional modes over colour classes; never raises the labelling's energy."""
    labels = labels.copy()
    for _ in range(max_sweeps):
        changed = False
        for group in graph.colours:
            # cost of each particle of each node given its neighbours' current labels
            local = np.zeros_like(unary)
            local += unary
            local += graph.incidence @ cost_dir[np.arange(len(graph.src)), labels[graph.src], :]
            best = local[group].argmin(axis=1)
            keep = local[group, best] < local[group, labels[group]] - 1e-12
            if keep.any():
                labels[group[keep]] = best[keep]
                changed = True
        if not changed:
            break
    return labels


def _min_sum_sweeps(graph: _Graph, unary: np.ndarray, cost_dir: np.ndarray, sweeps: int, damping: float):
    """Flooding min-sum on fixed particle sets. unary (D, Pa); cost_dir (2E, Pa, Pa) indexed
    [message, source particle, target particle]. Returns beliefs (D, Pa) and the messages'
    'pre' terms (2E, Pa) = belief of the source minus the opposite message."""
    msgs = np.zeros((2 * graph.n_edges, unary.shape[1]))
    for _ in range(sweeps):
        belief = unary + graph.incidence @ msgs
        pre = belief[graph.src] - msgs[graph.rev]
        new = (pre[:, :, None] + cost_dir).min(axis=1)
        new -= new.min(axis=1, keepdims=True)
        msgs = damping * msgs + (1.0 - damping) * new
    belief = unary + graph.incidence @ msgs
    pre = belief[graph.src] - msgs[graph.rev]
    return belief, pre


class _KnownCosts:
    """Pairwise costs the slice sampler evaluated, for the augmented set's cost table: between the
    ``n_kept`` kept particles (augmented indices 0 ..) and each chain's accepted sample (augmented
    index ``offset`` + chain), per edge, in both directions (E edges, Q chains)."""

    def __init__(self, n_edges: int, n_kept: int, n_chains: int, offset: int):
        self.offset, self.n_kept, self.n_chains = offset, n_kept, n_chains
        self.forward = np.zeros((n_edges, n_kept, n_chains))  # [m, kept of e0, sample of e1]
        self.backward = np.zeros((n_edges, n_chains, n_kept))  # [m, sample of e0, kept of e1]
        self.has_forward = np.zeros((n_edges, n_chains), bool)
        self.has_backward = np.zeros((n_edges, n_chains), bool)
        self.kept = np.zeros((n_edges, n_kept, n_kept))  # [m, kept of e0, kept of e1]
        self.has_kept = np.zeros((n_edges, n_kept), bool)  # [m, kept of e1]

    def any(self) -> bool:
        return bool(self.has_forward.any() or self.has_backward.any() or self.has_kept.any())

    def add_kept(self, e1: np.ndarray, order: np.ndarray, m1, q1, to_second) -> None:
        """Keep the costs of the beliefs at the chains' starts, the kept particles ``order`` (D, Q)
        (rows (m1, q1): every kept particle of e0 vs the start of chain q1 of e1, a kept particle)."""
        j = order[e1[m1], q1]
        self.kept[m1, :, j] = to_second
        self.has_kept[m1, j] = True

    def add(self, e0: np.ndarray, e1: np.ndarray, accepted: np.ndarray, m1, q1, to_second, m2, q2, to_first) -> None:
        """Keep the costs of one shrink step's beliefs (``_belief_at_wanted``'s message costs, rows
        (m1, q1): kept of e0 vs the point of chain q1 of e1; (m2, q2): the point of e0 vs kept of
        e1) at the chains ``accepted`` (D, Q) in that step."""
        a = np.flatnonzero(accepted[e1[m1], q1])
        self.forward[m1[a], :, q1[a]] = to_second[a]
        self.has_forward[m1[a], q1[a]] = True
        b = np.flatnonzero(accepted[e0[m2], q2])
        self.backward[m2[b], q2[b], :] = to_first[b]
        self.has_backward[m2[b], q2[b]] = True

    def take(self, m: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For table entries (m, i, j) (augmented indices): (known mask, values there, else 0)."""
        values = np.zeros(len(m))
        taken = np.zeros(len(m), bool)
        lo, hi = self.offset, self.offset + self.n_chains
        f = np.flatnonzero((i < self.n_kept) & (j >= lo) & (j < hi))
        f = f[self.has_forward[m[f], j[f] - lo]]
        values[f] = self.forward[m[f], i[f], j[f] - lo]
        taken[f] = True
        b = np.flatnonzero((i >= lo) & (i < hi) & (j < self.n_kept))
        b = b[self.has_backward[m[b], i[b] - lo]]
        values[b] = self.backward[m[b], i[b] - lo, j[b]]
        taken[b] = True
        k = np.flatnonzero((i < self.n_kept) & (j < self.n_kept))
        k = k[self.has_kept[m[k], j[k]]]
        values[k] = self.kept[m[k], i[k], j[k]]
        taken[k] = True
        return taken, values


class ParticleBP:
    """Min-sum particle BP on ``model`` starting from ``init`` (D, S). See the module docstring."""

    def __init__(self, model: PairwiseModel, config: PBPConfig, rng: np.random.Generator | None = None):
        self.model = model
        self.config = config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.edges = np.asarray(model.edges, dtype=np.int64).reshape(-1, 2)

    # ------------------------------------------------------------------ batch costs
    def _directed_costs(self, particles: np.ndarray, known: _KnownCosts | None = None) -> np.ndarray:
        """(2E, Pa, Pa) pairwise costs for messages in both directions. With a model that has
        ``unary_rows`` (its costs element by element), a node's repeated particles (the state
        among the kept ones, proposals that did not move) are evaluated once, and the pairs the
        slice sampler evaluated (``known``) are taken from it: the same table."""
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        if hasattr(self.model, "unary_rows") and len(self.edges):
            cost = self._pairwise_distinct(particles, known)
        else:
            cost = self.model.pairwise(particles[e0], particles[e1], np.arange(len(self.edges)))
        return np.concatenate([cost, cost.transpose(0, 2, 1)], axis=0)

    def _pairwise_distinct(self, particles: np.ndarray, known: _KnownCosts | None = None) -> np.ndarray:
        """``model.pairwise(particles[e0], particles[e1], all edges)`` (E, Pa, Pa), each pair of
        distinct particle values evaluated once (pairs of a row of M = 1) and copied to its repeats;
        pairs in ``known`` (the slice sampler's, evaluated element by element as well) not again."""
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        n = particles.shape[1]
        bits = np.ascontiguousarray(particles, dtype=np.float64).view(np.int64)  # the same bits: NaN, -0.0 too
        same = (bits[:, :, None, :] == bits[:, None, :, :]).all(axis=3)
        first = same.argmax(axis=2)  # (D, Pa): the first particle with the same value
        if (known is None or not known.any()) and (first == np.arange(n)).mean() > 0.95:
            return self.model.pairwise(particles[e0], particles[e1], np.arange(len(self.edges)))
        single = first == np.arange(n)
        m, i, j = np.nonzero(single[e0][:, :, None] & single[e1][:, None, :])
        have = known.take(m, i, j) if known is not None else None
        if have is None:
            values = self.model.pairwise(particles[e0[m], i][:, None, :], particles[e1[m], j][:, None, :], m)[:, 0, 0]
        else:
            taken, values = have
            todo = np.flatnonzero(~taken)
            mt, it, jt = m[todo], i[todo], j[todo]
            values[todo] = self.model.pairwise(particles[e0[mt], it][:, None, :], particles[e1[mt], jt][:, None, :],
                                               mt)[:, 0, 0]
        slot = np.zeros((len(e0), n, n), dtype=np.int64)
        slot[m, i, j] = np.arange(len(m))
        return values[slot[np.arange(len(e0))[:, None, None], first[e0][:, :, None], first[e1][:, None, :]]]

    def _belief_at(self, points: np.ndarray, kept: np.ndarray, pre: np.ndarray, graph: _Graph,
                   wanted: np.ndarray | None = None, record: list | None = None) -> np.ndarray:
        """Belief of every node at new points (D, Q, S): unary plus, for each neighbour, the min
        over its kept particles (D, P, S) of pre + pairwise. ``pre`` (2E, P) as from the sweeps.
        ``wanted`` (D, Q) bool: only those entries are needed (the others are returned as
        anything); with a model that has ``unary_rows`` only they are evaluated."""
        if hasattr(self.model, "unary_rows"):
            return self._belief_at_wanted(points, kept, pre, graph,
                                          np.ones(points.shape[:2], bool) if wanted is None else wanted, record)
        belief = self.model.unary(points)
        if graph.n_edges == 0:
            return belief
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        e = graph.n_edges
        all_edges = np.arange(e)
        # messages e0 -> e1 evaluated at new states of e1
        to_second = (pre[:e, :, None] + self.model.pairwise(kept[e0], points[e1], all_edges)).min(axis=1)
        # messages e1 -> e0 evaluated at new states of e0
        to_first = (pre[e:, None, :] + self.model.pairwise(points[e0], kept[e1], all_edges)).min(axis=2)
        return belief + graph.incidence @ np.concatenate([to_second, to_first], axis=0)

    def _belief_at_wanted(self, points: np.ndarray, kept: np.ndarray, pre: np.ndarray, graph: _Graph,
                          wanted: np.ndarray, record: list | None = None) -> np.ndarray:
        """:meth:`_belief_at` at the ``wanted`` (D, Q) entries only (0 elsewhere), the same values:
        a node's belief at a point depends on that point alone (its neighbours' particles are the
        kept ones), the costs are computed element by element, and the messages into each node
        are summed by the same matrix product of the same shape (unwanted entries 0)."""
        model, e = self.model, graph.n_edges
        if not isinstance(model, RowUnaryModel):
            raise TypeError("beliefs at the wanted entries need the model's unary_rows")
        nodes, chains = np.nonzero(wanted)
        belief = np.zeros(wanted.shape)
        belief[nodes, chains] = model.unary_rows(nodes, points[nodes, chains])
        if e == 0:
            return belief
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        msgs = np.zeros((2 * e, wanted.shape[1]))
        m1, q1 = np.nonzero(wanted[e1])  # messages e0 -> e1 at the wanted new states of e1
        m2, q2 = np.nonzero(wanted[e0])  # messages e1 -> e0 at the wanted new states of e0
        if getattr(model, "symmetric_pairwise", False):
            # pairwise(a, b) is pairwise(b, a) transposed: both directions in one evaluation
            cost = model.pairwise(np.concatenate([kept[e0[m1]], kept[e1[m2]]]),
                                  np.concatenate([points[e1[m1], q1], points[e0[m2], q2]])[:, None, :],
                                  np.concatenate([m1, m2]))[:, :, 0]
            to_second, to_first = cost[: len(m1)], cost[len(m1):]
        else:
            to_second = model.pairwise(kept[e0[m1]], points[e1[m1], q1][:, None, :], m1)[:, :, 0]  # (K, P)
            to_first = model.pairwise(points[e0[m2], q2][:, None, :], kept[e1[m2]], m2)[:, 0, :]
        msgs[m1, q1] = (pre[m1] + to_second).min(axis=1)
        msgs[e + m2, q2] = (pre[e + m2] + to_first).min(axis=1)
        if record is not None:  # the costs (kept of e0, point of e1) and (point of e0, kept of e1)
            record.append((m1, q1, to_second, m2, q2, to_first))
        return belief + graph.incidence @ msgs

    def _belief_at_kept(self, order: np.ndarray, unary_kept: np.ndarray, table: np.ndarray, pre: np.ndarray,
                        graph: _Graph) -> np.ndarray:
        """:meth:`_belief_at_wanted` at the kept particles ``order`` (D, Q) (every entry wanted), from
        the kept particles' unary costs (D, P) and pair costs ``table`` (E, P, P) evaluated under the
        same parameters: the same entries in the same sums (the reverse messages' costs read
        transposed, as the model's pairwise is symmetric bit for bit)."""
        e = graph.n_edges
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        wanted = np.ones(order.shape, bool)
        nodes, chains = np.nonzero(wanted)
        belief = np.zeros(wanted.shape)
        belief[nodes, chains] = unary_kept[nodes, order[nodes, chains]]
        msgs = np.zeros((2 * e, order.shape[1]))
        m1, q1 = np.nonzero(wanted[e1])
        m2, q2 = np.nonzero(wanted[e0])
        to_second = table[m1, :, order[e1[m1], q1]]  # (K, P): kept of e0 vs the start of e1
        to_first = table[m2, order[e0[m2], q2], :]  # (K, P): the start of e0 vs kept of e1
        msgs[m1, q1] = (pre[m1] + to_second).min(axis=1)
        msgs[e + m2, q2] = (pre[e + m2] + to_first).min(axis=1)
        return belief + graph.incidence @ msgs

    def _slice_sample(self, start: np.ndarray, kept: np.ndarray, pre: np.ndarray, graph: _Graph,
                      width: np.ndarray, order: np.ndarray | None = None,
                      at_kept: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, _KnownCosts | None]:
        """One hyper-rectangle slice-sampling step (Neal 2003, Sec. 5.1: a randomly placed box of
        side ``width`` around the start, shrunk toward it after each rejection) for all nodes and
        chains at once; one belief evaluation per shrink step. start (D, Q, S) -> samples, and
        (with a model that has ``unary_rows``) the pairwise costs between the kept particles and
        the accepted samples that the beliefs evaluated (None without); with ``order`` (D, Q), the
        kept particles the chains start from (``start`` = those of ``kept``), between the kept
        particles as well. ``at_kept``: the kept particles' unary costs (D, P) and pair costs
        (E, P, P) under the current parameters, when known (the start beliefs are read from them;
        needs ``order`` and a symmetric pairwise)."""
        cfg, rng = self.config, self.rng
        x = start
        rows = hasattr(self.model, "unary_rows") and graph.n_edges > 0
        known = _KnownCosts(len(self.edges), kept.shape[1], x.shape[1], kept.shape[1] + 1) if rows else None
        e0, e1 = self.edges[:, 0], self.edges[:, 1]
        record: list = []
        if known is not None and order is not None and at_kept is not None \
                and getattr(self.model, "symmetric_pairwise", False):
            b = self._belief_at_kept(order, at_kept[0], at_kept[1], pre, graph)
            known.kept[:] = at_kept[1]
            known.has_kept[:] = True
        else:
            b = self._belief_at(x, kept, pre, graph, None, record if known is not None and order is not None else None)
            if known is not None and order is not None and record:
                known.add_kept(e1, order, *record[0][:3])
        level = b + cfg.temperature * rng.exponential(size=b.shape)
        lo = x - width * rng.random(x.shape)
        hi = lo + width
        done = np.zeros(b.shape, dtype=bool)
        new_x = x.copy()
        for _ in range(cfg.slice_steps):
            cand = lo + (hi - lo) * rng.random(x.shape)
            # chains already done need no belief (their candidates are not taken)
            record = []
            ok = (self._belief_at(cand, kept, pre, graph, ~done, record if rows else None) < level) & ~done
            if known is not None and record:
                known.add(e0, e1, ok, *record[0])
            new_x[ok] = cand[ok]
            done |= ok
            if done.all():
                break
            left = cand < x
            open_ = ~done[..., None]
            lo = np.where(open_ & left, cand, lo)
            hi = np.where(open_ & ~left, cand, hi)
        return new_x, known

    # ------------------------------------------------------------------ proposals
    def _mobility(self, state: np.ndarray, graph: _Graph) -> np.ndarray:
        """(D, max_degree, S): the node's state with ``mobility_dims`` taken from each neighbour."""
        prop = np.repeat(state[:, None, :], graph.neighbours.shape[1], axis=1)
        dims = list(self.config.mobility_dims)
        prop[:, :, dims] = state[graph.neighbours][:, :, dims]
        return prop

    @staticmethod
    def _distinct_best(beliefs: np.ndarray, particles: np.ndarray, n: int) -> np.ndarray:
        """(D, n) indices of the n lowest-belief particles per node, duplicates pushed last."""
        a, b = particles[:, :, None, :], particles[:, None, :, :]
        # np.isclose(a, b, rtol=0, atol=1e-9) without its overhead: |a - b| <= atol, or equal infinities
        with np.errstate(invalid="ignore"):
            close = np.abs(a - b) <= 1e-9
        if not np.isfinite(particles).all():
            close |= (a == b) & np.isinf(a)
        same = np.all(close, axis=3)
        earlier = np.tril(np.ones(same.shape[1:], dtype=bool), k=-1)
        duplicate = np.any(same & earlier[None], axis=2)
        ranked = np.where(duplicate, np.inf, beliefs)
        return np.argsort(ranked, axis=1, kind="stable")[:, :n]

    # ------------------------------------------------------------------ main loop
    def run(self, init: np.ndarray, iterations: int | None = None) -> PBPResult:
        cfg, rng, model = self.config, self.rng, self.model
        state = np.asarray(init, dtype=float).copy()
        n_nodes, dim = state.shape
        graph = _Graph(self.edges, n_nodes)
        width = np.broadcast_to(np.asarray(cfg.slice_width, dtype=float), (dim,)).copy()
        spread = np.broadcast_to(np.asarray(cfg.init_spread, dtype=float), (dim,))

        model.prepare(state)
        energy = mrf_energy(model, state)
        history, accepted, baselines = [energy], [], []
        kept = state[:, None, :] + rng.normal(size=(n_nodes, cfg.n_particles, dim)) * spread
        kept[:, 0] = state
        cost = self._directed_costs(kept)
        unary_kept = model.unary(kept)
        beliefs, pre = _min_sum_sweeps(graph, unary_kept, cost, cfg.sweeps, cfg.damping)
        # the first iteration's kept particles and parameters are these (prepare is then skipped)
        # (with a model that tells its prepared parameters, to see that they were not set again)
        reports = model if isinstance(model, PreparedParametersModel) else None
        prepared = reports.prepared_parameters() if reports is not None else ()
        at_kept: tuple[np.ndarray, np.ndarray] | None = (unary_kept, cost[: len(self.edges)]) if reports is not None else None

        for _ in range(cfg.iterations if iterations is None else iterations):
            model.prepare(state)
            if at_kept is not None and reports is not None and any(
                    a is not b for a, b in zip(prepared, reports.prepared_parameters())):
                at_kept = None  # the parameters were set again: the costs no longer hold
            order = np.argsort(beliefs, axis=1)[:, : min(cfg.n_slice, kept.shape[1])]
            start = np.take_along_axis(kept, order[:, :, None], axis=1)
            groups = [kept, state[:, None, :]]
            known = None
            if cfg.n_slice > 0:
                samples, known = self._slice_sample(start, kept, pre, graph, width, order, at_kept)
                groups.append(samples)  # at kept.shape[1] + 1, as the known costs expect
            at_kept = None  # the next iteration's kept particles are others
            if cfg.mobility and graph.n_edges:
                groups.append(self._mobility(state, graph))
            extra = model.extra_proposals(state)
            if extra is not None and extra.size:
                groups.append(extra)
            aug = np.concatenate(groups, axis=1)

            cost = self._directed_costs(aug, known)
            unary = model.unary(aug)
            beliefs_aug, pre_aug = _min_sum_sweeps(graph, unary, cost, cfg.sweeps, cfg.damping)
            candidates = [
                _icm(graph, unary, cost, beliefs_aug.argmin(axis=1)),
                _icm(graph, unary, cost, np.full(n_nodes, kept.shape[1])),  # from the current state
            ]
            scores = [_labelling_energy(graph, unary, cost, lab) for lab in candidates]
            labels = candidates[int(np.argmin(scores))]
            new_energy = min(scores)
            # the current state's energy under this iteration's prepared parameters (normals,
            # visibility may have moved with the state): the step is judged against it
            energy = _labelling_energy(graph, unary, cost, np.full(n_nodes, kept.shape[1]))
            baselines.append(energy)
            took = new_energy < energy - 1e-9 * max(1.0, abs(energy))
            if took:
                state, energy = aug[np.arange(n_nodes), labels], new_energy
            history.append(energy)
            accepted.append(bool(took))

            keep = self._distinct_best(beliefs_aug, aug, cfg.n_particles)
            kept = np.take_along_axis(aug, keep[:, :, None], axis=1)
            beliefs = np.take_along_axis(beliefs_aug, keep, axis=1)
            pre = np.take_along_axis(pre_aug, keep[graph.src], axis=1)
            width *= cfg.width_decay

        return PBPResult(state=state, energy_history=history, particles=kept, beliefs=beliefs,
                         accepted=accepted, baselines=baselines)


def minimise(model: PairwiseModel, init: np.ndarray, config: PBPConfig, rng: np.random.Generator | None = None) -> PBPResult:
    """Run particle BP on ``model`` from ``init`` (D, S); see :class:`ParticleBP`."""
    return ParticleBP(model, config, rng).run(init)
