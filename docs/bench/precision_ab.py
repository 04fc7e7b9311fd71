"""The network's arithmetic in tracking: ``Detector("net", precision=P)`` for several P (e.g.
``float32,int8``) on frames A:B of a capture, in one process, alternating per round.

    python docs/bench/precision_ab.py CAPTURE_DIR float32,int8 --frames 0:100            # accuracy, frames read from disk
    python docs/bench/precision_ab.py CAPTURE_DIR float32,int8 --frames 40:80 --memory --reps 3   # speed, frames in memory

Each variant runs ``track_source`` with the default :class:`SpeedOptions` (``--serial``: cameras one
after the other in the calling thread) with ``precision=P`` (the detectors it builds). Per run: CPU
seconds per frame (the process's; with frames read from disk this includes decoding), the
network's passes (count and thread CPU ms per pass, measured around each pass in the thread that
runs it), accuracy against the ground truth (mean / p95 mm, swaps), the detector's routes, and the
largest position difference from the first variant. ``--memory`` holds the frames decoded in
memory (70 MB per frame of six 2448x1600 cameras: keep A:B to ~40 frames).
"""

from __future__ import annotations

import argparse
import functools
import os
import threading
import time
import warnings
from pathlib import Path

import numpy as np


class _PassClock:
    """Thread CPU time and count of :class:`OnnxUNet` / torch passes (``_logits_batch``)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.cpu = 0.0
        self.n = 0

    def wrap(self, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            t = time.thread_time()
            out = fn(*args, **kwargs)
            dt = time.thread_time() - t
            with self.lock:
                self.cpu += dt
                self.n += 1
            return out

        return timed


def run(capture, source, frames: range, precision: str, serial: bool) -> dict:
    import spinemocap.app.streaming as streaming
    from spinemocap.app.run import track_source
    from spinemocap.detect import detector as det
    from spinemocap.track.evaluate import evaluate_tracking

    clock = _PassClock()
    original_logits = det.NetSegmenter._logits_batch
    det.NetSegmenter._logits_batch = clock.wrap(original_logits)  # type: ignore[method-assign]
    # the tracker builds its detectors with SpeedOptions.precision (session 26's integration)
    options = (streaming.SpeedOptions(workers=1, prefetch=0, precision=precision) if serial
               else streaming.SpeedOptions(precision=precision))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            track_source(source, capture.rig, capture.tape, capture.fps, frames[:2], up=capture.up, progress=False,
                         speed=options)  # warm-up (and the int8 model made once)
            clock.cpu, clock.n = 0.0, 0
            cpu, wall = time.process_time(), time.perf_counter()
            result = track_source(source, capture.rig, capture.tape, capture.fps, frames, up=capture.up,
                                  progress=False, speed=options)
            cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    finally:
        det.NetSegmenter._logits_batch = original_logits  # type: ignore[method-assign]
    accuracy = evaluate_tracking(result.table, capture.groundtruth(), float(capture.tape.graph.rest_length_mm.min()))
    n = len(frames)
    return {"cpu": cpu / n, "fps": n / wall, "passes": clock.n / n, "pass_ms": 1000 * clock.cpu / max(clock.n, 1),
            "net_ms": 1000 * clock.cpu / n, "mean": accuracy.mean_error_mm, "p95": accuracy.p95_error_mm,
            "swaps": accuracy.label_swaps, "positions": result.table.to_arrays()["positions"],
            "routes": result.detector_searches, "load": os.getloadavg()[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("precisions", help="comma-separated, e.g. float32,int8")
    parser.add_argument("--frames", default="0:100", help="A:B")
    parser.add_argument("--reps", type=int, default=1, help="alternating rounds")
    parser.add_argument("--memory", action="store_true", help="hold frames A:B decoded in memory")
    parser.add_argument("--serial", action="store_true", help="cameras one after the other (workers=1, no prefetch)")
    args = parser.parse_args()
    from spinemocap.bench.speed import MemorySource
    from spinemocap.capture import Capture

    capture = Capture.open(args.capture)
    a, b = (int(x) for x in args.frames.split(":"))
    frames = range(a, b)
    source = capture.frame_source()
    if args.memory:
        held: list = [None] * capture.n_frames
        for f in frames:
            held[f] = source.read(f)
        source = MemorySource(held, list(source.camera_names))
    names = args.precisions.split(",")
    for rep in range(args.reps):
        positions = {}
        for name in names if rep % 2 == 0 else names[::-1]:
            m = run(capture, source, frames, name, args.serial)
            positions[name] = m["positions"]
            print(f"{rep} {name}: {m['cpu']:.3f} CPU s / frame, {m['fps']:.2f} frames/s, network {m['passes']:.2f} "
                  f"passes / frame at {m['pass_ms']:.2f} ms = {m['net_ms']:.1f} ms / frame; mean {m['mean']:.4f} / "
                  f"p95 {m['p95']:.4f} mm, swaps {m['swaps']}, routes {m['routes']}, load {m['load']:.2f}", flush=True)
        ref = positions[names[0]]
        for name in names[1:]:
            d = np.abs(positions[name] - ref)
            same_nan = np.array_equal(np.isnan(positions[name]), np.isnan(ref))
            print(f"   {name} vs {names[0]}: largest position difference {np.nanmax(d):.3g} mm, "
                  f"{np.mean(d[~np.isnan(d)] > 0.1):.2%} of coordinates > 0.1 mm, NaN pattern "
                  f"{'the same' if same_nan else 'differs'}", flush=True)

if __name__ == "__main__":
    main()
