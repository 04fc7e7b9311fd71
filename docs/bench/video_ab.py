"""Reading (and tracking) a capture of videos: this checkout against a peer checkout (e.g. main),
each with its default speed options, alternating in one process; CPU s per frame (all threads of
this process), frames/s, cores used, minor page faults per frame, and for tracking the accuracy
against the capture's ground truth.

    python docs/bench/video_ab.py CAPTURE_DIR PEER_CHECKOUT --frames 40:80 --reps 3 [--track]

Without ``--track``: decoding alone, as the tracker's reader does it (``prefetched_frames``: the
cameras in ``--workers`` threads, ``--prefetch`` frames ahead), the consumer holding each frame's
images for ``--hold`` more frames (as the tracker holds the views of the frame it solves). With
``--track``: ``track_source`` over the frames after a two-frame warm-up. The peer package is
imported as ``sm_peer`` (see track3d_ab.py); the files are read once before the first timed run
(page cache).
"""

from __future__ import annotations

import argparse
import importlib
import os
import resource
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from track3d_ab import _load_peer  # noqa: E402


def _decode(package: str, root: Path, frames: range, workers: int, prefetch: int, hold: int) -> dict:
    capture = importlib.import_module(package + ".capture").Capture.open(root)
    prefetched = importlib.import_module(package + ".app.streaming").prefetched_frames
    source = capture.frame_source()
    held: list = []
    try:
        for _, images, _ in prefetched(source, frames, workers=workers, prefetch=prefetch):
            held.append(images)
            if len(held) > hold:
                held.pop(0)
    finally:
        held.clear()
        source.close()
    return {}


def _track(package: str, root: Path, frames: range, workers: int, prefetch: int, hold: int) -> dict:
    capture = importlib.import_module(package + ".capture").Capture.open(root)
    run_mod = importlib.import_module(package + ".app.run")
    options = importlib.import_module(package + ".app.streaming").SpeedOptions()
    evaluate = importlib.import_module(package + ".track.evaluate").evaluate_tracking
    source = capture.frame_source()
    try:
        result = run_mod.track_source(source, capture.rig, capture.tape, capture.fps, frames, up=capture.up,
                                      progress=False, speed=options)
    finally:
        source.close()
    # the table's frame numbers index the capture's ground truth
    accuracy = evaluate(result.table, capture.groundtruth(), float(capture.tape.graph.rest_length_mm.min()))
    return {"mean": accuracy.mean_error_mm, "p95": accuracy.p95_error_mm, "swaps": accuracy.label_swaps}


def _timed(fn, *args) -> dict:
    usage, cpu, wall = resource.getrusage(resource.RUSAGE_SELF), time.process_time(), time.perf_counter()
    out = fn(*args)
    after = resource.getrusage(resource.RUSAGE_SELF)
    out.update(cpu=time.process_time() - cpu, wall=time.perf_counter() - wall, faults=after.ru_minflt - usage.ru_minflt,
               sys=after.ru_stime - usage.ru_stime)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("peer", type=Path, help="the other checkout (its folder holding spinemocap/)")
    parser.add_argument("--frames", default="40:80", help="A:B, frames A to B-1")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--track", action="store_true", help="track the frames (else decode them alone)")
    parser.add_argument("--workers", type=int, default=2, help="reader threads (decoding alone)")
    parser.add_argument("--prefetch", type=int, default=2, help="frames read ahead (decoding alone)")
    parser.add_argument("--hold", type=int, default=2, help="frames the consumer holds (decoding alone)")
    args = parser.parse_args()
    _load_peer(args.peer)
    import cv2

    cv2.setNumThreads(1)
    a, b = (int(x) for x in args.frames.split(":"))
    frames = range(a, b)
    settings = (args.capture, frames, args.workers, args.prefetch, args.hold)
    run = _track if args.track else _decode
    _decode("spinemocap", *settings)  # the files into the page cache
    if args.track:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for package in ("sm_peer", "spinemocap"):  # warm-up: model loading, first calls
                _track(package, args.capture, range(a, a + 2), *settings[2:])
    n = len(frames)
    for rep in range(args.reps):
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            load = os.getloadavg()[0]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = _timed(run, "sm_peer" if name == "peer" else "spinemocap", *settings)
            line = (f"{rep} {name}: {m['cpu'] / n:.4f} CPU s/frame ({m['sys'] / n:.4f} system), {n / m['wall']:.2f} frames/s, "
                    f"{m['cpu'] / m['wall']:.2f} cores, {m['faults'] / n:.0f} minor faults/frame, load {load:.2f}")
            if "mean" in m:
                line += f", mean {m['mean']:.3f} / p95 {m['p95']:.3f} mm, swaps {m['swaps']}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
