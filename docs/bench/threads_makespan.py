"""Two camera threads' detection time per frame, simulated from measured per-camera CPU: the
camera order, stage 1 batched before the pool or inside it, longest first.

    python docs/bench/threads_ab.py CAPTURE_DIR S --frames 40:80 --reps 1 --instrument --percam percam.json
    python docs/bench/threads_makespan.py percam.json --stage1-ms 29.7 --refresh-every 10

``percam.json``: each camera detection's CPU s in a serial run (``S``: cameras one after the other,
stage 1 batched before them, so a full search's camera time excludes stage 1; the warm-up's two
frames first). ``--stage1-ms``: stage 1's CPU per image (the run's ``tape_boxes`` CPU over its
images). Frames whose index is a multiple of ``--refresh-every`` are full searches; a run of fewer
cameras than the rig is a fallback's full search. Each frame's cameras go to whichever of two
threads is free first (a pool), with no interpreter lock: what the scheduling alone can gain.
"""

from __future__ import annotations

import argparse
import json


def makespan(times: list[float], threads: int = 2) -> float:
    """The pool's finishing time: each task to the thread free first, in the given order."""
    load = [0.0] * threads
    for t in times:
        i = load.index(min(load))
        load[i] += t
    return max(load)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("percam")
    parser.add_argument("--stage1-ms", type=float, required=True)
    parser.add_argument("--refresh-every", type=int, default=10)
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--warm-up-frames", type=int, default=2)
    args = parser.parse_args()
    calls = json.load(open(args.percam))[args.warm_up_frames * args.cameras:]
    groups: list[list[tuple[int, float]]] = []
    for camera, _, cpu in calls:
        if not groups or camera <= groups[-1][-1][0]:
            groups.append([])
        groups[-1].append((camera, cpu))
    stage1 = args.stage1_ms / 1000
    frame = 0
    totals = {"stage 1 batched, camera order (default)": 0.0, "stage 1 batched, longest first": 0.0,
              "stage 1 in the pool, camera order (stage1_in_pool)": 0.0, "stage 1 in the pool, longest first": 0.0}
    last: dict[tuple[int, bool], float] = {}
    for group in groups:
        full = len(group) < args.cameras or frame % args.refresh_every == 0
        frame += len(group) == args.cameras
        times = [cpu for _, cpu in group]
        with_stage1 = [cpu + (stage1 if full else 0.0) for cpu in times]
        longest = sorted(range(len(group)), key=lambda k: -last.get((group[k][0], full), 0.0))
        batched = stage1 * len(group) if full else 0.0
        totals["stage 1 batched, camera order (default)"] += batched + makespan(times)
        totals["stage 1 batched, longest first"] += batched + makespan([times[k] for k in longest])
        totals["stage 1 in the pool, camera order (stage1_in_pool)"] += makespan(with_stage1)
        totals["stage 1 in the pool, longest first"] += makespan([with_stage1[k] for k in longest])
        for (camera, _), t in zip(group, with_stage1):
            last[camera, full] = t
    for name, total in totals.items():
        print(f"{name}: {1000 * total / frame:.1f} ms per frame")


if __name__ == "__main__":
    main()
