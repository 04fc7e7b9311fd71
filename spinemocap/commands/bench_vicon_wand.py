"""``spinemocap bench vicon-wand``: the virtual Vicon's wand wave co-registers the rig with the Vicon
(offset, rotation and point errors), and cross-validation with that transform against the transform
estimated from the tape markers; the benchmark is :mod:`spinemocap.bench.vicon_wand`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    from .synth import _size

    p = subparsers.add_parser(
        "vicon-wand", help="virtual Vicon: wand co-registration (transform, clock offset) vs truth, and crossval with it",
        description="Per realism level: build a studio trial, record the virtual Vicon and its wand wave (images at "
                    "the cameras' rate + Vicon C3D), co-register the capture's rig.toml with the Vicon as "
                    "'spinemocap calibrate wand' does, score offset/rotation/point errors against the truth, then "
                    "cross-validate the exact dots (+ noise) with the wand's transform and, as the peer, with the "
                    "transform estimated from the Vicon markers on the tape.")
    p.add_argument("--json", type=Path, default=Path("bench_vicon_wand.json"), help="results file")
    p.add_argument("--levels", nargs="+", default=["lab", "ideal"], choices=("ideal", "skin", "lab"),
                   help="realism levels (default lab, then the ideal case)")
    p.add_argument("--preset", default="artificial", choices=("artificial", "studio"),
                   help="camera layout (tiny's views are too narrow for the T-wand)")
    p.add_argument("--motion", default="mixed", help="studio motion (default mixed; flexion bends to 70 deg)")
    p.add_argument("--frames", type=int, default=60, help="trial frames (default 60)")
    p.add_argument("--fps", type=float, default=30.0, help="camera frame rate (default 30)")
    p.add_argument("--size", type=_size, help="image size WxH (default the preset's)")
    p.add_argument("--wand-seconds", type=float, default=4.0, help="wand wave length (default 4 s)")
    p.add_argument("--dot-noise", type=float, default=0.3, help="noise on the exact dots for crossval, mm (default 0.3)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.vicon_wand import run_benchmark
    from ..fileio import InputError

    if args.frames < 2 or not args.fps > 0 or not args.wand_seconds > 0 or args.dot_noise < 0:
        raise InputError("spinemocap bench vicon-wand", "--frames must be >= 2, --fps and --wand-seconds positive, "
                                                        "--dot-noise >= 0")

    run_benchmark(args.levels, args.preset, args.frames, args.fps, args.size, args.wand_seconds, args.dot_noise,
                  args.seed, args.json, progress=not args.no_progress, motion=args.motion)
    return 0
