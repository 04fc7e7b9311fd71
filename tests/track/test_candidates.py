"""Candidate search: the faster search finds the same candidates as the straightforward
one on a studio frame (six cameras, the lab's 2448x1600 views), and its parts agree with the
library functions they replace."""

from __future__ import annotations

import numpy as np
import pytest

import spinemocap.track.candidates as candidates
from spinemocap.geometry import triangulate_dlt
from spinemocap.track.config import CandidateConfig
from spinemocap.views import ViewDots


@pytest.fixture(scope="module")
def studio_frame():
    """One flexion frame of the studio preset: each camera's visible dots projected (+0.3 px
    noise) and 6 clutter blobs per camera near the tape (ghost pairings along epipolar lines)."""
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("studio", frames=12, motion="flexion"))
    gt = scene.groundtruth
    rng = np.random.default_rng(3)
    frame = 11
    views = []
    for c in range(len(scene.rig)):
        uv = gt["uv"][frame, c][gt["visible"][frame, c]]
        uv = uv + rng.normal(0, 0.3, uv.shape)
        if len(uv):
            clutter = uv[rng.integers(0, len(uv), 6)] + rng.normal(0, 25, (6, 2))
            uv = np.concatenate([uv, clutter])
        views.append(ViewDots(c, uv, np.ones(len(uv))))
    return scene.rig, views


def _straightforward(monkeypatch):
    """The search with straightforward primitives: every row triangulated
    again at every call (no memory), the full DLT with zero rows, numpy's unique rows."""

    def solve(self, blob_ids, th1):
        uv, used = self.gather(blob_ids)
        points = triangulate_dlt(self.P, uv, used)
        err = candidates.reprojection_errors(self.P, points, uv, used)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(points).all(axis=1) & ~(np.isnan(err) & used).any(axis=1)
            ok &= np.nanmax(np.where(used, err, 0.0), axis=1) < th1
            rms = np.sqrt(np.nanmean(np.where(used, err**2, np.nan), axis=1))
        return points, rms, ok

    monkeypatch.setattr(candidates._Views, "solve", solve)
    monkeypatch.setattr(candidates, "_unique_row_index",
                        lambda ids: np.unique(ids, axis=0, return_index=True)[1] if len(ids) else np.arange(len(ids)))
    monkeypatch.setattr(candidates, "_fundamental_cached",
                        lambda a, b: candidates.fundamental_matrix(np.frombuffer(a).reshape(3, 4),
                                                                   np.frombuffer(b).reshape(3, 4)))


def test_fast_search_finds_the_same_candidates_on_a_studio_frame(studio_frame, monkeypatch):
    rig, views = studio_frame
    fast = candidates.build_candidates(rig, views)
    with monkeypatch.context() as m:
        _straightforward(m)
        plain = candidates.build_candidates(rig, views)
    assert (np.array([len(v) for v in views]) > 0).sum() >= 3 and len(plain.points) >= 20  # not trivial
    assert (plain.blob_ids >= 0).sum(axis=1).max() >= 3                                       # merges happened
    np.testing.assert_array_equal(fast.blob_ids, plain.blob_ids)
    np.testing.assert_allclose(fast.points, plain.points, rtol=0, atol=1e-8)     # mm: rounding only
    np.testing.assert_allclose(fast.residual, plain.residual, rtol=0, atol=1e-8)  # px
    np.testing.assert_allclose(fast.normals, plain.normals, rtol=0, atol=1e-10)


def test_remembered_rows_are_the_rows_solved_again(studio_frame):
    rig, views = studio_frame
    v = candidates._Views(rig, views)
    rows = candidates._pairwise_rows(v, CandidateConfig())[0]
    first = v.solve(rows, 2.0)
    shuffled = np.random.default_rng(0).permutation(len(rows))
    again = v.solve(np.concatenate([rows[shuffled], rows[:3]]), 2.0)      # remembered, other order
    fresh = candidates._Views(rig, views).solve(rows[shuffled], 2.0)      # a new memory
    for a, b, c in zip(first, again, fresh):
        np.testing.assert_array_equal(a[shuffled], b[:len(rows)])
        np.testing.assert_array_equal(a[:3], b[len(rows):])
        np.testing.assert_array_equal(a[shuffled], c)


def test_unique_row_index_and_compact_dlt_agree_with_the_library():
    rng = np.random.default_rng(1)
    ids = rng.integers(-1, 4, (500, 6))
    rows, first = np.unique(ids, axis=0, return_index=True)
    np.testing.assert_array_equal(candidates._unique_row_index(ids), first)
    np.testing.assert_array_equal(ids[candidates._unique_row_index(ids)], rows)
    # many blobs, rows repeated in shuffled order; ids too large for one integer per row (the
    # lexsort path); ids below -1 (not blob ids: the lexsort path as well)
    for ids in (rng.integers(-1, 300, (400, 6)), rng.integers(-1, 2**20, (300, 6)), rng.integers(-3, 5, (300, 6))):
        ids = np.concatenate([ids, ids[rng.permutation(len(ids))[:150]]])
        np.testing.assert_array_equal(candidates._unique_row_index(ids), np.unique(ids, axis=0, return_index=True)[1])
    P = rng.normal(size=(6, 3, 4))
    uv = rng.normal(size=(500, 6, 2))
    used = rng.random((500, 6)) < 0.5
    used[:, :2] = True  # at least two views each
    np.testing.assert_allclose(candidates._triangulate_compact(P, uv, used), triangulate_dlt(P, uv, used),
                               rtol=1e-9, atol=1e-9)


def test_rig_constants_follow_the_cameras(studio_frame):
    """The per-rig constants (projection matrices, centres, fundamental matrices) are those of the
    cameras as they are now: a camera moved in place gets its own (and the same candidates as a
    search that computes them afresh)."""
    import copy

    rig, views = studio_frame
    rig = copy.deepcopy(rig)
    P, centers, _ = candidates._rig_constants(rig)
    np.testing.assert_array_equal(P, np.stack([cam.projection_matrix for cam in rig]))
    np.testing.assert_array_equal(centers, np.stack([cam.center for cam in rig]))
    before = candidates.build_candidates(rig, views)
    rig.cameras[1].t = rig.cameras[1].t + np.array([3.0, 0.0, 0.0])  # moved in place
    P2, _, _ = candidates._rig_constants(rig)
    np.testing.assert_array_equal(P2[1], rig.cameras[1].projection_matrix)
    v = candidates._Views(rig, views)
    F = candidates.fundamental_matrix(rig.cameras[0].projection_matrix, rig.cameras[1].projection_matrix)
    np.testing.assert_array_equal(v.fundamental(0, 1), F)
    after = candidates.build_candidates(rig, views)
    candidates._RIGS.clear()
    fresh = candidates.build_candidates(rig, views)
    np.testing.assert_array_equal(after.points, fresh.points)
    np.testing.assert_array_equal(after.blob_ids, fresh.blob_ids)
    assert not np.array_equal(after.points[:5], before.points[:5]) or len(after) != len(before)
