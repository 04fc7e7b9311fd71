"""Particle belief propagation engine (spinemocap.track.pbp) on problems with known answers."""

import itertools

import numpy as np

from spinemocap.track.pbp import ParticleBP, PBPConfig, mrf_energy


class QuadraticChain:
    """1D chain: unary (x_s - a_s)^2, pairwise w (x_s - x_t - g)^2; a quadratic with a unique
    minimum found by solving the normal equations."""

    def __init__(self, anchors, gap, weight):
        self.anchors = np.asarray(anchors, float)
        n = len(anchors)
        self.edges = np.column_stack([np.arange(n - 1), np.arange(1, n)])
        self.gap, self.weight = gap, weight

    def unary(self, x):
        return (x[..., 0] - self.anchors[:, None]) ** 2

    def pairwise(self, xs, xt, edge_index):
        return self.weight * (xs[:, :, None, 0] - xt[:, None, :, 0] - self.gap) ** 2

    def prepare(self, state):
        pass

    def extra_proposals(self, state):
        return None

    def optimum(self):
        n = len(self.anchors)
        A = np.eye(n)
        b = self.anchors.copy()
        for s, t in self.edges:
            A[s, s] += self.weight
            A[t, t] += self.weight
            A[s, t] -= self.weight
            A[t, s] -= self.weight
            b[s] += self.weight * self.gap
            b[t] -= self.weight * self.gap
        return np.linalg.solve(A, b)


def test_pbp_lowers_energy_towards_the_chain_optimum():
    rng = np.random.default_rng(3)
    model = QuadraticChain(anchors=rng.normal(scale=5.0, size=10), gap=2.0, weight=1.5)
    init = np.zeros((10, 1))
    config = PBPConfig(n_particles=6, n_slice=6, iterations=25, sweeps=8, slice_width=(3.0,),
                       init_spread=(1.0,), temperature=0.5, mobility=False)
    result = ParticleBP(model, config, np.random.default_rng(0)).run(init)
    hist = np.array(result.energy_history)
    assert np.all(np.diff(hist) <= 1e-12), "the estimate's energy must never rise"
    np.testing.assert_allclose(result.baselines, hist[:-1])  # nothing state-dependent to refresh
    best = model.optimum()
    e_opt = mrf_energy(model, best[:, None])
    assert hist[0] - e_opt > 50  # the start is far from the optimum
    assert hist[-1] - e_opt < 0.05 * (hist[0] - e_opt)
    np.testing.assert_allclose(result.state[:, 0], best, atol=0.5)
    assert mrf_energy(model, result.state) == hist[-1]


class DiscreteToy:
    """A tree (star + chain) over 7 nodes whose states are restricted to 5 labels by handing all
    labels in as proposals: min-sum BP on a tree must return the brute-force optimum."""

    labels = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])

    def __init__(self, rng):
        self.edges = np.array([[0, 1], [0, 2], [0, 3], [3, 4], [4, 5], [5, 6]])
        self.table_u = rng.uniform(0, 3, size=(7, 5))
        self.table_p = rng.uniform(0, 3, size=(6, 5, 5))

    def _index(self, x):
        return np.rint(x[..., 0] + 2).astype(int)

    def unary(self, x):
        return np.take_along_axis(self.table_u, self._index(x), axis=1)

    def pairwise(self, xs, xt, edge_index):
        i, j = self._index(xs), self._index(xt)
        return self.table_p[edge_index[:, None, None], i[:, :, None], j[:, None, :]]

    def prepare(self, state):
        pass

    def extra_proposals(self, state):
        return np.broadcast_to(self.labels[None, :, None], (7, 5, 1)).copy()


def test_pbp_finds_the_exact_optimum_of_a_discrete_tree():
    for seed in range(3):
        model = DiscreteToy(np.random.default_rng(seed))
        every = np.array(list(itertools.product(range(5), repeat=7)))  # all 5^7 labellings
        energy = model.table_u[np.arange(7), every].sum(axis=1)
        for e, (s, t) in enumerate(model.edges):
            energy += model.table_p[e, every[:, s], every[:, t]]
        brute = every[np.argmin(energy)]
        assert np.sort(energy)[1] > energy.min()  # a unique optimum
        config = PBPConfig(n_particles=5, n_slice=0, iterations=2, sweeps=8, mobility=False,
                           slice_width=(1.0,), init_spread=(0.0,), damping=0.0)
        result = ParticleBP(model, config, np.random.default_rng(0)).run(np.full((7, 1), 2.0))
        np.testing.assert_array_equal(result.state[:, 0], DiscreteToy.labels[list(brute)])
        # min-sum BP is exact on a tree: each node's lowest-belief particle is its optimal label
        np.testing.assert_array_equal(result.particles[:, 0, 0], DiscreteToy.labels[list(brute)])
