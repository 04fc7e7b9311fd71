"""``spinemocap opensim RESULTS --capture CAPTURE --out DIR``: a multi-segment spine model carrying
the tape's markers, placed on a static trial by OpenSim's MarkerPlacer and solved by its
InverseKinematicsTool (see :mod:`spinemocap.opensim`); ``spinemocap bench opensim``: arguments and
printing, the benchmark is :mod:`spinemocap.bench.opensim`."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from .synth import JOINT_DEPTH_NAMES


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "opensim", help="OpenSim spine model + inverse kinematics from tracked tape markers",
        description="Build a pelvis-sacrum-L5..T1-head/neck model with one marker per tape dot on the "
                    "vertebra under it (level map), place the markers on a static trial (MarkerPlacer) "
                    "and solve inverse kinematics; writes model.osim, markers_opensim.trc, setup_scale.xml, "
                    "setup_ik.xml, ik.mot, ik_marker_errors.sto, spine_angles.csv/.png and summary.json "
                    "into DIR. Needs the optional extra: pip install 'spinemocap[opensim]'.")
    p.add_argument("results", type=Path, help="tracking results folder (markers.csv) or any marker file the "
                                              "exporters read (csv, trc, c3d, parquet)")
    p.add_argument("--capture", type=Path, required=True,
                   help="capture folder: tape spec and [subject] up/facing (the OpenSim axes) from capture.toml")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--levels", type=Path, help="row-to-level map (TOML); default: as `spinemocap batch` finds it "
                                              "(levels.toml in the capture or subject folder, [levels] in "
                                              "capture.toml, a synthetic capture's ground truth)")
    p.add_argument("--static", type=Path, help="static trial marker file (default: the first --static-frames frames)")
    p.add_argument("--static-frames", type=int, default=10, help="frames averaged as the static trial (default 10)")
    p.add_argument("--depth-scale", type=float, default=1.0,
                   help="factor on the published skin-to-vertebral-body depths, which are scaled to the subject by "
                        "the tape (default 1); give the subject's measured depth (imaging) over the published one")
    p.add_argument("--depth-source", help="where --depth-scale comes from (written to summary.json)")
    p.add_argument("--rigid-skin", action="store_true",
                   help="no skin model: every marker fixed to its vertebra, row tilt as measured (default: tilt kept "
                        "at the static angle, rows above the lowest two slip along their vertebrae)")
    p.add_argument("--slip-from-tape", choices=("held", "goal", "off"), default="held",
                   help="how IK uses each row's skin slip that the tape's own lengthening shows: held = each "
                        "frame's slip prescribed at it, IK solves the spine's rotations only (default; solved to "
                        "1e-7); goal = a prior centred on it (SD 3 mm), slip and rotations solved together (to "
                        "1e-6; the answer moves with rounding, e.g. in a world turned about the vertical); off = "
                        "slips solved from the markers with a prior toward 0 (SD 25 mm, OpenSim's accuracy 1e-5)")
    p.add_argument("--coupling", choices=("rows", "region"), default="rows",
                   help="rows: couple a vertebra's rotations to its neighbour's only when no tape row lies over "
                        "it (default); region: couple lateral bending and axial rotation over each region, as "
                        "the published lumbar models")
    p.add_argument("--prior-weight", type=float, default=0.0,
                   help="IK weight of a prior pulling every level's lateral bending and axial rotation toward the "
                        "static posture (per rad^2, against the markers' weighted sum of squared errors in m^2: a weight "
                        "of (marker SD / prior SD)^2 is a prior of that SD; default 0 = off; larger weights trade range "
                        "for stability)")
    p.add_argument("--accuracy", type=float,
                   help="IK solver accuracy (default: 1e-7; 1e-6 with --slip-from-tape goal; OpenSim's 1e-5 with off; tighter reads "
                        "a trunk twist more fully, but forward bending with the slips' prior at 0 less well)")
    p.add_argument("--model", type=Path, help="attach the markers to this lab model (.osim) instead of building one")
    p.add_argument("--bodies", type=Path, help="with --model: TOML mapping vertebrae to the model's bodies, "
                                               "e.g. L3 = \"lumbar3\"")
    p.set_defaults(func=run_opensim_command)


def run_opensim_command(args: argparse.Namespace) -> int:
    from ..app.opensim import opensim_capture
    from ..opensim import OpenSimSettings
    from ..opensim.pipeline import slip_solved_as
    from ..opensim.summary import SpineModelSummary

    source = args.depth_source or (
        OpenSimSettings.depth_source if args.depth_scale == 1.0 else f"given: {args.depth_scale:g} x the published depths")
    settings = slip_solved_as(args.slip_from_tape, OpenSimSettings(
        static_frames=args.static_frames, depth_scale=args.depth_scale, depth_source=source, coupling=args.coupling,
        prior_weight=args.prior_weight))
    if args.accuracy is not None:
        settings = replace(settings, accuracy=args.accuracy)
    if args.rigid_skin:
        settings = replace(settings, slip=None, normalise_tilt=False)
    result, levels_from = opensim_capture(args.results, args.capture, args.out, args.levels, args.static,
                                          args.model, args.bodies, settings)
    s = result.summary
    print(f"level map: {levels_from}")
    print(f"{s.frames} frames: marker RMS {s.marker_rms_mm:.2f} mm mean, {s.marker_rms_mm_max:.2f} mm worst "
          f"frame; IK {s.ms_per_frame:.1f} ms/frame; driven joints {', '.join(s.driven_joints)}")
    if isinstance(s, SpineModelSummary):
        print(f"joint centres {s.depth.scale_on_published:.2f} x the published depth under the skin "
              f"({s.depth.source})")
        slip = s.skin_model.slip
        if slip is not None:
            print("skin slip at peak (mm): " + ", ".join(f"{k[:3]} {v:+.1f}" for k, v in slip.at_peak_mm.items()))
    for reason, count in s.flag_reasons.items():
        print(f"  flagged {count} frames: {reason}")
    for warning in s.warnings:
        print(f"  warning: {warning}")
    for name in ("model.osim", "markers_opensim.trc", "setup_scale.xml", "setup_ik.xml", "ik.mot",
                 "ik_marker_errors.sto", "spine_angles.csv", "spine_angles.png", "summary.json"):
        if (result.out_dir / name).is_file():
            print(f"  {result.out_dir / name}")
    return 0


def register_bench(subparsers) -> None:
    p = subparsers.add_parser(
        "opensim", help="OpenSim IK spine angles vs the studio's applied motion (RMSE, R^2, marker RMS), "
                        "geometric angles as the peer",
        description="Runs the studio's flexion, lateral, rotation and mixed motions through `spinemocap "
                    "opensim` (model, MarkerPlacer, IK) on ground-truth and tracked markers and scores the "
                    "IK angles between two tape levels against the applied ones, beside the geometric "
                    "angles of the same markers. See spinemocap/bench/opensim.py.")
    p.add_argument("--frames", type=int, default=100, help="frames per motion (default 100)")
    p.add_argument("--fps", type=float, default=100 / 3, help="frame rate (default 33.3: 3 s of motion)")
    p.add_argument("--rows", type=int, default=13, help="tape rows (default 13)")
    p.add_argument("--motions", nargs="+", default=["flexion", "lateral", "rotation", "mixed"],
                   choices=("flexion", "lateral", "rotation", "mixed"))
    p.add_argument("--sources", nargs="+", default=["groundtruth", "tracked"], choices=("groundtruth", "tracked"))
    p.add_argument("--tracked-frames", type=int, help="frames to render and track per motion (default: --frames)")
    p.add_argument("--cache", type=Path, help="keep the tracked markers here (markers_<motion>_<frames>_<fps>.csv) "
                                              "and reuse them instead of rendering and tracking again")
    p.add_argument("--realism", default="lab", choices=("ideal", "skin", "lab"),
                   help="studio realism level (default lab: tape tension, skin strain, the lab's inexact rig)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="studio subjects (seeds), default 0")
    p.add_argument("--joint-depth", default="anny", choices=JOINT_DEPTH_NAMES,
                   help="where the studio's spine bends under the skin: anny (the body model's joints; default) or "
                        "anatomical (the published depth of the vertebral bodies; see spinemocap synth --help)")
    p.add_argument("--accuracy", type=float, help="IK solver accuracy of every IK method (default: the pipeline's)")
    p.add_argument("--methods", nargs="+",
                   help="IK methods to run (default all; the geometric peer always runs): ik = the pipeline, "
                        "ik_slip_goal / ik_slip_from_markers = the pipeline with --slip-from-tape goal / off, "
                        "ik_one_start, "
                        "ik_rigid (see spinemocap/bench/opensim.py)")
    p.add_argument("--json", type=Path, help="write the numbers here")
    p.add_argument("--plot", type=Path, help="write the headline (worst over subjects per method, goals) as a PNG here")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    from ..bench.opensim import IK_METHODS, format_table, headline_plot_png, run_opensim_benchmark
    from ..fileio import atomic_write, strict_json
    accuracy = args.accuracy
    methods = list(IK_METHODS) if args.methods is None else args.methods

    report = run_opensim_benchmark(args.motions, args.sources, args.frames, args.fps, args.rows,
                                   args.tracked_frames, args.cache, not args.no_progress, realism=args.realism,
                                   seeds=args.seeds, accuracy=accuracy, methods=methods, joint_depth=args.joint_depth)
    command = " ".join(
        ["spinemocap bench opensim", f"--frames {args.frames}", f"--fps {args.fps:.4g}", f"--rows {args.rows}",
         f"--realism {args.realism}", f"--joint-depth {args.joint_depth}",
         "--motions " + " ".join(args.motions), "--sources " + " ".join(args.sources),
         "--seeds " + " ".join(str(s) for s in args.seeds)]
        + ([f"--accuracy {accuracy:g}"] if accuracy is not None else []) + ["--methods " + " ".join(methods)]
        + ([f"--tracked-frames {args.tracked_frames}"] if args.tracked_frames else []))
    print(format_table(report.sources))
    for source, table in report.headline.items():
        for method, row in table.items():
            print(f"worst over subjects ({source}, {method}): " + ", ".join(
                f"{k} {v:.2f}" for k, v in row.numbers().items())
                + "; goals " + ", ".join(f"{k} {'met' if ok else 'NOT met'}" for k, ok in row.goals_met.items()))
    if args.json:
        with atomic_write(args.json) as handle:
            handle.write(strict_json({**report.to_dict(), "command": command}))
        print(f"numbers: {args.json}")
    if args.plot:
        with atomic_write(args.plot, "wb") as handle:
            handle.write(headline_plot_png(report))
        print(f"plot: {args.plot}")
    return 0
