"""Detecting a frame's camera images in worker processes: a real pool, one detector per
worker, images passed through shared memory.

Threads share one interpreter lock, and detection's full-resolution clean-up (numpy on small
arrays, per-blob Python) holds it most of the time: six camera threads on 16 cores gave only
~1.4x one thread. :class:`CameraProcesses` runs ``n`` spawned processes instead, each with its own
:class:`~spinemocap.detect.Detector` (one torch and one OpenCV thread). For each frame the
caller's images are copied once into a shared-memory block (no pickled copies); a worker detects
one camera image there, writes its grey image (MRF2's evidence) next to it in the same block and
returns the dots plus the tape mask as its bounding box and the crop inside it (the mask is empty
elsewhere), so only a few kB travel back through the pool's pipe.

With prediction, detection of a frame ends before the next one's starts (sequence-mode
prediction needs the previous frame solved); frames searched in full may be detected at once
(:meth:`CameraProcesses.detect` may be called from several threads). The reading thread copies the next frames into a ring of blocks while a
frame is detected (:meth:`CameraProcesses.stage`), so the copy is off the tracker's path. Workers ignore SIGINT (the
parent stops them: Ctrl-C ends the run in the parent, which terminates its workers) and exit by
themselves when the parent dies.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing import shared_memory
from pathlib import Path
from typing import Sequence

import numpy as np

from ..views import ViewDots
from .worker_processes import exit_with_parent, join_or_kill, processes_cpu_s

log = logging.getLogger(__name__)

Box = tuple[slice, slice]
# (offset in bytes, shape) of one array in the shared block
Slot = tuple[int, tuple[int, ...]]

START_TIMEOUT_S = 180.0  # workers import torch and load the network: minutes at most on a loaded machine
STOP_GRACE_S = 2.0       # terminated workers get this long before they are killed
MAX_ATTACHED = 16        # blocks a worker keeps mapped (the ring and the direct block: a few)


class ProcessesUnavailable(RuntimeError):
    """The worker processes could not be started, or their shared memory cannot hold a frame
    (the caller falls back to threads)."""


def shared_memory_free() -> int | None:
    """Bytes free where POSIX shared memory lives (``/dev/shm`` on Linux; None where unknown).
    A block larger than this is created without complaint but kills the process (SIGBUS) when
    its pages are written, so blocks are checked against it first."""
    try:
        stat = os.statvfs("/dev/shm")
    except OSError:
        return None
    return stat.f_bavail * stat.f_frsize


class _Block:
    """One frame's images and grey images in a shared-memory block (made on first use, made
    again when the images' shapes change)."""

    def __init__(self) -> None:
        self.memory: shared_memory.SharedMemory | None = None
        self.layout: list[tuple[Slot, Slot]] = []   # per camera: (image, grey) slots
        self._key: tuple = ()

    def fill(self, images: Sequence[np.ndarray], copiers: ThreadPoolExecutor | None = None) -> None:
        """Copy ``images`` into the block (made or made again for their shapes); ``copiers``:
        threads that copy the cameras at the same time (a frame is tens of MB: one thread's copy
        is bound by one core's memory bandwidth)."""
        key = tuple((im.shape, im.dtype.str) for im in images)
        if self.memory is None or key != self._key:
            self.free()
            layout, offset = [], 0
            for im in images:
                if im.dtype != np.uint8:
                    raise ValueError(f"camera images must be uint8, got {im.dtype}")
                image_slot = (offset, tuple(im.shape))
                offset += _aligned(im.nbytes)
                grey_slot = (offset, tuple(im.shape[:2]))
                offset += _aligned(im.shape[0] * im.shape[1])
                layout.append((image_slot, grey_slot))
            free = shared_memory_free()
            if free is not None and offset > free:
                raise ProcessesUnavailable(f"shared memory (/dev/shm) has {free / 2**20:.0f} MiB free, a frame "
                                           f"needs {offset / 2**20:.0f} MiB")
            self.memory = shared_memory.SharedMemory(create=True, size=max(offset, 1))
            self.layout, self._key = layout, key
        memory = self.memory
        copies = [(_view(memory, image_slot, np.uint8), im) for im, (image_slot, _) in zip(images, self.layout)]
        if copiers is None or len(copies) < 2:
            for target, im in copies:
                np.copyto(target, im)
        else:
            list(copiers.map(lambda pair: np.copyto(*pair), copies))

    def free(self) -> None:
        if self.memory is not None:
            self.memory.close()
            self.memory.unlink()
            self.memory = None


class StagedImages(list):
    """A frame's camera images already copied into a block of ``owner`` (by :meth:`CameraProcesses.stage`)."""

    def __init__(self, images: Sequence[np.ndarray], owner: "CameraProcesses", block: _Block):
        super().__init__(images)
        self.owner, self.block = owner, block


class CameraProcesses:
    """A pool of ``n`` processes detecting camera images with ``Detector(name, device=device,
    precision=precision, weights=weights)`` (``weights`` None: the shipped ones).

    :meth:`detect` takes a frame's images (BGR uint8, one per camera) and per camera either a list
    of boxes to search or None (the full two-stage search, stage 1 on that image alone), and
    returns :class:`ViewDots` exactly as ``Detector.detect`` in this process would. A reading
    thread may copy frames into shared memory ahead of detection with :meth:`stage` (a ring of
    ``staged`` blocks: as many frames staged or in detection at once).
    Raises :class:`ProcessesUnavailable` when the processes cannot start; :meth:`close` stops them
    and frees the shared memory (also on Ctrl-C)."""

    def __init__(self, name: str, n: int, device: str = "cpu", staged: int = 0, precision: str = "float32",
                 weights: Path | None = None):
        self.name, self.n, self.device = name, n, device
        self._ring = [_Block() for _ in range(staged)]
        self._next = 0
        self._direct = _Block()          # frames not staged are copied here when detected
        self._last: _Block | None = None  # the block of the last detection
        self._lock = threading.Lock()
        self._direct_lock = threading.Lock()  # one frame at a time in the direct block
        self._closed = False
        # the reading thread's copies of staged frames: the cameras copied at once, up to 8 threads (cores)
        self._copiers = ThreadPoolExecutor(min(8, max(1, os.cpu_count() or 1)), thread_name_prefix="stage-copy")
        self.startup_s = self.cpu_s = float("nan")  # start-up wall s; workers' CPU s after it (at close)
        self.calls, self.slowest_s = 0, 0.0  # detect() calls; sum over them of the slowest worker's seconds
        self._pool: ProcessPoolExecutor | None = None
        try:
            self._pool = ProcessPoolExecutor(n, mp_context=mp.get_context("spawn"), initializer=_worker_start,
                                             initargs=(os.getpid(), name, device, precision, weights))
            started = time.perf_counter()
            self.pids = self._every_worker_up(started)
            self.startup_s = time.perf_counter() - started
            self._cpu_at_start = self.workers_cpu_s()
        except Exception as exc:
            self.close()
            raise ProcessesUnavailable(f"{type(exc).__name__}: {exc}") from exc
        except BaseException:  # Ctrl-C while the workers start: stop them too
            self.close()
            raise

    def _workers(self) -> ProcessPoolExecutor:
        if self._pool is None:
            raise RuntimeError("the camera processes are closed")
        return self._pool

    def _every_worker_up(self, started: float) -> list[int]:
        """The pids of the ``n`` workers once each has answered, its detector loaded (an import or
        CUDA failure shows here, not mid-run). A round of ``n`` start-up calls can all go to a
        worker that came up first while another still loads (1 start in 3 on 2 cores),
        which then went on loading inside the timed run and whose CPU went uncounted: rounds
        repeat until every worker has answered."""
        pids: set[int] = set()
        while len(pids) < self.n:
            left_s = START_TIMEOUT_S - (time.perf_counter() - started)
            if left_s <= 0:
                raise TimeoutError(f"{len(pids)} of {self.n} workers started within {START_TIMEOUT_S:.0f} s")
            calls = [self._workers().submit(_worker_ready, 0.2) for _ in range(self.n)]
            pids |= {call.result(timeout=left_s) for call in calls}
        return sorted(pids)

    # ------------------------------------------------------------------ per frame
    def stage(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Copy a frame's images into the next block of the ring (from the reading thread, ahead
        of :meth:`detect`); the images as :class:`StagedImages` (unchanged without a ring)."""
        with self._lock:  # not while close() frees the blocks
            if not self._ring or self._closed:
                return list(images)
            block = self._ring[self._next]
            self._next = (self._next + 1) % len(self._ring)
            try:
                block.fill(images, self._copiers)
            except ProcessesUnavailable:  # no room: detect() copies the frame (and says so)
                return list(images)
            return StagedImages(images, self, block)

    def detect(self, images: Sequence[np.ndarray], cameras: Sequence[int], boxes: Sequence[list[Box] | None],
               copy: bool = True) -> list[ViewDots]:
        """Detect the images of ``cameras`` (indices into ``images``, one BGR uint8 image per
        camera), camera ``cameras[k]`` in the boxes ``boxes[k]`` (None: the full search); one
        :class:`ViewDots` per entry of ``cameras``. ``copy=False``: the last detection's block
        already holds these images (a second pass over the same frame). Staged frames may be
        detected from several threads at once; frames that are not staged take turns."""
        if isinstance(images, StagedImages) and images.owner is self:
            return self._detect_in(images.block, cameras, boxes)
        with self._direct_lock:
            if copy or self._last is None:
                self._direct.fill(images, self._copiers)
                return self._detect_in(self._direct, cameras, boxes)
            return self._detect_in(self._last, cameras, boxes)

    def _detect_in(self, block: _Block, cameras: Sequence[int], boxes: Sequence[list[Box] | None]) -> list[ViewDots]:
        self._last = block
        memory = block.memory
        assert memory is not None
        futures = [self._workers().submit(_worker_detect, memory.name, block.layout[c], c, None if b is None else list(b))
                   for c, b in zip(cameras, boxes)]
        results = [future.result() for future in futures]
        with self._lock:
            self.calls += 1
            self.slowest_s += max((r[-1] for r in results), default=0.0)
        return [self._view_dots(block, c, result[:-1]) for c, result in zip(cameras, results)]

    def _view_dots(self, block: _Block, camera: int, result: tuple) -> ViewDots:
        uv, confidence, box, crop = result
        grey_slot = block.layout[camera][1]
        assert block.memory is not None
        grey = np.array(_view(block.memory, grey_slot, np.uint8))  # a copy: the block is reused
        mask = np.zeros(grey_slot[1][:2], bool)  # calloc: pages are touched only where the crop goes
        if box is not None:
            mask[box] = crop
        return ViewDots(camera=camera, uv=uv, confidence=confidence, mask=mask, image=grey)

    def workers_cpu_s(self) -> float:
        """CPU seconds (user + system) the live workers have used so far (NaN without psutil)."""
        return processes_cpu_s(getattr(self, "pids", []))

    # ------------------------------------------------------------------ stopping
    def close(self) -> None:
        """Stop the workers (queued work cancelled, running work abandoned) and free the block.
        ``cpu_s`` then holds the CPU seconds the workers used after their start-up."""
        pool = getattr(self, "_pool", None)
        if pool is not None:
            self.cpu_s = self.workers_cpu_s() - getattr(self, "_cpu_at_start", float("nan"))
            processes = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for process in processes:
                if process.is_alive():
                    process.terminate()
            join_or_kill(processes, STOP_GRACE_S)
            self._pool = None
        with self._lock:
            self._closed = True
            for block in [*self._ring, self._direct]:
                block.free()
        copiers = getattr(self, "_copiers", None)
        if copiers is not None:
            copiers.shutdown(wait=True)


def _aligned(nbytes: int, to: int = 64) -> int:
    return (nbytes + to - 1) // to * to


def _view(block: shared_memory.SharedMemory, slot: Slot, dtype) -> np.ndarray:
    offset, shape = slot
    return np.ndarray(shape, dtype=dtype, buffer=block.buf, offset=offset)


# ---------------------------------------------------------------------- in the workers
_STATE: dict = {}


def _worker_start(parent_pid: int, name: str, device: str, precision: str = "float32",
                  weights: Path | None = None) -> None:
    """Each worker: Ctrl-C is the parent's to handle; exit when the parent is gone; one torch
    and one OpenCV thread (the parallelism is the processes); its own detector."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent_pid)
    import cv2
    import torch

    from ..detect import Detector

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    _STATE["detector"] = (Detector(name, device=device, precision=precision, weights=weights) if name == "net"
                          else Detector(name))
    _STATE["blocks"] = {}


def _worker_ready(pause_s: float) -> int:
    time.sleep(pause_s)  # held long enough that each worker takes one of the start-up calls
    return os.getpid()


def _attached(name: str) -> shared_memory.SharedMemory:
    blocks = _STATE["blocks"]
    if name not in blocks:
        while len(blocks) >= MAX_ATTACHED:  # blocks the parent has made again (new image shapes)
            blocks.pop(next(iter(blocks))).close()
        # the parent owns and unlinks the block (spawned workers share its resource tracker, so
        # their registration of the attachment is the parent's own)
        blocks[name] = shared_memory.SharedMemory(name=name)
    return blocks[name]


def _worker_detect(name: str, slots: tuple[Slot, Slot], camera: int, boxes: list[Box] | None):
    """One camera image: (uv, confidence, mask box or None, mask crop or None, seconds spent);
    the grey image is written into its slot of the shared block."""
    start = time.perf_counter()
    detector = _STATE["detector"]
    block = _attached(name)
    image = _view(block, slots[0], np.uint8)
    if boxes is None and detector.searches_boxes:
        boxes = detector.tape_boxes([image])[0]
    view = detector.detect(image, camera=camera, boxes=boxes)
    np.copyto(_view(block, slots[1], np.uint8), view.image)
    box = mask_box(view.mask)
    crop = None if box is None else np.ascontiguousarray(view.mask[box])
    return view.uv, view.confidence, box, crop, time.perf_counter() - start


def mask_box(mask: np.ndarray | None) -> Box | None:
    """Bounding box of a bool mask's pixels, or None when empty."""
    if mask is None:
        return None
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return None
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)
