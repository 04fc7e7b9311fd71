"""The candidate stage built ahead of the tracker: a cloud built with one gate is, bit for bit,
the cloud of every gate in its recorded range, the range ends where a test would come out
otherwise, and a tracker given such clouds tracks exactly as one that builds them itself."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from spinemocap.app.run import run_tracking
from spinemocap.track.ahead import FrameCandidates, frame_candidates
from spinemocap.track.candidates import build_candidates, candidates_and_gate_range
from spinemocap.track.config import CandidateConfig, TrackerConfig
from spinemocap.track.stretch import StretchEstimate, estimate_stretch, read_stretch
from tests.tape_scenes import SPEC, blobs, rig_behind, sequence

CLOUD_FIELDS = ("points", "normals", "blob_ids", "residual", "pixels")


def _same_cloud(a, b) -> bool:
    return all(getattr(a, f).shape == getattr(b, f).shape and np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
               for f in CLOUD_FIELDS)


@pytest.fixture(scope="module")
def scene():
    """Six frames of the tape swept past four cameras; 1 px pixel noise (reprojection errors
    around the gates tried) and 8 clutter blobs per camera."""
    rig = rig_behind(4)
    views = [blobs(rig, dots, noise_px=1.0, clutter=8, seed=f) for f, dots in enumerate(sequence(6))]
    return rig, views


def test_a_cloud_serves_exactly_the_gates_of_its_range(scene):
    rig, views = scene
    rng = np.random.default_rng(0)
    narrowed = 0
    for frame_views in views[:3]:
        for gate in (1.5, 2.0, 2.7, 4.0):
            cloud, (lo, hi) = candidates_and_gate_range(rig, frame_views, CandidateConfig(th1_px=gate))
            assert lo < gate <= hi
            for other in [*rng.uniform(lo, min(hi, gate + 1.0), 3), min(hi, 50.0)]:
                assert _same_cloud(cloud, build_candidates(rig, frame_views, CandidateConfig(th1_px=float(other))))
            if np.isfinite(hi):
                narrowed += 1
                # just beyond, the test that set hi passes: that build's range no longer holds the gate
                _, (lo_beyond, _) = candidates_and_gate_range(rig, frame_views,
                                                              CandidateConfig(th1_px=float(np.nextafter(hi, np.inf))))
                assert lo_beyond >= hi >= gate
    assert narrowed >= 6  # the noisy frames' tests decide near every gate tried


def test_a_fixed_epipolar_tolerance_leaves_the_pairing_out_of_the_range(scene):
    rig, views = scene
    config = CandidateConfig(th1_px=2.0, epipolar_px=4.0)
    cloud, (lo, hi) = candidates_and_gate_range(rig, views[0], config)
    assert lo < 2.0 <= hi
    inside = dataclasses.replace(config, th1_px=float(np.nextafter(lo, np.inf)))
    assert _same_cloud(cloud, build_candidates(rig, views[0], inside))


def test_the_stretch_reading_completed_by_the_fallback_is_the_estimate(scene):
    rig, views = scene
    points = build_candidates(rig, views[0], CandidateConfig()).points
    fallback = StretchEstimate(along=1.2, across=1.1, along_min=1.1, along_max=1.3, coherence=0.9, source="data")
    for pts in (points, points[:3], np.zeros((0, 3))):
        for last in (None, fallback):
            assert read_stretch(pts, SPEC).estimate(last) == estimate_stretch(pts, SPEC, fallback=last)


@pytest.mark.filterwarnings("ignore::spinemocap.track.rig_check.CalibrationWarning")
def test_tracking_with_clouds_built_ahead_is_tracking_without(scene):
    """Clouds built with the gate known two frames earlier are taken where they serve the
    frame's gate, and one built with a gate far off is built again; the output is the same."""
    rig, views = scene
    views = views[:4]
    config = TrackerConfig()
    alone = run_tracking(((f, v, 0.0) for f, v in enumerate(views)), rig, SPEC, fps=10.0, config=config, progress=False)
    gates = [np.nan] + [r.gate_px for r in alone.frames[:-1]]  # the gate each frame was built with
    built: list[FrameCandidates | None] = [None] + [
        frame_candidates(rig, views[f], SPEC, config, gates[max(f - 1, 1)]) for f in range(1, len(views))]
    built[2] = frame_candidates(rig, views[2], SPEC, config, 6.0)
    assert not built[2].serves(gates[2])
    ahead = run_tracking(((f, v, 0.0) for f, v in enumerate(views)), rig, SPEC, fps=10.0, config=config, progress=False,
                         ahead_for=lambda f: built[f])
    a, b = alone.table.to_arrays(), ahead.table.to_arrays()
    for name in ("positions", "n_views", "residual", "confidence", "stretch"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert np.array_equal(a.status, b.status)
    assert [r.flags for r in alone.frames] == [r.flags for r in ahead.frames]
    serving = sum(b is not None and b.serves(g) for b, g in zip(built, gates))
    assert ahead.candidates_taken_ahead == serving >= 1
