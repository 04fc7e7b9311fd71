"""``spinemocap bench track``: arguments and printing; the benchmark is :mod:`spinemocap.bench.track`."""

from __future__ import annotations

import argparse
from pathlib import Path


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "track", help="tracking accuracy on the synthetic studio vs the paper's Tables 1-2",
        description="Render the synthetic sequence in-process, track it and print the paper's "
                    "Table 1 and Table 2 beside ours. Runs at the studio's 'lab' realism level by default "
                    "(--realism ideal for the paper's conditions).")
    p.add_argument("--preset", default="artificial", choices=("tiny", "artificial", "studio"))
    p.add_argument("--occlusion", default="none", choices=("none", "light", "heavy"))
    p.add_argument("--frames", type=int, default=None, help="frames to render and track (default: the preset's)")
    p.add_argument("--mode", choices=("sequence", "paper"), default="sequence")
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net",
                   help="tape/dot detector (default: the shipped network); 'mask' finds dots inside the "
                        "renderer's exact tape masks, isolating the tracker from tape segmentation")
    p.add_argument("--weights", type=Path, help="the net detector's weights file (default: shipped)")
    p.add_argument("--config", type=Path, help="tracker settings (TOML)")
    p.add_argument("--seed", type=int, default=0, help="synthetic scene seed")
    p.add_argument("--realism", choices=("ideal", "skin", "lab"), default="lab",
                   help="studio realism level (default lab: taping tension, skin strain, calibration and sync "
                        "error; ideal = no skin strain, exact set-up, as the paper's Artificial set-up)")
    p.add_argument("--json", type=Path, help="write all numbers to this JSON file (+ a .png plot beside it)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)



def run(args: argparse.Namespace) -> int:
    from ..bench.track import format_report, run_track_benchmark
    from ..track.config import TrackerConfig

    config = TrackerConfig.from_toml(args.config) if args.config else TrackerConfig()
    if args.weights is not None:
        from ..detect.segnet import load_weights

        load_weights(args.weights)  # a missing or foreign file is refused before any rendering
    result = run_track_benchmark(args.preset, args.occlusion, args.frames, args.mode, args.detector, config,
                                 args.seed, progress=not args.no_progress, realism=args.realism,
                                 weights=args.weights)
    print(format_report(result))
    if args.json:
        plot = result.save(args.json)
        print(f"numbers written to {args.json}, plot to {plot}")
    return 0
