"""``spinemocap crossval TRACKED VICON.c3d --capture CAPTURE --out DIR``: cross-validate the tape
against a Vicon recording (clock offset, transform, marker and angle agreement; merged C3D; HTML
page with plots; summary.json)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "crossval", help="cross-validate tracked tape dots against Vicon markers (agreement, merged C3D, report)",
        description="Bring the tracked dots and a Vicon C3D into one frame and clock (from Vicon markers on the "
                    "tape's centre line, VT_Rnn, or the wand calibration's rig with --rig-vicon), resample, and "
                    "compare markers and segment angles: RMSE, bias, Bland-Altman limits, ICC(2,1), CMC. Writes "
                    "summary.json, merged.c3d (tracked dots + VICON_* markers in the rig frame), angles.csv and "
                    "report.html into --out.")
    p.add_argument("tracked", type=Path, help="tracked dots: a results folder (markers.csv) or a marker file (C3D, "
                                              "TRC, CSV)")
    p.add_argument("vicon", type=Path, help="Vicon C3D")
    p.add_argument("--capture", type=Path, required=True, help="the capture folder (tape spec, rig)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--rig-vicon", type=Path, help="the capture's rig expressed in the Vicon frame (from "
                   "'spinemocap calibrate wand'): the transform is taken from it, only the clock offset is estimated")
    p.add_argument("--reference", type=Path, help="body-model tape dots in the Vicon frame and clock ('spinemocap "
                   "bodyfit VICON.c3d --tape CAPTURE' -> tape_dots.c3d): compared with the tracked dots and written "
                   "as REF_* markers in merged.c3d")
    p.add_argument("--levels", type=Path, help="row-to-level map TOML for the angles (default: the capture's "
                   "levels.toml / [levels] / ground truth, as the batch finds it)")
    p.add_argument("--marker-diameter", type=float, default=14.0, help="Vicon marker diameter in mm (default 14)")
    p.add_argument("--max-offset", type=float, default=1.0, help="largest clock offset searched, s (default 1)")
    p.set_defaults(func=run_crossval)


def run_crossval(args: argparse.Namespace) -> int:
    from ..app.crossval import ICC_FLAG, crossval_files
    from ..app.results import find_markers

    result = crossval_files(find_markers(args.tracked), args.vicon, args.capture, args.out, args.rig_vicon,
                            args.marker_diameter, args.max_offset, args.reference, args.levels)
    a, summary = result.alignment, result.summary
    print(f"clock offset (t_vicon - t_rgb) {1000 * a.offset_s:+.2f} ms; alignment residual {a.residual_mm:.2f} mm "
          f"over {a.n_frames} frames ({a.estimated} estimated)")
    for name, stats in summary.angles.items():
        print(f"  {name:28s} RMSE {stats.rmse:5.2f} deg  bias {stats.bias:+5.2f}  LoA "
              f"[{stats.loa_low:+.2f}, {stats.loa_high:+.2f}]  ICC {stats.icc:.3f}  CMC {stats.cmc:.3f}")
    if summary.reference is not None:
        r = summary.reference
        print(f"body-fit tape vs tracked dots: mean {r.dot_distance_mean_mm:.2f} mm, median "
              f"{r.dot_distance_median_mm:.2f}, p95 {r.dot_distance_p95_mm:.2f} mm over {r.n} dot-frames")
    if summary.angles_skipped is not None:
        print(f"WARNING: no angles compared: {summary.angles_skipped}")
    flagged = summary.poorly_agreeing(ICC_FLAG)
    if flagged:
        print(f"WARNING: poor agreement (ICC <= {ICC_FLAG}) for {', '.join(flagged)}")
    print(f"wrote {args.out}/summary.json, merged.c3d, angles.csv, report.html")
    return 0
