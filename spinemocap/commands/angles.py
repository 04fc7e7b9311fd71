"""``spinemocap angles MARKERS``: spine angles of one marker file; ``spinemocap bench angles``:
do the tape's spine angles follow the synthetic studio's applied motion?"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

from ..fileio import atomic_write


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "angles", help="spine angles of one labelled marker file (CSV/TRC/C3D/Parquet) to CSV + plot",
        description="Compute lumbar/thoracic flexion, lateral bending, axial rotation, lordosis/kyphosis "
                    "and pelvis angles for every frame of a tape marker file (labels R01L...). For whole "
                    "studies use `spinemocap batch`.")
    p.add_argument("markers", type=Path, help="marker file readable by the exporters (csv, trc, c3d, parquet)")
    p.add_argument("--levels", type=Path, required=True, help="row-to-level map (TOML)")
    p.add_argument("--out", type=Path, help="angles CSV (default: beside the markers, *_angles.csv); "
                                            "a PNG plot goes beside it")
    p.add_argument("--lumbar", nargs=2, metavar=("LOWER", "UPPER"), default=("S1", "T12/L1"))
    p.add_argument("--up", type=float, nargs=3, default=(0.0, 0.0, 1.0), help="subject's up (world)")
    p.add_argument("--facing", type=float, nargs=3, default=(0.0, -1.0, 0.0), help="subject's facing (world)")
    p.set_defaults(func=run_angles)


def run_angles(args: argparse.Namespace) -> int:
    import exporters

    from ..analysis.angles import AngleSettings, compute_angles
    from ..analysis.levels import LevelMap
    from ..app.report import angles_plot_png
    from ..fileio import InputError
    from ..tape import TapeSpec

    markers = exporters.read(args.markers)
    rows = [int(label[1:3]) for label in markers.labels if len(label) == 4 and label[0] == "R" and label[1:3].isdigit()]
    if not rows:
        raise InputError(args.markers, "no tape labels (R01L, R02C, ...) in this marker file")
    tape = TapeSpec(n_rows=max(rows) if max(rows) % 2 else max(rows) + 1)
    levels = LevelMap.from_toml(args.levels, tape.n_rows)
    settings = AngleSettings(lower=args.lumbar[0], thoracolumbar=args.lumbar[1])
    result = compute_angles(markers, tape, levels, up=args.up, facing=args.facing, settings=settings)
    out = args.out or args.markers.with_name(args.markers.stem + "_angles.csv")
    with atomic_write(out) as handle:
        result.table.to_csv(handle, index=False, float_format="%.4f")
    with atomic_write(out.with_suffix(".png"), "wb") as handle:
        handle.write(angles_plot_png(result.table))
    stats = result.summary()
    print(f"{len(result.table)} frames, {100 * result.completeness:.0f}% of dots observed; lumbar flexion "
          f"{stats['lumbar_flexion_min']:.1f}..{stats['lumbar_flexion_max']:.1f} deg (ROM {stats['lumbar_flexion_rom']:.1f})")
    for group, reasons in result.notes.items():
        for reason, count in reasons.items():
            print(f"  {group} angles NaN in {count} frames: {reason}")
    print(f"angles: {out}\nplot:   {out.with_suffix('.png')}")
    return 0


def register_bench(subparsers) -> None:
    p = subparsers.add_parser(
        "angles", help="spine angles vs the synthetic studio's applied flexion/lateral/rotation "
                       "(RMSE, R^2, crosstalk) on ground-truth markers, with an analytic peer",
        description="Runs the studio's flexion, lateral and rotation motions (ground-truth dots, no "
                    "rendering) and an analytic bent rod through the angle pipeline; prints and saves "
                    "RMSE (deg), R^2 and crosstalk of the change from neutral. See "
                    "spinemocap/bench/analysis.py for how the expected angles are derived.")
    p.add_argument("--frames", type=int, default=60, help="frames per motion (default 60)")
    p.add_argument("--fps", type=float, default=20.0, help="frame rate (default 20: 3 s of motion)")
    p.add_argument("--rows", type=int, default=13, help="tape rows (default 13, the paper's tape)")
    p.add_argument("--json", type=Path, help="write the numbers here")
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    from ..bench.analysis import bench_analytic, bench_studio

    started = time.time()
    results: dict[str, Any] = {
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
