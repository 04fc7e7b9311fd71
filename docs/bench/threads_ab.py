"""Where the CPU of cameras in threads, detection ahead of the tracker and worker processes goes:
speed options A/B, alternating in one process, on a capture's frames held in memory.

    python docs/bench/threads_ab.py CAPTURE_DIR T,T:p,L,L:p --frames 40:80 --reps 4
    python docs/bench/threads_ab.py CAPTURE_DIR S,T,L --frames 40:80 --reps 1 --instrument

A configuration is ``BASE[@SWITCH_MS][:p][+NAME=VALUE...]``: BASE ``S`` (cameras one after the other), ``T``
(threads, the default), ``L`` (threads, ``lookahead=1``), ``P`` (worker processes), ``PL`` (processes,
``lookahead=1``); ``@SWITCH_MS`` sets ``sys.setswitchinterval`` (ms; 5 by default) for
that run; ``:p`` each camera thread's full search runs its own stage 1 (``stage1_in_pool=True``;
without it: stage 1 of all cameras batched in the calling thread while the pool waits, the default before it was measured on an idle machine);
``+NAME=VALUE``: a ``SpeedOptions`` field (an int where VALUE is one), e.g. ``T:p+refresh_every=30``,
``T:p+refresh=camera+refresh_settled_every=30``, or ``+prestep=K``: ``detect.dataset.AREA_PRESTEP``
(stage 1's integer area step; 1: the one-step area resize). Session 27 (fullsearch), refresh schedules:

    python docs/bench/threads_ab.py CAPTURE_DIR T:p,T:p+refresh_every=30,T:p+refresh=camera --frames 40:80 --reps 4
    python docs/bench/threads_ab.py CAPTURE_DIR T:p,T:p+prestep=1 --frames 0:100 --reps 1 --from-disk

``--from-disk``: the frames are read from the capture's files in every run (for accuracy over a
long range without holding it in memory; the CPU then includes decoding); ``--per-frame``: each
frame's mean error too. Per run:
frames/s, CPU s per frame (this process plus the camera workers), cores used, user/system CPU,
minor page faults and context switches per frame (``getrusage``), accuracy against the ground
truth (frames numbered from the range's start), the detector's routes, and the largest position
difference (mm) against every configuration run before it. ``--instrument`` adds per-thread CPU
(``/proc/self/task``, sampled every 0.25 s) and per-stage CPU and wall time (``time.thread_time``
around ``Detector.detect``, ``tape_boxes``, ``SequenceTracker.step``, ``CaptureDetector.__call__``)
and writes each camera detection's CPU to ``--percam`` (the input of a scheduling simulation).
``--cache FILE.npy``: the frames' images, decoded once (``np.save`` of a (F, C, H, W, 3) array).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from spinemocap.app import streaming
from spinemocap.app.run import parse_frames, track_source
from spinemocap.app.streaming import SpeedOptions
from spinemocap.bench.speed import MemorySource
from spinemocap.capture import Capture
from spinemocap.detect import dataset
from spinemocap.track.evaluate import evaluate_tracking

CONFIGS = {"S": dict(workers=1), "T": dict(), "L": dict(lookahead=1),
           "P": dict(parallel="processes"), "PL": dict(parallel="processes", lookahead=1)}
STAGES: dict[str, list] = {}  # stage -> [calls, CPU s, wall s]
PER_CAMERA: list = []          # (camera, full search?, CPU s) per camera detection
_lock = threading.Lock()
PER_FRAME: list[bool] = []     # --per-frame given
PRESTEP = dataset.AREA_PRESTEP


def _timed(owner, attr: str, key: str) -> None:
    inner = getattr(owner, attr)

    def timed(*args, **kwargs):
        cpu, wall = time.thread_time(), time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
            with _lock:
                entry = STAGES.setdefault(key, [0, 0.0, 0.0])
                entry[0] += 1
                entry[1] += cpu
                entry[2] += wall
                if key == "detect_camera":
                    PER_CAMERA.append((kwargs.get("camera", 0), kwargs.get("boxes") is None, cpu))

    setattr(owner, attr, timed)


def instrument() -> None:
    from spinemocap.detect.detector import Detector, NetSegmenter
    from spinemocap.track.sequence import SequenceTracker

    _timed(Detector, "detect", "detect_camera")
    _timed(NetSegmenter, "tape_boxes", "tape_boxes")
    _timed(SequenceTracker, "step", "track_step")
    _timed(streaming.CaptureDetector, "__call__", "capture_detect")


class ThreadCPU:
    """CPU s and context switches per OS thread of this process, sampled every 0.25 s (a thread's
    last sample before it ends counts)."""

    def __init__(self) -> None:
        self.cpu: dict[int, float] = {}
        self.names: dict[int, str] = {}
        self._stop = threading.Event()
        self.sample()
        self.start = dict(self.cpu)
        self._thread = threading.Thread(target=self._run, daemon=True, name="sampler")
        self._thread.start()

    def sample(self) -> None:
        python = {t.native_id: t.name for t in threading.enumerate()}
        tick = os.sysconf("SC_CLK_TCK")
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
                with open(f"/proc/self/task/{tid}/comm") as fh:
                    comm = fh.read().strip()
            except OSError:
                continue
            self.cpu[int(tid)] = (int(fields[11]) + int(fields[12])) / tick
            self.names.setdefault(int(tid), python.get(int(tid), "native:" + comm))

    def _run(self) -> None:
        while not self._stop.wait(0.25):
            self.sample()

    def finish(self) -> dict[str, float]:
        """CPU s per thread group since the start (pool threads summed by name prefix)."""
        self._stop.set()
        self._thread.join()
        self.sample()
        out: dict[str, float] = {}
        for tid, cpu in self.cpu.items():
            name = self.names[tid]
            group = next((p for p in ("detect-ahead", "detect", "prefetch", "read", "MainThread", "sampler")
                          if name.startswith(p)), name)
            out[group] = out.get(group, 0.0) + cpu - self.start.get(tid, 0.0)
        return out


def run(config: str, capture: Capture, source, truth: dict, instrumented: bool) -> tuple[dict, np.ndarray]:
    config_main, *settings = config.split("+")
    base, _, flags = config_main.partition(":")
    base, _, switch_ms = base.partition("@")
    fields = {k: int(v) if v.isdigit() else v for k, v in (item.split("=", 1) for item in settings)}
    dataset.AREA_PRESTEP = fields.pop("prestep", PRESTEP)
    sys.setswitchinterval(float(switch_ms) / 1000 if switch_ms else 0.005)
    options = SpeedOptions(**CONFIGS[base], stage1_in_pool="p" in flags, **fields)
    n = source.n_frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        track_source(source, capture.rig, capture.tape, capture.fps, range(2), up=capture.up, progress=False,
                     speed=options)  # warm-up: model loading, worker start-up
        STAGES.clear()
        threads = ThreadCPU() if instrumented else None
        usage = resource.getrusage(resource.RUSAGE_SELF)
        cpu, wall = time.process_time(), time.perf_counter()
        result = track_source(source, capture.rig, capture.tape, capture.fps, range(n), up=capture.up,
                              progress=False, speed=options)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        after = resource.getrusage(resource.RUSAGE_SELF)
    sys.setswitchinterval(0.005)
    dataset.AREA_PRESTEP = PRESTEP
    workers = result.detector_info.get("workers_cpu_s", 0.0) or 0.0
    accuracy = evaluate_tracking(result.table, truth, float(capture.tape.graph.rest_length_mm.min()))
    out = {"config": config, "fps": n / wall, "cpu_s_per_frame": (cpu + workers) / n, "cores": (cpu + workers) / wall,
           "user_s": (after.ru_utime - usage.ru_utime) / n, "system_s": (after.ru_stime - usage.ru_stime) / n,
           "minor_faults": (after.ru_minflt - usage.ru_minflt) / n,
           "voluntary_switches": (after.ru_nvcsw - usage.ru_nvcsw) / n,
           "involuntary_switches": (after.ru_nivcsw - usage.ru_nivcsw) / n,
           "mean_mm": accuracy.mean_error_mm, "p95_mm": accuracy.p95_error_mm, "swaps": accuracy.label_swaps,
           "routes": result.detector_searches, "parallel": result.detector_info.get("parallel"),
           "load": os.getloadavg()[0]}
    if PER_FRAME:
        out["frame_mean_mm"] = [round(float(x), 4) for x in _frame_errors(result.table, truth)]
    if threads is not None:
        out["thread_cpu_ms_per_frame"] = {k: round(1000 * v / n, 1) for k, v in sorted(threads.finish().items())
                                          if v > 0.005}
        out["stage_calls_cpu_wall_ms_per_frame"] = {k: (v[0], round(1000 * v[1] / n, 1), round(1000 * v[2] / n, 1))
                                                    for k, v in STAGES.items()}
    return out, result.table.positions()


def _frame_errors(table, truth: dict) -> np.ndarray:
    """Each frame's mean dot error (mm) over its tracked dots (NaN: none), as evaluate_tracking."""
    arrays = table.to_arrays()
    labels = [str(x) for x in arrays["labels"]]
    gt_labels = [str(x) for x in truth.get("labels", labels)]
    order = [gt_labels.index(label) for label in labels]
    err = np.linalg.norm(arrays["positions"] - np.asarray(truth["dots"], float)[arrays["frames"]][:, order], axis=2)
    err[arrays["status"] == "missing"] = np.nan
    return np.nanmean(err, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("configs", help="comma-separated, e.g. T:o,T,L:o,L")
    parser.add_argument("--frames", default="40:80")
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--instrument", action="store_true")
    parser.add_argument("--cache", type=Path, help=".npy of the frames' images (made when missing)")
    parser.add_argument("--percam", type=Path, help="with --instrument: JSON of each camera detection's CPU s")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--from-disk", action="store_true", help="read the frames from the capture's files in every run")
    parser.add_argument("--per-frame", action="store_true", help="each frame's mean error (mm) in the output")
    args = parser.parse_args()
    if args.per_frame:
        PER_FRAME.append(True)
    capture = Capture.open(args.capture)
    frames = parse_frames(args.frames, capture.n_frames)
    reader = capture.frame_source()
    truth = {k: (v[frames.start:frames.stop] if k in ("dots", "visible", "keypoints") else v)
             for k, v in capture.groundtruth().items()}
    source = FramesOnDisk(reader, frames) if args.from_disk else _in_memory(args, reader, frames)
    if args.instrument:
        instrument()
    configs = args.configs.split(",")
    positions: dict[str, np.ndarray] = {}
    runs = []
    for rep in range(args.reps):
        for config in configs if rep % 2 == 0 else configs[::-1]:
            m, pos = run(config, capture, source, truth, args.instrument)
            m["rep"] = rep
            positions.setdefault(config, pos)
            m["max_difference_mm"] = {k: float(np.nanmax(np.abs(pos - p))) for k, p in positions.items()}
            runs.append(m)
            print(json.dumps(m), flush=True)
    if args.percam is not None:
        args.percam.write_text(json.dumps(PER_CAMERA))
    if args.json is not None:
        args.json.write_text(json.dumps(runs, indent=1))


class FramesOnDisk:
    """The frames ``frames`` of a capture's reader, renumbered from 0, read from disk when asked."""

    def __init__(self, reader, frames: range) -> None:
        self.reader, self.frames = reader, frames
        self.camera_names = list(reader.camera_names)
        self.n_frames = len(frames)

    def read(self, frame: int) -> list[np.ndarray]:
        return self.reader.read(self.frames[frame])

    def read_camera(self, camera: int, frame: int) -> np.ndarray:
        return self.reader.read_camera(camera, self.frames[frame])


def _in_memory(args, reader, frames: range) -> MemorySource:
    if args.cache is not None and args.cache.is_file():
        images = np.load(args.cache)
    else:
        images = np.stack([np.stack(reader.read(f)) for f in frames])
        if args.cache is not None:
            np.save(args.cache, images)
    return MemorySource([list(frame) for frame in images], list(reader.camera_names))


if __name__ == "__main__":
    main()
