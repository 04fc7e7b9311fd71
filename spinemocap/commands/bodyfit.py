"""``spinemocap bodyfit MARKERS --out DIR``: MoSh-like body-model fit to sparse skin markers
(Plug-in Gait, trunk/spine sets, or any set through a mapping file) from a C3D/TRC file."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bodyfit", help="fit a body model (anny, SMPL, SMPL-X) to sparse skin markers (MoSh-like)",
        description="Fit a body model's shape, per-marker offsets and per-frame pose to the labelled "
                    "markers of a C3D/TRC file (Plug-in Gait and trunk/spine markers are recognised by "
                    "label; --mapping for others). Writes body.npz, summary.json (marker_rms_mm, "
                    "trunk_marker_rms_mm), residuals.csv and residuals.png into --out.")
    p.add_argument("markers", type=Path, help="marker file (C3D or TRC, any file the exporters read)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--model", default="anny", choices=("anny", "smpl", "smplh", "smplx"),
                   help="body model (default anny; the SMPL family needs --model-path)")
    p.add_argument("--model-path", type=Path, help="your SMPL/SMPL+H/SMPL-X model file or folder (licence-gated)")
    p.add_argument("--gender", default="neutral", help="SMPL-family model gender (neutral, female, male)")
    p.add_argument("--static", type=Path, help="static trial (C3D/TRC) for the shape stage")
    p.add_argument("--frames", help="the file's frames to fit: A:B (B exclusive) or A:B:S (every S-th); default all")
    p.add_argument("--key-frames", type=int, default=5, help="frames of the shape stage (default 5)")
    p.add_argument("--mapping", type=Path, help="TOML mapping unknown labels to markers or placement rules")
    p.add_argument("--tape", dest="tape_capture", type=Path, help="capture folder (or tape TOML) whose tape to lay "
                   "on the fitted body: writes tape_dots.c3d/.csv (the tracker's labels; the body-model ground truth)")
    p.add_argument("--tape-start", default="L4", help="vertebral level of the tape's first row (default L4)")
    p.add_argument("--save-vertices", action="store_true", help="also store all mesh vertices per frame in body.npz")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_bodyfit)


def run_bodyfit(args: argparse.Namespace) -> int:
    from ..app.bodyfit import fit_marker_file

    summary = fit_marker_file(args.markers, args.out, args.model, args.model_path, args.gender, args.static,
                              args.frames, args.mapping, args.key_frames, args.save_vertices,
                              progress=not args.no_progress, tape_capture=args.tape_capture,
                              tape_start=args.tape_start)
    print(f"{args.model} fit of {len(summary.markers)} markers over {summary.n_frames} frames: marker RMS "
          f"{summary.marker_rms_mm:.2f} mm" + (f", trunk markers {summary.trunk_marker_rms_mm:.2f} mm"
                                               if summary.trunk_marker_rms_mm is not None else ""))
    if summary.markers_flagged:
        print(f"WARNING: markers the body could not explain (RMS > 20 mm): {', '.join(summary.markers_flagged)}")
    if summary.frames_without_fit:
        print(f"WARNING: {len(summary.frames_without_fit)} frames had too few markers and keep the previous pose")
    print("note: the body fit is a baseline, not a truth (free marker offsets hide a misplaced back surface)")
    print(f"wrote {args.out}/body.npz, summary.json, residuals.csv, residuals.png"
          + (", tape_dots.c3d, tape_dots.csv" if args.tape_capture else ""))
    return 0


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bodyfit", help="the paper's Studio row: body fit to virtual Vicon markers vs the tracker, and "
                        "cross-validation with a known clock offset and transform")
    p.add_argument("--preset", default="artificial", choices=("tiny", "artificial", "studio"),
                   help="studio scene to render and track (default artificial)")
    p.add_argument("--frames", type=int, default=10, help="camera frames (default 10)")
    p.add_argument("--misplacement", type=float, default=10.0, help="Vicon marker misplacement on the skin, mm")
    p.add_argument("--key-frames", type=int, default=3, help="frames of the fit's shape stage")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, help="save every number to this JSON file")
    p.add_argument("--no-peer", action="store_true",
                   help="skip the peer fit (per frame, autograd through all bones)")
    p.add_argument("--crossval-rows", type=int, default=9, help="tape rows of the cross-validation trial (default 9)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run_bench_bodyfit)


def run_bench_bodyfit(args: argparse.Namespace) -> int:
    from ..bench.bodyfit import format_report, run_bodyfit_benchmark, save

    numbers = run_bodyfit_benchmark(args.preset, args.frames, args.misplacement, args.key_frames, args.seed,
                                    progress=not args.no_progress, peer=not args.no_peer,
                                    crossval_rows=args.crossval_rows)
    print(format_report(numbers))
    if args.json:
        save(numbers, args.json)
        print(f"wrote {args.json}")
    return 0
