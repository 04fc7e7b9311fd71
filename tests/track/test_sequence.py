"""The sequence tracker's hidden rows after a full re-solve, on dots laid on a curved back."""

from __future__ import annotations

import numpy as np
from tape_scenes import SPEC, rig_behind, tape_on_back

from spinemocap.markers import INFERRED, OBSERVED
from spinemocap.track.pipeline import FrameResult, FrameTracker
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
