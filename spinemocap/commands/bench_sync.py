"""``spinemocap bench sync``: clock-offset estimates against the truth on studio captures whose
cameras are not synchronised; the benchmark is :mod:`spinemocap.bench.sync`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sync", help="camera clock offsets estimated (dot motion, audio clap) against the truth on studio captures",
        description="Render small studio captures whose cameras record on their own clocks (whole and fractional "
                    "offsets up to 2 s, 50/60/100 fps, dropped frames, a clap on the audio), estimate the offsets "
                    "from the dots' motion and from the clap, and compare with the truth (goal: |error| <= 1 ms on "
                    "100 fps cameras); also the dropped frames found and the frames paired as the truth pairs them.")
    p.add_argument("--out", type=Path, default=Path("bench_out/sync"), help="folder for the captures, numbers and plot")
    p.add_argument("--scenarios", default=None,
                   help="comma-separated scenarios (default all: offsets_100fps, mixed_50_60_100fps)")
    p.add_argument("--detector", choices=("net", "classical"), default="classical",
                   help="dot detector of the motion estimate (default classical)")
    p.add_argument("--realism", choices=("ideal", "skin", "lab"), default="lab", help="studio realism (default lab)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.sync import SCENARIOS, format_table, run_sync_benchmark, save
    from ..fileio import InputError

    names = list(SCENARIOS) if args.scenarios is None else [n.strip() for n in args.scenarios.split(",") if n.strip()]
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown or not names:
        raise InputError("spinemocap bench sync --scenarios", f"unknown scenarios {unknown} (choose from {list(SCENARIOS)})")
    numbers = run_sync_benchmark(args.out, names, args.detector, args.realism, progress=not args.no_progress)
    save(numbers, args.out / "sync.json", args.out / "sync.png")
    print(format_table(numbers))
    print(f"numbers written to {args.out / 'sync.json'}, plot to {args.out / 'sync.png'}")
    return 0
