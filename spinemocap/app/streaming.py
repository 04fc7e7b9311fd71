"""Reading and detecting a capture's frames fast: a prefetching reader, cameras in
parallel, and detection by prediction in sequence mode.

- :func:`prefetched_frames` decodes each camera's image once, the cameras in parallel threads,
  in a background thread that stays ``prefetch`` frames ahead of the tracker (a bounded queue:
  memory stays flat however long the sequence). Ground-truth tape masks are read only when the
  detector uses them (``mask``).
- :class:`CaptureDetector` runs the detector on all cameras of a frame in parallel: in worker
  processes (:mod:`spinemocap.app.camera_processes`, one detector each, images through shared
  memory; ``parallel="processes"``) or in a thread pool (``"threads"``: OpenCV and torch release
  the GIL, detection's Python clean-up does not), with stage 1 of the ``net`` detector batched
  across cameras on a GPU (one image per pass in processes, and in the camera threads on the CPU,
  ``SpeedOptions.stage1_in_pool``: the same boxes). In
  sequence mode it is told each solved frame (:meth:`CaptureDetector.observe`): the dots, moved
  on by their velocity, are projected into every camera and the network searches only that
  predicted tape box (stage 1, the whole-frame pass, is skipped). A camera falls back to the full
  two-stage search when its box finds fewer than ``min_dot_share`` of the dots it found in the
  previous frame, and every camera does every ``refresh_every`` frames: all cameras in the same
  frame (``refresh="frame"``) or each camera on its own schedule, the cameras' refreshes spread
  over the period (``refresh="camera"``; a camera that found all its dots well inside its image
  may then wait ``refresh_settled_every`` frames).
- With ``SpeedOptions.lookahead`` > 0 frame t+1 is detected while the tracker solves frame t, so
  detection and the tracker run at the same time; the boxes of frame t+1 are then predicted from
  frame t-1 over two frames (``lookahead_margin_px`` wider per extra frame, 0 by default). With
  the cameras in threads :meth:`CaptureDetector.stream` runs each camera through the frames on
  its own (no camera waits for the slowest camera of a frame); otherwise :func:`detected_ahead`
  detects whole frames in a background thread. Both give the same output. ``lookahead=0`` (the
  default) keeps the exact serial order.
- With ``SpeedOptions.frames_at_once`` > 1 (prediction off) :func:`detected_at_once` detects that
  many frames at the same time, each searched in full, their camera images spread over the
  workers (one per core, processes or threads): for machines with more cores than cameras. The
  views are those of one frame at a time.

:data:`SERIAL` is the serial pipeline (one camera after the other, no prefetching, masks read
whenever the capture has them, the full search in every frame): the speed benchmark's peer.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
import warnings
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Literal, Sequence, cast

import cv2
import numpy as np

from ..camera import Rig
from ..capture import FrameSource, check_image_size, read_image, to_grey
from ..detect import find_dots
from ..fileio import InputError
from ..views import ViewDots
from .camera_processes import CameraProcesses, ProcessesUnavailable, mask_box

if TYPE_CHECKING:
    from ..detect import Detector

#: How a camera image was searched: in the box predicted from the last frames' dots, in full
#: as a periodic refresh, in full after the predicted box found too few dots, or in full.
DetectionRoute = Literal["predicted", "refresh", "fallback", "full"]

log = logging.getLogger(__name__)

Box = tuple[slice, slice]
PARALLEL = ("threads", "processes")
REFRESH = ("frame", "camera")
SETTLED_EDGE_PX = 64  # a settled camera's tape box lies at least this far inside its image (px)
# Threads are the default: as fast as worker processes or faster on 2 and 16 cores, with no shared
# memory or start-up (docs/decisions/0004-camera-threads-not-processes.md).


def resolve_parallel(mode: str) -> str:
    """``mode`` checked against :data:`PARALLEL` (``processes`` or ``threads``)."""
    if mode not in PARALLEL:
        raise InputError(None, f"unknown parallel mode {mode!r} (choose {', '.join(PARALLEL)})")
    return mode


@dataclass
class DetectorInfo:
    """How a capture's cameras were detected (:attr:`CaptureDetector.info`, filled in while it runs).

    ``parallel``: ``serial``, ``threads``, ``processes`` or ``threads (fallback from processes)``;
    ``workers``: camera threads or processes. With worker processes, once closed: their start-up
    (``startup_s``, wall s), the CPU seconds they used after it (``workers_cpu_s``: this process's
    CPU clock misses them) and the slowest camera's time per detection pass (``slowest_camera_ms``);
    None otherwise. ``missing_frames``: camera name -> capture frames it had no image for;
    ``unreadable``: camera name -> frame -> why its image could not be read (the source's record,
    added by the tracking run)."""

    parallel: str
    workers: int
    startup_s: float | None = None
    workers_cpu_s: float | None = None
    slowest_camera_ms: float | None = None
    missing_frames: dict[str, list[int]] = field(default_factory=dict)
    unreadable: dict[str, dict[int, str]] = field(default_factory=dict)


class ParallelFallbackWarning(UserWarning):
    """Camera worker processes could not start (or died); the cameras run in threads instead."""


@dataclass(frozen=True)
class SpeedOptions:
    """How a capture is read and detected.

    Attributes:
        workers: processes or threads for the cameras (0: one per CPU core, at most one per
            camera; 1: one camera after the other in this process).
        parallel: ``"threads"`` (default) or ``"processes"`` (:mod:`~spinemocap.app.camera_processes`;
            images are still read in threads).
        prefetch: frames decoded ahead of the tracker (0: read when needed).
        predict: sequence mode searches only each camera's predicted tape box.
        refresh_every: frames between full searches.
        min_dot_share: a predicted box must find this share of the camera's dots of the previous
            frame, else that camera is searched in full.
        box_margin_px: px added around the predicted dots' box before the training crops' padding
            (half the box per side). 20 px: wider cost detection CPU for no better dots, narrower
            missed dots.
        batch: stage 1 of all cameras in one network pass (else one pass per camera).
        device: where the network runs (``auto``: CUDA when torch sees it, else CPU).
        opencv_threads: OpenCV's threads while cameras run in parallel threads (restored
            afterwards). 1: serial OpenCV per camera thread (a pool per core spins on the small
            images on many-core machines); None: leave OpenCV's setting.
        masks_always: read ``masks/`` even when the detector does not use them (the serial
            pipeline's behaviour, for the speed benchmark's peer).
        lookahead: frames whose detection may run ahead of the tracker. 0: the exact serial
            order. 1: frame t+1 is detected while frame t is solved, its boxes predicted from
            frame t-1 over two frames; the dots may then differ slightly from lookahead 0's.
        lookahead_margin_px: box margin added per extra predicted frame.
        stage1_in_pool: with cameras in threads and the network on the CPU, each camera's full
            search runs its own stage 1 in its camera thread (same boxes, same output) instead of
            one batched pass in the calling thread. On a GPU stage 1 stays batched.
        precision: the network's arithmetic (``spinemocap.detect.Detector``'s ``precision``;
            ``auto``: :func:`spinemocap.detect.detector.auto_precision`).
        refresh: ``"frame"`` (every camera in the same frame, every ``refresh_every`` frames) or
            ``"camera"`` (each camera ``refresh_every`` frames after its own last full search,
            the cameras' refreshes spread over the period).
        refresh_settled_every: with ``refresh="camera"``, the period of a *settled* camera (its
            last search found at least the dots of the one before, its box at least
            ``SETTLED_EDGE_PX`` inside the image); 0: ``refresh_every``.
        frames_at_once: frames detected at the same time, their camera images sharing the
            workers (then ``workers`` 0 means one per CPU core, not capped at the cameras; with
            ``parallel="processes"`` each worker a process of its own). Needs ``predict=False``:
            every frame is searched in full, so no frame waits for another's solution and the
            views are those of one frame at a time, whatever the timing. 1: one frame at a time.
        candidate_workers: processes that build the tracker's candidate stage ahead of it
            (:mod:`~spinemocap.app.candidates_ahead`; the same output); 0: the tracker builds it.
            Used in sequence mode when detection does not predict (``predict=False``).
        candidate_depth: frames the candidate stage is built ahead of the tracker.

    Raises:
        InputError: a negative ``lookahead``, an unknown ``refresh``, a period below 1,
            ``frames_at_once`` below 1 or above 1 with prediction on, or candidate workers
            below 0 or with prediction on.
    """

    workers: int = 0
    parallel: str = "threads"
    prefetch: int = 2
    predict: bool = True
    refresh_every: int = 10
    min_dot_share: float = 0.8
    box_margin_px: float = 20.0
    batch: bool = True
    device: str = "auto"
    opencv_threads: int | None = 1
    masks_always: bool = False
    lookahead: int = 0
    lookahead_margin_px: float = 0.0
    stage1_in_pool: bool = True
    precision: str = "auto"
    refresh: str = "frame"
    refresh_settled_every: int = 0
    frames_at_once: int = 1
    candidate_workers: int = 0
    candidate_depth: int = 2

    def __post_init__(self) -> None:
        if self.lookahead < 0:
            raise InputError("lookahead", f"must be 0 or more, got {self.lookahead}")
        if self.refresh not in REFRESH:
            raise InputError("refresh", f"unknown refresh schedule {self.refresh!r} (choose {', '.join(REFRESH)})")
        if self.refresh_every < 1 or self.refresh_settled_every < 0:
            raise InputError("refresh_every", f"must be 1 or more (settled: 0 or more), got {self.refresh_every}, "
                             f"{self.refresh_settled_every}")
        if self.frames_at_once < 1:
            raise InputError("frames_at_once", f"must be 1 or more, got {self.frames_at_once}")
        if self.candidate_workers < 0 or self.candidate_depth < 1:
            raise InputError("candidate_workers", f"workers must be 0 or more and depth 1 or more, got "
                             f"{self.candidate_workers} and {self.candidate_depth}")
        if self.candidate_workers > 0 and self.predict:
            raise InputError("candidate_workers", "the candidate workers build frames ahead of the tracker, which "
                             "prediction cannot wait for: turn prediction off (`frames_at_once=N` or `predict=False`)")
        if self.frames_at_once > 1 and self.predict:
            raise InputError("frames_at_once", "frames detected at once are each searched in full: "
                             "turn prediction off (`predict=False`)")

    def camera_period(self, settled: bool) -> int:
        """Frames between a camera's full searches (``refresh="camera"``)."""
        return self.refresh_settled_every if settled and self.refresh_settled_every > 0 else self.refresh_every

    def n_workers(self, n_cameras: int) -> int:
        """Processes or threads for ``n_cameras`` cameras: ``workers`` (0: one per CPU core), at
        most one per camera unless several frames are detected at once."""
        wanted = self.workers or os.cpu_count() or 1
        return max(1, wanted if self.frames_at_once > 1 else min(n_cameras, wanted))


SERIAL = SpeedOptions(workers=1, parallel="threads", prefetch=0, predict=False, batch=False, device="cpu", opencv_threads=None,
                      masks_always=True, lookahead=0, precision="float32")


# ---------------------------------------------------------------------- reading
def read_masks(mask_dir: Path, camera_names: Sequence[str], frame: int,
               images: Sequence[np.ndarray | None] | None = None) -> list[np.ndarray | None]:
    """The synthetic studio's ground-truth tape masks of one frame (``masks/<cam>/NNNNNN.png``),
    each checked against the size of its camera's image when ``images`` are given (None for a
    camera without an image in this frame)."""
    masks: list[np.ndarray | None] = []
    for k, cam in enumerate(camera_names):
        if images is not None and images[k] is None:
            masks.append(None)
            continue
        path = mask_dir / cam / f"{frame:06d}.png"
        mask = read_image(path)
        if images is not None:
            height, width = images[k].shape[:2]  # type: ignore[union-attr]
            check_image_size(mask, (width, height), cam, path)
        masks.append(mask[:, :, 0] > 127)
    return masks


def _read_frame(source: FrameSource, frame: int, pool: ThreadPoolExecutor | None) -> list[np.ndarray | None]:
    read_camera = getattr(source, "read_camera", None)
    if pool is None or read_camera is None:
        return source.read(frame)
    return list(pool.map(lambda k: read_camera(k, frame), range(len(source.camera_names))))


def prefetched_frames(source: FrameSource, frames: Sequence[int], mask_dir: Path | None = None,
                      workers: int = 1, prefetch: int = 2,
                      stage: Callable[[list[np.ndarray | None]], list[np.ndarray | None]] | None = None
                      ) -> Iterator[tuple[int, list[np.ndarray | None], list[np.ndarray | None] | None]]:
    """Yield ``(frame, images, masks)`` (BGR uint8 per camera, None for a camera without a frame
    there; masks only from ``mask_dir``, else None). Cameras are decoded by ``workers`` threads; with ``prefetch`` > 0 a background
    thread keeps up to that many frames decoded ahead. ``stage``: applied to each frame's images
    by the reader (:meth:`CaptureDetector.stage`: copied into the camera processes' shared
    memory ahead of detection). Errors of the reader are raised here."""
    pool = ThreadPoolExecutor(workers, thread_name_prefix="read") if workers > 1 else None

    def load(frame: int):
        images = _read_frame(source, frame, pool)
        if stage is not None:
            images = stage(images)
        masks = read_masks(mask_dir, source.camera_names, frame, images) if mask_dir is not None else None
        return frame, images, masks

    try:
        if prefetch <= 0:
            for frame in frames:
                yield load(frame)
            return
        yield from _in_background(load, frames, prefetch)
    finally:
        if pool is not None:
            pool.shutdown(wait=True)


def _in_background(load, frames: Sequence[int], depth: int):
    done = object()
    buffer: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                buffer.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for frame in frames:
                if not put(load(frame)):
                    return
            put(done)
        except BaseException as exc:  # handed to the consumer, raised there
            put(exc)

    thread = threading.Thread(target=work, name="prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item = buffer.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join()


def _close(frames: Iterator) -> None:
    """Close a frame iterator that can be closed (a generator: its reading thread stops)."""
    close = getattr(frames, "close", None)
    if close is not None:
        close()


def detected_ahead(frames_in: Iterator[tuple[int, list[np.ndarray | None], list[np.ndarray | None] | None]],
                   detect: "CaptureDetector", lookahead: int) -> Iterator[tuple[int, list, float]]:
    """Yield ``(frame, views, wait_ms)`` for the tracker with detection in a background thread that
    runs up to ``lookahead`` frames ahead of it: the ``i``-th frame is detected once the tracker
    has asked for frame ``i - lookahead``, i.e. is done with every frame before it (and has told
    the detector their dots: ``run_tracking`` calls ``on_frame`` before it asks for the next
    frame). So frame t+1 is detected while the tracker solves frame t (two cores busy), memory
    stays bounded, and the prediction of frame ``i`` always starts from the same solved frame
    (``i - 1 - lookahead``): the output does not depend on the threads' timing. ``wait_ms``: the
    time the tracker waited for the frame. Errors of the reader or detector are raised here;
    closing this generator (the tracker stopped, Ctrl-C) stops the thread and waits for it."""
    ready = threading.Condition()
    state = {"taken": 0, "stop": False}
    out: queue.Queue = queue.Queue()
    done = object()

    def work() -> None:
        try:
            for i, (frame, images, masks) in enumerate(frames_in):
                with ready:
                    while state["taken"] < i - lookahead and not state["stop"]:
                        ready.wait(0.1)
                    if state["stop"]:
                        return
                out.put((frame, detect(frame, images, masks if detect.needs_masks else None)))
            out.put(done)
        except BaseException as exc:  # handed to the tracker's thread, raised there
            out.put(exc)
        finally:
            _close(frames_in)

    thread = threading.Thread(target=work, name="detect-ahead", daemon=True)
    thread.start()
    try:
        taken = 0
        while True:
            with ready:
                state["taken"] = taken
                ready.notify_all()
            t0 = time.perf_counter()
            item = out.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            frame, views = item
            yield frame, views, 1000 * (time.perf_counter() - t0)
            taken += 1
    finally:
        with ready:
            state["stop"] = True
            ready.notify_all()
        thread.join()


def detected_at_once(frames_in: Iterator[tuple[int, list[np.ndarray | None], list[np.ndarray | None] | None]],
                     detect: "CaptureDetector", at_once: int) -> Iterator[tuple[int, list, float]]:
    """Yield ``(frame, views, wait_ms)`` for the tracker, in order, with up to ``at_once`` frames
    detected at the same time (``SpeedOptions.frames_at_once``: their camera images share the
    detector's workers). Every frame is searched in full (``detect`` must not predict), so the
    views are those of detecting the frames one after the other. Memory stays bounded: at most
    ``at_once`` frames are held beyond the reader's. ``wait_ms``: the time the tracker waited for
    the frame (reading not hidden by the prefetching, plus detection). Errors of the reader or
    detector are raised here; closing the generator waits for the detections under way."""
    if detect.predicts:
        raise ValueError("frames detected at once must be searched in full (prediction off)")
    pool = ThreadPoolExecutor(max(1, at_once), thread_name_prefix="detect-frame")
    pending: deque = deque()
    frames_in = iter(frames_in)
    try:
        more = True
        while True:
            t0 = time.perf_counter()
            while more and len(pending) < at_once:
                item = next(frames_in, None)
                if item is None:
                    more = False
                    break
                frame, images, masks = item
                pending.append((frame, pool.submit(detect, frame, images, masks if detect.needs_masks else None)))
            if not pending:
                return
            frame, future = pending.popleft()
            views = future.result()
            yield frame, views, 1000 * (time.perf_counter() - t0)
    finally:
        for _, future in pending:
            future.cancel()
        pool.shutdown(wait=True)
        _close(frames_in)


# ---------------------------------------------------------------------- detection
class CaptureDetector:
    """``(frame, images, masks) -> [ViewDots per camera]`` for one rig (see the module docstring).

    ``name``: ``net`` / ``classical`` (:class:`spinemocap.detect.Detector`) or ``mask`` (dots
    inside given tape masks; always in threads: finding dots in given masks is cheap); ``weights``:
    the ``net`` detector's weights file (None: the shipped ones). Call
    :meth:`observe` with each frame's solved dots (mm, world) to enable prediction; :meth:`close`
    ends the worker processes or threads."""

    def __init__(self, name: str, rig: Rig | None = None, options: SpeedOptions | None = None,
                 weights: Path | None = None):
        self.name = name
        self.rig = rig
        self.options = options or SpeedOptions()
        self.weights = weights
        self.detector: Detector | None = None
        if name in ("net", "classical"):
            try:  # the network detector loads torch: imported only when chosen
                from ..detect import Detector
            except ImportError as exc:
                raise InputError(None, f"detector {name!r} is not available in this installation ({exc})") from exc
            self.detector = (Detector(name=name, device=self.options.device, precision=self.options.precision,
                                      weights=weights)
                             if name == "net" else Detector(name=name))
        elif name != "mask":
            raise InputError(None, f"unknown detector {name!r} (choose net, classical or mask)")
        # stage 1 per camera in the pool on the CPU; on a GPU one batched pass serves all cameras
        self._stage1_in_pool = self.options.stage1_in_pool and self._network_on_cpu()
        mode = resolve_parallel(self.options.parallel)
        self._n = self.options.n_workers(len(rig) if rig is not None else os.cpu_count() or 1)
        self._processes: CameraProcesses | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._opencv_threads_before: int | None = None
        if self._n > 1 and mode == "processes" and self.detector is not None:
            self._processes = self._start_processes()
        if self._n > 1 and self._processes is None:
            self._start_threads()
        self.info = DetectorInfo(self.parallel, self._n)
        self._observed: dict[int, np.ndarray | None] = {}  # frame -> its solved dots (D, 3), None: unsolved
        self._boxes: dict[int, Box] = {}             # camera -> last frame's tape box
        self._counts: dict[int, int] = {}            # camera -> dots found in the last frame
        self._since_full = 0
        self._since_search: dict[int, int] = {}      # camera -> predicted frames since its full search
        self._settled: dict[int, bool] = {}          # camera -> settled (SpeedOptions.refresh_settled_every)
        self._first: int | None = None               # the first frame detected (by prediction's rules)
        self.searches: dict[DetectionRoute, int] = {"full": 0, "predicted": 0, "fallback": 0, "refresh": 0}  # images per route
        self._searches_lock = threading.Lock()
        # camera index -> capture frames it had no image for (its clock, a drop); also info.missing_frames
        # by camera name (the rig's; without a rig the index as text)
        self.missing: dict[int, list[int]] = {}

    @property
    def needs_masks(self) -> bool:
        """Does detection read the capture's ground-truth masks (``mask`` detector)?"""
        return self.name == "mask"

    @property
    def predicts(self) -> bool:
        return (self.options.predict and self.rig is not None and self.detector is not None
                and self.detector.searches_boxes)

    @property
    def parallel(self) -> str:
        """How the cameras run now: ``processes``, ``threads`` or ``serial``."""
        return "processes" if self._processes is not None else "threads" if self._pool is not None else "serial"

    def _network_on_cpu(self) -> bool:
        from ..detect.detector import resolve_device

        return self.name != "net" or resolve_device(self.options.device) == "cpu"

    def _start_processes(self) -> CameraProcesses | None:
        from ..detect.detector import resolve_device

        device = resolve_device(self.options.device) if self.name == "net" else "cpu"
        # see CameraProcesses.stage: the frames in detection, those queued by the reader and the one it stages
        staged = self.options.prefetch + self.options.frames_at_once + 1 if self.options.prefetch > 0 else 0
        try:
            return CameraProcesses(self.name, self._n, device, staged=staged,
                                   precision=self.options.precision if self.name == "net" else "float32",
                                   weights=self.weights if self.name == "net" else None)
        except ProcessesUnavailable as exc:
            self._fall_back(f"camera worker processes could not start ({exc})")
            return None

    def _fall_back(self, why: str) -> None:
        message = f"{why}; detecting the cameras in {self._n} threads instead"
        log.warning("%s", message)
        warnings.warn(message, ParallelFallbackWarning, stacklevel=3)

    def _start_threads(self) -> None:
        self._pool = ThreadPoolExecutor(self._n, thread_name_prefix="detect")
        if self.options.opencv_threads is not None:
            self._opencv_threads_before = cv2.getNumThreads()
            cv2.setNumThreads(self.options.opencv_threads)

    def stage(self, images: list[np.ndarray | None]) -> list[np.ndarray | None]:
        """For the reading thread: with camera processes, copy a frame's images into their shared
        memory ahead of its detection (the frame must then be detected in reading order). A frame
        that lacks a camera's image stays here (:meth:`__call__` detects it in this process)."""
        processes = self._processes
        if processes is None or any(image is None for image in images):
            return images
        return processes.stage(images)  # type: ignore[arg-type, return-value]

    def close(self) -> None:
        """Stop the worker processes or threads (also after Ctrl-C) and restore OpenCV's threads."""
        if self._processes is not None:
            self._processes.close()
            processes = self._processes
            self.info.startup_s, self.info.workers_cpu_s = processes.startup_s, processes.cpu_s
            # per detection pass, the slowest camera's time in its worker (ms): what the pass
            # costs at best; the rest of detect's time is the round trip
            self.info.slowest_camera_ms = 1000 * processes.slowest_s / max(processes.calls, 1)
            self._processes = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._opencv_threads_before is not None:
            cv2.setNumThreads(self._opencv_threads_before)
            self._opencv_threads_before = None

    def _map(self, fn, items):
        return list(self._pool.map(fn, items)) if self._pool is not None else [fn(x) for x in items]

    # ------------------------------------------------------------------ per frame
    def __call__(self, frame: int, images: list[np.ndarray | None], masks: list[np.ndarray | None] | None
                 ) -> list[ViewDots]:
        """The views of capture frame ``frame``: one per camera, an empty one for a camera whose
        image is None (it has no frame there; recorded in :attr:`missing`)."""
        if any(image is None for image in images):
            return self._with_missing(frame, images, masks)
        # the list itself, not a copy: images staged in the camera processes' shared memory are
        # detected there without a second copy (and frames detected at once need not take turns)
        return self._every_camera(frame, cast("list[np.ndarray]", images), masks)

    def _every_camera(self, frame: int, images: list[np.ndarray], masks: list[np.ndarray | None] | None
                      ) -> list[ViewDots]:
        """:meth:`__call__` for a frame every camera has an image of."""
        if self.name == "mask":
            if masks is None:
                raise InputError(None, "detector 'mask' needs tape masks (synthetic captures have masks/)")
            return self._map(lambda c: _dots_in_mask(c, images[c], masks[c]), range(len(images)))
        if not self.predicts:
            if self.detector is not None and self.detector.searches_boxes and self.options.batch:
                return self._full(images, range(len(images)))
            self._count("full", len(images))
            return self._run(images, range(len(images)), [None] * len(images))
        plan = self._plan(frame)
        if self._cameras_whole_in_pool():
            # each camera's box, search, fallback and remembered box in its camera thread: no
            # camera's fallback waits for the frame's slowest camera, and the calling thread's
            # per-camera work runs beside the other cameras' (the same views: _camera_view)
            return self._map(lambda c: self._camera_view(c, images[c], plan), range(len(images)))
        if plan.full:
            views = self._full(images, range(len(images)))
            for c in range(len(images)):
                self._searched(c, full=True, whole_frame=True)
            return views
        refresh = [self._refresh_due(c) for c in range(len(images))]
        boxes = [None if refresh[c] else _listed(self._camera_box(c, plan, image.shape[:2]))
                 for c, image in enumerate(images)]
        views = self._run(images, range(len(images)), boxes)
        self.searches["predicted"] += len(images) - sum(refresh)
        self.searches["refresh"] += sum(refresh)
        self.searches["full"] += sum(refresh)
        redo = [c for c, v in enumerate(views) if not refresh[c] and self._too_few(v)]
        if redo:
            self.searches["fallback"] += len(redo)
            for c, v in zip(redo, self._full(images, redo, copy=False)):
                views[c] = v
        for c in range(len(images)):
            self._searched(c, full=refresh[c] or c in redo, whole_frame=False)
        self._remember(views)
        return views

    def _with_missing(self, frame: int, images: list[np.ndarray | None], masks: list[np.ndarray | None] | None
                      ) -> list[ViewDots]:
        """A frame some cameras have no image of: those get empty views, the others a full
        search each in this process's threads (no prediction: a rare frame), remembered for the
        next frame's prediction only where every camera was seen."""
        for c, image in enumerate(images):
            if image is None:
                self._note_missing(c, frame)

        def view(c: int) -> ViewDots:
            image = images[c]
            if image is None:
                return empty_view(c)
            if self.name == "mask":
                if masks is None or masks[c] is None:
                    raise InputError(None, "detector 'mask' needs tape masks (synthetic captures have masks/)")
                return _dots_in_mask(c, image, masks[c])
            self._count("full", 1)
            return self._detect(c, image, None)

        return self._map(view, range(len(images)))

    def _count(self, route: DetectionRoute, images: int) -> None:
        """Count ``images`` camera images searched by ``route`` (frames may be detected at once)."""
        with self._searches_lock:
            self.searches[route] += images

    def _note_missing(self, camera: int, frame: int) -> None:
        with self._searches_lock:
            self.missing.setdefault(camera, []).append(int(frame))
            names = self.rig.names if self.rig is not None else [str(c) for c in range(max(self.missing) + 1)]
            self.info.missing_frames = {names[c]: list(frames) for c, frames in sorted(self.missing.items())}

    def _cameras_whole_in_pool(self) -> bool:
        """Does a frame's every camera run whole (box, search, fallback) in the camera threads?
        With threads and stage 1 in the pool (a full search per camera in its thread either way):
        the views, searches and remembered boxes of :meth:`__call__`'s frame-wide steps, camera by
        camera (each camera's fallback test reads its own last count only)."""
        return self._pool is not None and self._processes is None and self._stage1_in_pool

    def full_search_next(self) -> bool:
        """Will the next frame :meth:`__call__` detects be searched in full by the refresh schedule
        (:meth:`_plan`'s first test, ``refresh_every``)? Its detection then needs no solved
        frame: :meth:`frames_in_order` starts it before the tracker solves the frame before."""
        return self.predicts and self._first is not None and self._frame_refresh_due()

    def _frame_refresh_due(self) -> bool:
        """Is the ``refresh="frame"`` schedule's full search of every camera due in the next
        planned frame (every ``refresh_every`` planned frames)?"""
        return self.options.refresh == "frame" and self._since_full + 1 >= self.options.refresh_every

    def frames_in_order(self, frames_in: Iterator[tuple[int, list[np.ndarray | None], list[np.ndarray | None] | None]]
                        ) -> Iterator[tuple[int, list[ViewDots], float]]:
        """Yield ``(frame, views, wait_ms)`` frame by frame in the exact serial order (lookahead 0:
        each frame detected after the tracker solved the one before and told :meth:`observe`),
        except that a frame due for a refresh (:meth:`full_search_next`: every camera searched
        in full, no prediction) is started in a background thread before the frame before it is
        handed to the tracker, so its detection runs while the tracker solves that frame. The
        same views as detecting every frame after the tracker: a full search reads no solved
        frame, and the tracker's steps read nothing the detection writes. ``wait_ms``: the time
        the tracker waited for the frame. Errors are raised here; closing the generator waits for
        a detection under way."""
        ahead = ThreadPoolExecutor(1, thread_name_prefix="detect-refresh")
        frames_in = iter(frames_in)
        pending = None  # the started detection of the next frame
        try:
            t0 = time.perf_counter()
            item = next(frames_in, None)
            while item is not None:
                frame, images, masks = item
                views = pending.result() if pending is not None else self(frame, images, masks if self.needs_masks else None)
                pending = None
                item = next(frames_in, None)
                if item is not None and self.full_search_next():
                    pending = ahead.submit(self, item[0], item[1], item[2] if self.needs_masks else None)
                yield frame, views, 1000 * (time.perf_counter() - t0)
                t0 = time.perf_counter()
        finally:
            if pending is not None:
                pending.cancel()
            ahead.shutdown(wait=True)
            _close(frames_in)

    def _too_few(self, view: ViewDots) -> bool:
        """Did a predicted box find fewer than ``min_dot_share`` of the camera's last frame's dots?"""
        return len(view) < self.options.min_dot_share * self._counts.get(view.camera, 0)

    def _full(self, images: list[np.ndarray], cameras: Sequence[int], copy: bool = True) -> list[ViewDots]:
        """Full two-stage search of the given cameras (stage 1 batched over them in this process;
        in worker processes, and in threads with ``stage1_in_pool`` on the CPU, each does its
        camera's stage 1 in the pool, beside the other cameras' work: the same boxes)."""
        cameras = list(cameras)
        if self._processes is not None or (self._pool is not None and self._stage1_in_pool):
            views = self._run(images, cameras, [None] * len(cameras), copy)
        else:
            views = self._run(images, cameras, self._loaded_detector().tape_boxes([images[c] for c in cameras]))
        self._count("full", len(cameras))
        if self.predicts and len(cameras) == len(images):  # what prediction starts from (unused without it)
            self._remember(views)
        return views

    def _run(self, images: list[np.ndarray], cameras: Sequence[int], boxes: Sequence[list[Box] | None],
             copy: bool = True) -> list[ViewDots]:
        """Detect ``images[c]`` for each ``c`` in ``cameras`` in ``boxes[k]`` (None: the full
        search), in the worker processes or threads; processes that die fall back to threads."""
        cameras = list(cameras)
        if self._processes is not None:
            try:
                return self._processes.detect(images, cameras, boxes, copy)
            except (BrokenProcessPool, ProcessesUnavailable) as exc:
                self._processes.close()
                self._processes = None
                why = "a camera worker process died" if isinstance(exc, BrokenProcessPool) else "camera worker processes"
                self._fall_back(f"{why} ({exc})")
                self._start_threads()
                self.info.parallel = "threads (fallback from processes)"
        return self._map(lambda k: self._detect(cameras[k], images[cameras[k]], boxes[k]), range(len(cameras)))

    def _detect(self, camera: int, image: np.ndarray, boxes: list[Box] | None) -> ViewDots:
        # In sequence tracking (prediction on) each frame's views are dropped once the frame is
        # solved, and MRF2 reads the grey images in few frames: they are made when read. Without
        # prediction (the benchmarks keep every frame's views) they are made now, holding a third
        # of the colour image's memory. (The images here are the reader's own arrays, also after
        # camera processes fell back to threads: only the workers' copies lie in shared memory.)
        return self._loaded_detector().detect(image, camera=camera, boxes=boxes, grey_now=not self.predicts)

    def _loaded_detector(self) -> Detector:
        if self.detector is None:
            raise ValueError(f"detector {self.name!r} finds dots in given masks, not in images")
        return self.detector

    def _camera_view(self, camera: int, image: np.ndarray, plan: "_Plan") -> ViewDots:
        """One camera's view of a frame searched by ``plan`` (:meth:`_plan`), with its fallback
        to the full search, remembered for its next frame: what :meth:`__call__` does for each
        camera, for one camera alone (:meth:`stream`; a camera's frames in order, different
        cameras at once)."""
        routes: tuple[DetectionRoute, ...]
        if plan.full:
            view, routes = self._detect(camera, image, None), ("full",)
        elif self.predicts and self._refresh_due(camera):
            view, routes = self._detect(camera, image, None), ("refresh", "full")
        else:
            box = self._camera_box(camera, plan, image.shape[:2])
            view, routes = self._detect(camera, image, _listed(box)), ("predicted",)
            if self._too_few(view):
                view, routes = self._detect(camera, image, None), ("predicted", "fallback", "full")
        with self._searches_lock:
            for route in routes:
                self.searches[route] += 1
        if self.predicts:
            self._searched(camera, full="full" in routes, whole_frame=plan.full)
            self._remember([view])
        return view

    def _remember(self, views: list[ViewDots]) -> None:
        for v in views:
            box = mask_box(v.mask)
            self._settled[v.camera] = (box is not None and v.mask is not None and len(v) >= self._counts.get(v.camera, 0)
                                       and _well_inside(box, v.mask.shape[:2], SETTLED_EDGE_PX))
            self._counts[v.camera] = len(v)
            if box is None:
                self._boxes.pop(v.camera, None)
            else:
                self._boxes[v.camera] = box

    # ------------------------------------------------------------------ streamed cameras
    @property
    def streams(self) -> bool:
        """Can the cameras run through the frames on their own (:meth:`stream`): threads, a
        detector that reads images (not ``mask``)?"""
        return self._pool is not None and self.detector is not None

    def stream(self, frames_in: Iterator[tuple[int, list[np.ndarray | None], list[np.ndarray | None] | None]],
               lookahead: int) -> Iterator[tuple[int, list[ViewDots], float]]:
        """Yield ``(frame, views, wait_ms)`` in order, the cameras in the thread pool, each
        running through the frames on its own: camera c starts frame i once it is done with
        frame i - 1 and, with prediction, once the tracker has solved frame i - 1 - ``lookahead``
        (whose dots predict frame i's boxes, :meth:`_plan`; :meth:`observe` is called before
        the tracker asks for the next frame), so no camera waits for the slowest camera of a
        frame, and with ``lookahead`` >= 1 the cameras work on frame t + 1 while the tracker
        solves frame t. The views are those :meth:`__call__` gives frame by frame with the same
        ``lookahead``. ``wait_ms``: the time the tracker waited for the frame. Errors of the
        reader or of a camera are raised here; closing the generator (the tracker stopped,
        Ctrl-C) stops the reading and waits for the detections running."""
        pool = self._pool
        if not self.streams or pool is None:
            raise ValueError("stream() needs the cameras in threads and a detector that reads images")
        steps = 1 + lookahead
        cond = threading.Condition()
        # by frame index, dropped when handed to the tracker: (frame, images), plan, views, cameras left
        read: dict[int, tuple[int, list[np.ndarray | None]]] = {}
        plans: dict[int, _Plan] = {}
        views: dict[int, list[ViewDots | None]] = {}
        left: dict[int, int] = {}
        next_index: dict[int, int] = {}  # camera -> the index of its next frame
        busy: set[int] = set()           # cameras with a detection in the pool
        state: dict = {"read": 0, "planned": 0, "observed": 0, "cameras": 0, "ended": False, "stop": False,
                       "error": None, "error_at": None}  # the error and the frame index it belongs to

        def plan_ready(i: int) -> bool:  # under cond
            if not self.predicts or i == 0:
                return True
            if i - steps >= 0:
                return state["observed"] >= i - steps + 1
            return left.get(i - 1, 0) == 0  # the first frames: their boxes come from the last detected frame

        def advance() -> None:  # under cond: plan the next frames, start the cameras that can go
            while state["planned"] < state["read"] and plan_ready(state["planned"]):
                i = state["planned"]
                plans[i] = self._plan(read[i][0]) if self.predicts else _FULL
                state["planned"] = i + 1
            for camera in range(state["cameras"]):
                i = next_index.get(camera, 0)
                failed = state["error_at"] is not None and i >= state["error_at"]
                if camera not in busy and i < state["planned"] and not state["stop"] and not failed:
                    busy.add(camera)
                    pool.submit(detect_one, camera, i)

        def fail(exc: BaseException, i: int) -> None:  # under cond: the frames before i are still handed out
            if state["error_at"] is None or i < state["error_at"]:
                state["error"], state["error_at"] = exc, i
            cond.notify_all()

        def detect_one(camera: int, i: int) -> None:
            try:
                frame, images = read[i]
                image = images[camera]
                if image is None:  # the camera has no frame here: an empty view, nothing remembered
                    self._note_missing(camera, frame)
                    view = empty_view(camera)
                else:
                    view = self._camera_view(camera, image, plans[i])
                with cond:
                    views[i][camera] = view
                    left[i] -= 1
                    next_index[camera] = i + 1
                    busy.discard(camera)
                    advance()
                    cond.notify_all()
            except BaseException as exc:  # handed to the tracker's thread, raised there
                with cond:
                    busy.discard(camera)
                    fail(exc, i)

        def read_frames() -> None:
            try:
                for i, (frame, images, _masks) in enumerate(frames_in):
                    with cond:
                        while i > state["observed"] + lookahead and not state["stop"]:
                            cond.wait(0.1)
                        if state["stop"]:
                            return
                        read[i], views[i], left[i] = (frame, images), [None] * len(images), len(images)
                        state["read"], state["cameras"] = i + 1, len(images)
                        advance()
                        cond.notify_all()
            except BaseException as exc:
                with cond:
                    fail(exc, state["read"])
            finally:
                with cond:
                    state["ended"] = True
                    cond.notify_all()
                _close(frames_in)

        reader = threading.Thread(target=read_frames, name="detect-stream", daemon=True)
        reader.start()
        try:
            i = 0
            while True:
                t0 = time.perf_counter()
                with cond:
                    while (left.get(i) != 0 and not (state["error_at"] is not None and i >= state["error_at"])
                           and not (state["ended"] and i >= state["read"])):
                        cond.wait(0.1)
                    if state["error_at"] is not None and i >= state["error_at"]:
                        raise state["error"]
                    if i >= state["read"]:
                        return
                    (frame, _), frame_views = read.pop(i), views.pop(i)
                    plans.pop(i)
                    left.pop(i)
                wait_ms = 1000 * (time.perf_counter() - t0)
                yield frame, frame_views, wait_ms  # type: ignore[misc]
                with cond:  # the tracker has solved the frame and told observe()
                    state["observed"] = i + 1
                    advance()
                    cond.notify_all()
                i += 1
        finally:
            with cond:
                state["stop"] = True
                cond.notify_all()
            reader.join()
            with cond:
                while busy:
                    cond.wait(0.1)

    # ------------------------------------------------------------------ prediction
    def observe(self, frame: int, positions: np.ndarray | None) -> None:
        """The tracker's dots of ``frame`` (D, 3) mm, world (None or all-NaN: not solved). Frames
        are numbered consecutively; detecting frame f predicts from frames f - 1 - lookahead and
        the one before it (:class:`SpeedOptions`), so the prediction does not depend on how far
        the tracker has got (the same dots however the threads are timed)."""
        solved = positions is not None and np.isfinite(positions).any()
        self._observed[frame] = np.asarray(positions, float).copy() if solved else None
        keep = self.options.lookahead + 3
        for old in [f for f in list(self._observed) if f <= frame - keep]:
            self._observed.pop(old, None)

    def _plan(self, frame: int) -> "_Plan":
        """How ``frame``'s cameras are searched (called for the frames in order): in full (the
        first frame, no solved frame to predict from, or with ``refresh="frame"`` a refresh is
        due: every ``refresh_every`` planned frames; with ``refresh="camera"`` each camera's own
        refresh is decided when it is detected, :meth:`_refresh_due`) or in the boxes predicted
        from the dots of the frame ``1 + lookahead`` before it, moved on by their velocity
        (:meth:`_camera_box`). The sequence's first frames ahead of the tracker (no solved frame
        can be there yet) search the last detected frame's tape boxes with the margin (as
        lookahead 0 predicts the second frame: the same full-search schedule). A camera's
        fallback to the full search does not move the ``frame`` schedule (it restarts that
        camera's ``camera`` schedule)."""
        steps = 1 + self.options.lookahead
        if self._first is None:
            self._first = frame
        if self._frame_refresh_due():
            return self._planned(_FULL)
        last = self._observed.get(frame - steps)
        if last is None:
            return self._planned(_BOXES_ALONE if frame - steps < self._first and self._boxes else _FULL)
        before_last = self._observed.get(frame - steps - 1)
        velocity = np.nan_to_num(last - before_last) if before_last is not None else np.zeros_like(last)
        predicted = last + steps * velocity
        if steps > 1:  # where the dots were in the last detected frame, the one the boxes come from
            last = last + (steps - 1) * velocity
        ok = np.isfinite(predicted).all(axis=1)
        return self._planned(_Plan(False, predicted[ok], last[ok]))

    def _refresh_due(self, camera: int) -> bool:
        """Is ``camera``'s periodic full search due in the frame being detected
        (``refresh="camera"``)? Reads only this camera's own state (its frames come in order)."""
        if self.options.refresh != "camera":
            return False
        period = self.options.camera_period(self._settled.get(camera, False))
        return self._since_search.get(camera, 0) + 1 >= period

    def _searched(self, camera: int, full: bool, whole_frame: bool) -> None:
        """Count ``camera``'s frames since its last full search. After a frame searched in full
        camera c starts ``c * refresh_every // cameras`` frames into its period: the cameras'
        refreshes spread over it."""
        if not full:
            self._since_search[camera] = self._since_search.get(camera, 0) + 1
        elif whole_frame and self.rig is not None:
            self._since_search[camera] = camera * self.options.refresh_every // len(self.rig)
        else:
            self._since_search[camera] = 0

    def _planned(self, plan: "_Plan") -> "_Plan":
        self._since_full = 0 if plan.full else self._since_full + 1
        return plan

    def _camera_box(self, camera: int, plan: "_Plan", shape: tuple[int, int]) -> Box | None:
        """The box to search in camera ``camera`` (image ``shape``) by ``plan``: the predicted
        dots' outline joined with the camera's last tape box moved with them, grown by the margin
        and padded like the training crops; None (nothing to search) when the camera saw no tape
        in its last frame or no predicted dot falls into its image (a tape coming into view is
        found by the next full search). Needs only this camera's last frame."""
        if camera not in self._boxes:
            return None
        ys, xs = self._boxes[camera]
        m = self.options.box_margin_px
        if plan.predicted is None:  # the last frame's box alone
            return _training_padded_box(xs.start - m, ys.start - m, xs.stop + m, ys.stop + m, shape)
        if self.rig is None or plan.last is None:
            raise ValueError("predicted boxes need the rig and the dots the boxes were last seen with")
        cam = self.rig[camera]
        now, before = cam.project(plan.predicted), cam.project(plan.last)
        inside = cam.in_image(now) & np.isfinite(before).all(axis=1)
        if not inside.any():
            return None
        x0, x1 = now[inside, 0].min(), now[inside, 0].max()
        y0, y1 = now[inside, 1].min(), now[inside, 1].max()
        shift = np.median(now[inside] - before[inside], axis=0)  # last frame's outline moved with the dots
        x0, x1 = min(x0, xs.start + shift[0]), max(x1, xs.stop + shift[0])
        y0, y1 = min(y0, ys.start + shift[1]), max(y1, ys.stop + shift[1])
        m += self.options.lookahead * self.options.lookahead_margin_px
        return _training_padded_box(x0 - m, y0 - m, x1 + m, y1 + m, shape)


@dataclass(frozen=True)
class _Plan:
    """How one frame's cameras are searched: ``full`` (every camera in full), else the boxes
    predicted from the dots ``predicted`` (D, 3) mm, world, which were at ``last`` in the frame
    the cameras' last tape boxes come from (both None: those boxes alone, with the margin)."""

    full: bool
    predicted: np.ndarray | None = None
    last: np.ndarray | None = None


_FULL = _Plan(True)
_BOXES_ALONE = _Plan(False)


def _training_padded_box(x0: float, y0: float, x1: float, y1: float, shape: tuple[int, int]) -> Box:
    from ..detect.detector import padded_box

    return padded_box(max(0.0, x0), max(0.0, y0), min(float(shape[1]), x1), min(float(shape[0]), y1), shape)


def _well_inside(box: Box, shape: tuple[int, int], edge_px: float) -> bool:
    """Does ``box`` lie at least ``edge_px`` from every edge of an image of ``shape`` (h, w)?"""
    ys, xs = box
    return (ys.start >= edge_px and xs.start >= edge_px and shape[0] - ys.stop >= edge_px
            and shape[1] - xs.stop >= edge_px)


def _listed(box: Box | None) -> list[Box]:
    return [] if box is None else [box]


def empty_view(camera: int) -> ViewDots:
    """The view of a camera that has no image in a frame: no dots, no mask, no image."""
    return ViewDots(camera, np.zeros((0, 2)), np.zeros(0))


def _dots_in_mask(camera: int, image: np.ndarray, mask: np.ndarray | None) -> ViewDots:
    if mask is None:
        raise InputError(None, f"detector 'mask' needs a tape mask for every camera; camera {camera} has none")
    uv, conf = find_dots(image, mask)
    return ViewDots(camera, uv, conf, mask=mask, image=to_grey(image))
