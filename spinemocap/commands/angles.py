"""``spinemocap bench angles``: do the tape's spine angles follow the studio's applied motion?"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from ..fileio import atomic_write


def register_bench(subparsers) -> None:
    p = subparsers.add_parser(
        "angles", help="spine angles vs the synthetic studio's applied flexion/lateral/rotation "
                       "(RMSE, R^2, crosstalk) on ground-truth markers, with an analytic peer",
        description="Runs the studio's flexion, lateral and rotation motions (ground-truth dots, no "
                    "rendering) and an analytic bent rod through the angle pipeline; prints and saves "
                    "RMSE (deg), R^2 and crosstalk of the change from neutral. See "
                    "spinemocap/analysis/benchmark.py for how the expected angles are derived.")
    p.add_argument("--frames", type=int, default=60, help="frames per motion (default 60)")
    p.add_argument("--fps", type=float, default=20.0, help="frame rate (default 20: 3 s of motion)")
    p.add_argument("--rows", type=int, default=13, help="tape rows (default 13, the paper's tape)")
    p.add_argument("--json", type=Path, help="write the numbers here")
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    from ..analysis.benchmark import bench_analytic, bench_studio

    started = time.time()
    results = {
        "command": f"spinemocap bench angles --frames {args.frames} --fps {args.fps} --rows {args.rows}",
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "date": time.strftime("%Y-%m-%d"),
        "targets": {"rmse_deg": 2.0, "r2": 0.98},
        "studio_groundtruth": bench_studio(args.frames, args.fps, args.rows),
        "analytic_rod": bench_analytic(args.frames, args.rows),
    }
    results["wall_s"] = round(time.time() - started, 1)
    print(f"{'':<22}{'motion':<10}{'RMSE deg':>9}{'R^2':>8}{'gain':>7}{'xtalk rms':>10}{'xtalk pk':>9}{'expected pk':>12}")
    for source in ("studio_groundtruth", "analytic_rod"):
        for motion, r in results[source].items():
            print(f"{source:<22}{motion:<10}{r['rmse_deg']:>9.2f}{r['r2']:>8.4f}{r['gain']:>7.3f}"
                  f"{r['crosstalk_rms_deg']:>10.2f}{r['crosstalk_peak_deg']:>9.2f}{r['expected_peak_deg']:>12.1f}")
    if args.json:
        with atomic_write(args.json) as handle:
            json.dump(results, handle, indent=1)
        print(f"numbers: {args.json}")
    return 0
