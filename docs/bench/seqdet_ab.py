"""Sequence-mode detection and tracking of frames A:B of a capture: this checkout against a peer
checkout (e.g. ``git worktree add PEER main``), with option variants for this one.

    python docs/bench/seqdet_ab.py detect CAPTURE_DIR PEER --frames 40:80 --variants '[{}, {"box_margin_px": 40}]'
    python docs/bench/seqdet_ab.py track CAPTURE_DIR PEER --frames 40:80 --reps 3

``detect``: the peer's and each variant's :class:`CaptureDetector` (cameras serial, ``workers=1``)
detect every frame in turn, the order rotating per frame (a loaded machine slows all alike), each
told the ground-truth dots of the frame (prediction as in tracking); thread CPU ms per frame, dots
per frame and the routes. ``track``: ``track_source`` of both checkouts with default options on the
frames held in memory (70 MB per frame of six 2448x1600 cameras), alternating; CPU s per frame,
frames/s, accuracy against the ground truth, and the largest position difference between the two.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from track3d_ab import _load_peer  # noqa: E402


def detect(capture, frames: range, variants: list[dict]) -> None:
    import sm_peer.app.streaming as peer_streaming

    import spinemocap.app.streaming as streaming

    source = capture.frame_source()
    truth = capture.groundtruth()["dots"]
    detectors = [("peer", peer_streaming.CaptureDetector("net", capture.rig, peer_streaming.SpeedOptions(workers=1)))]
    detectors += [(json.dumps(v), streaming.CaptureDetector("net", capture.rig, streaming.SpeedOptions(workers=1, **v)))
                  for v in variants]
    cpu, dots = np.zeros(len(detectors)), np.zeros(len(detectors))
    for f in frames:
        images = source.read(f)
        for j in range(len(detectors)):
            k = (f + j) % len(detectors)
            detector = detectors[k][1]
            t = time.thread_time()
            views = detector(f, images, None)
            cpu[k] += time.thread_time() - t
            dots[k] += sum(len(v) for v in views)
            detector.observe(f, truth[f])
    for (name, detector), c, d in zip(detectors, cpu, dots):
        print(f"{name}: {1000 * c / len(frames):.1f} ms CPU / frame, {d / len(frames):.1f} dots / frame, "
              f"routes {detector.searches}", flush=True)
        detector.close()
    print(f"load {os.getloadavg()[0]:.2f}")


def _track(package: str, capture, memory_frames: list, names: list[str], frames: range) -> dict:
    run_mod = importlib.import_module(package + ".app.run")
    options = importlib.import_module(package + ".app.streaming").SpeedOptions()
    memory = importlib.import_module(package + ".bench.speed").MemorySource(memory_frames, names)
    evaluate = importlib.import_module(package + ".track.evaluate").evaluate_tracking
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, frames[:2], up=capture.up, progress=False,
                             speed=options)  # warm-up
        cpu, wall = time.process_time(), time.perf_counter()
        result = run_mod.track_source(memory, capture.rig, capture.tape, capture.fps, frames, up=capture.up,
                                      progress=False, speed=options)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    accuracy = evaluate(result.table, capture.groundtruth(), float(capture.tape.graph.rest_length_mm.min()))
    n = len(frames)
    return {"cpu": cpu / n, "fps": n / wall, "mean": accuracy.mean_error_mm, "p95": accuracy.p95_error_mm,
            "swaps": accuracy.label_swaps, "positions": result.table.to_arrays()["positions"],
            "routes": result.detector_searches, "load": os.getloadavg()[0]}


def track(capture, frames: range, reps: int) -> None:
    source = capture.frame_source()
    memory_frames: list = [None] * capture.n_frames
    for f in frames:
        memory_frames[f] = source.read(f)
    names = list(source.camera_names)
    last: dict = {}
    for rep in range(reps):
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            m = last[name] = _track("sm_peer" if name == "peer" else "spinemocap", capture, memory_frames, names, frames)
            print(f"{rep} {name}: {m['cpu']:.3f} CPU s / frame, {m['fps']:.2f} frames/s, mean {m['mean']:.4f} / "
                  f"p95 {m['p95']:.4f} mm, swaps {m['swaps']}, routes {m['routes']}, load {m['load']:.2f}", flush=True)
        d = np.nanmax(np.abs(last["this"]["positions"] - last["peer"]["positions"]))
        print(f"   largest position difference this - peer: {d:.3g} mm", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("detect", "track"))
    parser.add_argument("capture", type=Path)
    parser.add_argument("peer", type=Path, help="the other checkout (its folder holding spinemocap/)")
    parser.add_argument("--frames", default="40:80", help="A:B")
    parser.add_argument("--reps", type=int, default=2, help="track: alternating rounds")
    parser.add_argument("--variants", default="[{}]", help="detect: JSON list of SpeedOptions fields for this checkout")
    args = parser.parse_args()
    _load_peer(args.peer)
    from spinemocap.capture import Capture

    capture = Capture.open(args.capture)
    a, b = (int(x) for x in args.frames.split(":"))
    if args.mode == "detect":
        detect(capture, range(a, b), json.loads(args.variants))
    else:
        track(capture, range(a, b), args.reps)


if __name__ == "__main__":
    main()
