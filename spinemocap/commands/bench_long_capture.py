"""``spinemocap bench long-capture``: peak memory of ``track --chunk-frames`` against the
capture's length; the benchmark is :mod:`spinemocap.bench.long_capture`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "long-capture", help="peak memory of `track --chunk-frames` over captures of growing length",
        description="Loop a short rendered capture (images and masks played forward and back) to each "
                    "length, track it in chunks in its own process and sample its memory; writes "
                    "long_capture_memory.json and .png into OUT.")
    p.add_argument("base", type=Path, help="a short rendered image capture with masks (spinemocap synth)")
    p.add_argument("out", type=Path, help="folder for the looped captures, outputs and results")
    p.add_argument("--lengths", type=int, nargs="+", default=[600, 2400, 6000], help="frames per run")
    p.add_argument("--chunk-frames", type=int, default=300, help="frames per chunk (default 300)")
    p.add_argument("--peer", type=Path, help="a previous run's long_capture_memory.json, drawn beside")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..bench.long_capture import run_benchmark

    runs = run_benchmark(args.base, args.out, args.lengths, args.chunk_frames, args.peer)
    peaks = np.array([r.peak_rss_mb for r in runs])
    print(f"peak RSS {peaks.min():.0f}..{peaks.max():.0f} MiB over {args.lengths} frames")
    return 0
