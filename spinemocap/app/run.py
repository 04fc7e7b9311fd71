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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from tqdm import tqdm

from ..camera import Rig
from ..capture import Capture, check_image_size, read_image, to_grey
from ..detect import find_dots
from ..fileio import InputError, check_writable
from ..markers import MarkerTable
from ..tape import TapeSpec
from ..track.config import TrackerConfig
from ..track.pipeline import STAGES, FrameResult, FrameTracker
from ..track.sequence import SequenceTracker, fill_and_smooth
from ..views import ViewDots
from .results import TrackingStopped, write_markers

log = logging.getLogger(__name__)

MODES = ("sequence", "paper")


class TrackingWarning(UserWarning):
    """A frame could not be solved (its dots are reported missing)."""




# ---------------------------------------------------------------------- dot detection
DotDetector = Callable[[int, list[np.ndarray], list[np.ndarray] | None], list[ViewDots]]


def make_detector(name: str) -> DotDetector:
    """A function ``(frame, images, masks) -> [ViewDots per camera]``.

    ``net`` / ``classical``: :class:`spinemocap.detect.Detector` (tape mask + dots from the image);
    ``mask``: dots found inside given tape masks (synthetic captures ship exact masks; this
    isolates the tracker from tape-segmentation errors)."""
    if name == "mask":
        def detect_in_masks(frame, images, masks):
            if masks is None:
                raise InputError(None, "detector 'mask' needs tape masks (synthetic captures have masks/)")
            out = []
            for c, (image, mask) in enumerate(zip(images, masks)):
                uv, conf = find_dots(image, mask)
                out.append(ViewDots(c, uv, conf, mask=mask, image=to_grey(image)))
            return out

        return detect_in_masks
    if name in ("net", "classical"):
        try:  # the network detector loads torch: imported only when chosen
            from ..detect import Detector
        except ImportError as exc:
            raise InputError(None, f"detector {name!r} is not available in this installation ({exc})") from exc
        detector = Detector(name=name)

        def detect_images(frame, images, masks):
            out = []
            for c, image in enumerate(images):
                dots = detector.detect(image, camera=c)
                if dots.image is None:
                    dots.image = to_grey(image)
                out.append(dots)
            return out

        return detect_images
    raise InputError(None, f"unknown detector {name!r} (choose net, classical or mask)")


# ---------------------------------------------------------------------- sequences
@dataclass
class TrackResult:
    """A tracked sequence: the marker table plus per-frame diagnostics."""

    table: MarkerTable
    frames: list[FrameResult]

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
) -> TrackResult:
    """Track a sequence. ``views_per_frame`` yields ``(frame, views, detect_ms)``.

    Returns the table (frames numbered as yielded) and the per-frame results. A frame without a
    solution gives ``missing`` rows and a :class:`TrackingWarning`, never an exception.
    ``stop``: asked before every frame; True ends the run with :class:`TrackingStopped`."""
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


def _capture_views(capture: Capture, frames: range, detect: DotDetector):
    source = capture.frame_source()
    mask_dir = capture.root / "masks"
    for frame in frames:
        t0 = time.perf_counter()
        images = source.read(frame)
        masks = None
        if mask_dir.is_dir():
            masks = [check_image_size(read_image(path), cam.size, cam.name, path)[:, :, 0] > 127
                     for cam in capture.rig for path in [mask_dir / cam.name / f"{frame:06d}.png"]]
        views = detect(frame, images, masks)
        yield frame, views, 1000 * (time.perf_counter() - t0)


def track_capture(
    capture_dir: str | Path,
    out_dir: str | Path,
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | range | None = None,
    progress: bool = True,
    stop: Callable[[], bool] | None = None,
) -> MarkerTable:
    """Track a capture folder and write ``out_dir/markers.csv`` plus ``.trc`` and ``.c3d`` as one
    set (:func:`write_markers`). ``out_dir`` is checked for writing before any work.

    ``frames``: ``"A:B"`` or a range (default: all); ``stop``: see :func:`run_tracking`.
    Returns the marker table (mm, world Z up)."""
    capture = Capture.open(capture_dir)
    check_writable(out_dir)
    if mode not in MODES:
        raise InputError(capture_dir, f"unknown tracking mode {mode!r}; choose from {MODES}")
    frame_range = frames if isinstance(frames, range) else parse_frames(frames, capture.n_frames)
    detect = make_detector(detector)
    result = run_tracking(
        _capture_views(capture, frame_range, detect), capture.rig, capture.tape, capture.fps,
        up=capture.up, mode=mode, config=config, progress=progress, n_frames=len(frame_range),
        meta={"subject": capture.subject.get("id", ""), "source": str(capture.root), "detector": detector},
        stop=stop,
    )
    write_markers(result.table, out_dir)
    return result.table
