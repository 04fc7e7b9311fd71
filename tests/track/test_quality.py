"""Which dots an implausible row pitch puts in doubt: the unseen end rows the model laid, or
(a pitch within the observed rows) the frame's labels."""

from __future__ import annotations

import numpy as np
from tape_scenes import SPEC

from spinemocap.track.quality import implausible_pitches, unobserved_ends_beside

ROWS = SPEC.graph.row
GAPS = SPEC.n_rows - 1


def _gaps(*k: int) -> np.ndarray:
    out = np.zeros(GAPS, bool)
    out[list(k)] = True
    return out


def test_pitches_outside_the_tape_range_or_the_measured_one_are_implausible():
    pitches = np.array([1.0, 1.3, 0.6, np.nan, 2.2, 1.1])
    np.testing.assert_array_equal(implausible_pitches(pitches, (0.7, 2.0)), [0, 0, 1, 0, 1, 0])
    np.testing.assert_array_equal(implausible_pitches(pitches, (0.7, 2.0), (0.9, 1.2)), [0, 1, 1, 0, 1, 0])


def test_an_implausible_pitch_beside_the_unseen_end_rows_doubts_only_those_rows():
    observed = ROWS <= 9  # rows 10-12 seen by no camera pair
    for gap in (9, 10, 11):  # last observed row to the first unseen one, and between unseen rows
        np.testing.assert_array_equal(unobserved_ends_beside(_gaps(gap), observed, SPEC.graph), ROWS >= 10)
    low = ROWS >= 3  # the other end unseen
    np.testing.assert_array_equal(unobserved_ends_beside(_gaps(0, 2), low, SPEC.graph), ROWS <= 2)
    both = (ROWS >= 2) & (ROWS <= 10)
    np.testing.assert_array_equal(unobserved_ends_beside(_gaps(1, 10), both, SPEC.graph), (ROWS <= 1) | (ROWS >= 11))
    np.testing.assert_array_equal(unobserved_ends_beside(_gaps(11), both, SPEC.graph), ROWS >= 11)


def test_an_implausible_pitch_within_the_observed_rows_doubts_the_frame():
    observed = ROWS <= 9
    assert unobserved_ends_beside(_gaps(4), observed, SPEC.graph) is None  # a row carrying its neighbour's label
    assert unobserved_ends_beside(_gaps(4, 10), observed, SPEC.graph) is None  # one inside is enough
    hidden_middle = observed & (ROWS != 5)  # a row unseen between observed ones: its pitches tell a skipped row
    assert unobserved_ends_beside(_gaps(5), hidden_middle, SPEC.graph) is None
    assert unobserved_ends_beside(_gaps(4), hidden_middle, SPEC.graph) is None
    assert unobserved_ends_beside(np.zeros(GAPS, bool), observed, SPEC.graph) is None
    assert unobserved_ends_beside(_gaps(10), np.zeros(SPEC.n_dots, bool), SPEC.graph) is None
