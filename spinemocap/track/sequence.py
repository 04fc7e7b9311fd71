"""Sequence tracking, beyond the paper (its own future work): carry identities and state from
frame to frame.

Per frame (``mode = "sequence"``):
1. predict every dot from the last two solved frames (constant velocity);
2. if the predicted dots find candidate points (>= 2 views) within ``match_radius_mm`` for at
   least ``min_explained`` of the dots (a dot the last frame inferred, whose prediction is the
   model's place moved on, may instead find its point where this frame's matched dots' lattice
   puts it), and the matched dots keep tape-like solid-edge lengths,
   the previous solution "explains" the frame: the LP and MRF1 are skipped, matched dots take
   their triangulated points and the others follow their observed tape neighbours (a locally
   weighted affine map from the flat tape to 3D), then MRF2 refines them on the images;
3. otherwise the full per-frame pipeline runs with the previous dots handed to MRF1, which
   orients the template by them (labels survive handstands) and warm-starts from them; a
   re-solve that relabels the tape by whole rows against the prediction is overruled unless the
   evidence is unambiguous (:mod:`spinemocap.track.continuity`: previous identity kept, frame
   flagged ``identity_kept``; accepted shifts are flagged ``relabelled``).
The first frame's identity comes from that frame alone: while the rows observed so far admit
another whole-row labelling (one end of the tape unseen, e.g. a capture that starts at full
flexion; :func:`~spinemocap.track.continuity.other_shifts`), every frame is flagged
``identity_unsure`` and a carried frame that leaves strong points unlabelled beyond an end of the
tape is re-solved, so that the rows coming into view correct the labels (``pin_identity``).
Both routes work with the frame's measured dot spacing (:mod:`spinemocap.track.stretch`).
After the sequence, short gaps (frames without a solution) are interpolated in time and
inferred stretches smoothed (:func:`fill_and_smooth`).
"""

from __future__ import annotations

import numpy as np

from ..markers import INFERRED, OBSERVED
from ..tape import TapeSpec
from ..timing import StageTimer
from ..views import ViewDots
from .ahead import FrameCandidates
from .config import SequenceConfig
from .continuity import other_shifts, relabel_rows, row_shift, shift_is_unambiguous
from .edges import edge_bounds
from .lattice import affine_from_neighbours, rows_beyond
from .pipeline import FrameResult, FrameTracker, match_points
from .quality import DOT_FLAG_FACTORS
from .stretch import StretchEstimate
from .types import CandidateCloud


class SequenceTracker:
    """Stateful wrapper around a :class:`FrameTracker`; call :meth:`step` once per frame."""

    def __init__(self, tracker: FrameTracker):
        self.tracker = tracker
        self.config: SequenceConfig = tracker.config.sequence
        self.last: np.ndarray | None = None  # (D, 3) dots of the last solved frame
        self.before_last: np.ndarray | None = None
        self.last_observed: np.ndarray | None = None  # (D,) bool: the last solved frame's observed dots
        self.uv = tracker.graph.uv_mm
        self.solid = tracker.graph.solid_edges
        self.pinned = False  # the identity told by the observed rows (no other labelling fits them)

    def predict(self) -> np.ndarray:
        """Constant-velocity prediction (mm) from the last two solved frames (the last one alone
        after the first). Raises RuntimeError before any frame is solved."""
        if self.last is None:
            raise RuntimeError("no frame solved yet: nothing to predict from")
        if self.before_last is None:
            return self.last.copy()
        velocity = np.nan_to_num(self.last - self.before_last)
        return self.last + velocity

    def step(self, views: list[ViewDots], stage_ms: dict, ahead: FrameCandidates | None = None) -> FrameResult:
        """Track one frame. ``ahead``: its candidate stage built ahead (taken where it serves,
        :meth:`FrameTracker.candidates`)."""
        timer = StageTimer(stage_ms)
        with timer("candidates"):
            cloud = self.tracker.candidates(views, ahead)
            reading = ahead.stretch if ahead is not None and cloud is ahead.cloud else None
            stretch = self.tracker.measure_stretch(cloud, reading)
        tape = self.tracker.frame_tape(stretch)
        result = None
        if self.last is not None and self.config.skip_lp:
            result = self._carry(views, cloud, timer, tape)
            if result is not None:
                self.tracker.add_quality(result, cloud, stretch)
                if self._identity_unsure() and "unlabelled_dots" in result.flags:
                    result = None  # dots beyond the labelled end may tell the identity: re-solve
        if result is None:
            result = self._solve_full(views, cloud, stage_ms, stretch)
        result.stage_ms = stage_ms
        self._pin_identity(result)
        self._remember(result)
        return result

    # ------------------------------------------------------------------ identity
    def _identity_unsure(self) -> bool:
        return self.config.pin_identity and not self.pinned

    def _pin_identity(self, result: FrameResult) -> None:
        """Until the observed rows of a frame admit no other whole-row labelling, flag every frame
        ``identity_unsure``: the labels were chosen on a first frame that could not tell them (a
        capture starting at full flexion with the top rows unseen: two labellings two rows apart
        can score almost alike, and the wrong one would be carried unflagged)."""
        if not self._identity_unsure() or not result.solved:
            return
        if other_shifts(result.status == OBSERVED, self.tracker.graph):
            result.flags.append("identity_unsure")
            result.note = result.note or "no frame so far has seen enough rows to tell the labels from a shift by whole rows"
        else:
            self.pinned = True

    # ------------------------------------------------------------------ routes
    def _solve_full(self, views, cloud: CandidateCloud, stage_ms: dict, stretch: StretchEstimate) -> FrameResult:
        warm_start = self.last is not None and self.config.warm_start
        result = self.tracker.solve(views, previous=self.last, cloud=cloud, stage_ms=stage_ms,
                                    warm_start=warm_start, stretch=stretch)
        if self.last is None or not result.solved:
            return result
        if self.config.keep_identity:
            result = self._keep_identity(result, views, cloud, stretch, stage_ms)
        if self.config.follow_hidden_rows and "relabelled" not in result.flags:
            self._hidden_rows_follow(result)
        return result

    def _hidden_rows_follow(self, result: FrameResult, sigma_mm: float = 30.0) -> None:
        """Unobserved dots beyond the re-solve's outermost observed rows move with the observed
        dots near them on the tape (the predicted dots shifted by their Gaussian-weighted mean
        displacement, ``sigma_mm`` on the tape), in place of the re-solve's placement. The
        re-solve lays hidden rows with the mean stretch of the rows it sees, which at full
        flexion (lumbar rows 20-30 % longer than thoracic ones) overshoots by a row within
        three rows; the last frames saw them with their own stretch. A dot moved more than half
        the smallest dot spacing from the re-solve's place is marked unanchored
        (``result.unanchored``, flag ``dot_unanchored``): the last frames' labels there may be
        wrong (a doubted frame's)."""
        predicted = self.predict()
        observed = result.status == OBSERVED
        hidden = ~observed & (rows_beyond(observed, self.tracker.graph) >= 1) & np.isfinite(predicted).all(axis=1)
        moved = observed & np.isfinite(predicted).all(axis=1)
        if not hidden.any() or moved.sum() < 3:
            return
        shift = result.positions[moved] - predicted[moved]
        gap = self.uv[hidden][:, None, :] - self.uv[moved][None, :, :]
        w = np.exp(-0.5 * (gap**2).sum(axis=2) / sigma_mm**2) + 1e-12
        followed = predicted[hidden] + (w @ shift) / w.sum(axis=1, keepdims=True)
        # the re-solve and the last frames' motion disagree on these dots by more than half a dot
        # spacing: one of them has the wrong dot there, and nothing observed tells which
        limit = 0.5 * self.tracker.graph.min_spacing_mm
        apart = np.zeros(len(hidden), bool)
        apart[hidden] = ~(np.linalg.norm(followed - result.positions[hidden], axis=1) <= limit)
        result.positions[hidden] = followed
        if apart.any():
            result.unanchored = apart if result.unanchored is None else result.unanchored | apart
            if "dot_unanchored" not in result.flags:
                result.flags.append("dot_unanchored")

    def _keep_identity(self, result: FrameResult, views, cloud: CandidateCloud, stretch: StretchEstimate,
                       stage_ms: dict) -> FrameResult:
        """Check a re-solve's labels against the prediction (see module): unchanged, accepted
        as ``relabelled``, or relabelled back to the previous identity (``identity_kept``)."""
        graph = self.tracker.graph
        predicted = self.predict()
        shift, _ = row_shift(result.positions, predicted, graph, self.config.max_row_shift)
        if shift == 0:
            return result
        if shift_is_unambiguous(result.status == OBSERVED, graph, shift):
            result.flags.append("relabelled")
            result.note = f"labels moved by {shift} row(s) against the previous frame (the cameras demand it)"
            return result
        timer = StageTimer(stage_ms)
        tape = self.tracker.frame_tape(stretch)
        with timer("status"):
            model = relabel_rows(result.positions, graph, shift)
            known = np.isfinite(model).all(axis=1)
            if known.sum() >= 3 and not known.all():
                model[~known] = self._follow_neighbours(model, predicted, known)
            elif not known.all():
                model[~known] = predicted[~known]
        usable = np.nonzero(cloud.n_views >= 2)[0] if len(cloud) else np.zeros(0, np.int64)
        with timer("mrf2"):
            model = self.tracker.refine(model, views, cloud.points[usable], tape=tape)
        with timer("status"):
            kept = self.tracker.assign_status(model, cloud)
        kept.route, kept.lp_status, kept.lp_time_limited = result.route, result.lp_status, result.lp_time_limited
        dot_level = {"unlabelled_dots", *DOT_FLAG_FACTORS}  # the re-solve's, not kept's
        kept.flags = [f for f in result.flags if f not in dot_level] + kept.flags + ["identity_kept"]
        kept.note = f"the re-solve moved the labels by {shift} row(s); the previous identity was kept"
        kept.stretch, kept.gate_px = result.stretch, result.gate_px
        return kept

    def _carry(self, views, cloud: CandidateCloud, timer: StageTimer, tape: TapeSpec) -> FrameResult | None:
        """The previous solution moved onto this frame's points, or None if it does not fit."""
        with timer("status"):
            predicted = self.predict()
            usable = np.nonzero(cloud.n_views >= 2)[0] if len(cloud) else np.zeros(0, np.int64)
            match = match_points(predicted, cloud.points[usable], self.config.match_radius_mm)
            seen = match >= 0
            positions = predicted.copy()
            positions[seen] = cloud.points[usable[match[seen]]]
            seen |= self._match_inferred_on_lattice(positions, seen, cloud.points[usable], match)
            if seen.mean() < self.config.min_explained:
                return None
            if not self._tape_like(positions, seen, edge_bounds(tape, self.tracker.config.edges)):
                return None
            positions[~seen] = self._follow_neighbours(positions, predicted, seen)
        if (~seen).any() and self.config.refine_skipped:
            with timer("mrf2"):
                positions = self.tracker.refine(positions, views, cloud.points[usable], tape=tape)
        with timer("status"):
            result = self.tracker.assign_status(positions, cloud)
        result.route, result.lp_status = "carried", "skipped"
        return result

    def _match_inferred_on_lattice(self, positions: np.ndarray, seen: np.ndarray, points: np.ndarray,
                                   match: np.ndarray) -> np.ndarray:
        """(D,) bool: the dots the last frame inferred that found no point near their prediction
        (``seen`` (D,) bool: the dots matched, ``match`` (D,) their index in ``points`` (N, 3) mm,
        -1 none), lie between the matched rows or one row beyond them, and find an unclaimed
        point within ``match_radius_mm`` of where the matched dots' lattice puts them
        (:func:`.lattice.affine_from_neighbours`, weights of ``status.lattice_sigma_mm``; the
        lattice holds a row out, not several). ``positions`` (D, 3) mm and ``match`` are updated
        in place for them. An inferred dot's prediction is the model's place moved by a velocity
        made of two such places: off by more than the radius at a tape end the cameras lose,
        though its point is there; the lattice of the dots tracked beside it is not."""
        found = np.zeros(len(seen), bool)
        if self.last_observed is None or seen.sum() < 3:
            return found
        targets = np.flatnonzero(~seen & ~self.last_observed & (rows_beyond(seen, self.tracker.graph) <= 1))
        free = np.setdiff1d(np.arange(len(points)), match[seen])
        if not len(targets) or not len(free):
            return found
        where = affine_from_neighbours(self.uv, positions, seen, targets, self.tracker.config.status.lattice_sigma_mm)
        extra = match_points(where, points[free], self.config.match_radius_mm)
        hit = extra >= 0
        match[targets[hit]] = free[extra[hit]]
        positions[targets[hit]] = points[free[extra[hit]]]
        found[targets[hit]] = True
        return found

    def _tape_like(self, positions: np.ndarray, seen: np.ndarray, bounds: tuple[float, float]) -> bool:
        """Solid edges between matched dots all have lengths within ``bounds`` (th3, th4)."""
        both = seen[self.solid[:, 0]] & seen[self.solid[:, 1]]
        if not both.any():
            return False
        e = self.solid[both]
        lengths = np.linalg.norm(positions[e[:, 0]] - positions[e[:, 1]], axis=1)
        return bool(((lengths > bounds[0]) & (lengths < bounds[1])).all())

    def _follow_neighbours(self, positions, predicted, seen, sigma_mm: float = 30.0) -> np.ndarray:
        """Unmatched dots from this frame's matched dots alone (no drift from earlier frames): the
        tape's local lattice (:func:`.lattice.affine_from_neighbours`) at each unmatched dot;
        the prediction where it cannot be made."""
        out = affine_from_neighbours(self.uv, positions, seen, np.flatnonzero(~seen), sigma_mm)
        bad = ~np.isfinite(out).all(axis=1)
        out[bad] = predicted[~seen][bad]
        return out

    def _remember(self, result: FrameResult) -> None:
        if not result.solved:
            self.before_last = None  # velocity across a gap is unknown
            return
        # across an accepted relabelling the labels' velocity is rows, not motion
        self.before_last = None if "relabelled" in result.flags else self.last
        self.last = result.positions.copy()
        self.last_observed = result.status == OBSERVED


def fill_and_smooth(positions: np.ndarray, status: np.ndarray, config: SequenceConfig,
                    doubted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Post-process a tracked sequence (F, D, 3) / (F, D): interpolate gaps of up to
    ``gap_fill_frames`` frames linearly in time (status ``inferred``), then replace inferred
    samples by a centred moving average of width ``smooth_inferred`` over the finite samples.
    ``doubted`` (F, D) bool (with ``smooth_trusted_only``): samples the tracker does not vouch
    for (flagged frames, frames without a solution) enter no trusted sample's average (those
    beside them keep their own places), so that a flagged frame's wrong end rows are not carried
    into the frames beside it."""
    positions, status = positions.copy(), status.copy()
    F = len(positions)
    frames = np.arange(F)
    for d in range(positions.shape[1]):
        finite = np.isfinite(positions[:, d]).all(axis=1)
        if finite.sum() < 2 or finite.all():
            continue
        gaps = _short_gaps(finite, config.gap_fill_frames)
        if gaps.any():
            for k in range(3):
                positions[gaps, d, k] = np.interp(frames[gaps], frames[finite], positions[finite, d, k])
            status[gaps, d] = INFERRED
    w = int(config.smooth_inferred)
    if w >= 3 and F >= w:
        trusted = None
        if doubted is not None and config.smooth_trusted_only:
            trusted = ~np.asarray(doubted, bool)
        positions = _smooth_inferred(positions, status, w, trusted)
    return positions, status


def _short_gaps(finite: np.ndarray, max_len: int) -> np.ndarray:
    """(F,) bool: non-finite frames inside runs of <= max_len bounded by finite frames."""
    out = np.zeros_like(finite)
    F, f = len(finite), 0
    while f < F:
        if finite[f]:
            f += 1
            continue
        start = f
        while f < F and not finite[f]:
            f += 1
        if start > 0 and f < F and f - start <= max_len:
            out[start:f] = True
    return out


def _smooth_inferred(positions: np.ndarray, status: np.ndarray, w: int, trusted: np.ndarray | None = None) -> np.ndarray:
    """Inferred samples replaced by the mean of the finite samples within ``w`` frames. With
    ``trusted`` (F, D) bool, a trusted sample whose window holds an untrusted one keeps its own
    place (a one-sided mean would lag the motion by half a frame, the full one would import the
    untrusted place)."""
    half = w // 2

    def window_sum(values: np.ndarray) -> np.ndarray:
        padded = np.pad(values, ((half, half),) + ((0, 0),) * (values.ndim - 1), mode="edge")
        csum = np.concatenate([np.zeros_like(padded[:1]), np.cumsum(padded, axis=0)])
        return csum[w:] - csum[:-w]

    finite = np.isfinite(positions).all(axis=2, keepdims=True)
    total = window_sum(np.where(finite, positions, 0.0))
    count = window_sum(finite.astype(np.int64))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    out = positions.copy()
    pick = (status == INFERRED) & np.isfinite(mean).all(axis=2)
    if trusted is not None:
        trusted = np.asarray(trusted, bool)
        pick &= ~(trusted & (window_sum((~trusted).astype(np.int64)) > 0))
    out[pick] = mean[pick]
    return out
