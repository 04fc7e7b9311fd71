"""The sequence tracker's hidden rows after a full re-solve, on dots laid on a curved back."""

from __future__ import annotations

import numpy as np
from tape_scenes import SPEC, blobs, rig_behind, tape_on_back

from spinemocap.markers import INFERRED, OBSERVED
from spinemocap.track.evaluate import label_swaps
from spinemocap.track.pipeline import FrameResult, FrameTracker, match_points
from spinemocap.track.quality import flagged_from_confidence, label_confidence
from spinemocap.track.sequence import SequenceTracker


def _resolved_with_hidden_top_rows(last: np.ndarray) -> tuple[SequenceTracker, FrameResult, np.ndarray]:
    """A sequence tracker whose last frame's dots are ``last`` (D, 3) mm and a re-solve of the
    next frame with every dot on its own place, rows 12-13 unseen by any camera pair (inferred).
    Returns (tracker, re-solve, the (D,) bool hidden dots)."""
    dots = tape_on_back(SPEC)
    hidden = SPEC.graph.row >= 11
    status = np.where(hidden, INFERRED, OBSERVED).astype(object)
    result = FrameResult(dots.copy(), status, np.where(hidden, 0, 4), np.full(SPEC.n_dots, np.nan))
    sequence = SequenceTracker(FrameTracker(rig_behind(), SPEC))
    sequence.last = last
    return sequence, result, hidden


def _doubted(result: FrameResult) -> np.ndarray:
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    return flagged_from_confidence(np.array(result.status)[:, None], confidence[:, None])


def test_hidden_rows_moved_a_column_from_the_resolves_places_are_doubted():
    """The last frame had the top rows a column aside (labels of a frame it doubted): following
    its motion moves the unseen rows there, away from where the re-solve put them."""
    dots = tape_on_back(SPEC)
    column = dots[SPEC.graph.index("R12C")] - dots[SPEC.graph.index("R12L")]
    top = SPEC.graph.row >= 11
    sequence, result, hidden = _resolved_with_hidden_top_rows(dots + np.where(top[:, None], column, 0.0))
    sequence._hidden_rows_follow(result)
    assert np.allclose(result.positions[hidden], dots[hidden] + column)  # followed the last frame's motion
    assert result.unanchored is not None and result.unanchored[hidden].all() and not result.unanchored[~hidden].any()
    assert "dot_unanchored" in result.flags and _doubted(result)[hidden].all()


def test_hidden_rows_following_the_re_solve_are_not_doubted():
    dots = tape_on_back(SPEC)
    sequence, result, hidden = _resolved_with_hidden_top_rows(dots + [0.0, 0.0, -3.0])  # the tape moved 3 mm
    sequence._hidden_rows_follow(result)
    assert np.allclose(result.positions, dots)
    assert result.unanchored is None and not result.flags and not _doubted(result).any()


def test_a_carried_frame_finds_the_points_of_dots_the_last_frames_inferred_on_the_tracked_lattice():
    """The last two frames inferred the tape's last four rows (their places the model's, 5 mm off
    in one frame and 1 mm in the other, e.g. a flexed back's end the cameras lost): the constant
    velocity prediction puts them 9 mm and more from their points, too far for the match and too
    many dots to carry the frame on the rest. The row next to the tracked ones finds its points
    where the tracked dots' lattice puts it: the frame is carried with every label, and the end
    rows beyond are found from there (the status's row-by-row search of the tape's end)."""
    dots = tape_on_back(SPEC)
    end = SPEC.graph.row >= SPEC.n_rows - 4
    tracker = FrameTracker(rig_behind(), SPEC)
    sequence = SequenceTracker(tracker)
    sequence.step(blobs(rig_behind(), dots, noise_px=0.2, seed=1), {})  # measures the rig and the spacing
    before_last, last = dots.copy(), dots.copy()
    before_last[end] += [0.0, 0.0, 1.0]
    last[end] += [0.0, 0.0, 5.0]
    sequence.before_last, sequence.last = before_last, last
    sequence.last_observed = ~end
    views = blobs(rig_behind(), dots, noise_px=0.2, seed=2)
    cloud = tracker.candidates(views)
    predicted = sequence.predict()
    usable = cloud.points[cloud.n_views >= 2]
    explained = (match_points(predicted, usable, sequence.config.match_radius_mm) >= 0).mean()
    assert np.linalg.norm(predicted[end] - dots[end], axis=1).min() > sequence.config.match_radius_mm
    assert explained < sequence.config.min_explained, "precondition: the prediction alone must not carry the frame"
    result = sequence.step(views, {})
    assert result.route == "carried"
    assert (result.status[end] == OBSERVED).mean() > 0.8
    assert not label_swaps(result.positions[None], dots[None], 15.0).any()
    observed = result.status == OBSERVED
    assert np.linalg.norm(result.positions[observed] - dots[observed], axis=1).max() < 1.5
    assert not _doubted(result).any()


def test_the_lattice_match_seeks_only_dots_the_last_frame_inferred_and_one_row_out():
    """A dot the last frame observed was predicted from points: when it finds none near its
    prediction it is not sought elsewhere (it is unseen now, or the frame is re-solved). Of the
    inferred ones, those between the matched rows and one row beyond them are sought: farther
    out the lattice no longer holds."""
    dots = tape_on_back(SPEC)
    sequence = SequenceTracker(FrameTracker(rig_behind(), SPEC))
    sequence.last_observed = np.ones(SPEC.n_dots, bool)
    rows = SPEC.graph.row
    seen = (rows < SPEC.n_rows - 4) & (rows != 4)
    match = np.where(seen, np.arange(SPEC.n_dots), -1)
    positions = np.where(seen[:, None], dots, dots + [0.0, 0.0, 20.0])
    assert not sequence._match_inferred_on_lattice(positions.copy(), seen, dots, match.copy()).any()
    sequence.last_observed = seen.copy()
    found = sequence._match_inferred_on_lattice(positions, seen, dots, match)
    sought = (rows == 4) | (rows == SPEC.n_rows - 4)
    np.testing.assert_array_equal(found, sought)
    np.testing.assert_array_equal(match[seen | sought], np.flatnonzero(seen | sought))
    np.testing.assert_allclose(positions[seen | sought], dots[seen | sought])
    assert (match[~(seen | sought)] == -1).all()
