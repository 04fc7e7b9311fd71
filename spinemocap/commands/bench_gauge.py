"""``spinemocap bench gauge``: the world frame left after ``--refine-rig`` over several scenes
and seeded calibrations per error level; the benchmark is
:mod:`spinemocap.bench.rig_gauge`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "gauge", help="--refine-rig's world frame over many seeded calibrations",
        description="Render and track the artificial preset once per scene seed (with its 2 px rig), then for "
                    "every calibration error level and several seeded rigs written by the studio's perturbation "
                    "refine the rig on the tracked dots and score the dots: given rig, --refine-rig (priors "
                    "gauge), the same with the world frame removed, the reported frame uncertainty, and two "
                    "other gauges as peers (cloud fit to the given rig's triangulation; closest cameras).")
    p.add_argument("--json", type=Path, required=True, help="results file")
    p.add_argument("--plot", type=Path, help="PNG: each calibration's mean error per gauge against its level")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="scene seeds (default 0 1 2)")
    p.add_argument("--levels", type=float, nargs="+", default=[1.0, 2.0, 3.0],
                   help="calibration errors of the given rigs, px RMS (default 1 2 3)")
    p.add_argument("--rigs", type=int, default=5, help="seeded calibrations per scene and level (default 5)")
    p.add_argument("--frames", type=int, default=30, help="frames per scene (default 30)")
    p.add_argument("--fps", type=float, default=25.0, help="frame rate (default 25)")
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net")
    p.add_argument("--reference", action="store_true",
                   help="render the studio's L-frame beside the subject and refine every calibration also with its "
                        "markers as control points (the world frame from the reference), beside the refinement without")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.realism import save
    from ..bench.rig_gauge import format_table, plot, run_gauge_benchmark
    from ..fileio import InputError

    if args.rigs < 1 or args.frames < 2 or any(not 0 < level <= 20 for level in args.levels):
        raise InputError("bench gauge", "--rigs must be >= 1, --frames >= 2 and every level in (0, 20] px")
    numbers = run_gauge_benchmark(args.seeds, args.levels, args.rigs, frames=args.frames, fps=args.fps,
                                  detector=args.detector, progress=not args.no_progress,
                                  after_scene=lambda partial: save(partial.to_dict(), args.json, None),
                                  reference=args.reference)
    save(numbers.to_dict(), args.json, args.plot, plot)
    print(format_table(numbers.summary))
    print(f"numbers written to {args.json}" + (f", plot to {args.plot}" if args.plot else ""))
    return 0
