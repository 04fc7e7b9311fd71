"""The tracker on a real back: a tape longer than its spec, an inexact rig, label
continuity through an ambiguous re-solve, and the rig refined on the tracked dots.

Blobs are projections of dots laid on a curved back (see test_track_stages), so the truth is
exact and no rendering is needed."""

from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np
import pytest
from tape_scenes import SPEC, blobs, rig_behind, tape_on_back

from spinemocap.app.run import TrackingWarning, run_tracking
from spinemocap.app.trial_summary import TrialSummary
from spinemocap.camera import Rig
from spinemocap.track.config import TrackerConfig
from spinemocap.track.continuity import relabel_rows, row_shift
from spinemocap.track.evaluate import label_swaps
from spinemocap.track.pipeline import FrameTracker
from spinemocap.track.quality import flagged_from_confidence, is_flagged, label_confidence
from spinemocap.track.rig_check import CalibrationWarning
from spinemocap.track.rig_refine import (
    RigRefineConfig,
    frame_uncertainty_mm,
    given_rig_disagreement_mm,
    refine_rig,
    retriangulate,
)
from spinemocap.track.sequence import SequenceTracker, fill_and_smooth
from spinemocap.track.stretch import estimate_stretch, row_stretch
from spinemocap.views import ViewDots


def stretched_tape(along: float, across: float = 1.0, uneven: float = 0.0, seed: int = 0) -> np.ndarray:
    """(D, 3) dots of SPEC laid ``along``/``across`` times its spacing on the back, each row gap
    varied by up to +-``uneven`` (relative) around ``along``."""
    rng = np.random.default_rng(seed)
    gaps = SPEC.row_pitch_mm * along * (1 + rng.uniform(-uneven, uneven, SPEC.n_rows - 1))
    rows_v = np.concatenate([[0.0], np.cumsum(gaps)])
    laid = dataclasses.replace(SPEC.graph, uv_mm=np.column_stack([SPEC.graph.uv_mm[:, 0] * across,
                                                                  rows_v[SPEC.graph.row]]))
    return tape_on_back(_SpecLike(laid))


@dataclasses.dataclass
class _SpecLike:
    graph: object


def drifting(dots: np.ndarray, n: int, step_mm: float = 2.0) -> list[np.ndarray]:
    return [dots + [0.0, 0.0, step_mm * f] for f in range(n)]


def perturbed(rig: Rig, degrees: float, seed: int = 1) -> Rig:
    """Every camera turned by ``degrees`` about a random axis (the rig a lab would be given)."""
    rng = np.random.default_rng(seed)
    cams = []
    for cam in rig:
        axis = rng.normal(size=3)
        dR = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.deg2rad(degrees))[0]
        cams.append(dataclasses.replace(cam, R=dR @ cam.R, t=dR @ cam.t))
    return Rig(cams)


def reprojection_rms(given: Rig, true_rig: Rig, dots: np.ndarray) -> float:
    """RMS (px) of the true dots' pixels against the given rig's projection of the true dots."""
    err = [np.linalg.norm(g.project(dots) - t.project(dots), axis=1) for g, t in zip(given, true_rig)]
    return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))


def test_stretch_estimate_recovers_the_tape_on_the_body_from_any_spec():
    rig = rig_behind()
    dots = stretched_tape(1.3, 1.1, uneven=0.05)
    cloud = FrameTracker(rig, SPEC).candidates(blobs(rig, dots, noise_px=0.2))
    true_along = float(np.mean(row_stretch(dots, SPEC.graph)[0]))  # on the curved back: > 1.3
    estimate = estimate_stretch(cloud.points, SPEC)
    assert estimate.source == "data"
    assert estimate.along == pytest.approx(true_along, abs=0.03)
    assert estimate.across == pytest.approx(1.1, abs=0.03)
    assert estimate.along_min < true_along < estimate.along_max
    longer_spec = dataclasses.replace(SPEC, row_pitch_mm=SPEC.row_pitch_mm * 1.1)  # spec 10 % longer
    assert estimate_stretch(cloud.points, longer_spec).along * 1.1 == pytest.approx(true_along, abs=0.03)


def test_tracker_keeps_every_label_with_30_percent_tension():
    rig = rig_behind()
    poses = drifting(stretched_tape(1.3, 1.05, uneven=0.04), 3)
    views = [(f, blobs(rig, p, noise_px=0.2, seed=f), 0.0) for f, p in enumerate(poses)]
    truth = np.stack(poses)
    result = run_tracking(iter(views), rig, SPEC, fps=100.0, mode="sequence", progress=False)
    positions = result.table.positions()
    assert not label_swaps(positions, truth, 15.0).any()
    assert np.nanmax(np.linalg.norm(positions - truth, axis=2)) < 1.5
    stretch = result.table.to_arrays().stretch  # markers.csv tells the tension
    assert np.nanmedian(stretch) == pytest.approx(np.median(row_stretch(truth[0], SPEC.graph)[0]), abs=0.02)
    # the tracker without stretch estimation (nominal spacing) loses the tape on the same frame
    with pytest.warns(TrackingWarning):
        before = run_tracking(iter(views[:1]), rig, SPEC, fps=100.0, mode="paper", progress=False,
                              config=TrackerConfig.nominal_unchecked())
    assert not before.frames[0].solved or label_swaps(before.table.positions(), truth[:1], 15.0).mean() > 0.2


def test_tracker_keeps_every_label_with_a_2px_calibration_error_and_names_the_cameras():
    true_rig = rig_behind()
    dots = tape_on_back(SPEC)
    given = perturbed(true_rig, 0.09)
    assert 1.8 < reprojection_rms(given, true_rig, dots) < 2.6  # the studio's --calibration-error 2
    poses = drifting(dots, 3)
    views = [(f, blobs(true_rig, p, noise_px=0.2, seed=f), 0.0) for f, p in enumerate(poses)]
    with pytest.warns(CalibrationWarning, match="cam1") as caught:
        result = run_tracking(iter(views), given, SPEC, fps=100.0, mode="sequence", progress=False)
    assert "candidate gate widened" in str(caught[0].message)
    truth = np.stack(poses)
    assert all(f.solved for f in result.frames)
    assert not label_swaps(result.table.positions(), truth, 15.0).any()
    assert (result.table.to_arrays().status == "observed").mean() > 0.9
    assert result.frames[-1].gate_px > 2.0


def test_an_ambiguous_resolve_keeps_the_previous_labels_and_flags_the_frame():
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    hidden = np.zeros((len(rig), SPEC.n_dots), bool)
    hidden[:, np.isin(SPEC.graph.row, [0, 1, 11, 12])] = True  # both ends hidden: rows 3-11 only
    partial = blobs(rig, dots, noise_px=0.2, hidden=hidden, seed=3)
    config = TrackerConfig()
    config = dataclasses.replace(config, sequence=dataclasses.replace(config.sequence, skip_lp=False))
    # the frame alone: the per-frame pipeline slides the template (9 of 13 rows seen, no images)
    alone = FrameTracker(rig, SPEC, config).solve(partial, previous=None)
    shift, _ = row_shift(alone.positions, dots, SPEC.graph)
    assert shift != 0, "precondition: this partial frame must be ambiguous for the per-frame pipeline"
    # in sequence mode, after a frame that saw the whole tape, the previous identity wins
    seq = SequenceTracker(FrameTracker(rig, SPEC, config))
    first = seq.step(blobs(rig, dots, noise_px=0.2, seed=2), {})
    assert not label_swaps(first.positions[None], dots[None], 15.0).any()
    second = seq.step(partial, {})
    assert "identity_kept" in second.flags
    assert not label_swaps(second.positions[None], dots[None], 15.0).any()
    seen = second.status == "observed"
    assert np.linalg.norm(second.positions[seen] - dots[seen], axis=1).max() < 1.5
    assert is_flagged(second.flags) and not is_flagged(first.flags)
    assert label_confidence(second.status, second.flags).max() <= 0.5  # markers.csv's confidence


def ghost_frame(rig: Rig, dots: np.ndarray, dot: int, offset_mm=(0.0, 12.0, 0.0), seen_by: int = 2) -> list:
    """Blobs of the dots plus a ghost point ``offset_mm`` from dot ``dot`` seen by ``seen_by``
    cameras only (a wrong blob pairing of a poor rig, 12 mm off the tape)."""
    ghost = dots[dot] + np.asarray(offset_mm)
    hidden = np.zeros((len(rig), len(dots) + 1), bool)
    hidden[seen_by:, -1] = True
    return blobs(rig, np.vstack([dots, ghost]), noise_px=0.2, hidden=hidden, seed=5)


def test_a_dot_matched_to_a_ghost_is_moved_back_onto_the_tape_lattice():
    """The 2 px benchmark's one swapped dot: the sequence's prediction strayed ~10 mm, a ghost
    point lay within the observe radius, the true point did not; the dot took the ghost with
    confidence 1.0. Its tape neighbours say where it must be."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    d = SPEC.graph.index("R08C")
    views = ghost_frame(rig, dots, d)
    model = dots.copy()
    model[d] = dots[d] + [0.0, 13.0, 0.0]  # the stray prediction, 1 mm beyond the ghost
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(views))
    assert np.linalg.norm(result.positions[d] - dots[d]) < 1.0  # the true point, not the ghost
    assert result.status[d] == "observed" and result.relocated[d] and result.relocated.sum() == 1
    assert "dot_relocated" in result.flags and not is_flagged(result.flags)
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    assert confidence[d] == pytest.approx(0.8) and np.delete(confidence, d).min() == 1.0
    # without the lattice check the ghost is taken: 12 mm off, nearer nothing, confidence 1.0
    config = TrackerConfig()
    unchecked = FrameTracker(rig, SPEC, dataclasses.replace(config, status=dataclasses.replace(config.status, lattice_check=False)))
    wrong = unchecked.assign_status(model, unchecked.candidates(views))
    assert np.linalg.norm(wrong.positions[d] - dots[d]) > 10.0 and not wrong.flags


def test_an_end_dot_placed_by_extrapolation_flags_the_frame():
    """The last row's dot strayed 15 mm off the tape, its blobs hidden and its row partner lost:
    it is put back where the rows below extrapolate, and the frame is flagged (its label and
    place are not vouched for)."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    end = np.flatnonzero(SPEC.graph.row == SPEC.n_rows - 1)
    hidden = np.zeros((len(rig), len(dots)), bool)
    hidden[:, end] = True
    tracker = FrameTracker(rig, SPEC)
    model = dots.copy()
    model[end[0]] += [0.0, 15.0, 0.0]
    model[end[1]] = np.nan
    result = tracker.assign_status(model, tracker.candidates(blobs(rig, dots, noise_px=0.2, hidden=hidden)))
    assert result.extrapolated[end[0]] and result.extrapolated.sum() == 1
    assert result.status[end[0]] == "inferred"
    assert np.linalg.norm(result.positions[end[0]] - dots[end[0]]) < 3.0
    assert is_flagged(result.flags)
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    assert flagged_from_confidence(np.array(result.status)[None], confidence[None])[0]  # markers.csv tells it


def test_a_relocated_dot_beyond_the_observed_rows_is_extrapolated_whatever_the_model_laid_beyond():
    """The last three rows seen by no camera, the model laid the first of them 15 mm off its
    neighbours' lattice: the dot is put back where the lattice extrapolates it, a place the
    model's rows beyond it (inferred, no evidence) do not bear out, so its label is doubted
    (``dot_extrapolated``); the rows observed keep confidence 1.0."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    unseen = SPEC.graph.row >= SPEC.n_rows - 3
    d = np.flatnonzero(SPEC.graph.row == SPEC.n_rows - 3)[0]
    tracker = FrameTracker(rig, SPEC)
    model = dots.copy()
    model[d] += [0.0, 15.0, 0.0]
    result = tracker.assign_status(model, tracker.candidates(blobs(rig, dots, noise_px=0.2, hidden=np.tile(unseen, (len(rig), 1)))))
    assert (result.status[unseen] == "inferred").all() and (result.status[~unseen] == "observed").all()
    assert result.relocated[d] and result.extrapolated[d] and result.extrapolated.sum() == 1
    assert not result.unanchored[d]  # one row out: the unanchored check leaves it
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    assert confidence[d] == pytest.approx(0.6 * 0.8 * 0.5)
    assert flagged_from_confidence(np.array(result.status)[None, [d]], confidence[None, [d]])[0]
    assert confidence[~unseen].min() == 1.0


def _column_shifted(dots: np.ndarray, shifted: np.ndarray, step: tuple[str, str]) -> np.ndarray:
    """The truth with the ``shifted`` (D,) bool dots moved by one column (from dot ``step[0]``'s
    place to ``step[1]``'s): a model that laid an end of the tape a column aside."""
    model = dots.copy()
    model[shifted] += dots[SPEC.graph.index(step[1])] - dots[SPEC.graph.index(step[0])]
    return model


def _unchecked_tracker(rig: Rig) -> FrameTracker:
    config = TrackerConfig()
    return FrameTracker(rig, SPEC, dataclasses.replace(
        config, status=dataclasses.replace(config.status, observed_lattice_limit=0.0, detached_max_dots=0)))


def _vouched_swaps(result, dots: np.ndarray) -> np.ndarray:
    """(D,) bool: dots given a neighbour's place whose confidence does not doubt them."""
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    doubted = flagged_from_confidence(np.array(result.status)[:, None], confidence[:, None])
    swapped = label_swaps(result.positions[None], dots[None], float(SPEC.graph.rest_length_mm.min()))[0]
    return swapped & ~doubted & (result.status != "missing")


def test_a_lone_observed_dot_on_its_row_neighbours_point_is_not_vouched_for():
    """The held-out look's frame 21: two cameras saw the tape, the sacral rows barely; the model
    laid them a column aside and R02L took R02C's point (two views, 0.2 px residual), the
    inferred dots around it following. The other observed dots' lattice puts R02L a dot
    spacing away."""
    rig = rig_behind(2)
    dots = tape_on_back(SPEC)
    rows = SPEC.graph.row
    seen = (rows >= 3) | np.isin(np.arange(len(dots)), [SPEC.graph.index("R02C"), SPEC.graph.index("R03R")])
    views = blobs(rig, dots, noise_px=0.2, hidden=np.repeat(~seen[None], len(rig), axis=0))
    model = _column_shifted(dots, rows <= 1, ("R02L", "R02C"))
    lone = SPEC.graph.index("R02L")
    unchecked = _unchecked_tracker(rig)
    before = unchecked.assign_status(model, unchecked.candidates(views))
    swapped = _vouched_swaps(before, dots)  # R02L, and the inferred R01L and R02C laid beside it
    assert before.status[lone] == "observed" and swapped[lone] and (before.status[swapped] == "inferred").sum() == 2
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(views))
    assert result.unsupported[lone] and "dot_unsupported" in result.flags and is_flagged(result.flags)
    assert not _vouched_swaps(result, dots).any()
    # the observed dots on their own points are not doubted, the inferred ones beside R02L are
    assert (result.status[result.unsupported] == "inferred").sum() == result.unsupported.sum() - 1


def test_a_small_group_of_observed_dots_beyond_an_unseen_row_is_not_vouched_for():
    """The held-out look's frame 8: row 11 unseen by any camera pair, two dots of row 12 seen by
    three; the carried model had moved the rows beyond the gap a column aside, R12L and R12C took
    R12C's and R12R's points and agree with each other (and with the inferred dots around them)."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    rows = SPEC.graph.row
    seen = (rows <= 9) | np.isin(np.arange(len(dots)), [SPEC.graph.index("R12C"), SPEC.graph.index("R12R")])
    views = blobs(rig, dots, noise_px=0.2, hidden=np.repeat(~seen[None], len(rig), axis=0))
    model = _column_shifted(dots, rows >= 10, ("R12L", "R12C"))
    group = [SPEC.graph.index("R12L"), SPEC.graph.index("R12C")]
    unchecked = _unchecked_tracker(rig)
    before = unchecked.assign_status(model, unchecked.candidates(views))
    swapped = _vouched_swaps(before, dots)  # the group, and inferred dots laid beside it
    assert swapped[group].all() and (before.status[swapped] == "inferred").sum() == swapped.sum() - 2
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(views))
    assert result.unsupported[group].all() and is_flagged(result.flags)
    assert (result.status[result.unsupported] == "observed").sum() == 2  # rows 1-10 on their points are not doubted
    assert not _vouched_swaps(result, dots).any()
    # every dot seen on its own point: nothing is doubted
    whole = tracker.assign_status(dots, tracker.candidates(blobs(rig, dots, noise_px=0.2)))
    assert not whole.unsupported.any() and not is_flagged(whole.flags)


def test_the_end_rows_lone_observed_dots_on_their_neighbours_points_are_not_vouched_for():
    """A carried frame at the tape's top end: rows 12 and 13 hold one observed dot each, R12L on
    R12C's point and R13L on R13R's (three views each, their row neighbours and R11L unseen by
    any camera pair), the model's other dots of those rows half a column aside. The two wrong
    dots bear each other out: the worse (R13L) is off the other observed dots' lattice, and
    without it R12L lies a dot spacing off."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    rows = SPEC.graph.row
    index = SPEC.graph.index
    seen = (rows <= 9) | np.isin(np.arange(len(dots)), [index(x) for x in ("R11R", "R12C", "R13R")])
    views = blobs(rig, dots, noise_px=0.2, hidden=np.repeat(~seen[None], len(rig), axis=0))
    column = dots[index("R12C")] - dots[index("R12L")]
    model = dots.copy()
    model[index("R12L")], model[index("R13L")] = dots[index("R12C")], dots[index("R13R")]
    model[[index("R12C"), index("R13R")]] += 0.5 * column
    lone = [index("R12L"), index("R13L")]
    unchecked = _unchecked_tracker(rig)
    before = unchecked.assign_status(model, unchecked.candidates(views))
    assert (before.status[lone] == "observed").all() and _vouched_swaps(before, dots)[lone].all()
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(views))
    assert result.unsupported[lone].all() and is_flagged(result.flags)
    assert not _vouched_swaps(result, dots).any()
    # the observed dots of rows 1-11 (row index 0-10), on their own points, are not doubted
    assert not result.unsupported[(rows <= 10) & (result.status == "observed")].any()


def test_relabel_rows_maps_a_two_row_shift_back_exactly():
    dots = tape_on_back(SPEC)
    shifted = relabel_rows(dots, SPEC.graph, -2)  # labels moved two rows toward the sacrum
    assert row_shift(shifted, dots, SPEC.graph)[0] == 2
    back = relabel_rows(shifted, SPEC.graph, 2)
    ok = np.isfinite(back).all(axis=1)
    assert ok.sum() == SPEC.n_dots - 5  # the two end rows have no source
    assert np.allclose(back[ok], dots[ok])


def test_refine_rig_lowers_the_residual_of_a_perturbed_rig():
    true_rig = rig_behind()
    given = perturbed(true_rig, 0.09, seed=1)
    poses = [p + [3.0 * f, 0.0, 0.0] for f, p in enumerate(drifting(tape_on_back(SPEC), 4, 5.0))]
    views = [(f, blobs(true_rig, p, noise_px=0.1, seed=f), 0.0) for f, p in enumerate(poses)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        result = run_tracking(iter(views), given, SPEC, fps=100.0, mode="sequence", progress=False)
    refinement = refine_rig(given, result.pixels(), result.table.positions(), 100.0, RigRefineConfig())
    assert refinement.before_px["all"] > 1.0  # triangulation spreads the 2 px over the views
    assert refinement.after_px["all"] < 0.3 * refinement.before_px["all"]
    assert set(refinement.after_px) == {"cam1", "cam2", "cam3", "cam4", "all"}


def test_refine_rig_recovers_from_a_3px_rig():
    """At 3 px every residual lies far in the Huber loss's linear part; the solver must
    not stall there and hand the given rig back unchanged."""
    true_rig = rig_behind()
    poses = [p + [3.0 * f, 0.0, 0.0] for f, p in enumerate(drifting(tape_on_back(SPEC), 6, 5.0))]
    given = perturbed(true_rig, 0.14, seed=1)
    assert 2.6 < reprojection_rms(given, true_rig, poses[0]) < 3.6
    rng = np.random.default_rng(0)
    pixels = np.stack([np.stack([cam.project(p) + rng.normal(0, 0.1, (len(p), 2)) for cam in true_rig], axis=1)
                       for p in poses])  # (F, D, C, 2)
    refinement = refine_rig(given, pixels, np.stack(poses), 100.0, RigRefineConfig())
    assert refinement.before_px["all"] > 1.5
    assert refinement.after_px["all"] < 0.3


def test_the_refined_rig_reports_how_far_the_given_cameras_disagree():
    """A world similarity (invisible to the dots) is undone exactly by the closest gauge; a
    camera moved on its own shows up as disagreement and as frame uncertainty."""
    rig = rig_behind()
    turn = cv2.Rodrigues(np.array([0.01, -0.02, 0.015]))[0]
    moved = rig.transformed(turn, np.array([30.0, -12.0, 5.0]), 1.002)
    assert given_rig_disagreement_mm(moved, rig, 20.0, 0.5).max() < 1e-6
    shifted = Rig([dataclasses.replace(c, t=c.t - c.R @ np.array([0.0, 0.0, 6.0])) if k == 2 else c
                   for k, c in enumerate(rig)])  # camera 3's centre 6 mm off, its orientation kept
    disagreement = given_rig_disagreement_mm(moved, shifted, 20.0, 0.5)
    assert disagreement[2] == disagreement.max() and 2.0 < disagreement[2] < 6.0
    assert 0.5 < frame_uncertainty_mm(disagreement) < 6.0


def test_the_report_lists_flagged_frames_from_markers_csv(tmp_path):
    import exporters
    from spinemocap.app.report import tracking_quality_table
    from spinemocap.markers import MarkerTable

    dots = np.stack(drifting(tape_on_back(SPEC), 4))
    status = np.full(dots.shape[:2], "observed", dtype=object)
    flags = [[], ["identity_kept"], [], ["stretch_carried"]]  # frame 1 flagged, frame 3 only mildly
    confidence = np.stack([label_confidence(s, f) for s, f in zip(status, flags)])
    table = MarkerTable.from_arrays(SPEC.labels, dots, 100.0, status=status, confidence=confidence,
                                    stretch=np.ones(dots.shape[:2]))
    exporters.write(table, tmp_path / "markers.csv")
    results = [TrialSummary(key="s1/t1", subject="s1", condition="", trial="t1", capture=str(tmp_path),
                            source="tracked", status="ok", reason="", out_dir=str(tmp_path))]
    quality = tracking_quality_table(results)
    assert quality.to_dict("records") == [{"key": "s1/t1", "flagged_frames": 1, "of_frames": 4, "frames": "1",
                                          "median_stretch": 1.0}]
    exporters.write(MarkerTable.from_arrays(SPEC.labels, dots, 100.0), tmp_path / "markers.csv")
    assert tracking_quality_table(results).empty  # nothing flagged (no confidence known): no section


def test_an_unobserved_tape_end_placed_by_the_model_alone_flags_its_dots_and_the_frame():
    """The 3 px benchmark's silent swaps: the tape's last rows seen by no camera pair, the model
    (a re-solve) put them off together, so they agree with one another and the lattice check
    passes them; labels a dot spacing off with no flag. Dots two or more rows beyond the last
    observed row are placed by extrapolation alone: flagged per dot and per frame."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    top = SPEC.n_rows - 1
    hidden = np.zeros((len(rig), len(dots)), bool)
    hidden[:, SPEC.graph.row >= top - 2] = True  # the last three rows unseen
    end = SPEC.graph.row >= top - 2
    model = dots.copy()  # the end bent sideways, 8 mm more per row (as the re-solve did at 3 px)
    model[:, 0] += 8.0 * np.clip(SPEC.graph.row - (top - 3), 0, None)
    views = blobs(rig, dots, noise_px=0.2, hidden=hidden)
    config = TrackerConfig()
    unchecked = FrameTracker(rig, SPEC, dataclasses.replace(config, status=dataclasses.replace(config.status, unanchored_rows=0)))
    silent = unchecked.assign_status(model, unchecked.candidates(views))
    assert label_swaps(silent.positions[None], dots[None], 15.0)[0][end].sum() >= 2  # precondition: wrong labels...
    assert not is_flagged(silent.flags)  # ... that passed every other check
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(views))
    assert (result.status[end] == "inferred").all() and (result.status[~end] == "observed").mean() > 0.9
    beyond_two = SPEC.graph.row >= top - 1  # one row out stays unflagged (extrapolation holds there)
    np.testing.assert_array_equal(result.unanchored, beyond_two)
    assert "dot_unanchored" in result.flags and is_flagged(result.flags)
    confidence = label_confidence(result.status, result.flags, result.dot_flags())
    assert confidence[beyond_two].max() == pytest.approx(0.3)
    assert confidence[~end & (result.status == "observed")].min() == 1.0
    assert flagged_from_confidence(np.array(result.status)[None], confidence[None])[0]  # markers.csv tells it
    # the peer (no stretch estimation) keeps the check off
    assert TrackerConfig.nominal_unchecked().status.unanchored_rows == 0


def test_a_resolve_after_an_unsolved_frame_with_an_unseen_tape_end_is_flagged():
    """In sequence mode, after a frame without a solution, the re-solve of a frame whose last
    four rows no camera sees (too few dots for the previous frame to explain it): the re-solve
    slides the template by 4 rows; the previous identity is kept (all 4 rows back, not only 2),
    and the unseen end rows, extrapolated from the rows seen, are flagged per dot in the markers'
    confidence and per frame."""
    rig = rig_behind()
    poses = drifting(tape_on_back(SPEC), 3)
    hidden = np.zeros((len(rig), SPEC.n_dots), bool)
    hidden[:, SPEC.graph.row >= SPEC.n_rows - 4] = True
    views = [(0, blobs(rig, poses[0], noise_px=0.2, seed=0), 0.0),
             (1, [ViewDots(c, np.zeros((0, 2)), np.zeros(0)) for c in range(len(rig))], 0.0),
             (2, blobs(rig, poses[2], noise_px=0.2, hidden=hidden, seed=2), 0.0)]
    with pytest.warns(TrackingWarning):
        result = run_tracking(iter(views), rig, SPEC, fps=100.0, mode="sequence", progress=False)
    assert not result.frames[1].solved and result.frames[2].route == "full"
    last = result.frames[2]
    assert "identity_kept" in last.flags and "dot_unanchored" in last.flags and 2 in result.flagged_frames()
    swapped = label_swaps(last.positions[None], poses[2][None], 15.0)[0]
    assert not swapped[~last.unanchored].any()  # the rows seen keep their labels; the rest is flagged
    np.testing.assert_array_equal(last.unanchored, SPEC.graph.row >= SPEC.n_rows - 3)
    arrays = result.table.to_arrays()
    assert flagged_from_confidence(arrays.status, arrays.confidence).tolist() == [False, True, True]


def test_a_tape_end_the_model_left_off_its_points_is_anchored_back_on_them():
    """``tension 30 % + skin``, frame 12: the model left the last two rows 8-20 mm off while
    their points (>= 3 cameras) were there, beyond the observe radius: inferred, silently wrong.
    Row by row outward, the observed dots' lattice finds them."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    top = SPEC.n_rows - 1
    end = SPEC.graph.row >= top - 1
    model = dots.copy()
    model[:, 2] += 10.0 * np.clip(SPEC.graph.row - (top - 2), 0, None)  # 10, 20 mm out along the tape
    tracker = FrameTracker(rig, SPEC)
    result = tracker.assign_status(model, tracker.candidates(blobs(rig, dots, noise_px=0.2)))
    assert (result.status == "observed").all() and result.relocated[end].all()
    assert np.linalg.norm(result.positions - dots, axis=1).max() < 1.0
    assert not result.unanchored.any() and not is_flagged(result.flags)
    config = TrackerConfig()
    off = FrameTracker(rig, SPEC, dataclasses.replace(config, status=dataclasses.replace(config.status, anchor_ends=False)))
    left = off.assign_status(model, off.candidates(blobs(rig, dots, noise_px=0.2)))
    assert (left.status[end] == "inferred").all() and is_flagged(left.flags)


def test_smoothing_does_not_carry_a_flagged_frames_dots_into_its_neighbours():
    """The 3 px capture's unflagged swaps: a flagged frame's end rows, 26-37 mm off, averaged into
    the next frame's inferred rows moved them 9-10 mm, onto their neighbours' places."""
    positions = np.zeros((5, 1, 3))
    positions[3, 0, 0] = 30.0  # frame 3: the dot placed 30 mm off, the frame flagged
    status = np.full((5, 1), "inferred", dtype=object)
    doubted = np.zeros((5, 1), bool)
    doubted[3] = True
    config = TrackerConfig().sequence
    blind, _ = fill_and_smooth(positions, status, config)
    assert blind[2, 0, 0] == pytest.approx(10.0)  # without the flags: the good frame pulled 10 mm
    out, _ = fill_and_smooth(positions, status, config, doubted)
    assert out[2, 0, 0] == 0.0 and out[4, 0, 0] == 0.0  # the frames beside it keep their places
    assert out[3, 0, 0] == pytest.approx(10.0)  # the flagged one still averages with them
    moving = positions.copy()
    moving[:, 0, 2] = 10.0 * np.arange(5)  # moving 10 mm a frame: a trusted frame's mean is unbiased
    np.testing.assert_allclose(fill_and_smooth(moving, status, config, doubted)[0][[1, 2, 4], 0, 2], [10.0, 20.0, 40.0])


def test_retriangulation_keeps_no_point_that_misses_its_own_blobs():
    """Under a refined rig an observed dot is re-triangulated from its blobs; one whose point misses
    a blob by more than ``max_reprojection_px`` (here a blob 40 px off in one of three cameras) is
    not taken: it moves with the frame's similarity like an inferred dot."""
    rig = rig_behind()
    dots = tape_on_back(SPEC)
    pixels = np.stack([cam.project(dots) for cam in rig], axis=1)[None]  # (1, D, C, 2)
    pixels[0, :, 3] = np.nan  # three cameras per dot
    pixels[0, 5, 0] += (40.0, 0.0)
    status = np.full((1, len(dots)), "observed", dtype=object)
    shifted = dots[None] + (0.7, -0.4, 0.3)  # where the given rig had put them
    out = retriangulate(rig, pixels, shifted, status)
    others = np.arange(len(dots)) != 5
    assert np.abs(out[0, others] - dots[others]).max() < 1e-3  # re-triangulated from exact blobs
    assert np.linalg.norm(out[0, 5] - dots[5]) < 0.05  # moved with the others' similarity
    kept = retriangulate(rig, pixels, shifted, status, max_reprojection_px=np.inf)
    assert np.linalg.norm(kept[0, 5] - dots[5]) > 3.0  # taken as triangulated: the check mattered
