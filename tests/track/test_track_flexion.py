"""A back at full flexion (the `flexion (lab)` benchmark case): the lumbar rows of the
tape stretch 20-30 % more than its thoracic rows, so the dots' arc positions hold two periods.
The stretch estimate must give the tape's mean pitch (not the lumbar one: a template a row too
long then slid the labels by two rows with perfect residuals), and dots the tracker can only
extrapolate far beyond the rows it sees must flag the frame.

Blobs are projections of dots laid on a curved back (see test_track_stages): no rendering."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tape_scenes import SPEC, blobs, rig_behind, tape_on_back

from spinemocap.track.config import TrackerConfig
from spinemocap.track.continuity import other_shifts
from spinemocap.track.evaluate import label_swaps
from spinemocap.track.lattice import rows_beyond
from spinemocap.track.pipeline import FrameTracker
from spinemocap.track.quality import is_flagged, label_confidence
from spinemocap.track.sequence import SequenceTracker
from spinemocap.track.stretch import estimate_stretch, row_stretch


@dataclasses.dataclass
class _SpecLike:
    graph: object


def flexed_tape(lumbar: float = 1.53, thoracic: float = 1.26) -> np.ndarray:
    """(D, 3) dots of SPEC with the lower half of the row gaps ``lumbar`` times the spec's pitch
    and the upper half ``thoracic`` times it (the truth at the benchmark's full flexion)."""
    n_gaps = SPEC.n_rows - 1
    ratio = np.where(np.arange(n_gaps) < n_gaps // 2, lumbar, thoracic)
    rows_v = np.concatenate([[0.0], np.cumsum(SPEC.row_pitch_mm * ratio)])
    laid = dataclasses.replace(SPEC.graph, uv_mm=np.column_stack([SPEC.graph.uv_mm[:, 0], rows_v[SPEC.graph.row]]))
    return tape_on_back(_SpecLike(laid))


def test_the_stretch_estimate_of_an_unevenly_stretched_tape_is_its_mean_pitch():
    rig = rig_behind()
    dots = flexed_tape()
    cloud = FrameTracker(rig, SPEC).candidates(blobs(rig, dots, noise_px=0.2))
    along = row_stretch(dots, SPEC.graph)[0]
    estimate = estimate_stretch(cloud.points, SPEC)
    assert estimate.source == "data"
    assert estimate.along == pytest.approx(float(np.mean(along)), abs=0.03)  # the periodogram said 1.55
    assert estimate.along_min == pytest.approx(float(along.min()), abs=0.05)
    assert estimate.along_max == pytest.approx(float(along.max()), abs=0.05)


def test_a_flexed_back_keeps_every_label_and_hidden_rows_follow_their_neighbours():
    """Frame 1 sees the whole flexed tape; frame 2 (re-solved in full) hides the last three,
    thoracic rows: the re-solve would lay them with the mean stretch of the rows it sees (the
    lumbar ones, longer), they follow their observed neighbours from frame 1 instead."""
    rig = rig_behind()
    dots = flexed_tape()
    config = TrackerConfig()
    config.sequence.skip_lp = False  # every frame a full re-solve
    sequence = SequenceTracker(FrameTracker(rig, SPEC, config))
    first = sequence.step(blobs(rig, dots, noise_px=0.2), {})
    assert not label_swaps(first.positions[None], dots[None], 15.0).any()
    observed = first.status == "observed"
    assert observed.sum() >= 28
    assert np.linalg.norm(first.positions - dots, axis=1)[observed].max() < 2.0

    moved = dots + [0.0, 0.0, 2.0]
    hidden_rows = SPEC.graph.row >= SPEC.n_rows - 3
    hidden = np.zeros((len(rig), len(dots)), bool)
    hidden[:, hidden_rows] = True
    second = sequence.step(blobs(rig, moved, noise_px=0.2, hidden=hidden), {})
    assert not label_swaps(second.positions[None], moved[None], 15.0).any()
    error = np.linalg.norm(second.positions - moved, axis=1)
    assert error[hidden_rows].max() < 4.0  # laid with the seen rows' mean stretch: ~10 mm at the end
    assert "dot_unanchored" in second.flags


def test_dots_inferred_two_rows_beyond_the_seen_rows_flag_the_frame():
    graph = SPEC.graph
    observed = graph.row <= SPEC.n_rows - 4  # the last three rows hidden
    beyond = rows_beyond(observed, graph) >= 2
    assert set(graph.row[beyond]) == {SPEC.n_rows - 2, SPEC.n_rows - 1}
    assert not (rows_beyond(np.ones(len(observed), bool), graph) >= 1).any()

    rig = rig_behind()
    dots = flexed_tape()
    hidden = np.zeros((len(rig), len(dots)), bool)
    hidden[:, ~observed] = True
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(dots, tracker.candidates(blobs(rig, dots, noise_px=0.2, hidden=hidden)))
    assert result.unanchored is not None and (result.unanchored == beyond).all()
    assert "dot_unanchored" in result.flags and is_flagged(result.flags)


def test_a_row_closer_to_its_neighbour_than_any_pitch_in_the_points_flags_the_frame():
    """The last row carried a third of a pitch toward its neighbour (a row taking its neighbour's
    place on the way to a label shift): inside the range a tape can take (0.68-2.0 x the spec),
    outside the pitches this frame's points show."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    tracker = FrameTracker(rig, SPEC)
    cloud = tracker.candidates(blobs(rig, dots, noise_px=0.2))
    stretch = tracker.measure_stretch(cloud)
    assert "stretch_implausible" not in tracker.add_quality(tracker.assign_status(dots, cloud), cloud, stretch).flags
    result = tracker.assign_status(dots, cloud)
    last = SPEC.graph.row == SPEC.n_rows - 1
    result.positions[last] -= [0.0, 0.0, 0.35 * SPEC.row_pitch_mm]  # the tape runs along +Z
    assert "stretch_implausible" in tracker.add_quality(result, cloud, stretch).flags


def test_an_implausible_pitch_beside_the_unseen_end_rows_doubts_only_their_dots():
    """The last two rows seen by no camera, the model laid the last one 0.6 pitch too far (a
    flexed back's end extrapolated with the wrong stretch): its dots and the unseen row before
    it are doubted, the observed rows keep confidence 1.0 and the frame holds no
    ``stretch_implausible``. The same pitch at a row unseen between observed rows (it may tell
    a skipped row: the labels beyond it) flags the frame."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    tracker = FrameTracker(rig, SPEC)
    stretch = tracker.measure_stretch(tracker.candidates(blobs(rig, dots, noise_px=0.2)))
    for unseen_rows, moved_row, doubts_frame in (((11, 12), 12, False), ((6,), 6, True)):
        unseen = np.isin(SPEC.graph.row, unseen_rows)
        cloud = tracker.candidates(blobs(rig, dots, noise_px=0.2, hidden=np.tile(unseen, (len(rig), 1))))
        result = tracker.assign_status(dots, cloud)
        assert (result.status[unseen] == "inferred").all() and (result.status[~unseen] == "observed").all()
        result.positions[SPEC.graph.row == moved_row] += [0.0, 0.0, 0.6 * SPEC.row_pitch_mm]
        flags = tracker.add_quality(result, cloud, stretch).flags
        assert ("stretch_implausible" in flags) == doubts_frame
        assert is_flagged(flags)
        confidence = label_confidence(result.status, flags, result.dot_flags())
        if doubts_frame:
            assert confidence.max() <= 0.5
        else:
            np.testing.assert_array_equal(result.end_misplaced, unseen)
            assert "dot_end_misplaced" in flags
            assert confidence[unseen].max() <= 0.3 and confidence[~unseen].min() == 1.0


def test_a_capture_that_starts_with_the_tape_end_unseen_doubts_every_label_until_the_rows_show():
    """The first frame of a capture (no previous identity) sees all but the last three rows of
    the flexed tape: a labelling two rows toward the sacrum explains its points as well (the
    benchmark's ``flexion (lab)`` tracked from frame 130 took the wrong one and carried it for 70
    frames, the observed dots at confidence 1.0). No wrongly labelled dot may look trusted: the
    frames are flagged ``identity_unsure`` until the rows come into view, which then give the
    right labels (re-solved) and an unflagged frame."""
    rig = rig_behind()
    dots = flexed_tape(1.4, 1.4)
    sequence = SequenceTracker(FrameTracker(rig, SPEC, TrackerConfig()))
    last_rows = {3: SPEC.graph.row >= SPEC.n_rows - 3, 1: SPEC.graph.row >= SPEC.n_rows - 1}
    results = []
    for k, unseen in enumerate((3, 3, 1, 1)):
        moved = dots + [0.0, 0.0, 1.5 * k]
        hidden = np.repeat(last_rows[unseen][None], len(rig), axis=0)
        result = sequence.step(blobs(rig, moved, noise_px=0.2, hidden=hidden, seed=k), {})
        swapped = label_swaps(result.positions[None], moved[None], 15.0)[0]
        confidence = label_confidence(result.status, result.flags, result.dot_flags())
        assert confidence[swapped].max(initial=0.0) <= 0.5, (k, result.flags)  # wrong labels never look right
        assert "identity_unsure" in result.flags or unseen == 1
        results.append((result, swapped))
    final, swapped = results[-1]
    assert not swapped.any() and not is_flagged(final.flags)


def test_other_shifts_are_the_whole_row_labellings_that_fit_the_observed_dots():
    graph = SPEC.graph
    assert other_shifts(np.ones(SPEC.n_dots, bool), graph) == []
    assert other_shifts(graph.row <= SPEC.n_rows - 4, graph) == [2]  # odd shifts put a C dot on a 2-dot row
    no_centre = (graph.row <= SPEC.n_rows - 2) & (np.asarray(graph.column) != "C")
    assert other_shifts(no_centre, graph) == [1]
