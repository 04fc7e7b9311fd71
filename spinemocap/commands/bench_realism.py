"""``spinemocap bench realism``: the tracker on a studio as hard as a real back, beside
the tracker without stretch estimation; the benchmark is :mod:`spinemocap.bench.realism`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "realism", help="tracker vs taping tension, skin strain, calibration and sync error",
        description="Render the artificial preset once per case (tension 0/10/20/30 %% with skin strain, "
                    "calibration error 0.5/1/2/3 px with and without --refine-rig, sync error 1/3 ms, full "
                    "flexion and the forehand at the lab level, the held-out look of bench detect (blue tape, painted "
                    "rooms, lab cameras) at the lab level, lab and ideal), track it in sequence mode "
                    "with the shipped detector, and score the tracker and its peer without stretch estimation "
                    "(nominal spacing, fixed 2 px gate) on the same frames.")
    p.add_argument("--json", type=Path, required=True, help="results file")
    p.add_argument("--plot", type=Path, help="PNG: mean error and swapped dot-frames per case")
    p.add_argument("--frames", type=int, default=200, help="frames per case (default 200)")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate (default the preset's 100 fps; a lower rate covers more motion in fewer frames)")
    p.add_argument("--cases", nargs="+", default=None, metavar="NAME",
                   help="run only these cases (names as printed, e.g. 'lab' 'calibration 2.0 px'); default all")
    p.add_argument("--occlusion", default="light", choices=("none", "light", "heavy"))
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--weights", type=Path, help="the net detector's weights file (default: shipped)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bench.realism import format_table, run_realism_benchmark, save, sweep
    from ..fileio import InputError

    cases = sweep()
    if args.cases:
        known = {c.name: c for c in cases}
        unknown = [n for n in args.cases if n not in known]
        if unknown:
            raise InputError("--cases", f"unknown cases {unknown}; choose from {list(known)}")
        cases = [known[n] for n in args.cases]
    if args.weights is not None:
        from ..detect.segnet import load_weights

        load_weights(args.weights)  # a missing or foreign file is refused before any rendering
    numbers = run_realism_benchmark(cases, frames=args.frames, fps=args.fps, occlusion=args.occlusion,
                                    detector=args.detector, seed=args.seed, progress=not args.no_progress,
                                    after_case=lambda partial: save(partial.to_dict(), args.json, None),
                                    weights=args.weights)
    save(numbers.to_dict(), args.json, args.plot)
    print(format_table(numbers))
    for goal, judged in numbers.verdict.items():
        print(f"goal {goal}: {'met' if judged.met else 'NOT met'} ({judged.numbers()})")
    print(f"numbers written to {args.json}" + (f", plot to {args.plot}" if args.plot else ""))
    return 0
