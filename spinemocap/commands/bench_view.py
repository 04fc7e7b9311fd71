"""``spinemocap bench view``: how long the labelled videos and the 3D viewer take; the benchmark
is :mod:`spinemocap.bench.view`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view", help="time of `spinemocap view`: labelled videos (frames per CPU second) and the 3D viewer",
        description="Write the labelled videos and the 3D viewer of a tracked capture (or of a capture made here) "
                    "and print one JSON line per run: wall and CPU seconds, frames per second, video size.")
    p.add_argument("--capture", type=Path, help="capture folder (with --results)")
    p.add_argument("--results", type=Path, help="its results folder or marker file")
    p.add_argument("--made", help="instead: a capture made here, WIDTHxHEIGHTxCAMERAS (e.g. 2448x1600x6)")
    p.add_argument("--frames", type=int, default=60, help="frames of the made capture (default 60)")
    p.add_argument("--scale", type=float, default=None, help="as `spinemocap view --scale`")
    p.add_argument("--repeat", type=int, default=2, help="runs (default 2)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.view import run_benchmark
    from ..fileio import InputError

    if not args.made and (args.capture is None or args.results is None):
        raise InputError("--capture", "give --capture and --results, or --made WIDTHxHEIGHTxCAMERAS")
    for result in run_benchmark(args.capture, args.results, args.made, args.frames, args.scale, args.repeat):
        print(json.dumps(result.to_dict()), flush=True)
    return 0
