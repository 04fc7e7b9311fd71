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
from typing import Callable, Iterable, Sequence

import numpy as np
from tqdm import tqdm

from ..camera import Rig
from ..capture import Capture, FrameSource
from ..fileio import InputError, check_writable
from ..markers import MarkerTable
from ..tape import TapeSpec
from ..track.config import TrackerConfig
from ..track.pipeline import STAGES, FrameResult, FrameTracker
from ..track.sequence import SequenceTracker, fill_and_smooth
from ..views import ViewDots
from .results import TrackingStopped, write_markers
from .streaming import CaptureDetector, SpeedOptions, prefetched_frames

log = logging.getLogger(__name__)

MODES = ("sequence", "paper")


class TrackingWarning(UserWarning):
    """A frame could not be solved (its dots are reported missing)."""




# ---------------------------------------------------------------------- dot detection
DotDetector = Callable[[int, list[np.ndarray], list[np.ndarray] | None], list[ViewDots]]


def make_detector(name: str, rig: Rig | None = None, speed: SpeedOptions | None = None) -> CaptureDetector:
    """A function ``(frame, images, masks) -> [ViewDots per camera]`` (a :class:`CaptureDetector`).

    ``net`` / ``classical``: :class:`spinemocap.detect.Detector` (tape mask + dots from the image);
    ``mask``: dots found inside given tape masks (synthetic captures ship exact masks; this
    isolates the tracker from tape-segmentation errors). ``rig`` enables detection by
    prediction in sequence mode; ``speed``: threads, prefetching, prediction (default: all on)."""
    return CaptureDetector(name, rig, speed)


# ---------------------------------------------------------------------- sequences
@dataclass
class TrackResult:
    """A tracked sequence: the marker table plus per-frame diagnostics."""

    table: MarkerTable
    frames: list[FrameResult]
    detector_searches: dict[str, int] = field(default_factory=dict)  # camera images per detection route

    def stage_ms(self) -> dict[str, float]:
        """Mean time per stage per frame (ms), over all frames."""
        n = max(len(self.frames), 1)
        return {s: sum(f.stage_ms.get(s, 0.0) for f in self.frames) / n for s in STAGES}

    def routes(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.frames:
            out[f.route] = out.get(f.route, 0) + 1
        return out


def run_tracking(
    views_per_frame: Iterable[tuple[int, list[ViewDots], float]],
    rig: Rig,
    tape: TapeSpec,
    fps: float,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    progress: bool = True,
    n_frames: int | None = None,
    meta: dict | None = None,
    stop: Callable[[], bool] | None = None,
    on_frame: Callable[[int, FrameResult], None] | None = None,
) -> TrackResult:
    """Track a sequence. ``views_per_frame`` yields ``(frame, views, detect_ms)``.

    Returns the table (frames numbered as yielded) and the per-frame results. A frame without a
    solution gives ``missing`` rows and a :class:`TrackingWarning`, never an exception.
    ``stop``: asked before every frame; True ends the run with :class:`TrackingStopped`.
    ``on_frame(frame, result)`` is called after each frame, before the next is asked for
    (detection by prediction learns the dots there)."""
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
        stage_ms = {"detect": detect_ms}
        try:
            result = carry.step(views, stage_ms) if carry else tracker.solve(views, stage_ms=stage_ms)
        except InputError:
            raise
        except Exception as exc:  # one unsolvable frame must not end the sequence: report it missing
            log.debug("frame %d failed", frame, exc_info=True)
            result = FrameResult.missing(tracker.n_dots, stage_ms, f"{type(exc).__name__}: {exc}")
        if not result.solved:
            warnings.warn(f"frame {frame}: tape not found ({result.note}); dots reported missing",
                          TrackingWarning, stacklevel=2)
        results.append(result)
        frame_ids.append(frame)
        if on_frame is not None:
            on_frame(frame, result)
    positions = np.stack([r.positions for r in results]) if results else np.zeros((0, tracker.n_dots, 3))
    status = np.stack([r.status for r in results]) if results else np.zeros((0, tracker.n_dots), object)
    n_views = np.stack([r.n_views for r in results]) if results else np.zeros((0, tracker.n_dots), int)
    residual = np.stack([r.residual for r in results]) if results else np.zeros((0, tracker.n_dots))
    if carry is not None and len(results):
        positions, status = fill_and_smooth(positions, status, config.sequence)
    first = frame_ids[0] if frame_ids else 0
    if frame_ids and frame_ids != list(range(first, first + len(frame_ids))):
        raise ValueError("frames must be consecutive")
    table = MarkerTable.from_arrays(tape.labels, positions, fps, status=status, n_views=n_views,
                                    residual=residual, first_frame=first,
                                    meta={"mode": mode, **(meta or {})})
    return TrackResult(table, results)


def parse_frames(spec: str | None, n_frames: int, source: str = "--frames") -> range:
    """``A:B`` (Python slice, B exclusive, either side optional) -> frame range within the capture."""
    if not spec:
        return range(n_frames)
    try:
        a, _, b = spec.partition(":")
        start = int(a) if a else 0
        stop = int(b) if b else n_frames
    except ValueError:
        raise InputError(source, f"frame range {spec!r} is not of the form A:B") from None
    start, stop = max(start, 0), min(stop, n_frames)
    if start >= stop:
        raise InputError(source, f"frame range {spec!r} selects no frame of the {n_frames} in the capture")
    return range(start, stop)


def source_views(source: FrameSource, frames: Sequence[int], detect: CaptureDetector,
                 speed: SpeedOptions | None = None, mask_dir: Path | None = None):
    """Yield ``(frame, views, detect_ms)`` for :func:`run_tracking`: images decoded once (cameras
    in parallel, prefetched), ground-truth masks (``mask_dir``) read only for the ``mask``
    detector (or always with ``speed.masks_always``, the legacy path). ``detect_ms`` is the time
    the tracker waited for the frame: reading not hidden by the prefetching, plus detection."""
    speed = speed or SpeedOptions()
    read_masks = (detect.needs_masks or speed.masks_always) and mask_dir is not None and mask_dir.is_dir()
    frames_in = prefetched_frames(source, frames, mask_dir if read_masks else None,
                                  workers=speed.n_workers(len(source.camera_names)), prefetch=speed.prefetch)
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
    up: Sequence[float] = (0.0, 0.0, 1.0),
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    progress: bool = True,
    speed: SpeedOptions | None = None,
    mask_dir: Path | None = None,
    meta: dict | None = None,
    stop: Callable[[], bool] | None = None,
) -> TrackResult:
    """Detect and track the frames of any :class:`~spinemocap.capture.FrameSource` (a capture's
    images or videos, the synthetic studio's, frames held in memory); see :func:`track_capture`."""
    frames = range(source.n_frames) if frames is None else frames
    speed = speed or SpeedOptions()
    if mode != "sequence":  # every frame on its own: no prediction from earlier frames
        speed = replace(speed, predict=False)
    detect = make_detector(detector, rig, speed)
    try:
        result = run_tracking(
            source_views(source, frames, detect, speed, mask_dir), rig, tape, fps, up=up, mode=mode,
            config=config, progress=progress, n_frames=len(frames), meta={**(meta or {}), "detector": detector},
            on_frame=lambda frame, r: detect.observe(frame, r.positions if r.solved else None), stop=stop,
        )
    finally:
        detect.close()
    result.detector_searches = dict(detect.searches)
    return result


def track_capture(
    capture_dir: str | Path,
    out_dir: str | Path,
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | range | None = None,
    progress: bool = True,
    stop: Callable[[], bool] | None = None,
    speed: SpeedOptions | None = None,
) -> MarkerTable:
    """Track a capture folder and write ``out_dir/markers.csv`` plus ``.trc`` and ``.c3d`` as one
    set (:func:`write_markers`). ``out_dir`` is checked for writing before any work.

    ``frames``: ``"A:B"`` or a range (default: all); ``stop``: see :func:`run_tracking`;
    ``speed``: reading and detection options (:class:`~spinemocap.app.streaming.SpeedOptions`;
    ``streaming.LEGACY`` is the pre-issue-15 path). Returns the marker table (mm, world Z up)."""
    capture = Capture.open(capture_dir)
    check_writable(out_dir)
    if mode not in MODES:
        raise InputError(capture_dir, f"unknown tracking mode {mode!r}; choose from {MODES}")
    frame_range = frames if isinstance(frames, range) else parse_frames(frames, capture.n_frames)
    result = track_source(capture.frame_source(), capture.rig, capture.tape, capture.fps, frame_range,
                          up=capture.up, mode=mode, config=config, detector=detector, progress=progress,
                          speed=speed, mask_dir=capture.root / "masks",
                          meta={"subject": capture.subject.get("id", ""), "source": str(capture.root)},
                          stop=stop)
    write_markers(result.table, out_dir)
    return result.table
