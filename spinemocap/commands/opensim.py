"""``spinemocap opensim RESULTS --capture CAPTURE --out DIR``: a multi-segment spine model carrying
the tape's markers, placed on a static trial by OpenSim's MarkerPlacer and solved by its
InverseKinematicsTool (see :mod:`spinemocap.opensim`)."""

from __future__ import annotations

import argparse
from pathlib import Path


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
    p.add_argument("--depth-scale", type=float,
                   help="factor on the published skin-to-vertebral-body depths (1 = anatomical); default: "
                        "fitted to the trial by minimising the IK marker RMS")
    p.add_argument("--coupling", choices=("rows", "region"), default="rows",
                   help="rows: couple a vertebra's rotations to its neighbour's only when no tape row lies over "
                        "it (default); region: couple lateral bending and axial rotation over each region, as "
                        "the published lumbar models")
    p.add_argument("--accuracy", type=float, default=1e-5, help="IK solver accuracy (default 1e-5)")
    p.add_argument("--model", type=Path, help="attach the markers to this lab model (.osim) instead of building one")
    p.add_argument("--bodies", type=Path, help="with --model: TOML mapping vertebrae to the model's bodies, "
                                               "e.g. L3 = \"lumbar3\"")
    p.set_defaults(func=run_opensim_command)


def read_results(path: Path):
    """A marker table from a results folder (``markers.csv``) or a marker file."""
    import exporters

    from ..fileio import InputError

    if path.is_dir():
        candidates = [path / name for name in ("markers.csv", "markers.parquet", "markers.c3d", "markers.trc")]
        found = next((c for c in candidates if c.is_file()), None)
        if found is None:
            raise InputError(path, "no markers.csv/.parquet/.c3d/.trc in this results folder")
        path = found
    if not path.is_file():
        raise InputError(path, "marker file not found")
    return exporters.read(path)


def run_opensim_command(args: argparse.Namespace) -> int:
    from ..opensim import OpenSimSettings, require_opensim, run_opensim

    require_opensim()
    from ..analysis.batch import find_level_map
    from ..analysis.levels import LevelMap
    from ..capture import Capture
    from ..fileio import InputError

    if (args.model is None) != (args.bodies is None):
        raise InputError("--model/--bodies", "a lab model needs both --model FILE.osim and --bodies MAP.toml")
    capture = Capture.open(args.capture)
    markers = read_results(args.results)
    if args.levels:
        levels, levels_from = LevelMap.from_toml(args.levels, capture.tape.n_rows), str(args.levels)
    else:
        levels, levels_from = find_level_map(capture)
    facing = capture.subject.get("facing")
    if facing is None:
        raise InputError(Path(args.capture) / "capture.toml", "[subject] facing is not set: OpenSim's forward axis "
                         "comes from it (e.g. facing = [0.0, -1.0, 0.0])")
    static = read_results(args.static) if args.static else None
    settings = OpenSimSettings(static_frames=args.static_frames, accuracy=args.accuracy,
                               depth_scale=args.depth_scale, coupling=args.coupling)
    if args.model is not None:
        from ..opensim.labmodel import run_lab_model

        result = run_lab_model(markers, capture.tape, levels, capture.up, facing, args.out, args.model,
                               args.bodies, static=static, settings=settings, source=str(args.results))
    else:
        result = run_opensim(markers, capture.tape, levels, capture.up, facing, args.out, static=static,
                             settings=settings, source=str(args.results))
    s = result.summary
    print(f"level map: {levels_from}")
    print(f"{s['frames']} frames: marker RMS {s['marker_rms_mm']:.2f} mm mean, {s['marker_rms_mm_max']:.2f} mm worst "
          f"frame; IK {s['ms_per_frame']:.1f} ms/frame; driven joints {', '.join(s['driven_joints'])}")
    if "depth_scale" in s:
        d = s["depth_scale"]
        print(f"joint centres {d['value']:.2f} x the published depth under the skin ({'fitted' if d['fitted'] else 'given'})")
    for reason, count in s["flag_reasons"].items():
        print(f"  flagged {count} frames: {reason}")
    for warning in s.get("warnings", []):
        print(f"  warning: {warning}")
    for name in ("model.osim", "markers_opensim.trc", "setup_scale.xml", "setup_ik.xml", "ik.mot",
                 "ik_marker_errors.sto", "spine_angles.csv", "spine_angles.png", "summary.json"):
        if (args.out / name).is_file():
            print(f"  {args.out / name}")
    return 0
