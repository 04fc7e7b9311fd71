"""Running a capture end to end (application layer): detector choice, frame ranges, reading the
capture's images, the per-frame or sequence tracker over the frames, writing the outputs.

:func:`track_capture` is the entry point for a capture folder (``spinemocap track``, batch);
:func:`run_tracking` drives :class:`~spinemocap.track.pipeline.FrameTracker` over a sequence in
``paper`` mode (every frame independent, as the paper) or ``sequence`` mode (identities and states
carried from frame to frame, :class:`~spinemocap.track.sequence.SequenceTracker`).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Literal, Sequence

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from ..camera import Rig
from ..capture import Capture, FrameSource
from ..fileio import InputError, atomic_write, check_writable, strict_json
from ..frames import parse_frames
from ..markers import MISSING_CAMERAS, MarkerTable
from ..reference import ReferenceObject
from ..tape import TapeSpec
from ..track.ahead import FrameCandidates
from ..track.config import TrackerConfig
from ..track.pipeline import STAGES, FrameResult, FrameTracker
from ..track.quality import is_flagged, label_confidence
from ..track.rig_check import REFINE_ADVICE, CalibrationWarning, RigResiduals
from ..track.rig_refine import (
    ControlPoints,
    ReferenceFitError,
    RigRefineConfig,
    RigRefinement,
    refine_rig,
    retriangulate,
)
from ..track.sequence import SequenceTracker, fill_and_smooth
from ..track.stretch import row_stretch
from ..track.template import tape_frames
from ..views import ViewDots
from .candidates_ahead import AheadInfo, CandidatesAhead
from .reference import observe_reference, pose_doubt, source_images
from .results import TrackingStopped, write_markers
from .streaming import (
    CaptureDetector,
    DetectionRoute,
    DetectorInfo,
    SpeedOptions,
    detected_ahead,
    detected_at_once,
    prefetched_frames,
)

log = logging.getLogger(__name__)

#: ``sequence``: frame to frame (identities carried, gaps filled); ``paper``: every frame on its own.
TrackingMode = Literal["sequence", "paper"]
MODES: tuple[TrackingMode, ...] = ("sequence", "paper")


# A capture whose tape is not found in more than this share of its frames has no markers to give
NO_TAPE_SHARE = 0.5
# The file in a results folder that lists every frame's conditions (unsolved, flagged), one a line
TRACKING_LOG = "tracking.log"


class TrackingWarning(UserWarning):
    """Frames that could not be solved (their dots are reported missing): one warning per kind
    of condition at the end of a run, naming the frames."""


class NoTapeFound(InputError):
    """The tape was not found in most frames of a capture (:data:`NO_TAPE_SHARE`): nothing to
    report. ``spinemocap track`` exits with :attr:`exit_code`."""

    exit_code = 3


def frame_ranges(frames: Sequence[int]) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``"frames 0-2, 5, 7-8"`` (``"frame 5"`` for one frame)."""
    frames = sorted(int(f) for f in frames)
    spans: list[list[int]] = []
    for f in frames:
        if spans and f == spans[-1][1] + 1:
            spans[-1][1] = f
        else:
            spans.append([f, f])
    text = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in spans)
    return f"frame{'s' if len(frames) != 1 else ''} {text}"


# ---------------------------------------------------------------------- dot detection


def make_detector(name: str, rig: Rig | None = None, speed: SpeedOptions | None = None,
                  weights: Path | None = None) -> CaptureDetector:
    """A function ``(frame, images, masks) -> [ViewDots per camera]`` (a :class:`CaptureDetector`).

    ``net`` / ``classical``: :class:`spinemocap.detect.Detector` (tape mask + dots from the image);
    ``mask``: dots found inside given tape masks (synthetic captures ship exact masks; this
    isolates the tracker from tape-segmentation errors). ``rig`` enables detection by
    prediction in sequence mode; ``speed``: threads, prefetching, prediction (default: all on);
    ``weights``: the ``net`` detector's weights file (None: the shipped ones)."""
    return CaptureDetector(name, rig, speed, weights=weights)


# ---------------------------------------------------------------------- sequences
@dataclass(frozen=True)
class TrackQuality:
    """What the tracker can vouch for in a tracked sequence (:meth:`TrackResult.quality`).

    ``flagged_frames``: capture frame numbers whose labels are not vouched for (a quality flag of
    :mod:`spinemocap.track.quality`, or unsolved); ``flags``: frames per condition (``tape not
    found`` and each quality flag); ``stretch_along``: (min, median, max) over the vouched-for
    frames of the measured dot spacing along the tape over the roll's spec (ratio), None when no
    frame measured it; ``stretch_across``: the median ratio across the tape (None likewise);
    ``gate_px``: the median candidate gate (px; None when no frame set one); ``rig_rms_px``: camera
    name -> the rig's reprojection RMS on the capture's dots (px; None when not measured);
    ``calibration_warning``: the tracker's warning about the rig, None when none;
    ``missing_cameras``: camera name -> the frames it had no image for."""

    flagged_frames: list[int]
    flags: dict[str, int]
    stretch_along: tuple[float, float, float] | None
    stretch_across: float | None
    gate_px: float | None
    rig_rms_px: dict[str, float] | None
    calibration_warning: str | None
    missing_cameras: dict[str, list[int]]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object (keys in field order; ``stretch_along`` a list)."""
        return {"flagged_frames": list(self.flagged_frames), "flags": dict(self.flags),
                "stretch_along": list(self.stretch_along) if self.stretch_along is not None else None,
                "stretch_across": self.stretch_across, "gate_px": self.gate_px,
                "rig_rms_px": dict(self.rig_rms_px) if self.rig_rms_px is not None else None,
                "calibration_warning": self.calibration_warning,
                "missing_cameras": {camera: list(frames) for camera, frames in self.missing_cameras.items()}}


@dataclass
class TrackResult:
    """A tracked sequence: the marker table plus per-frame diagnostics."""

    table: MarkerTable
    frames: list[FrameResult]
    rig_residuals: RigResiduals | None = None
    calibration_warning: str | None = None
    refinement: RigRefinement | None = None
    detector_searches: dict[DetectionRoute, int] = field(default_factory=dict)  # camera images per detection route
    detector_info: DetectorInfo | None = None  # how the cameras were detected (None: views given, not detected)
    candidates_taken_ahead: int = 0  # frames whose candidate stage built ahead served the tracker
    candidates_ahead: AheadInfo | None = None  # how the candidate workers ran (None: none ran)

    def stage_ms(self) -> dict[str, float]:
        """Mean time per stage per frame (ms), over all frames."""
        n = max(len(self.frames), 1)
        return {s: sum(f.stage_ms.get(s, 0.0) for f in self.frames) / n for s in STAGES}

    def routes(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.frames:
            out[f.route] = out.get(f.route, 0) + 1
        return out

    def pixels(self) -> np.ndarray:
        """(F, D, C, 2) distorted blob centres of the observed dots (NaN elsewhere)."""
        shape = next((f.pixels.shape for f in self.frames if f.pixels is not None), None)
        if shape is None:
            return np.full((len(self.frames), len(self.table.labels), 0, 2), np.nan)
        return np.stack([f.pixels if f.pixels is not None else np.full(shape, np.nan) for f in self.frames])

    def frame_numbers(self) -> list[int]:
        """The capture's frame number of each of :attr:`frames`."""
        first = int(self.table.frames[0]) if self.table.n_frames else 0
        return [first + k for k in range(len(self.frames))]

    def flagged_frames(self) -> list[int]:
        """Frame numbers whose labels the tracker cannot vouch for (see track.quality)."""
        return [n for n, f in zip(self.frame_numbers(), self.frames) if is_flagged(f.flags) or not f.solved]

    def flag_counts(self) -> dict[str, int]:
        """Frames per quality flag; an unsolved frame counts as ``tape not found``."""
        return {kind: len(frames) for kind, frames in self.conditions().items()}

    def conditions(self) -> dict[str, list[int]]:
        """Frame numbers per condition: ``tape not found`` (the frame's dots missing) and each
        quality flag (:mod:`spinemocap.track.quality`)."""
        out: dict[str, list[int]] = {}
        for number, f in zip(self.frame_numbers(), self.frames):
            for kind in ([] if f.solved else ["tape not found"]) + sorted(set(f.flags)):
                out.setdefault(kind, []).append(number)
        return out

    def condition_lines(self) -> list[str]:
        """One line per condition with its frames as ranges (for the screen, after the progress bar)."""
        total = len(self.frames)
        return [f"{kind}: {len(frames)} of {total} frames ({frame_ranges(frames)})"
                for kind, frames in self.conditions().items()]

    def missing_cameras(self) -> dict[str, list[int]]:
        """Camera name -> the capture frames it had no image for (its clock, a dropped, missing or
        damaged frame, a recording that ends early); the tracker used the other cameras there."""
        given = self.detector_info.missing_frames if self.detector_info is not None else {}
        missing = {str(k): sorted(int(f) for f in v) for k, v in given.items()}
        return {camera: frames for camera, frames in sorted(missing.items()) if frames}

    def missing_camera_lines(self) -> list[str]:
        """One line per camera with frames it had no image for, its frames as ranges and why."""
        reasons = self.detector_info.unreadable if self.detector_info is not None else {}
        lines = []
        for camera, frames in self.missing_cameras().items():
            why = sorted({str(r) for r in reasons.get(camera, {}).values()})
            lines.append(f"camera {camera} had no image in {len(frames)} of {len(self.frames)} frames "
                         f"({frame_ranges(frames)}); the other cameras were used there"
                         + (f": {why[0]}" + (f" (and {len(why) - 1} other reasons)" if len(why) > 1 else "") if why else ""))
        return lines

    def frame_log(self) -> str:
        """Every frame's conditions, one line per frame that has any (``tracking.log``)."""
        lines = []
        absent: dict[int, list[str]] = {}
        for camera, frames in self.missing_cameras().items():
            for frame in frames:
                absent.setdefault(frame, []).append(camera)
        for number, f in zip(self.frame_numbers(), self.frames):
            kinds = ([f"tape not found ({f.note})" if f.note else "tape not found"] if not f.solved else [])
            kinds += sorted(set(f.flags)) + ([f.note] if f.solved and f.note else [])
            kinds += [f"no image from camera {camera}" for camera in absent.get(int(number), [])]
            if kinds:
                lines.append(f"frame {number}: " + "; ".join(kinds))
        return "\n".join(lines) + ("\n" if lines else "")

    def no_tape(self) -> str | None:
        """Why this result holds no markers worth reporting (the tape not found in more than
        :data:`NO_TAPE_SHARE` of the frames), else None."""
        missing = sum(not f.solved for f in self.frames)
        if not self.frames or missing <= NO_TAPE_SHARE * len(self.frames):
            return None
        return f"no tape found in {missing} of {len(self.frames)} frames"

    def quality(self) -> TrackQuality:
        """What the tracker vouches for, for summaries and JSON (:class:`TrackQuality`)."""
        measured = [f.stretch for f in self.frames if f.solved and not is_flagged(f.flags)
                    and f.stretch is not None and f.stretch.source == "data"]  # never from frames not vouched for
        along = [m.along for m in measured]
        across = [m.across for m in measured]
        gates = [f.gate_px for f in self.frames if np.isfinite(f.gate_px)]
        res = self.rig_residuals
        return TrackQuality(
            flagged_frames=self.flagged_frames(),
            flags=self.flag_counts(),
            stretch_along=(float(np.min(along)), float(np.median(along)), float(np.max(along))) if along else None,
            stretch_across=float(np.median(across)) if across else None,
            gate_px=float(np.median(gates)) if gates else None,
            rig_rms_px=({n: float(r) for n, r in zip(res.cameras, res.rms_px)} if res is not None else None),
            calibration_warning=self._calibration_warning(),
            missing_cameras=self.missing_cameras(),
        )

    def _calibration_warning(self) -> str | None:
        """The tracker's calibration warning; after ``--refine-rig`` its advice to refine is
        replaced by where the refinement is reported."""
        if self.calibration_warning is None or self.refinement is None:
            return self.calibration_warning
        after = self.refinement.after_px["all"]
        return self.calibration_warning.replace(
            REFINE_ADVICE, f"the rig was refined on these dots (--refine-rig: {after:.2f} px RMS after, rig_refine.json).")

    def summary(self) -> str:
        """What the tracker can and cannot vouch for, in a few lines (end of ``spinemocap track``)."""
        q = self.quality()
        lines = []
        if q.stretch_along and q.stretch_across is not None:  # both come from the same frames
            lo, med, hi = q.stretch_along
            lines.append(f"tape spacing measured: {100 * (med - 1):+.0f} % along the tape vs the roll's spec "
                         f"(frames {100 * (lo - 1):+.0f} .. {100 * (hi - 1):+.0f} %), "
                         f"{100 * (q.stretch_across - 1):+.0f} % across")
        if self.rig_residuals is not None:
            lines.append("rig residuals on the capture's dots: " + self.rig_residuals.describe()
                         + (f"; candidate gate {q.gate_px:.1f} px" if q.gate_px else ""))
        if q.calibration_warning:
            lines.append("WARNING " + q.calibration_warning)
        if self.refinement is not None:
            before, after = self.refinement.before_px["all"], self.refinement.after_px["all"]
            lines.append(f"rig refined on {self.refinement.n_points} tracked dot-frames: reprojection RMS "
                         f"{before:.2f} -> {after:.2f} px (rig_refined.toml, rig_refine.json)")
            uncertainty = self.refinement.frame_uncertainty_mm
            frame = self.refinement.reference
            if frame is not None:
                lines.append(f"world frame from the reference object {frame.name!r}: {len(frame.markers_used)} "
                             f"markers, {frame.observations} camera views, fit {frame.fit_rms_px:.2f} px RMS, "
                             f"markers re-triangulated {frame.fit_rms_mm:.2f} mm RMS from the design (the given rig "
                             f"had them {frame.given_frame_offset_mm:.1f} mm off)")
                if frame.pose_warning:
                    lines.append("WARNING " + frame.pose_warning)
            elif np.isfinite(uncertainty):
                lines.append(f"absolute positions keep about {uncertainty:.1f} mm of the given rig's world-frame error "
                             "(no residual sees it; distances and angles do not)")
        lines += self.missing_camera_lines()
        flagged = q.flagged_frames
        if flagged:
            lines.append(f"WARNING {len(flagged)} of {len(self.frames)} frames flagged (labels not vouched for; the "
                         f"confidence column of markers.csv, every frame in {TRACKING_LOG}):")
            lines += [f"  {line}" for line in self.condition_lines()]
        else:
            mild = [line for line in self.condition_lines()]
            lines.append(f"no frame flagged ({len(self.frames)} frames" + (f"; mild: {'; '.join(mild)}" if mild else "")
                         + ")")
        return "\n".join(lines)


def run_tracking(
    views_per_frame: Iterable[tuple[int, list[ViewDots], float]],
    rig: Rig,
    tape: TapeSpec,
    fps: float,
    up: npt.ArrayLike = (0.0, 0.0, 1.0),
    mode: TrackingMode = "sequence",
    config: TrackerConfig | None = None,
    progress: bool = True,
    n_frames: int | None = None,
    meta: dict | None = None,
    stop: Callable[[], bool] | None = None,
    on_frame: Callable[[int, FrameResult], None] | None = None,
    ahead_for: Callable[[int], FrameCandidates | None] | None = None,
) -> TrackResult:
    """Track a sequence. ``views_per_frame`` yields ``(frame, views, detect_ms)``.

    Returns the table (frames numbered as yielded) and the per-frame results. A frame without a
    solution gives ``missing`` rows and a :class:`TrackingWarning`, never an exception.
    ``stop``: asked before every frame; True ends the run with :class:`TrackingStopped`.
    ``on_frame(frame, result)`` is called after each frame, before the next is asked for
    (detection by prediction learns the dots there). ``ahead_for(frame)``: the frame's candidate
    stage built ahead, or None (sequence mode; :mod:`spinemocap.app.candidates_ahead`); the time
    waited for it counts as ``detect``."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; choose from {MODES}")
    config = config or TrackerConfig()
    tracker = FrameTracker(rig, tape, config, up)
    carry = SequenceTracker(tracker) if mode == "sequence" else None
    results, frame_ids = [], []
    bar = tqdm(views_per_frame, total=n_frames, desc=f"tracking ({mode})", unit="frame", disable=not progress)
    for frame, views, detect_ms in bar:
        if stop is not None and stop():
            raise TrackingStopped(f"tracking stopped before frame {frame}")
        t0 = time.perf_counter()
        ahead = ahead_for(frame) if ahead_for is not None and carry is not None else None
        stage_ms = {"detect": detect_ms + 1000 * (time.perf_counter() - t0)}
        try:
            result = carry.step(views, stage_ms, ahead) if carry else tracker.solve(views, stage_ms=stage_ms)
        except InputError:
            raise
        except Exception as exc:  # one unsolvable frame must not end the sequence: report it missing
            log.debug("frame %d failed", frame, exc_info=True)
            result = FrameResult.missing(tracker.n_dots, stage_ms, f"{type(exc).__name__}: {exc}")
        results.append(result)
        frame_ids.append(frame)
        if on_frame is not None:
            on_frame(frame, result)
    positions = np.stack([r.positions for r in results]) if results else np.zeros((0, tracker.n_dots, 3))
    status = np.stack([r.status for r in results]) if results else np.zeros((0, tracker.n_dots), object)
    n_views = np.stack([r.n_views for r in results]) if results else np.zeros((0, tracker.n_dots), int)
    residual = np.stack([r.residual for r in results]) if results else np.zeros((0, tracker.n_dots))
    if carry is not None and len(results):
        doubted = np.repeat([[is_flagged(r.flags) or not r.solved] for r in results], tracker.n_dots, axis=1)
        positions, status = fill_and_smooth(positions, status, config.sequence, doubted)
        for result, frame_positions, frame_status in zip(results, positions, status):
            if result.solved:  # the followed, filled and smoothed dots may crowd a row put a column aside
                tracker.mark_crowded(result, frame_positions, frame_status)
    first = frame_ids[0] if frame_ids else 0
    if frame_ids and frame_ids != list(range(first, first + len(frame_ids))):
        raise ValueError("frames must be consecutive")
    confidence = np.stack([label_confidence(s, r.flags if r.solved else [*r.flags, "unsolved"], r.dot_flags())
                           for s, r in zip(status, results)]) if results else None
    stretch = np.stack([row_stretch(p, tracker.graph)[0] for p in positions]) if results else None
    table = MarkerTable.from_arrays(tape.labels, positions, fps, status=status, n_views=n_views,
                                    residual=residual, first_frame=first, confidence=confidence, stretch=stretch,
                                    meta={"mode": mode, **(meta or {})})
    residuals = tracker.monitor.residuals() if tracker.monitor.measured else None
    calibration = tracker.monitor.warning() if tracker.monitor.measured else None
    if calibration:
        warnings.warn(calibration, CalibrationWarning, stacklevel=2)
    out = TrackResult(table, results, residuals, calibration, candidates_taken_ahead=tracker.ahead_used)
    unsolved = out.conditions().get("tape not found", [])
    if unsolved:  # one warning for all such frames, after the progress bar
        warnings.warn(f"tape not found in {len(unsolved)} of {len(results)} frames ({frame_ranges(unsolved)}); "
                      "their dots reported missing", TrackingWarning, stacklevel=2)
    return out


def candidates_ahead(rig: Rig, tape: TapeSpec, config: TrackerConfig | None, speed: SpeedOptions,
                     mode: TrackingMode, detect: CaptureDetector) -> CandidatesAhead | None:
    """The workers that build the candidate stage ahead (``speed.candidate_workers`` > 0, sequence
    mode, detection that does not predict from the tracked dots), else None."""
    if speed.candidate_workers <= 0 or mode != "sequence" or detect.predicts:
        return None
    return CandidatesAhead(rig, tape, config, speed.candidate_workers, speed.candidate_depth)


def select_frames(frames: str | Sequence[int] | None, n_frames: int) -> range:
    """The capture's frames to track: all (``None`` or ``""``), a selection string
    (:func:`spinemocap.frames.parse_frames`) or the given indices. The tracker follows the tape
    from frame to frame and numbers its output rows from the first frame, so the selection must be
    consecutive frames. Raises :class:`InputError` naming ``frames`` otherwise."""
    if frames is None or len(frames) == 0:
        return range(n_frames)
    selected = parse_frames(frames, n_frames, "frames") if isinstance(frames, str) else list(frames)
    if any(b - a != 1 for a, b in zip(selected, selected[1:])):
        raise InputError("frames", f"the tracker needs consecutive frames (A:B), got {frames!r}")
    if selected[0] < 0 or selected[-1] >= n_frames:
        raise InputError("frames", f"frames {selected[0]}..{selected[-1]} are not all in the capture (0..{n_frames - 1})")
    return range(selected[0], selected[-1] + 1)


def source_views(source: FrameSource, frames: Sequence[int], detect: CaptureDetector,
                 speed: SpeedOptions | None = None, mask_dir: Path | None = None):
    """Yield ``(frame, views, detect_ms)`` for :func:`run_tracking`: images decoded once (cameras
    in parallel, prefetched), ground-truth masks (``mask_dir``) read only for the ``mask``
    detector (or always with ``speed.masks_always``, the serial pipeline). ``detect_ms`` is the time
    the tracker waited for the frame: reading not hidden by the prefetching, plus detection."""
    speed = speed or SpeedOptions()
    read_masks = (detect.needs_masks or speed.masks_always) and mask_dir is not None and mask_dir.is_dir()
    frames_in = prefetched_frames(source, frames, mask_dir if read_masks else None,
                                  workers=speed.n_workers(len(source.camera_names)), prefetch=speed.prefetch,
                                  stage=detect.stage if detect.parallel == "processes" else None)
    if speed.frames_at_once > 1:
        yield from detected_at_once(frames_in, detect, speed.frames_at_once)
        return
    if speed.lookahead > 0 and detect.streams:
        yield from detect.stream(frames_in, speed.lookahead)
        return
    if speed.lookahead > 0:
        yield from detected_ahead(frames_in, detect, speed.lookahead)
        return
    if detect.predicts and detect.streams:  # refresh frames start while the tracker solves the frame before
        yield from detect.frames_in_order(frames_in)
        return
    t0 = time.perf_counter()
    for frame, images, masks in frames_in:
        views = detect(frame, images, masks if detect.needs_masks else None)
        yield frame, views, 1000 * (time.perf_counter() - t0)
        t0 = time.perf_counter()


def track_source(
    source: FrameSource,
    rig: Rig,
    tape: TapeSpec,
    fps: float,
    frames: Sequence[int] | None = None,
    up: npt.ArrayLike = (0.0, 0.0, 1.0),
    mode: TrackingMode = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    progress: bool = True,
    speed: SpeedOptions | None = None,
    mask_dir: Path | None = None,
    meta: dict | None = None,
    stop: Callable[[], bool] | None = None,
    weights: Path | None = None,
) -> TrackResult:
    """Detect and track the frames of any :class:`~spinemocap.capture.FrameSource` (a capture's
    images or videos, the synthetic studio's, frames held in memory); see :func:`track_capture`.
    ``weights``: the ``net`` detector's weights file (None: the shipped ones)."""
    frames = range(source.n_frames) if frames is None else frames
    speed = speed or SpeedOptions()
    if mode != "sequence":  # every frame on its own: no prediction from earlier frames
        speed = replace(speed, predict=False)
    detect = make_detector(detector, rig, speed, weights if detector == "net" else None)
    views = source_views(source, frames, detect, speed, mask_dir)
    ahead = candidates_ahead(rig, tape, config, speed, mode, detect)

    def on_frame(frame: int, r: FrameResult) -> None:
        detect.observe(frame, r.positions if r.solved else None)
        if ahead is not None:
            ahead.observe(frame, r)

    try:
        result = run_tracking(
            ahead.frames(views) if ahead is not None else views, rig, tape, fps, up=up, mode=mode,
            config=config, progress=progress, n_frames=len(frames), meta={**(meta or {}), "detector": detector,
                                                          **({"detector_weights": str(weights)} if weights else {})},
            on_frame=on_frame, stop=stop, ahead_for=ahead.for_frame if ahead is not None else None,
        )
    finally:
        if ahead is not None:
            ahead.close()
        views.close()  # a detection running ahead of the tracker ends before its detector closes
        detect.close()
    if ahead is not None:
        result.candidates_ahead = ahead.info
    result.detector_searches = dict(detect.searches)
    unreadable = {camera: reasons for camera, reasons in getattr(source, "unreadable", {}).items() if reasons}
    result.detector_info = replace(detect.info, unreadable=unreadable)
    result.table.meta[MISSING_CAMERAS] = result.missing_cameras()  # into the marker files
    return result


def track_capture(
    capture_dir: str | Path,
    out_dir: str | Path,
    mode: TrackingMode = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | Sequence[int] | None = None,
    progress: bool = True,
    stop: Callable[[], bool] | None = None,
    speed: SpeedOptions | None = None,
) -> MarkerTable:
    """Track a capture folder and write ``out_dir/markers.csv`` plus ``.trc`` and ``.c3d`` as one
    set (:func:`write_markers`). ``out_dir`` is checked for writing before any work.

    ``frames``: a frame selection (:mod:`spinemocap.frames`, e.g. ``"0:100"``) or frame indices
    (default: all); ``stop``: see :func:`run_tracking`;
    ``speed``: reading and detection options (:class:`~spinemocap.app.streaming.SpeedOptions`;
    ``streaming.SERIAL`` is the serial pipeline). Returns the marker table (mm, world Z up)."""
    return track_capture_result(capture_dir, out_dir, mode, config, detector, frames, progress,
                                stop=stop, speed=speed).table


def track_capture_result(
    capture_dir: str | Path,
    out_dir: str | Path,
    mode: TrackingMode = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | Sequence[int] | None = None,
    progress: bool = True,
    refine: RigRefineConfig | None = None,
    stop: Callable[[], bool] | None = None,
    speed: SpeedOptions | None = None,
    reference: str | Path | None = None,
) -> TrackResult:
    """:func:`track_capture` returning the whole :class:`TrackResult` (quality flags, rig
    residuals). The ``net`` detector uses the weights ``capture.toml`` names
    (``[capture] detector_weights``), else the shipped ones. ``refine``: bundle-adjust the rig on the tracked dots afterwards
    (``--refine-rig``): the refined rig goes to ``out_dir/rig_refined.toml`` with the residuals
    before/after in ``out_dir/rig_refine.json``, and the observed dots are re-triangulated with it
    (labels unchanged, :func:`apply_refined_rig`).

    With a reference object (``reference``: a ``reference.toml``, else the one ``capture.toml``
    names; :mod:`spinemocap.reference`) the refinement holds its markers as control points, so the
    refined rig's world frame is the reference's. Its markers are looked for before tracking:
    too few found is an :class:`InputError` naming the reference file, as is a refined rig that
    cannot fit them; a reference frame far from the given rig's is a warning (see
    :func:`spinemocap.app.reference.pose_doubt`)."""
    capture = Capture.open(capture_dir)
    check_writable(out_dir)
    if mode not in MODES:
        raise InputError(capture_dir, f"unknown tracking mode {mode!r}; choose from {MODES}")
    frame_range = select_frames(frames, capture.n_frames)
    control, reference_path = None, None
    if refine is not None:
        control, reference_path = capture_control_points(capture, frame_range, reference)
    result = track_source(capture.frame_source(), capture.rig, capture.tape, capture.fps, frame_range,
                          up=capture.up, mode=mode, config=config, detector=detector, progress=progress,
                          speed=speed, mask_dir=capture.root / "masks",
                          meta={"subject": capture.subject.get("id", ""), "source": str(capture.root)},
                          stop=stop, weights=capture.detector_weights_path if detector == "net" else None)
    if refine is not None:
        try:
            result.refinement = refine_rig(capture.rig, result.pixels(), result.table.positions(), capture.fps, refine,
                                           control)
        except ReferenceFitError as exc:
            raise InputError(reference_path, str(exc)) from None
        doubt = pose_doubt(result.refinement)
        if doubt and result.refinement.reference is not None:
            result.refinement.reference.pose_warning = doubt
            warnings.warn(doubt, CalibrationWarning, stacklevel=2)
        write_refinement(result.refinement, out_dir)
        result.table = apply_refined_rig(result, result.refinement, capture.tape)
    with atomic_write(Path(out_dir) / TRACKING_LOG) as handle:
        handle.write(result.frame_log())
    reason = result.no_tape()
    if reason:  # nothing written over a previous result: a lost tape is not a result
        raise NoTapeFound(capture.root, f"{reason}: check the detector with "
                                        f"`spinemocap detector run {detector_example(capture, frame_range[0])} "
                                        f"--out {Path(out_dir) / 'detector'}` (per-frame list: "
                                        f"{Path(out_dir) / TRACKING_LOG})")
    write_markers(result.table, out_dir)
    return result


def detector_example(capture: Capture, frame: int) -> Path:
    """A recording to check the detector on: the first camera's image of ``frame`` (image
    captures) or its video."""
    name = capture.camera_names[0]
    path = capture.media_path(name)
    if capture.media == "video":
        return path
    clock = capture.camera_clocks.get(name)
    if clock is not None and clock.media:
        files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
        return files[min(frame, len(files) - 1)] if files else path
    return capture.root / capture.image_pattern.format(camera=name, frame=frame)


def capture_control_points(capture: Capture, frames: Sequence[int], reference: str | Path | None = None
                           ) -> tuple[ControlPoints | None, Path | None]:
    """The reference object's markers in a few of ``frames`` (``reference``: a reference file,
    else the capture's own; none: ``(None, None)``) and the file it came from. :class:`InputError`
    naming that file when they cannot fix a world frame (fewer than 3 markers found in >= 2
    cameras)."""
    if reference is not None:
        path: Path | None = Path(reference)
        obj: ReferenceObject | None = ReferenceObject.from_toml(reference)
    else:
        obj = capture.reference()
        path = capture.root / capture.reference_file if capture.reference_file else None
    if obj is None:
        return None, None
    control = observe_reference(capture.rig, obj, source_images(capture.frame_source(), frames))
    if control.problems():
        raise InputError(path, "; ".join(control.problems()) + ": the markers were looked for where the given rig "
                               "projects the design and pose of this file; check both (mm, world Z up)")
    return control, path


def apply_refined_rig(result: TrackResult, refinement: RigRefinement, tape: TapeSpec) -> MarkerTable:
    """The result's table with its observed dots re-triangulated under the refined rig (the
    other dots follow them, see :func:`spinemocap.track.rig_refine.retriangulate`)."""
    arrays = result.table.to_arrays()
    positions = arrays.positions
    normals = np.stack([tape_frames(p, tape.graph)[0] if np.isfinite(p).all() else np.zeros_like(p)
                        for p in positions])
    moved = retriangulate(refinement.rig, result.pixels(), positions, arrays.status, tape.thickness_mm, normals)
    table = MarkerTable.from_arrays(list(arrays.labels), moved, result.table.fps, status=arrays.status,
                                    n_views=arrays.n_views, residual=arrays.residual,
                                    first_frame=int(arrays.frames[0]), confidence=arrays.confidence,
                                    stretch=arrays.stretch, meta={**result.table.meta, "rig": "refined"})
    return table


def write_refinement(refinement: RigRefinement, out_dir: str | Path) -> tuple[Path, Path]:
    """``rig_refined.toml`` and ``rig_refine.json`` (residuals before/after) in ``out_dir``."""
    from ..fileio import atomic_path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rig_path, json_path = out / "rig_refined.toml", out / "rig_refine.json"
    with atomic_path(rig_path) as tmp:
        refinement.rig.to_toml(tmp)
    with atomic_write(json_path) as fh:
        fh.write(strict_json(refinement.to_dict(), indent=2))
    return rig_path, json_path
