"""The tracker's per-frame 3D stages' fast paths compute what the straightforward
code computed: each fast path against the loop or library call it replaced (kept here as the
reference), bit for bit where only the bookkeeping changed, to rounding where the arithmetic did."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spinemocap.camera import Camera, Rig
from spinemocap.tape import TapeSpec
from spinemocap.track import continuity, lattice, stretch, template
from spinemocap.track.config import MRF1Config, MRF2Config
from spinemocap.track.evidence import EvidenceImage
from spinemocap.track.mrf1 import AlignmentMRF
from spinemocap.track.mrf2 import RefinementMRF
from spinemocap.track.normals import NormalField
from spinemocap.track.pbp import ParticleBP

GRAPH = TapeSpec(n_rows=13).graph


def _flat_tape_in_space(rng, graph=GRAPH):
    """The flat tape (u, v, 0) turned, scaled and moved somewhere in a 2 m room, with noise."""
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    flat = np.column_stack([graph.uv_mm, np.zeros(graph.n_dots)])
    return flat @ q.T * rng.uniform(0.9, 1.3) + rng.normal(0, 1.5, (graph.n_dots, 3)) + rng.uniform(-2000, 2000, 3)


def _affine_reference(uv, positions, known, targets, sigma_mm=30.0):
    """affine_from_neighbours as first written: one np.linalg.lstsq per target."""
    out = np.full((len(targets), 3), np.nan)
    for k, i in enumerate(targets):
        use = known.copy()
        use[i] = False
        if use.sum() < 3:
            continue
        design = np.column_stack([uv[use], np.ones(use.sum())])
        w = np.exp(-0.5 * ((uv[use] - uv[i]) ** 2).sum(axis=1) / sigma_mm**2)
        if (w > 1e-3).sum() < 3:
            w = np.ones_like(w)
        sw = np.sqrt(w)[:, None]
        A, *_ = np.linalg.lstsq(design * sw, positions[use] * sw, rcond=None)
        out[k] = np.append(uv[i], 1.0) @ A
    return out


def test_affine_from_neighbours_is_the_per_target_least_squares_fit():
    rng = np.random.default_rng(0)
    uv, rows = GRAPH.uv_mm, GRAPH.row
    for trial in range(120):
        positions = _flat_tape_in_space(rng)
        known = rng.random(GRAPH.n_dots) < rng.uniform(0.05, 1.0)
        if trial % 6 == 0:  # one row only: its dots lie on a line of the flat tape (rank-deficient fit)
            known = rows == rows[rng.integers(GRAPH.n_dots)]
        if trial % 9 == 0:  # far from every known dot: the global fit
            known = rows <= 1
        targets = np.arange(GRAPH.n_dots)
        fast = lattice.affine_from_neighbours(uv, positions, known, targets)
        slow = _affine_reference(uv, positions, known, targets)
        np.testing.assert_array_equal(np.isnan(fast), np.isnan(slow))
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-7)  # mm, at ~2 m from the origin
    assert np.isnan(lattice.affine_from_neighbours(uv, positions, rows < 0, targets)).all()  # nothing known


def _row_loops(positions, excluded, graph):
    """tape_frames' row centres/across vectors, row_centres, row_stretch's centres and
    beyond_known_rows, as the per-row loops computed them."""
    n_rows = int(graph.row.max()) + 1
    column = np.array(graph.column)
    centre = np.stack([positions[graph.row == r].mean(axis=0) for r in range(n_rows)])
    across = np.stack([positions[(graph.row == r) & (column == "R")][0] - positions[(graph.row == r) & (column == "L")][0]
                       for r in range(n_rows)])
    finite_centre = np.full((n_rows, 3), np.nan)
    stretch_centre = np.full((n_rows, 3), np.nan)
    for r in range(n_rows):
        members = positions[graph.row == r]
        stretch_centre[r] = members[1] if len(members) == 3 else members.mean(axis=0)
        members = members[np.isfinite(members).all(axis=1)]
        if len(members):
            finite_centre[r] = members.mean(axis=0)
    known = np.isfinite(positions).all(axis=1) & ~excluded
    beyond = np.zeros(len(positions), bool)
    for d in range(len(positions)):
        others = known.copy()
        others[d] = False
        r = graph.row[others]
        beyond[d] = not ((r <= graph.row[d]).any() and (r >= graph.row[d]).any())
    return centre, across, finite_centre, stretch_centre, beyond


def test_row_index_gives_the_per_row_loops_bit_for_bit():
    rng = np.random.default_rng(1)
    for graph in (GRAPH, TapeSpec(n_rows=5).graph):
        rows = graph.row_index
        assert graph.row_index is rows  # built once per graph
        for trial in range(60):
            positions = _flat_tape_in_space(rng, graph)
            if trial % 3 == 0:
                positions[rng.random(graph.n_dots) < 0.3] = np.nan
            excluded = rng.random(graph.n_dots) < 0.3
            centre, across, finite_centre, stretch_centre, beyond = _row_loops(positions, excluded, graph)
            np.testing.assert_array_equal(rows.sums(positions) / rows.count[:, None], centre)
            np.testing.assert_array_equal(positions[rows.right] - positions[rows.left], across)
            np.testing.assert_array_equal(continuity.row_centres(positions, graph), finite_centre)
            np.testing.assert_array_equal(lattice.beyond_known_rows(excluded, positions, graph), beyond)
            # row_stretch's along values come from its row centres: the same centres, the same values
            pitch = np.linalg.norm(np.diff(stretch_centre, axis=0), axis=1) / graph.spec.row_pitch_mm
            along = stretch.row_stretch(positions, graph)[0]
            for r in range(1, int(graph.row.max())):
                sides = pitch[[r - 1, r]]
                if np.isfinite(sides).all():
                    assert along[graph.row == r][0] == sides.sum() / 2
            if not np.isnan(positions).any():
                normal, across_unit, _ = template.tape_frames(positions, graph)
                assert np.allclose(np.linalg.norm(normal, axis=1), 1.0) and np.allclose((normal * across_unit).sum(axis=1), 0.0)


def test_row_gaps_takes_each_rows_median_as_numpy_does():
    rng = np.random.default_rng(2)
    found = 0
    for _ in range(400):
        arc = np.repeat(np.cumsum(rng.uniform(22, 30, rng.integers(3, 14))), rng.integers(1, 4))
        arc = rng.permutation(arc + rng.normal(0, 1.0, len(arc)))
        got = stretch.row_gaps(arc, 20.0)
        order = np.sort(arc)
        groups = [g for g in np.split(order, np.flatnonzero(np.diff(order) > 8.0) + 1) if len(g) >= 2]
        if len(groups) < 4:
            assert got is None
            continue
        centres = np.array([float(np.median(g)) for g in groups])
        gaps = np.diff(centres)
        spans = np.round(gaps / np.median(gaps)).astype(np.int64)
        if (gaps < 0.6 * np.median(gaps)).any() or (spans > 2).any() or (spans < 1).any():
            assert got is None
            continue
        found += 1
        np.testing.assert_array_equal(got[0], gaps[spans == 1])
        assert got[1] == float(gaps.sum() / spans.sum())
    assert found > 50


def test_mrf1_pairwise_is_the_strided_formula_bit_for_bit():
    rng = np.random.default_rng(3)
    points = _flat_tape_in_space(rng)
    model = AlignmentMRF(points, NormalField(points, np.tile([0.0, 0.0, 1.0], (len(points), 1))), GRAPH, MRF1Config())
    for trial in range(8):
        x = np.concatenate([points[:, None, :] + rng.normal(0, 6, (len(points), 20, 3)),
                            rng.uniform(0.7, 1.4, (len(points), 20, 1))], axis=2)
        model.prepare(x[:, 0])
        e = model.edges
        sel = np.arange(len(e)) if trial % 2 else rng.choice(len(e), 25)
        xs, xt = x[e[sel, 0]], x[e[sel, 1]]
        p = xs[:, :, None, :3] - xt[:, None, :, :3]
        length = np.sqrt((p * p).sum(axis=3))
        rest = model.rest[sel][:, None, None]
        stretch_ = 0.5 * (xs[:, :, None, 3] + xt[:, None, :, 3])
        normal_part = np.einsum("mabk,mk->mab", p, model.edge_normals[sel])
        d_min = model.config.d_min_mm
        barrier = np.where(length < d_min, np.exp(np.minimum(d_min - length, 50.0)) ** 2, 0.0)
        w1, w2, w3, w4 = (arr[sel][:, None, None] for arr in (model.w1, model.w2, model.w3, model.w4))
        reference = w1 * (length - stretch_ * rest) ** 2 + w2 * normal_part**2 + w3 * barrier + w4 * (length - rest) ** 2
        assert (length < d_min).any()  # the barrier is exercised
        np.testing.assert_array_equal(model.pairwise(xs, xt, sel), reference)


@pytest.fixture(scope="module")
def mrf2_model():
    """An MRF2 over a tape in front of five cameras: one without an image, one whose view holds
    no tape (a uniform cost at the cap: it sees no dot), one looking at the tape's back."""
    rng = np.random.default_rng(4)
    positions = np.column_stack([GRAPH.uv_mm, np.zeros(GRAPH.n_dots)]) + [0.0, 0.0, 1000.0]
    target = positions.mean(axis=0)
    size = (640, 480)
    cams = [Camera.look_at(f"c{i}", target + offset, target, size, 900.0, up=(0.0, 1.0, 0.0))
            for i, offset in enumerate([(-400, 0, 1500), (400, 0, 1500), (0, -300, 1500), (0, 300, 1500), (0, 0, -1500)])]
    evidence: list[EvidenceImage | None] = [
        EvidenceImage(cost=rng.uniform(0, 1, (size[1], size[0])).astype(np.float32), scale=1.0, outside_cost=1.5)
        for _ in range(2)]
    evidence += [None, EvidenceImage(cost=np.full((1, 1), 2.0, np.float32), scale=1.0, outside_cost=2.0),
                 EvidenceImage(cost=rng.uniform(0, 1, (size[1], size[0])).astype(np.float32), scale=1.0, outside_cost=1.5)]
    model = RefinementMRF(GRAPH, Rig(cams), evidence, MRF2Config())
    model.start = torch.from_numpy(positions.copy())
    model.prepare(positions)
    return model, positions


def _torch_energy(model, x, xs=None, xt=None, edge_index=None):
    """The MRF2 energy terms as written in torch (unary_t / pairwise_t), every camera's costs
    evaluated and weighted (the straightforward sums)."""
    plain = staticmethod(lambda costs, weight: (costs(None) * weight).sum(dim=0))
    with torch.no_grad(), pytest.MonkeyPatch.context() as mp:
        mp.setattr(RefinementMRF, "_weighted_sum", plain)
        unary = model.unary_t(torch.from_numpy(x)).numpy()
        if xs is None:
            return unary, None
        pair = model.pairwise_t(torch.from_numpy(xs), torch.from_numpy(xt), torch.from_numpy(edge_index)).numpy()
    return unary, pair


def test_mrf2_costs_skip_unseeing_cameras_with_the_same_sums(mrf2_model):
    model, positions = mrf2_model
    seeing = model.visible.numpy().any(axis=0)
    assert seeing[:2].all() and not seeing[2:].any()  # two cameras see dots, three see none
    rng = np.random.default_rng(5)
    x = positions[:, None, :] + rng.normal(0, 3, (len(positions), 10, 3))
    e = model.edges
    plain = _torch_energy(model, x, x[e[:, 0]], x[e[:, 1]], np.arange(len(e)))
    fast = model.unary(x), model.pairwise(x[e[:, 0]], x[e[:, 1]], np.arange(len(e)))
    for a, b in zip(fast, plain):
        np.testing.assert_array_equal(a, b)
    model.unary_weight = torch.zeros_like(model.unary_weight)  # no camera at all
    np.testing.assert_array_equal(model.unary(x), np.zeros(x.shape[:2]))
    model.prepare(positions)  # the same state, but a parameter replaced since: prepared again
    assert model.unary_weight.numpy().any()


def _mrf2_scene(rng, cost_cap=1.0, distorted=True, half=False):
    """Five cameras around a tape (one behind it, one without an image, lens distortion on two),
    random cost images; ``half``: the images cover the left half of the frames only (dots on the
    right read the outside cost: at the cap, unseen)."""
    positions = np.column_stack([GRAPH.uv_mm, np.zeros(GRAPH.n_dots)]) + [0.0, 0.0, 1000.0]
    positions += rng.normal(0, 1.0, positions.shape)
    target = positions.mean(axis=0)
    size = (640, 480)
    cams = [Camera.look_at(f"c{i}", target + offset, target, size, 900.0, up=(0.0, 1.0, 0.0))
            for i, offset in enumerate([(-400, 0, 1500), (400, 0, 1500), (0, -300, 1500), (0, 300, 1500), (0, 0, -1500)])]
    if distorted:
        for cam in cams[:2]:
            cam.dist = np.array([0.1, -0.05, 0.001, -0.002, 0.01])
    width = size[0] // 2 if half else size[0]
    evidence: list[EvidenceImage | None] = [
        EvidenceImage(cost=rng.uniform(0, 1, (size[1], width)).astype(np.float32), scale=1.0, outside_cost=1.5,
                      origin=(0.0, 0.0) if c != 1 else (3.5, -2.0)) for c in range(2)]
    evidence += [None, EvidenceImage(cost=rng.uniform(0, 1, (size[1] // 2, width // 2)).astype(np.float32), scale=0.5,
                                     outside_cost=1.2),
                 EvidenceImage(cost=np.full((1, 1), 2.0, np.float32), scale=1.0, outside_cost=2.0)]
    return positions, Rig(cams), evidence, MRF2Config(cost_cap=cost_cap)


@pytest.mark.parametrize("cost_cap, distorted, half", [(1.0, True, False), (None, True, False), (1.0, False, True)])
def test_mrf2_numpy_costs_are_the_torch_energy_bit_for_bit(cost_cap, distorted, half):
    """RefinementMRF.unary / unary_rows / pairwise (numpy, what particle BP calls) against
    unary_t / pairwise_t (torch, what the polish differentiates): points near the tape, far off
    it, behind cameras (spread 3000 mm), a NaN point; unseen dots (their anchor term)."""
    rng = np.random.default_rng(11)
    positions, rig, evidence, config = _mrf2_scene(rng, cost_cap, distorted, half)
    model = RefinementMRF(GRAPH, rig, evidence, config)
    model.start = torch.from_numpy(positions + rng.normal(0, 2.0, positions.shape))
    model.prepare(positions)
    if half:
        assert model.unseen.numpy().any() and not model.unseen.numpy().all()
    e = model.edges
    for spread in (0.5, 3.0, 300.0, 3000.0):
        x = positions[:, None, :] + rng.normal(0, spread, (len(positions), 7, 3))
        x[3, 2] = np.nan
        unary, pair = _torch_energy(model, x, x[e[:, 0]], x[e[:, 1], :5], np.arange(len(e)))
        np.testing.assert_array_equal(model.unary(x), unary)
        np.testing.assert_array_equal(model.pairwise(x[e[:, 0]], x[e[:, 1], :5], np.arange(len(e))), pair)
        nodes = rng.integers(0, len(positions), 40)
        chains = rng.integers(0, 7, 40)
        np.testing.assert_array_equal(model.unary_rows(nodes, x[nodes, chains]), unary[nodes, chains])
        sel = rng.choice(len(e), 17)  # some edges, repeated, in any order, one particle against many
        xs, xt = x[e[sel, 0], :1], x[e[sel, 1]]
        np.testing.assert_array_equal(model.pairwise(xs, xt, sel), _torch_energy(model, x, xs, xt, sel)[1])
    assert model.unary_rows(np.zeros(0, np.int64), np.zeros((0, 3))).shape == (0,)


class _PlainMRF2:
    """A RefinementMRF seen as particle BP saw it before the fast paths: the torch energy with
    every camera's costs, prepared on every call, no ``unary_rows`` (so no open-chain beliefs and
    no shared evaluation of repeated particles)."""

    def __init__(self, model):
        self.model, self.edges = model, model.edges

    def prepare(self, state):
        self.model._prepare(state)

    def extra_proposals(self, state):
        return self.model.extra_proposals(state)

    def unary(self, x):
        return _torch_energy(self.model, np.ascontiguousarray(x, dtype=np.float64))[0]

    def pairwise(self, xs, xt, edge_index):
        x0 = np.zeros((1, 1, 3))
        return _torch_energy(self.model, x0, np.ascontiguousarray(xs, dtype=np.float64),
                             np.ascontiguousarray(xt, dtype=np.float64), np.asarray(edge_index))[1]


@pytest.mark.parametrize("half", [False, True])
def test_mrf2_particle_bp_is_the_straightforward_run_bit_for_bit(half):
    """The whole particle BP of MRF2 (the same random stream) with the numpy costs, the slice
    sampler's beliefs for open chains only, the repeated particles' costs shared and prepare
    skipped for an unchanged state, against the straightforward run: the same state, energies,
    particles and beliefs. Feasible points near some dots and far from others make the k-NN
    proposals repeat the state (repeated particles)."""
    rng = np.random.default_rng(12 + half)
    positions, rig, evidence, config = _mrf2_scene(rng, half=half)
    feasible = positions[rng.random(len(positions)) < 0.5] + rng.normal(0, 1.0, (1, 3))
    init = positions + rng.normal(0, 1.5, positions.shape)
    runs = []
    for plain in (False, True):
        model = RefinementMRF(GRAPH, rig, evidence, config, feasible_points=feasible)
        model.start = torch.from_numpy(init.copy())
        engine = ParticleBP(_PlainMRF2(model) if plain else model, config.pbp(), np.random.default_rng(5))
        runs.append(engine.run(init))
    fast, plain_run = runs
    assert len(fast.energy_history) == config.iterations + 1 and any(fast.accepted)
    np.testing.assert_array_equal(fast.state, plain_run.state)
    np.testing.assert_array_equal(fast.energy_history, plain_run.energy_history)
    np.testing.assert_array_equal(fast.particles, plain_run.particles)
    np.testing.assert_array_equal(fast.beliefs, plain_run.beliefs)


class _NoRows:
    """A model seen without its optional fast-path members (``unary_rows``, ``symmetric_pairwise``)."""

    def __init__(self, model):
        self.edges, self.unary, self.pairwise = model.edges, model.unary, model.pairwise
        self.prepare, self.extra_proposals = model.prepare, model.extra_proposals


def test_mrf2_pairwise_is_symmetric_bit_for_bit(mrf2_model):
    model, positions = mrf2_model
    rng = np.random.default_rng(15)
    e = model.edges
    for spread in (0.0, 2.0, 50.0):
        xs = positions[e[:, 0]][:, None, :] + rng.normal(0, spread, (len(e), 4, 3))
        xt = positions[e[:, 1]][:, None, :] + rng.normal(0, spread, (len(e), 3, 3))
        np.testing.assert_array_equal(model.pairwise(xs, xt, np.arange(len(e))),
                                      model.pairwise(xt, xs, np.arange(len(e))).transpose(0, 2, 1))


def test_open_chain_beliefs_and_shared_repeats_are_the_full_tables(mrf2_model):
    """_belief_at with a ``wanted`` mask gives the full evaluation's values at the wanted entries;
    the directed cost table with repeated particles (exact repeats, NaN, -0.0 beside 0.0) is the
    one evaluated pair by pair."""
    model, positions = mrf2_model
    rng = np.random.default_rng(13)
    engine = ParticleBP(model, MRF2Config().pbp(), rng)
    from spinemocap.track.pbp import _Graph

    graph = _Graph(engine.edges, len(positions))
    kept = positions[:, None, :] + rng.normal(0, 2, (len(positions), 4, 3))
    pre = rng.normal(0, 1, (2 * len(engine.edges), 4))
    points = positions[:, None, :] + rng.normal(0, 2, (len(positions), 4, 3))
    plain = ParticleBP(_NoRows(model), MRF2Config().pbp(), rng)  # unary on all points, one call per direction
    full = plain._belief_at(points, kept, pre, graph)
    np.testing.assert_array_equal(engine._belief_at(points, kept, pre, graph), full)
    for fraction in (0.9, 0.5, 0.1, 0.0):
        wanted = rng.random(full.shape) < fraction
        got = engine._belief_at(points, kept, pre, graph, wanted)
        np.testing.assert_array_equal(got[wanted], full[wanted])
    aug = positions[:, None, :] + rng.normal(0, 2, (len(positions), 11, 3))
    aug[:, 4] = aug[:, 0]
    aug[:, 9:] = aug[:, 4:5]
    aug[2, 5] = np.nan
    aug[2, 6] = np.nan
    aug[3, 7] = [0.0, 0.0, 1000.0]
    aug[3, 8] = [-0.0, 0.0, 1000.0]
    e = engine.edges
    reference = model.pairwise(aug[e[:, 0]], aug[e[:, 1]], np.arange(len(e)))
    np.testing.assert_array_equal(engine._pairwise_distinct(aug), reference)
    np.testing.assert_array_equal(engine._directed_costs(aug), np.concatenate([reference, reference.transpose(0, 2, 1)]))


def test_slice_samplers_costs_fill_the_augmented_table_bit_for_bit(mrf2_model):
    """The pairwise costs the slice sampler's beliefs evaluated (kept particles against each
    chain's accepted sample, both directions, and against the kept particles the chains start
    from) are those of the model, and the augmented set's
    table built with them is the table evaluated pair by pair; a changed remembered cost shows in
    the table (it is read, not evaluated again)."""
    model, positions = mrf2_model
    config = MRF2Config().pbp()
    engine = ParticleBP(model, config, np.random.default_rng(21))
    from spinemocap.track.pbp import _Graph

    graph = _Graph(engine.edges, len(positions))
    rng = np.random.default_rng(22)
    kept = positions[:, None, :] + rng.normal(0, 1.5, (len(positions), 4, 3))
    kept[:, 0] = positions
    pre = rng.normal(0, 0.2, (2 * len(engine.edges), 4))
    order = np.argsort(rng.normal(size=kept.shape[:2]), axis=1)  # the chains start from the kept particles
    start = np.take_along_axis(kept, order[:, :, None], axis=1)
    samples, known = engine._slice_sample(start, kept, pre, graph, np.full(3, 3.0), order)
    assert known is not None and known.has_forward.sum() > 10 and known.has_backward.sum() > 10
    assert not known.has_forward.all()  # some chains accepted nothing (their start: a kept particle)
    assert known.has_kept.all()
    e0, e1 = engine.edges[:, 0], engine.edges[:, 1]
    np.testing.assert_array_equal(known.kept, model.pairwise(kept[e0], kept[e1], np.arange(len(e0))))
    for m, q in zip(*np.nonzero(known.has_forward)):
        np.testing.assert_array_equal(known.forward[m, :, q], model.pairwise(kept[e0[m]][None], samples[e1[m], q][None, None], [m])[0, :, 0])
    for m, q in zip(*np.nonzero(known.has_backward)):
        np.testing.assert_array_equal(known.backward[m, q, :], model.pairwise(samples[e0[m], q][None, None], kept[e1[m]][None], [m])[0, 0, :])
    aug = np.concatenate([kept, positions[:, None, :], samples, kept[:, :2] + 0.5], axis=1)
    reference = model.pairwise(aug[e0], aug[e1], np.arange(len(e0)))
    np.testing.assert_array_equal(engine._pairwise_distinct(aug, known), reference)
    np.testing.assert_array_equal(engine._directed_costs(aug, known), engine._directed_costs(aug))
    m, q = np.argwhere(known.has_forward)[0]
    known.forward[m, 1, q] += 1.0
    known.kept[m, 2, 3] += 1.0
    changed = engine._pairwise_distinct(aug, known)
    assert changed[m, 1, kept.shape[1] + 1 + q] == reference[m, 1, kept.shape[1] + 1 + q] + 1.0
    assert changed[m, 2, 3] == reference[m, 2, 3] + 1.0


def test_start_beliefs_from_the_kept_particles_table_bit_for_bit(mrf2_model):
    """The slice sampler's beliefs at the chains' starts (kept particles) read from the kept
    particles' unary costs and pair-cost table are the beliefs evaluated at those points, and the
    sampler then draws the same samples."""
    model, positions = mrf2_model
    engine = ParticleBP(model, MRF2Config().pbp(), np.random.default_rng(23))
    from spinemocap.track.pbp import _Graph

    graph = _Graph(engine.edges, len(positions))
    rng = np.random.default_rng(24)
    kept = positions[:, None, :] + rng.normal(0, 1.5, (len(positions), 4, 3))
    pre = rng.normal(0, 0.2, (2 * len(engine.edges), 4))
    order = np.argsort(rng.normal(size=kept.shape[:2]), axis=1)[:, :3]
    start = np.take_along_axis(kept, order[:, :, None], axis=1)
    table = engine._directed_costs(kept)[: len(engine.edges)]
    unary = model.unary(kept)
    np.testing.assert_array_equal(engine._belief_at_kept(order, unary, table, pre, graph),
                                  engine._belief_at(start, kept, pre, graph))
    runs = []
    for at_kept in (None, (unary, table)):
        engine.rng = np.random.default_rng(25)
        samples, known = engine._slice_sample(start, kept, pre, graph, np.full(3, 3.0), order, at_kept)
        runs.append((samples, known))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[1][1].kept, table)
    np.testing.assert_array_equal(runs[0][1].kept[runs[0][1].has_kept[:, None, :].repeat(4, axis=1)],
                                  table[runs[0][1].has_kept[:, None, :].repeat(4, axis=1)])


def test_mrf2_visibility_of_all_cameras_is_the_per_camera_one_bit_for_bit(mrf2_model):
    """MRF2's visibility with all cameras' products stacked: the cosines and the pixels are each
    camera's own (``Camera.project``, the per-camera cosine) bit for bit, and the visibility the
    per-camera one (distorted cameras, dots behind a camera, NaN dots, many poses)."""
    model, positions = mrf2_model
    rng = np.random.default_rng(41)
    cams = [Camera(c.name, c.K, rng.normal(0, 0.05, 5), c.R, c.t, c.size) for c in model.rig]
    model = RefinementMRF(GRAPH, Rig(cams), model.evidence, MRF2Config())
    every = list(range(len(cams)))
    k = model._visibility_constants(every)
    for trial in range(200):
        pos = positions * rng.uniform(0.7, 1.4) + rng.normal(0, [0.5, 20.0, 300.0][trial % 3], positions.shape)
        if trial % 6 == 0:
            pos[rng.integers(len(pos))] = np.nan
        normals = template.tape_frames(pos, GRAPH)[0] if np.isfinite(pos).all() else rng.normal(size=pos.shape)
        cos, uv = model._facing_and_pixels(pos, normals, k)
        for c, cam in enumerate(cams):
            to_cam = cam.center[None, :] - pos
            np.testing.assert_array_equal(cos[c], (to_cam * normals).sum(axis=1) / np.maximum(np.linalg.norm(to_cam, axis=1), 1e-9))
            np.testing.assert_array_equal(uv[c], cam.project(pos))
        np.testing.assert_array_equal(model.visibility(pos, normals), model.visibility_per_camera(pos, normals))


def test_tape_frames_per_row_are_the_per_dot_frames_bit_for_bit():
    """tape_frames made per row and handed to the dots: the per-dot computation with np.cross and
    np.gradient, bit for bit (scaled, noisy, far-off and NaN positions)."""
    from spinemocap.track.normals import _unit

    def per_dot(pos, tape):
        rows = tape.row_index
        centre = rows.sums(pos) / rows.count[:, None]
        across = _unit(pos[rows.right] - pos[rows.left])[tape.row]
        along = _unit(np.gradient(centre, axis=0))[tape.row]
        normal = _unit(np.cross(across, along))
        return normal, across, _unit(np.cross(normal, across))

    rng = np.random.default_rng(31)
    flat = np.column_stack([GRAPH.uv_mm, np.zeros(GRAPH.n_dots)])
    for trial in range(300):
        pos = flat * rng.uniform(0.5, 2.0) + rng.normal(0, [0.01, 1.0, 10.0, 100.0][trial % 4], flat.shape)
        pos = pos @ np.linalg.qr(rng.normal(size=(3, 3)))[0] + rng.normal(0, 1000, 3)
        if trial % 7 == 0:
            pos[rng.integers(GRAPH.n_dots)] = np.nan
        for got, want in zip(template.tape_frames(pos, GRAPH), per_dot(pos, GRAPH)):
            np.testing.assert_array_equal(got, want)


def test_distinct_particles_are_numpys_isclose():
    rng = np.random.default_rng(6)
    for trial in range(100):
        d, p, s = (int(v) for v in rng.integers(1, 30, 3))
        particles = np.round(rng.normal(0, 2, (d, p, s)), 1)  # many duplicates ...
        particles[rng.random(particles.shape) < 0.05] += 5e-10  # ... some within the tolerance
        if trial % 5 == 0:
            particles[rng.random(particles.shape) < 0.05] = np.inf
        beliefs = rng.normal(size=(d, p))
        same = np.all(np.isclose(particles[:, :, None, :], particles[:, None, :, :], rtol=0, atol=1e-9), axis=3)
        duplicate = np.any(same & np.tril(np.ones((p, p), bool), k=-1)[None], axis=2)
        reference = np.argsort(np.where(duplicate, np.inf, beliefs), axis=1, kind="stable")[:, :3]
        np.testing.assert_array_equal(ParticleBP._distinct_best(beliefs, particles, 3), reference)


def test_chamfer_is_the_norm_formula_bit_for_bit():
    rng = np.random.default_rng(7)
    templates, points = rng.normal(0, 200, (30, GRAPH.n_dots, 3)), rng.normal(0, 200, (25, 3))
    dist = np.linalg.norm(templates[:, :, None, :] - points[None, None, :, :], axis=3)
    reference = np.minimum(dist.min(axis=2), 20.0).mean(axis=1) + np.minimum(dist.min(axis=1), 20.0).mean(axis=1)
    np.testing.assert_array_equal(template._chamfer(templates, points, 20.0), reference)


def test_epipolar_distance_is_the_plain_formula_bit_for_bit():
    from spinemocap.track.candidates import epipolar_distance

    rng = np.random.default_rng(8)
    for _ in range(50):
        F = rng.normal(size=(3, 3))
        x1, x2 = rng.uniform(0, 2448, (int(rng.integers(1, 40)), 2)), rng.uniform(0, 2448, (int(rng.integers(1, 40)), 2))
        h1, h2 = np.column_stack([x1, np.ones(len(x1))]), np.column_stack([x2, np.ones(len(x2))])
        algebraic = h1 @ F.T @ h2.T
        reference = np.maximum(np.abs(algebraic) / np.linalg.norm((h2 @ F)[:, :2], axis=1)[None, :],
                               np.abs(algebraic) / np.linalg.norm((h1 @ F.T)[:, :2], axis=1, keepdims=True))
        np.testing.assert_array_equal(epipolar_distance(F, x1, x2), reference)
        np.testing.assert_array_equal(epipolar_distance(F, x1, x2, h1, h2), reference)


def test_evidence_canvas_in_float32_samples_the_float64_values():
    """EvidenceStack keeps build_evidence's float32 costs in a float32 canvas: every sample
    (bilinear, off the images, behind the window) equals the float64 canvas's; a cost image in
    float64, or an outside cost float32 cannot hold, keeps the float64 canvas."""
    from spinemocap.track.evidence import EvidenceStack

    rng = np.random.default_rng(14)
    images = [EvidenceImage(cost=rng.uniform(0, 1, (60, 80)).astype(np.float32), scale=1.0, outside_cost=1.25),
              None,
              EvidenceImage(cost=rng.uniform(0, 2, (30, 50)).astype(np.float32), scale=0.5, outside_cost=2.0,
                            origin=(10.0, 5.5))]
    wide = [None if e is None else EvidenceImage(cost=e.cost.astype(np.float64), scale=e.scale, outside_cost=e.outside_cost,
                                                 origin=e.origin) for e in images]
    single, double = EvidenceStack(images), EvidenceStack(wide)
    assert single._flat.dtype == torch.float32 and double._flat.dtype == torch.float64
    uv = torch.from_numpy(rng.uniform(-20, 120, (3, 500, 2)))
    np.testing.assert_array_equal(single.sample_torch(uv).numpy(), double.sample_torch(uv).numpy())
    odd = [EvidenceImage(cost=images[0].cost, scale=1.0, outside_cost=1.1)]
    assert EvidenceStack(odd)._flat.dtype == torch.float64


def _costs_reference(costs, px, py, pz, k):
    """``_ImageCosts._costs`` as one expression per quantity (a fresh array per operation): the
    code the in-place passes replaced."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = k["r"]
    t0, t1, t2 = k["t"]
    xc0 = px * r00 + py * r01 + pz * r02 + t0
    xc1 = px * r10 + py * r11 + pz * r12 + t1
    xc2 = px * r20 + py * r21 + pz * r22 + t2
    z = np.maximum(xc2, 1e-6)
    xn, yn = xc0 / z, xc1 / z
    r2 = xn * xn + yn * yn
    radial = 1 + r2 * (k["k1"] + r2 * (k["k2"] + r2 * k["k3"]))
    xd = xn * radial + k["two_p1"] * xn * yn + k["p2"] * (r2 + 2 * xn * xn)
    yd = yn * radial + k["p1"] * (r2 + 2 * yn * yn) + k["two_p2"] * xn * yn
    u = k["fx"] * xd + k["skew"] * yd + k["cx"]
    v = k["fy"] * yd + k["cy"]
    h, w = costs.h, costs.w
    x = np.fmin(np.fmax((u - k["ox"]) * k["scale"] + 1.0, 0.0), w - 1)
    y = np.fmin(np.fmax((v - k["oy"]) * k["scale"] + 1.0, 0.0), h - 1)
    x[xc2 <= 1e-6] = 0.0
    xi = np.minimum(x.astype(np.int64), w - 2)
    yi = np.minimum(y.astype(np.int64), h - 2)
    fx, fy = x - xi, y - yi
    idx = k["base"] + yi * w + xi
    flat = costs.flat
    top = flat[idx] * (1 - fx) + flat[idx + 1] * fx
    bottom = flat[idx + w] * (1 - fx) + flat[idx + w + 1] * fx
    cost = top * (1 - fy) + bottom * fy
    return cost if costs.cap is None else np.minimum(cost, costs.cap)


@pytest.mark.parametrize("cost_cap, distorted, half, wide", [(1.0, True, False, False), (None, True, True, False),
                                                             (1.0, False, True, True)])
def test_mrf2_image_costs_in_place_are_the_expressions_bit_for_bit(cost_cap, distorted, half, wide):
    """The image costs computed in a few buffers in place (``_ImageCosts._costs``) against one
    fresh array per operation: every camera and camera subsets, scales 1 and 0.5, float32 and
    float64 (``wide``) canvases, points near the tape, far off it, behind cameras, NaN and
    infinite points; single points and passes of many."""

    rng = np.random.default_rng(21)
    positions, rig, evidence, config = _mrf2_scene(rng, cost_cap, distorted, half)
    # float32 costs with outside costs float32 holds give a float32 canvas; float64 costs a float64 one
    evidence = [None if e is None else EvidenceImage(cost=e.cost.astype(np.float64 if wide else np.float32), scale=e.scale,
                                                     outside_cost=float(np.float32(e.outside_cost)), origin=e.origin)
                for e in evidence]
    model = RefinementMRF(GRAPH, rig, evidence, config)
    costs = model._costs
    assert costs.flat.dtype == (np.float64 if wide else np.float32)
    x = np.concatenate([positions[rng.integers(0, len(positions), 300)] + rng.normal(0, s, (300, 3))
                        for s in (0.5, 5.0, 300.0, 3000.0)])
    x[:3] = [np.nan, 0.0, 1000.0], [np.inf, 0.0, 1000.0], [0.0, -np.inf, np.nan]
    for cams in (None, np.array([0, 1, 3]), np.array([4]), np.array([1, 3])):
        k = costs._constants(cams)
        for n in (1, 17, len(x)):
            px, py, pz = (np.ascontiguousarray(x[:n, i]) for i in range(3))
            with np.errstate(invalid="ignore", over="ignore"):  # the infinite points
                got = costs._costs(px, py, pz, k)
                ref = _costs_reference(costs, px, py, pz, k)
            assert got.dtype == ref.dtype == np.float64
            np.testing.assert_array_equal(got.view(np.int64), ref.view(np.int64))
    assert any(not costs._constants(c)["unit_scale"] for c in (None, np.array([1, 3])))  # scale 0.5 exercised


def _evidence_reference(image, mask, downscale=1.0, blur_sigma_px=None, outside_slope=0.05, dot_to_width=0.2,
                        crop_margin_px=64.0):
    """``build_evidence`` written plainly, the reference the fast path must equal: the whole frame
    converted to grey first, the mask's columns searched over all rows, a fresh array per operation."""
    import cv2

    from spinemocap.track.evidence import EvidenceImage, estimate_dot_radius_px

    grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY) if image.ndim == 3 else np.asarray(image)
    h, w = grey.shape
    tape = np.ones((h, w), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    origin = (0.0, 0.0)
    if crop_margin_px is not None and mask is not None and not tape.any():
        grey, tape = grey[:1, :1], tape[:1, :1]
        h, w = 1, 1
    elif crop_margin_px is not None and mask is not None:
        rows, cols = np.flatnonzero(tape.any(axis=1)), np.flatnonzero(tape.any(axis=0))
        m = int(np.ceil(crop_margin_px))
        y0, y1 = max(rows[0] - m, 0), min(rows[-1] + m + 1, h)
        x0, x1 = max(cols[0] - m, 0), min(cols[-1] + m + 1, w)
        grey, tape = grey[y0:y1, x0:x1], tape[y0:y1, x0:x1]
        h, w = grey.shape
        origin = (float(x0), float(y0))
    grey = grey.astype(np.float32)
    if blur_sigma_px is None:
        blur_sigma_px = 0.6 * estimate_dot_radius_px(tape, dot_to_width) if mask is not None else 1.5
    if downscale != 1.0:
        size = (max(1, int(round(w * downscale))), max(1, int(round(h * downscale))))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        tape = cv2.resize(tape.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    sigma = blur_sigma_px * downscale
    if sigma > 0.3 and tape.any():
        dark = np.float32(np.percentile(grey[tape], 1))
        grey = cv2.GaussianBlur(np.where(tape, grey, dark), (0, 0), sigma)
    elif sigma > 0.3:
        grey = cv2.GaussianBlur(grey, (0, 0), sigma)
    if tape.any():
        lo, hi = np.percentile(grey[tape], [1, 99.5])
    else:
        lo, hi = float(grey.min()), float(grey.max())
    cost = 1.0 - np.clip((grey - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    if not tape.all():
        with np.errstate(over="ignore"):
            outside = cv2.distanceTransform((~tape).astype(np.uint8), cv2.DIST_L2, 5) / downscale
        cost = np.where(tape, cost, 1.0 + outside_slope * outside)
    outside_cost = float(cost.max()) if cost.size else 1.0
    return EvidenceImage(cost=cost.astype(np.float32), scale=float(downscale), outside_cost=outside_cost, origin=origin)


def _taped_image(rng, shape=(150, 220), band=(40, 90, 30, 200)):
    """A colour image with a dark tape band (rows, columns of ``band``) holding bright dots, and its mask."""
    image = rng.integers(90, 200, shape + (3,), dtype=np.uint8)  # skin-like, noisy, colour channels differ
    y0, y1, x0, x1 = band
    mask = np.zeros(shape, bool)
    mask[y0:y1, x0:x1] = True
    mask[y0 + 5, x1:] = True  # a thin spur running to the image's edge
    image[mask] = rng.integers(10, 40, (int(mask.sum()), 3), dtype=np.uint8)
    for cy in range(y0 + 8, y1 - 4, 16):
        for cx in range(x0 + 8, x1 - 4, 16):
            image[cy - 2 : cy + 3, cx - 2 : cx + 3] = rng.integers(200, 255, 3, dtype=np.uint8)
    return image, mask


@pytest.mark.parametrize("options", [{}, {"downscale": 0.5}, {"blur_sigma_px": 0.2}, {"crop_margin_px": None},
                                     {"crop_margin_px": 7.5, "outside_slope": 0.3}])
def test_evidence_from_the_colour_window_is_the_whole_frames_grey_bit_for_bit(options):
    """build_evidence on the colour image (its window converted to grey) and on the grey image,
    against the code it replaced (the whole frame converted first, fresh arrays): the same cost
    image, outside cost and origin; a mask at the image's edge, a mask without tape, no mask."""
    from spinemocap.capture import to_grey
    from spinemocap.track.evidence import build_evidence

    rng = np.random.default_rng(22)
    cases = [_taped_image(rng), _taped_image(rng, band=(0, 30, 100, 220)), _taped_image(rng, band=(120, 150, 0, 60))]
    image, mask = cases[0]
    cases += [(image, np.zeros_like(mask)), (image, None)]
    for image, mask in cases:
        reference = _evidence_reference(to_grey(image), mask, **options)
        for given in (image, to_grey(image)):
            with np.errstate(over="ignore"):
                got = build_evidence(given, mask, **options)
            assert got.cost.dtype == reference.cost.dtype == np.float32
            np.testing.assert_array_equal(got.cost.view(np.int32), reference.cost.view(np.int32))
            assert (got.outside_cost, got.origin, got.scale) == (reference.outside_cost, reference.origin, reference.scale)
        colour_reference = _evidence_reference(image, mask, **options)  # the reference on the colour image: the same
        np.testing.assert_array_equal(colour_reference.cost, reference.cost)


def test_tracker_evidence_reads_colour_views_without_converting_the_frame():
    """FrameTracker.evidence on views that hold their colour images: the cost images of their grey
    images, bit for bit, and the views keep the colour images (no whole-frame grey image made);
    ``held_image`` hands out what a view holds without converting."""
    from spinemocap.capture import to_grey
    from spinemocap.track.evidence import build_evidence
    from spinemocap.track.pipeline import FrameTracker
    from spinemocap.views import ViewDots

    rng = np.random.default_rng(23)
    spec = TapeSpec(n_rows=13)
    cams = [Camera.look_at(f"c{i}", (x, 0.0, 1500.0), (0.0, 0.0, 0.0), (220, 150), 300.0, up=(0.0, 1.0, 0.0))
            for i, x in enumerate((-300.0, 300.0, 0.0))]
    tracker = FrameTracker(Rig(cams), spec)
    (a, mask_a), (b, mask_b) = _taped_image(rng), _taped_image(rng, band=(0, 30, 100, 220))
    empty = np.zeros((0, 2))
    views = [ViewDots(0, empty, np.zeros(0), mask_a, colour=a), ViewDots(1, empty, np.zeros(0), mask_b, image=to_grey(b)),
             ViewDots(2, empty, np.zeros(0), mask_a)]
    assert views[0].held_image is a and views[1].held_image is views[1]._image and views[2].held_image is None
    got = tracker.evidence(views)
    assert views[0]._image is None and views[0]._colour is a  # not converted
    assert got[2] is None
    for e, (image, mask) in zip(got[:2], ((a, mask_a), (b, mask_b))):
        reference = build_evidence(to_grey(image), mask)
        np.testing.assert_array_equal(e.cost, reference.cost)
        assert (e.outside_cost, e.origin) == (reference.outside_cost, reference.origin)
    assert views[0].image is not None and views[0].held_image is views[0].image  # converted on request, then held
    assert tracker.evidence([ViewDots(c, empty, np.zeros(0)) for c in range(3)]) is None


def test_tracker_evidence_threads_build_the_serial_images():
    """The cost images built by the tracker's evidence threads are those built one after another in
    the calling thread, in the cameras' order (cameras without an image: None)."""
    import dataclasses

    from spinemocap.track.config import EvidenceConfig, TrackerConfig
    from spinemocap.track.pipeline import FrameTracker
    from spinemocap.views import ViewDots

    rng = np.random.default_rng(24)
    cams = [Camera.look_at(f"c{i}", (x, 0.0, 1500.0), (0.0, 0.0, 0.0), (220, 150), 300.0, up=(0.0, 1.0, 0.0))
            for i, x in enumerate((-300.0, -100.0, 100.0, 300.0, 0.0))]
    bands = [(40, 90, 30, 200), (0, 30, 100, 220), (120, 150, 0, 60), (60, 100, 50, 150)]
    images = [_taped_image(rng, band=b) for b in bands]
    empty = np.zeros((0, 2))
    views = [ViewDots(c, empty, np.zeros(0), mask, colour=image) for c, (image, mask) in enumerate(images)]
    views.insert(2, ViewDots(4, empty, np.zeros(0)))
    results = []
    for threads in (1, 2, 3):
        config = dataclasses.replace(TrackerConfig(), evidence=EvidenceConfig(threads=threads))
        tracker = FrameTracker(Rig(cams), TapeSpec(n_rows=13), config)
        results.append(tracker.evidence(views))
        assert (tracker._pool is None) == (threads == 1)
    for got in results[1:]:
        assert got[2] is None
        for a, b in zip(results[0][:2] + results[0][3:], got[:2] + got[3:]):
            np.testing.assert_array_equal(a.cost.view(np.int32), b.cost.view(np.int32))
            assert (a.outside_cost, a.origin) == (b.outside_cost, b.origin)
