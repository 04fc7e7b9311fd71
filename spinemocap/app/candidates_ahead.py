"""The tracker's candidate stage built ahead in worker processes (``SpeedOptions.candidate_workers``).

The candidate stage (triangulation and merging, the rig residuals, the stretch reading) is most
of the tracker's time per frame and needs nothing of the earlier frames but the candidate gate
(:mod:`spinemocap.track.ahead`). :class:`CandidatesAhead` runs it in ``n`` spawned processes a
few frames ahead of the tracker, with the gate of the last frame the tracker finished; the
tracker takes a result only where it serves that frame's own gate and builds the cloud itself
otherwise, so the output is the same as without it. Only the dots' pixel positions travel to the
workers (a few kB a frame). For detection that does not predict from the tracked dots: frames
are read ahead of the tracker.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import os
import time
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from ..camera import Rig
from ..tape import TapeSpec
from ..track.ahead import FrameCandidates, frame_candidates
from ..track.config import TrackerConfig
from ..track.pipeline import FrameResult
from ..views import ViewDots
from .worker_processes import exit_with_parent, join_or_kill, processes_cpu_s

log = logging.getLogger(__name__)

START_TIMEOUT_S = 120.0  # workers import the tracker (seconds on a loaded machine)
BUILD_TIMEOUT_S = 60.0   # one frame's build takes milliseconds: a worker this late is stuck
STOP_GRACE_S = 2.0       # stopped workers get this long before they are killed
FrameViews = tuple[int, list[ViewDots], float]  # (frame, views, ms waited), as run_tracking takes them

_WORKER: tuple[Rig, TapeSpec, TrackerConfig] | None = None  # in a worker: what every frame shares


def _worker_start(parent_pid: int, rig: Rig, tape: TapeSpec, config: TrackerConfig) -> None:
    global _WORKER
    exit_with_parent(parent_pid)
    _WORKER = (rig, tape, config)


def _worker_ready(pause_s: float) -> int:
    time.sleep(pause_s)  # so that each of the first calls goes to a different worker
    return os.getpid()


def _worker_build(uv: list[np.ndarray], gate_px: float) -> FrameCandidates:
    if _WORKER is None:
        raise RuntimeError("candidate worker not started")
    rig, tape, config = _WORKER
    views = [ViewDots(camera=c, uv=points, confidence=np.ones(len(points))) for c, points in enumerate(uv)]
    return frame_candidates(rig, views, tape, config, gate_px)


@dataclass(frozen=True)
class AheadInfo:
    """How the candidate workers ran: ``workers``; their start-up (``startup_s``, wall s) and the
    CPU seconds they used after it (``workers_cpu_s``); frames ``built`` ahead (each frame once,
    whatever was built again for a changed gate) and ``rebuilt`` (builds for a changed gate)."""

    workers: int
    startup_s: float
    workers_cpu_s: float
    built: int
    rebuilt: int


class CandidatesAhead:
    """``workers`` processes building the candidate stage of frames ``depth`` frames ahead.

    Use :meth:`frames` on the tracker's views, :meth:`for_frame` for the tracker's ``ahead``
    argument and :meth:`observe` after each tracked frame (it learns the gate there); then
    :meth:`close`. ``built``: frames whose build ahead the tracker received; ``pids``: the
    workers' process ids."""

    def __init__(self, rig: Rig, tape: TapeSpec, config: TrackerConfig | None, workers: int, depth: int = 2):
        if workers < 1 or depth < 1:
            raise ValueError(f"candidate workers and depth must be >= 1, got {workers} and {depth}")
        self.depth = depth
        self.gate_px: float | None = None  # the gate of the frame after the last tracked one
        self._pending: dict[int, tuple[Future, list[np.ndarray]]] = {}  # frame -> (build, its pixels)
        self.built = 0
        self.workers, self.startup_s, self.rebuilt = workers, 0.0, 0
        self.cpu_s = float("nan")  # the workers' CPU seconds after their start-up (at close)
        self.pids: list[int] = []
        self._pool: ProcessPoolExecutor | None = ProcessPoolExecutor(
            workers, mp_context=mp.get_context("spawn"), initializer=_worker_start,
            initargs=(os.getpid(), rig, tape, config or TrackerConfig()))
        started = time.perf_counter()
        try:  # every worker up before the first frame (their imports are seconds, once)
            self.pids = sorted({call.result(timeout=START_TIMEOUT_S)
                                 for call in [self._pool.submit(_worker_ready, 0.2) for _ in range(workers)]})
            self._cpu_at_start = processes_cpu_s(self.pids)
        except Exception as exc:  # the tracker builds every cloud itself
            log.warning("candidate workers could not start (%s: %s); the tracker builds the candidates", type(exc).__name__, exc)
            self.close()
        self.startup_s = time.perf_counter() - started

    def frames(self, views_per_frame: Iterable[FrameViews]) -> Iterator[FrameViews]:
        """The same ``(frame, views, ms)`` items, each frame's candidate stage handed to the
        workers ``depth`` frames before the tracker asks for it (the wait for those frames'
        views is added to the frame's ms)."""
        ahead: deque[FrameViews] = deque()
        upstream = iter(views_per_frame)
        more = True
        while True:
            t0 = time.perf_counter()
            while more and len(ahead) <= self.depth:
                item = next(upstream, None)
                if item is None:
                    more = False
                    break
                self._submit(item[0], item[1])
                ahead.append(item)
            if not ahead:
                return
            frame, views, waited = ahead.popleft()
            yield frame, views, waited + 1000 * (time.perf_counter() - t0)

    def _submit(self, frame: int, views: list[ViewDots]) -> None:
        self._build(frame, [np.asarray(view.uv, float) for view in views])

    def _build(self, frame: int, uv: list[np.ndarray]) -> None:
        if self._pool is None or self.gate_px is None:
            return
        try:
            self._pending[frame] = (self._pool.submit(_worker_build, uv, self.gate_px), uv)
        except (BrokenProcessPool, RuntimeError) as exc:  # a worker died: the tracker builds the rest
            self._give_up(exc)

    def _give_up(self, exc: BaseException) -> None:
        log.warning("a candidate worker failed (%s: %s); the tracker builds the candidates", type(exc).__name__, exc)
        self.close()

    def for_frame(self, frame: int) -> FrameCandidates | None:
        """The frame's candidate stage built ahead (waits for it), or None where none was built."""
        pending = self._pending.pop(frame, None)
        if pending is None:
            return None
        future = pending[0]
        try:
            built = future.result(timeout=BUILD_TIMEOUT_S)
        except Exception as exc:  # a worker died or hangs: the tracker builds the clouds from here on
            self._give_up(exc)
            return None
        self.built += 1
        return built

    def observe(self, frame: int, result: FrameResult) -> None:
        """Learn the gate for the frames after ``frame`` from its result."""
        if not math.isfinite(result.gate_px) or result.gate_px == self.gate_px:
            return
        self.gate_px = result.gate_px
        # the frames handed out with the old gate: built again with the new one, unless what was
        # built serves it too (most of the time: a gate builds the same cloud over a range)
        for frame, (future, uv) in list(self._pending.items()):
            if future.done() and future.exception() is None and future.result().serves(self.gate_px):
                continue
            future.cancel()
            self.rebuilt += 1
            self._build(frame, uv)

    def close(self) -> None:
        """Stop the workers (pending builds are dropped)."""
        for future, _ in self._pending.values():
            future.cancel()
        self._pending.clear()
        if self._pool is not None:
            self.cpu_s = processes_cpu_s(self.pids) - getattr(self, "_cpu_at_start", float("nan"))
            processes = list((getattr(self._pool, "_processes", None) or {}).values())
            self._pool.shutdown(wait=False, cancel_futures=True)
            for process in processes:  # a hung worker must not hold the run
                if process.is_alive():
                    process.terminate()
            join_or_kill(processes, STOP_GRACE_S)
            self._pool = None

    @property
    def info(self) -> AheadInfo:
        """How the workers ran so far (:class:`AheadInfo`; their CPU once closed)."""
        return AheadInfo(self.workers, self.startup_s, self.cpu_s, self.built, self.rebuilt)
