"""Issue 15: the clean-up's dot finding (``extend_along_tape``: snap, levels, ``find_dots``) before
and after a change, on the calls a tracking run makes: bit-identical answers, CPU per frame, the
two versions alternating call by call in one process (the same load for both).

1. ``--record FILE.pkl``: a tracking run (cameras serial, frames in memory) records the
   arguments of every ``extend_along_tape`` call (the box's grey crop and the network's mask;
   the network and the tracker are not timed here) and pickles them.
2. Both versions then run every recorded call: their answers (mask, snapped mask, dots,
   confidences) are compared bit for bit (any difference stops the run), then timed
   (``time.thread_time``, ``--rounds`` rounds, the order swapped every round).
   ``--pipeline N``: instead, the whole tracker (threads, stage 1 in the pool: ``threads_ab.py``'s
   ``T:p``) on the frames (``--cache``: threads_ab's .npy of them), N runs per version alternating
   in this process (the detector's clean-up swapped between the versions): CPU s per frame of the
   process and the largest position difference between the versions' runs (mm; 0.0: identical).
   ``--profile``: cProfiles of the versions (``--before`` optional) on the recorded calls instead:
   the clean-up's functions by cumulative CPU ms per frame, the top calls by own time.

The previous package is imported under another name, e.g.

    mkdir -p /tmp/before && git archive fdbd8d3 spinemocap | tar -x -C /tmp/before
    mv /tmp/before/spinemocap /tmp/before/spinemocap_before
    OMP_NUM_THREADS=1 python docs/bench/dots_ab.py CAPTURE_DIR --frames 40:80 --record /tmp/calls.pkl
    OMP_NUM_THREADS=1 python docs/bench/dots_ab.py CAPTURE_DIR --frames 40:80 --calls /tmp/calls.pkl --before /tmp/before --rounds 6
    OMP_NUM_THREADS=1 python docs/bench/dots_ab.py CAPTURE_DIR --calls /tmp/calls.pkl --before /tmp/before --rounds 4 --profile
    OMP_NUM_THREADS=1 python docs/bench/dots_ab.py CAPTURE_DIR --frames 40:80 --before /tmp/before --pipeline 6 --cache frames.npy
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pickle
import pstats
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from cleanup_ab import alternating_rounds  # noqa: E402


def record(capture_dir: Path, frames: range, out: Path) -> None:
    import spinemocap.detect.detector as detector
    from spinemocap.app.run import track_source
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.bench.speed import MemorySource
    from spinemocap.capture import Capture

    cap = Capture.open(capture_dir)
    source = cap.frame_source()
    images = [source.read(f) if f in frames else [] for f in range(frames.stop)]
    calls = []
    extend = detector.extend_along_tape

    def recording(crop, mask, *args, **kwargs):
        calls.append((np.array(crop), np.array(mask)))
        return extend(crop, mask, *args, **kwargs)

    detector.extend_along_tape = recording  # type: ignore[assignment]
    warnings.simplefilter("ignore")
    track_source(MemorySource(images, list(source.camera_names)), cap.rig, cap.tape, cap.fps, frames,
                 up=cap.up, progress=False, speed=SpeedOptions(workers=1, prefetch=0))
    detector.extend_along_tape = extend
    with open(out, "wb") as f:
        pickle.dump({"frames": len(frames), "calls": calls}, f)
    print(f"recorded {len(calls)} extend_along_tape calls over {len(frames)} frames into {out}")


def pipeline(capture_dir: Path, frames: range, before_dir: Path, runs: int, cache: Path | None) -> None:
    import spinemocap.detect.detector as detector
    from spinemocap.app.run import track_source
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.bench.speed import MemorySource
    from spinemocap.capture import Capture
    from spinemocap.track.evaluate import evaluate_tracking

    sys.path.insert(0, str(before_dir))
    from spinemocap_before.detect.refine import extend_along_tape as before

    cap = Capture.open(capture_dir)
    reader = cap.frame_source()
    if cache is not None and cache.is_file():
        images = np.load(cache)
    else:
        images = np.stack([np.stack(reader.read(f)) for f in frames])
    source = MemorySource([list(frame) for frame in images], list(reader.camera_names))
    truth = {k: (v[frames.start:frames.stop] if k in ("dots", "visible", "keypoints") else v)
             for k, v in cap.groundtruth().items()}
    versions = {"before": before, "after": detector.extend_along_tape}
    options = SpeedOptions(stage1_in_pool=True)
    warnings.simplefilter("ignore")
    track_source(source, cap.rig, cap.tape, cap.fps, range(2), up=cap.up, progress=False, speed=options)  # warm-up
    cpu: dict[str, list[float]] = {"before": [], "after": []}
    positions: dict[str, np.ndarray] = {}
    n = len(images)
    for r in range(runs):
        for name in (("before", "after") if r % 2 == 0 else ("after", "before")):
            detector.extend_along_tape = versions[name]  # type: ignore[assignment]
            t = time.process_time()
            result = track_source(source, cap.rig, cap.tape, cap.fps, range(n), up=cap.up, progress=False, speed=options)
            cpu[name].append((time.process_time() - t + (result.detector_info.get("workers_cpu_s", 0.0) or 0.0)) / n)
            pos = result.table.positions()
            positions.setdefault(name, pos)
            accuracy = evaluate_tracking(result.table, truth, float(cap.tape.graph.rest_length_mm.min()))
            print(f"run {r} {name}: {cpu[name][-1]:.4f} CPU s/frame, mean {accuracy.mean_error_mm:.4f} mm, "
                  f"p95 {accuracy.p95_error_mm:.4f} mm, swaps {accuracy.label_swaps}, largest difference to the first "
                  f"runs: {max(float(np.nanmax(np.abs(pos - p))) for p in positions.values()):.3g} mm "
                  f"(1-min load {os.getloadavg()[0]:.1f})", flush=True)
    detector.extend_along_tape = versions["after"]  # type: ignore[assignment]
    b, a = (float(np.median(cpu[name])) for name in ("before", "after"))
    print(f"median CPU s/frame: before {b:.4f}, after {a:.4f}, after / before {a / b:.3f}; "
          f"runs paired in order: {[round(x / y, 3) for x, y in zip(cpu['after'], cpu['before'])]}")


def same(a, b) -> bool:
    return (a.mask.shape == b.mask.shape and bool((a.mask == b.mask).all()) and bool((a.snapped == b.snapped).all())
            and a.uv.shape == b.uv.shape and bool((a.uv == b.uv).all()) and bool((a.confidence == b.confidence).all()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--frames", default="40:80")
    parser.add_argument("--record", type=Path, help="record the calls into this pickle and stop")
    parser.add_argument("--calls", type=Path, help="a --record pickle")
    parser.add_argument("--before", type=Path, help="a folder holding the previous package as spinemocap_before/")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="cProfile the versions over the calls")
    parser.add_argument("--pipeline", type=int, default=0, help="runs of the whole tracker per version")
    parser.add_argument("--cache", type=Path, help="with --pipeline: a .npy of the frames' images (threads_ab's)")
    args = parser.parse_args()
    a, b = (int(v) for v in args.frames.split(":"))
    if args.pipeline:
        pipeline(args.capture, range(a, b), args.before, args.pipeline, args.cache)
        return
    cv2.setNumThreads(1)  # as the tracker's camera threads set it
    if args.record:
        record(args.capture, range(a, b), args.record)
        return
    with open(args.calls, "rb") as f:
        data = pickle.load(f)
    calls, n_frames = data["calls"], data["frames"]
    from spinemocap.detect.refine import extend_along_tape as after

    versions = {"after": after}
    if args.before is not None:
        sys.path.insert(0, str(args.before))
        from spinemocap_before.detect.refine import extend_along_tape as before

        versions = {"before": before, "after": after}
    if args.profile:
        _profile(versions, calls, n_frames, max(1, args.rounds))
        return
    dots = 0
    for k, (crop, mask) in enumerate(calls):
        x, y = before(crop, mask), after(crop, mask)
        if not same(x, y):
            raise SystemExit(f"call {k}: the answers differ ({len(x.uv)} vs {len(y.uv)} dots)")
        dots += len(x.uv)
    print(f"{len(calls)} calls, {n_frames} frames: identical masks, snapped masks, dots and confidences ({dots} dots)")
    parts = _time_parts(versions)
    cpu = alternating_rounds(calls, lambda name, call: versions[name](*call), args.rounds, n_frames)
    for name, values in cpu.items():
        print(f"{name}: median {np.median(values) * 1e3 / n_frames:.2f} CPU ms/frame")
    print(f"after / before (medians): {np.median(cpu['after']) / np.median(cpu['before']):.3f}")
    print("CPU ms per frame by part (all rounds; find_dots also inside the extension's region tests):")
    for part in ("find_dots", "_levels", "_snap"):
        b, a = (parts[name][part] * 1e3 / args.rounds / n_frames for name in ("before", "after"))
        print(f"  {part}: before {b:.2f}, after {a:.2f}, ratio {a / b:.3f}")


def _time_parts(versions: dict) -> dict[str, dict[str, float]]:
    """Wrap ``find_dots``, ``_levels`` and ``_snap`` as each version's clean-up calls them
    (``refine``'s names) in thread-CPU timers: the seconds spent in each, per version (the
    outermost call only)."""
    import importlib

    parts: dict[str, dict[str, float]] = {}
    for name, extend in versions.items():
        module = importlib.import_module(extend.__module__)
        totals = parts.setdefault(name, {})
        depth = [0]
        for part in ("find_dots", "_levels", "_snap"):
            totals[part] = 0.0
            setattr(module, part, _timed(getattr(module, part), part, totals, depth))
    return parts


def _timed(f, part: str, totals: dict[str, float], depth: list[int]):
    """``f`` adding its thread CPU seconds to ``totals[part]`` (outermost timed call only)."""
    def timed(*args, **kwargs):
        depth[0] += 1
        t = time.thread_time()
        try:
            return f(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                totals[part] += time.thread_time() - t
    return timed


def _profile(versions: dict, calls: list, n_frames: int, rounds: int) -> None:
    """cProfile of each version over the calls (rounds alternating): the clean-up's functions by
    cumulative CPU ms per frame, then the top calls by own time."""
    profiles = {name: cProfile.Profile() for name in versions}
    for r in range(rounds):
        for name in (list(versions) if r % 2 == 0 else list(versions)[::-1]):
            profiles[name].enable()
            for crop, mask in calls:
                versions[name](crop, mask)
            profiles[name].disable()
    for name, profile in profiles.items():
        stats = pstats.Stats(profile)
        print(f"== {name}: cumulative CPU ms per frame (profiled)")
        rows = [(ct, nc, f"{Path(fn).name}:{fl}({fname})") for (fn, fl, fname), (_, nc, _, ct, _) in stats.stats.items()  # type: ignore[attr-defined]
                if "spinemocap" in fn and ("refine" in fn or "blobs" in fn)]
        for ct, nc, where in sorted(rows, reverse=True)[:16]:
            print(f"{ct * 1e3 / rounds / n_frames:8.2f}  {nc // rounds:6d} calls  {where}")
    for name, profile in profiles.items():
        print(f"== {name}: top own time")
        pstats.Stats(profile).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":
    main()
