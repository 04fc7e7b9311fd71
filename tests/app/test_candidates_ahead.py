"""The candidate stage built ahead in worker processes: the same tracked output as the tracker
building it itself, the frames built ahead served, and a worker that dies costs nothing but time."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from spinemocap.app.candidates_ahead import CandidatesAhead
from spinemocap.app.run import TrackResult, run_tracking
from spinemocap.track.pipeline import FrameResult
from tests.tape_scenes import SPEC, blobs, rig_behind, sequence


@pytest.fixture(scope="module")
def scene():
    """Five frames of the tape moving past four cameras, and their tracking without workers."""
    rig = rig_behind(4)
    views = [blobs(rig, dots, noise_px=0.3, clutter=4, seed=f) for f, dots in enumerate(sequence(40)[:5])]
    return rig, views, run_tracking(_frames(views), rig, SPEC, fps=10.0, progress=False)


def _frames(views):
    return ((f, v, 0.0) for f, v in enumerate(views))


def _same_output(a: TrackResult, b: TrackResult) -> None:
    x, y = a.table.to_arrays(), b.table.to_arrays()
    for name in ("positions", "n_views", "residual", "confidence", "stretch"):
        assert np.array_equal(getattr(x, name), getattr(y, name), equal_nan=True), name
    assert np.array_equal(x.status, y.status)
    assert [r.flags for r in a.frames] == [r.flags for r in b.frames]


def _tracked_ahead(rig, views, ahead: CandidatesAhead, after_frame=None) -> TrackResult:
    def on_frame(frame: int, result: FrameResult) -> None:
        ahead.observe(frame, result)
        if after_frame is not None:
            after_frame(frame)

    try:
        return run_tracking(ahead.frames(_frames(views)), rig, SPEC, fps=10.0, progress=False,
                            on_frame=on_frame, ahead_for=ahead.for_frame)
    finally:
        ahead.close()


def test_workers_build_the_candidates_the_tracker_would(scene):
    rig, views, alone = scene
    ahead = CandidatesAhead(rig, SPEC, None, workers=1, depth=2)
    result = _tracked_ahead(rig, views, ahead)
    _same_output(alone, result)
    # the first frame sets the gate; the frames read before it was known are built in place
    assert ahead.built >= len(views) - 1 - ahead.depth
    assert result.candidates_taken_ahead == ahead.built  # a changed gate is built again in time


def test_a_dying_worker_leaves_the_tracker_to_build_the_rest(scene, caplog):
    rig, views, alone = scene
    ahead = CandidatesAhead(rig, SPEC, None, workers=1, depth=2)
    pids = list(ahead.pids)
    assert pids

    def kill_after_first(frame: int) -> None:
        if frame == 1:
            for pid in pids:
                os.kill(pid, signal.SIGKILL)

    with caplog.at_level("WARNING", logger="spinemocap.app.candidates_ahead"):
        result = _tracked_ahead(rig, views, ahead, kill_after_first)
    _same_output(alone, result)
    assert "candidate worker failed" in caplog.text
    assert ahead.built < len(views) - 1


def test_bad_worker_counts_and_workers_with_prediction_are_refused(scene):
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.fileio import InputError

    rig, _, _ = scene
    with pytest.raises(ValueError, match="workers and depth"):
        CandidatesAhead(rig, SPEC, None, workers=0)
    with pytest.raises(InputError, match="turn prediction off"):
        SpeedOptions(candidate_workers=2)  # prediction waits for each solved frame: nothing to build ahead
    with pytest.raises(InputError, match="0 or more"):
        SpeedOptions(candidate_workers=-1, predict=False)
    assert SpeedOptions(candidate_workers=2, predict=False, frames_at_once=4).candidate_workers == 2
