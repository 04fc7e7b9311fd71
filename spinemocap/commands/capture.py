"""``spinemocap capture init OUT``: a capture folder from a lab's own recordings and calibration;
``spinemocap capture sync CAPTURE``: the cameras' clock offsets estimated from the recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..app.capture_init import SIZE_FIXES
from ..fileio import InputError
from .capture_sync import add_sync_parser


def _pair(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name or not value:
        raise argparse.ArgumentTypeError(f"expected CAMERA=VALUE, got {text!r}")
    return name, value


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("capture", help="make a capture folder from a lab's recordings (init), sync its cameras",
                              description="Capture folders (docs/CAPTURE.md): `init` writes one from video files or "
                                          "image folders and a calibration; `sync` estimates the cameras' clock offsets.")
    sub = p.add_subparsers(dest="capture_command", metavar="SUBCOMMAND", required=True)
    init = sub.add_parser(
        "init", help="write a capture folder from one video or image folder per camera and a calibration",
        description="Write OUT/capture.toml and OUT/rig.toml from one recording per camera and a calibration (rig "
                    "TOML, Pose2Sim/Anipose TOML, Qualisys .qca.txt or Vicon .xcp). Recordings are matched to the "
                    "calibration's cameras by file name (the camera's name as the file name or a word of it) and "
                    "referenced where they are (external_media = true) unless --copy. Frame counts, rates and sizes "
                    "are read from the files; a recording whose size differs from its calibration is refused with "
                    "the reason unless --fix-size names the fix.")
    init.add_argument("out", type=Path, help="capture folder to write (new, or --force)")
    given = init.add_mutually_exclusive_group(required=True)
    given.add_argument("--video", type=_pair, action="append", metavar="CAMERA=PATH",
                       help="a camera's video file, named (repeat per camera)")
    given.add_argument("--videos", type=Path, nargs="+", metavar="PATH", help="video files, matched to cameras by name")
    given.add_argument("--images", type=Path, nargs="+", metavar="DIR",
                       help="image folders (one per camera, images in name order), matched by name; needs --fps")
    init.add_argument("--calibration", type=Path, required=True, metavar="FILE",
                      help="rig .toml (ours or Pose2Sim/Anipose), Qualisys .qca.txt or Vicon .xcp")
    init.add_argument("--map", type=_pair, action="append", default=[], metavar="CAMERA=FILE",
                      help="the calibration's camera for a recording whose name does not say it (repeatable)")
    init.add_argument("--fps", type=float, help="the capture's rate, frames/s (default: the slowest video's; image "
                                                "folders: required)")
    init.add_argument("--start", help="first capture frame: seconds (2.5s) or a frame number (250) (default 0)")
    init.add_argument("--end", help="end of the capture (exclusive): seconds (12s) or a frame number (default: the end "
                                    "of the shortest recording)")
    init.add_argument("--offset", type=_pair, action="append", default=[], metavar="CAMERA=SECONDS",
                      help="a camera's clock minus the capture's, s (a camera that started 0.2 s late: -0.2); "
                           "`spinemocap capture sync` estimates them")
    init.add_argument("--fix-size", choices=SIZE_FIXES,
                      help="calibrate recordings of another size than the calibration's: crop (an encoder's rows or "
                           "columns cut at the bottom/right: principal point kept), crop-centre (centred crop: "
                           "principal point moved by half the difference), scale (whole-number scale: focal lengths "
                           "and principal point scaled)")
    init.add_argument("--copy", action="store_true", help="copy the recordings into OUT (default: reference them)")
    init.add_argument("--tape", type=Path, metavar="FILE", help="the tape's layout (TOML of [tape] keys, "
                                                                "docs/CAPTURE.md; default: the standard roll, 9 rows)")
    init.add_argument("--subject", help="subject id (default: the folder's name)")
    init.add_argument("--force", action="store_true", help="replace OUT's capture.toml")
    init.set_defaults(func=run_init)
    add_sync_parser(sub)  # the offset estimate's own parser and handler


def _offsets(pairs: list[tuple[str, str]]) -> dict[str, float]:
    out = {}
    for name, value in pairs:
        try:
            out[name] = float(value.removesuffix("s"))
        except ValueError:
            raise InputError("--offset", f"{name}={value}: the offset is a number of seconds") from None
    return out


def run_init(args: argparse.Namespace) -> int:
    from ..app.capture_init import init_capture
    from ..fileio import read_toml, reading
    from ..tape import TapeSpec
    from ._flags import shown

    tape = None
    if args.tape is not None:
        data = read_toml(args.tape)
        with reading(args.tape, "tape"):
            tape = TapeSpec.from_dict(data.get("tape", data), source=str(args.tape))
    result = init_capture(args.out, args.calibration, media=args.videos or args.images or (),
                          named=dict(args.video or []), mapping=dict(args.map), fps=args.fps, start=args.start,
                          end=args.end, offsets=_offsets(args.offset), fix_size=args.fix_size, copy=args.copy,
                          tape=tape, subject=args.subject, force=args.force)
    capture = result.capture
    print(f"capture written: {result.root / 'capture.toml'} ({len(capture.camera_names)} cameras, {capture.n_frames} "
          f"frames at {capture.fps:g} frames/s from {capture.start_s:g} s)")
    for name, probe in result.probes.items():
        dropped = f", {probe.dropped} dropped" if probe.dropped else ""
        print(f"  {name}: {probe.path} ({probe.n_frames} frames, {probe.fps:g} frames/s, "
              f"{probe.size[0]}x{probe.size[1]} px{dropped})")
    for fix in result.fixes:
        print(f"  calibration fixed: {shown(fix)}")
    if result.unused_cameras:
        print(f"  cameras of the calibration without a recording (left out): {', '.join(result.unused_cameras)}")
    print(f"next: spinemocap track {result.root} --out {result.root / 'tracked'}")
    return 0
