"""``spinemocap angles MARKERS``: spine angles of one marker file; ``spinemocap bench angles``:
do the tape's spine angles follow the synthetic studio's applied motion?"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path
from typing import Any

from ..fileio import atomic_write, strict_json


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "angles", help="spine angles of one labelled marker file (CSV/TRC/C3D/Parquet) to CSV + plot",
        description="Compute lumbar/thoracic flexion, lateral bending, axial rotation, lordosis/kyphosis "
                    "and pelvis angles for every frame of a tape marker file (labels R01L...). For whole "
                    "studies use `spinemocap batch`.")
    p.add_argument("markers", type=Path, help="a results folder (markers.csv) or a marker file readable by the exporters "
                                              "(csv, trc, c3d, parquet)")
    p.add_argument("--levels", type=Path, required=True, help="row-to-level map (TOML)")
    p.add_argument("--out", type=Path, help="angles CSV (default: beside the markers, *_angles.csv); "
                                            "a PNG plot goes beside it")
    p.add_argument("--lumbar", nargs=2, metavar=("LOWER", "UPPER"), default=("S1", "T12/L1"))
    p.add_argument("--up", type=float, nargs=3, default=(0.0, 0.0, 1.0), help="subject's up (world)")
    p.add_argument("--facing", type=float, nargs=3, default=(0.0, -1.0, 0.0), help="subject's facing (world)")
    p.add_argument("--neutral", type=Path, metavar="STATIC",
                   help="marker file of a neutral (static, standing) trial of the same subject and tape: its median "
                        "angles are zero (default: the trial's first frame)")
    p.set_defaults(func=run_angles)


def run_angles(args: argparse.Namespace) -> int:
    from ..app.angles import marker_file_angles

    found = marker_file_angles(args.markers, args.levels, args.out, tuple(args.lumbar), args.up, args.facing,
                               args.neutral)
    stats = found.from_neutral
    print(f"{len(found.angles.table)} frames, {100 * found.angles.completeness:.0f}% of dots observed; "
          f"neutral: {found.neutral.source}")
    print(f"lumbar flexion from neutral {stats['lumbar_flexion_pos_from_neutral']:.1f} deg, extension from neutral "
          f"{stats['lumbar_flexion_neg_from_neutral']:.1f} deg, ROM {stats['lumbar_flexion_rom']:.1f} deg "
          f"(absolute {stats['lumbar_flexion_min']:.1f}..{stats['lumbar_flexion_max']:.1f} deg, "
          f"{stats['lumbar_flexion_neutral']:.1f} at neutral)")
    for group, reasons in found.angles.notes.items():
        for reason, count in reasons.items():
            print(f"  {group} angles NaN in {count} frames: {reason}")
    print(f"angles: {found.table_path}\nplot:   {found.plot_path}")
    return 0


def register_bench(subparsers) -> None:
    p = subparsers.add_parser(
        "angles", help="lumbar S1 -> T12/L1 and thoracic angles vs the synthetic studio's applied motion, "
                       "from tracked and ground-truth markers (RMSE, bias, R^2, Bland-Altman limits)",
        description="Renders the studio's flexion, lateral bending, rotation and mixed motions (realism level "
                    "'lab' by default), detects the dots with the shipped detector and tracks them through the "
                    "lab's calibrated rig; computes the lumbar (S1 -> T12/L1) and thoracic (T12/L1 -> the tape's "
                    "top level) angles from the tracked markers and from the ground-truth markers (the ceiling) "
                    "and scores their change from neutral against the applied motion (see "
                    "spinemocap/bench/analysis.py for the expected angles). The tracked markers are also scored with "
                    "row centres taken as plain L-R midpoints (source tracked_lr_midpoints: the peer). An analytic "
                    "bent rod (the pipeline's own error) and the mid-bone benchmark on ground-truth markers run "
                    "beside it.")
    p.add_argument("--frames", type=int, default=30, help="frames per motion (default 30)")
    p.add_argument("--fps", type=float, default=10.0, help="frame rate (default 10: 3 s of motion)")
    p.add_argument("--rows", type=int, default=13, help="tape rows (default 13, the paper's tape, from S1)")
    p.add_argument("--motions", nargs="+", default=["flexion", "lateral", "rotation", "mixed"],
                   choices=["flexion", "lateral", "rotation", "mixed"])
    p.add_argument("--realism", default="lab", choices=["ideal", "skin", "lab"],
                   help="the studio's realism level (default lab)")
    p.add_argument("--detector", default="net", choices=["net", "classical", "mask"],
                   help="dot detector for the tracked markers (default: the shipped network)")
    p.add_argument("--groundtruth-only", action="store_true", help="skip rendering and tracking (fast)")
    p.add_argument("--no-peers", action="store_true",
                   help="skip the analytic rod and the mid-bone benchmark (e.g. when running motion by motion); "
                        "the L-R midpoint peer on the same tracked markers always runs")
    p.add_argument("--json", type=Path, help="write the numbers here (and a plot beside it, .png)")
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    from ..bench.analysis import (
        PEER_SOURCE,
        TRACKED_GOALS_DEG,
        bench_analytic,
        bench_lab_angles,
        bench_studio,
        headline,
        lab_angles_plot_png,
    )

    started = time.time()
    command = (f"spinemocap bench angles --frames {args.frames} --fps {args.fps} --rows {args.rows} "
               f"--motions {' '.join(args.motions)} --realism {args.realism} --detector {args.detector}"
               + (" --groundtruth-only" if args.groundtruth_only else "") + (" --no-peers" if args.no_peers else ""))
    lab = bench_lab_angles(args.motions, args.frames, args.fps, args.rows, args.realism, args.detector,
                           tracked=not args.groundtruth_only)
    results: dict[str, Any] = {
        "command": command,
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "date": time.strftime("%Y-%m-%d"),
        **headline(lab),
        "goals_tracked_rmse_deg": TRACKED_GOALS_DEG,
        "lab_angles": {motion: entry.to_dict() for motion, entry in lab.items()},
    }
    if not args.no_peers:
        results["analytic_rod"] = {motion: agreement.to_dict()
                                   for motion, agreement in bench_analytic(args.frames, args.rows).items()}
        results["studio_mid_bone_groundtruth"] = {
            motion: agreement.to_dict()
            for motion, agreement in bench_studio(args.frames, args.fps, args.rows, progress=False).items()}
    results["wall_s"] = round(time.time() - started, 1)
    print(f"{'motion':<10}{'angle':<19}{'source':<21}{'RMSE':>6}{'bias':>7}{'LoA low':>8}{'LoA high':>9}"
          f"{'R^2':>7}{'valid':>7}{'expected pk':>12}")
    for motion, entry in lab.items():
        for column, r in entry.groundtruth.items():
            for source in ("tracked", PEER_SOURCE, "groundtruth"):
                scores = entry.scores(source)
                if scores is None or r.expected_peak_deg < 2.0 and column.startswith("thoracic"):
                    continue
                s, fit = scores[column], scores[column].fit
                r2 = f"{fit.r2:>7.3f}" if s.expected_peak_deg >= 2.0 else f"{'-':>7}"  # no R^2 of crosstalk
                print(f"{motion:<10}{column:<19}{source:<21}{fit.rmse_deg:>6.2f}{fit.bias_deg:>7.2f}"
                      f"{fit.loa_low_deg:>8.2f}{fit.loa_high_deg:>9.2f}{r2}{fit.valid:>7.2f}"
                      f"{s.expected_peak_deg:>12.1f}")
        if entry.tracking is not None:
            t = entry.tracking
            print(f"{motion:<10}tracking: mean error {t.mean_error_mm:.2f} mm, {t.label_swaps} swapped dot-frames "
                  f"in {t.frames_with_swaps} frames, {t.s_per_frame:.1f} s per frame")
    for motion, goal in TRACKED_GOALS_DEG.items():
        key = f"tracked_{motion}_rmse_deg"
        if key in results:
            verdict = "met" if results[key] <= goal else f"NOT met (gap {results[key] - goal:.2f} deg)"
            print(f"goal {motion}: RMSE {results[key]:.2f} deg <= {goal} deg: {verdict}")
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(strict_json(results))
        with atomic_write(args.json.with_suffix(".png"), "wb") as handle:
            handle.write(lab_angles_plot_png(lab))
        print(f"numbers: {args.json}\nplot:    {args.json.with_suffix('.png')}")
    return 0
