"""The default path (cameras in threads, lookahead 0) of this checkout against a peer checkout
(e.g. main), alternating in one process on frames held in memory: frames/s, CPU s per frame,
cores used, the whole table compared bit for bit, and where each run's wall time went.

    python docs/bench/overlap_ab.py CAPTURE_DIR PEER_CHECKOUT --frames 40:80 --reps 3

``PEER_CHECKOUT``: a folder holding ``spinemocap/`` (e.g. ``git archive 36b0a78 | tar -x -C DIR``),
imported as ``sm_peer`` (see track3d_ab.py). Each run: a warm-up of two frames (model loading),
then the frames timed; ``cores`` = CPU s / wall s of the whole process. Per run it prints the
largest position difference (mm) and whether status / views / flags are all equal to the peer's
run of the same rep (``same``: the table's every column bit for bit, NaN where NaN). With
``--timeline`` it also times (wall, per frame) the main thread's detection calls and tracker
steps and the camera threads' detections (``Detector.detect``), so the time one camera thread
runs alone at the end of a frame and the time the camera threads wait for the tracker show.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import threading
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from track3d_ab import _differences, _load_peer  # noqa: E402

EVENTS: list[tuple[str, str, float, float]] = []  # (what, thread, start s, end s)
_LOCK = threading.Lock()


def _timed(owner, attr: str, key: str) -> None:
    inner = getattr(owner, attr)

    def timed(*args, **kwargs):
        start = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            with _LOCK:
                EVENTS.append((key, threading.current_thread().name, start, time.perf_counter()))

    setattr(owner, attr, timed)


def instrument(package: str) -> None:
    """Time the detection calls, the camera detections and the tracker's steps of ``package``."""
    streaming = importlib.import_module(package + ".app.streaming")
    _timed(importlib.import_module(package + ".detect.detector").Detector, "detect", "camera")
    _timed(importlib.import_module(package + ".track.sequence").SequenceTracker, "step", "step")
    _timed(streaming.CaptureDetector, "__call__", "frame")


def timeline(n_frames: int) -> dict:
    """Per frame (ms): the main thread's detection call and tracker step, the camera threads'
    busy time, and the time from the first camera thread's last detection to the last one's end
    (one camera thread alone) in frames detected frame by frame."""
    frames = [e for e in EVENTS if e[0] == "frame"]
    cameras = [e for e in EVENTS if e[0] == "camera"]
    steps = [e for e in EVENTS if e[0] == "step"]
    alone = 0.0
    for _, _, start, end in frames:
        ends: dict[str, float] = {}
        for _, thread, s, e in cameras:
            if s >= start and e <= end:
                ends[thread] = max(ends.get(thread, 0.0), e)
        if len(ends) > 1:
            alone += max(ends.values()) - min(ends.values())
    ms = 1000 / n_frames
    return {"detect_call_ms": round(ms * sum(e - s for *_, s, e in frames), 1),
            "step_ms": round(ms * sum(e - s for *_, s, e in steps), 1),
            "camera_busy_ms": round(ms * sum(e - s for *_, s, e in cameras), 1),
            "one_camera_thread_alone_ms": round(ms * alone, 1)}


def run(package: str, capture, frames: list, camera_names: list[str], with_timeline: bool) -> tuple[dict, object]:
    run_mod = importlib.import_module(package + ".app.run")
    options = importlib.import_module(package + ".app.streaming").SpeedOptions()
    memory = importlib.import_module(package + ".bench.speed").MemorySource(frames, camera_names)
    n = len(frames)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, range(2), up=capture.up, progress=False,
                             speed=options)  # warm-up: model loading, first calls
        EVENTS.clear()
        cpu, wall = time.process_time(), time.perf_counter()
        result = run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, range(n), up=capture.up,
                                      progress=False, speed=options)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    out = {"fps": n / wall, "cpu": cpu / n, "cores": cpu / wall, "load": os.getloadavg()[0]}
    if with_timeline:
        out.update(timeline(n))
    return out, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("peer", type=Path, help="the other checkout (its folder holding spinemocap/)")
    parser.add_argument("--frames", default="40:80")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--timeline", action="store_true")
    args = parser.parse_args()
    _load_peer(args.peer)
    from spinemocap.app.run import parse_frames
    from spinemocap.capture import Capture

    capture = Capture.open(args.capture)
    frame_range = parse_frames(args.frames, capture.n_frames)
    source = capture.frame_source()
    frames = [source.read(f) for f in frame_range]
    if args.timeline:
        instrument("sm_peer")
        instrument("spinemocap")
    for rep in range(args.reps):
        results = {}
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            m, results[name] = run("sm_peer" if name == "peer" else "spinemocap", capture, frames,
                                   list(source.camera_names), args.timeline)
            extra = " ".join(f"{k} {v}" for k, v in m.items() if k.endswith("_ms"))
            print(f"{rep} {name}: {m['fps']:.2f} frames/s, {m['cpu']:.3f} CPU s/frame, {m['cores']:.2f} cores, "
                  f"load {m['load']:.2f} {extra}", flush=True)
        bad, worst = _differences(results["this"], results["peer"], tol_mm=0.0)
        print(f"{rep} this vs peer: largest difference {worst:.3g} mm, "
              f"{'same' if not bad else 'DIFFERENT: ' + '; '.join(bad[:5])}", flush=True)


if __name__ == "__main__":
    main()
