"""Tracking a whole capture held in memory: this checkout against a peer checkout (e.g. an earlier
commit), each with its default speed options, alternating in one process; frames/s, CPU s per
frame, cores used and accuracy against the capture's ground truth.

    python docs/bench/memory_ab.py CAPTURE_DIR PEER_CHECKOUT --reps 2

The capture's frames are decoded once (70 MB per frame of six 2448x1600 cameras) and replayed to
both; the peer package is imported as ``sm_peer`` (see track3d_ab.py).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from track3d_ab import _load_peer  # noqa: E402


def _run(package: str, capture, frames: list, camera_names: list[str]) -> dict:
    run_mod = importlib.import_module(package + ".app.run")
    options = importlib.import_module(package + ".app.streaming").SpeedOptions()
    memory = importlib.import_module(package + ".bench.speed").MemorySource(frames, camera_names)
    evaluate = importlib.import_module(package + ".track.evaluate").evaluate_tracking
    n = len(frames)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, range(2), up=capture.up, progress=False,
                             speed=options)  # warm-up: model loading, first calls
        cpu, wall = time.process_time(), time.perf_counter()
        result = run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, range(n), up=capture.up,
                                      progress=False, speed=options)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    accuracy = evaluate(result.table, capture.groundtruth(), float(capture.tape.graph.rest_length_mm.min()))
    return {"fps": n / wall, "cpu": cpu / n, "cores": cpu / wall, "mean": accuracy.mean_error_mm,
            "p95": accuracy.p95_error_mm, "swaps": accuracy.label_swaps, "load": os.getloadavg()[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("peer", type=Path, help="the other checkout (its folder holding spinemocap/)")
    parser.add_argument("--reps", type=int, default=2)
    args = parser.parse_args()
    _load_peer(args.peer)
    from spinemocap.capture import Capture

    capture = Capture.open(args.capture)
    source = capture.frame_source()
    frames = [source.read(f) for f in range(capture.n_frames)]
    for rep in range(args.reps):
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            m = _run("sm_peer" if name == "peer" else "spinemocap", capture, frames, list(source.camera_names))
            print(f"{rep} {name}: {m['fps']:.2f} frames/s, {m['cpu']:.3f} CPU s/frame, {m['cores']:.2f} cores, "
                  f"mean {m['mean']:.3f} / p95 {m['p95']:.3f} mm, swaps {m['swaps']}, load {m['load']:.2f}", flush=True)


if __name__ == "__main__":
    main()
