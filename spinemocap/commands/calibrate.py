"""``spinemocap calibrate intrinsics|extrinsics|wand-wave|wand|convert|check``,
``spinemocap synth-calibration`` and ``spinemocap bench calibration``: the :mod:`calibration`
package on the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..frames import parse_frames


def register(subparsers) -> None:
    parser = subparsers.add_parser("calibrate", help="calibrate cameras: boards, bundle adjustment, Vicon wand, formats")
    sub = parser.add_subparsers(dest="calibrate_command", metavar="STEP", required=True)

    p = sub.add_parser("intrinsics", help="one camera's intrinsics from board images or a video")
    p.add_argument("images", nargs="+", help="image files, a folder of images, or a video")
    p.add_argument("--board", required=True, help="checkerboard:COLSxROWS:SQUARE_MM (inner corners) or "
                   "charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]] (squares), then optionally :inverted, :legacy, :mirrored "
                   "(see extrinsics --help)")
    p.add_argument("--out", required=True, help="rig TOML (one camera, identity pose) or .xcp / Pose2Sim .toml")
    p.add_argument("--name", help="camera name (default: the folder or file name)")
    p.add_argument("--k3", action="store_true", help="also estimate the k3 radial term (wide-angle lenses)")
    p.add_argument("--max-frames", type=int, default=60, help="frames sampled from a video (default 60)")
    p.set_defaults(func=_intrinsics)

    p = sub.add_parser("extrinsics", help="all cameras' poses (and intrinsics) from board videos or image folders "
                       "+ bundle adjustment")
    p.add_argument("--intrinsics", nargs="+", help="rig/intrinsics files giving the cameras in order (default: "
                   "intrinsics from the same recordings, cameras named after the files)")
    p.add_argument("--views", nargs="+", required=True,
                   help="one board video (any codec or rate) or image folder per camera, in the cameras' order")
    p.add_argument("--board", required=True, help="charuco:COLSxROWS:SQUARE_MM[:MARKER_MM[:DICT]] or "
                   "checkerboard:COLSxROWS:SQUARE_MM (inner corners; one odd and one even count, e.g. 4x7), then "
                   "optionally :inverted / :normal, :legacy / :current (ChArUco layout), :mirrored / :front; "
                   "what is left out is found from the views")
    p.add_argument("--pair-by", choices=["index", "time"], default="index",
                   help="pair the cameras' frames by index (default) or by the videos' timestamps")
    p.add_argument("--max-frames", type=int, default=200, help="frames read per camera, spread evenly (default 200)")
    p.add_argument("--max-blur", type=float, help="views whose board edges are blurrier than this Gaussian sigma "
                   "(px; motion blur counts) are left out (default 3)")
    p.add_argument("--ba", choices=["ceres", "scipy"], default="ceres",
                   help="bundle adjustment: Ceres via pycolmap (default) or scipy least_squares")
    p.add_argument("--floor-frames", nargs="*", default=[],
                   help="frames where the board lies face up on the floor, e.g. 0 or 0:3 or 0,5 (world Z up); "
                        "none: the first camera's frame is the world")
    p.add_argument("--fixed-intrinsics", action="store_true", help="do not refine intrinsics in the adjustment")
    p.add_argument("--out", required=True, help="output rig (.toml ours, --format pose2sim, or .xcp)")
    p.add_argument("--format", choices=["spinemocap", "pose2sim"], help="TOML flavour of --out")
    p.add_argument("--plot", help="reprojection-error PNG (default: OUT.residuals.png; cameras and board poses "
                   "in 3D: OUT.rig3d.png)")
    p.set_defaults(func=_extrinsics)

    p = sub.add_parser("wand-wave", help="all cameras' poses from a wand wave alone (no board)")
    p.add_argument("--intrinsics", nargs="+", required=True, help="rig/intrinsics files giving the cameras in order")
    p.add_argument("--videos", nargs="+", required=True, help="one video (or image folder) per camera, in order")
    p.add_argument("--wand", default="t", help="t (5-marker T-wand, layout in calibration/wand.py), "
                   "linear:LENGTH_MM or linear:A_MM:LENGTH_MM (default t)")
    p.add_argument("--floor-frames", default="",
                   help="frames where the wand lies on the floor, e.g. 0:10 or 0,1,2 (world Z up; a linear wand "
                   "must lie in two directions); empty: the first camera's frame is the world")
    p.add_argument("--ba", choices=["ceres", "scipy"], default="ceres", help="bundle adjustment backend")
    p.add_argument("--fixed-intrinsics", action="store_true", help="do not refine intrinsics in the adjustment")
    p.add_argument("--out", required=True, help="output rig (.toml ours, --format pose2sim, or .xcp)")
    p.add_argument("--format", choices=["spinemocap", "pose2sim"], help="TOML flavour of --out")
    p.add_argument("--plot", help="wand-length error PNG (default: OUT.wand_length.png; residuals: OUT.residuals.png)")
    p.set_defaults(func=_wand_wave)

    p = sub.add_parser("wand", help="express a calibrated rig in the Vicon frame from a wand wave")
    p.add_argument("--rig", required=True, help="calibrated rig (any supported format)")
    p.add_argument("--videos", nargs="+", required=True, help="one video (or image folder) per rig camera, in order")
    p.add_argument("--vicon", required=True, help="Vicon C3D of the same wave with markers WAND1..WAND5")
    p.add_argument("--fps", type=float, help="RGB frame rate (default: from the first video)")
    p.add_argument("--max-offset", type=float, default=2.0, help="largest clock offset searched, s (default 2)")
    p.add_argument("--refine-extrinsics", action="store_true",
                   help="bundle-adjust the camera poses with the wand markers before registering")
    p.add_argument("--out", required=True, help="rig in the Vicon frame (.toml / .xcp)")
    p.set_defaults(func=_wand)

    p = sub.add_parser("convert", help="convert a calibration file (format by extension)")
    p.add_argument("input", help=".toml (ours / Pose2Sim / Anipose), .qca.txt (Qualisys) or .xcp (Vicon)")
    p.add_argument("output", help=".toml or .xcp")
    p.add_argument("--format", choices=["spinemocap", "pose2sim"], help="TOML flavour of the output (default ours)")
    p.set_defaults(func=_convert)

    p = sub.add_parser("check", help="per-camera table and reprojection-error plot of a rig, or its agreement "
                       "with another calibration")
    p.add_argument("rig", help="rig file (any supported format)")
    p.add_argument("--against", help="another calibration of the same cameras (any supported format): per-pair "
                   "baseline ratio and relative rotation difference; exit code 1 when a baseline differs by more than "
                   "2 %% or a relative rotation by more than 1 deg")
    p.add_argument("--views", nargs="+", help="synchronized board videos or image folders, one per camera (in order)")
    p.add_argument("--board", help="board of --views")
    p.add_argument("--plot", help="PNG path (default: RIG.check.png)")
    p.set_defaults(func=_check)

    p = subparsers.add_parser("synth-calibration",
                              help="render a synthetic calibration session (board and wand images) with its true rig")
    p.add_argument("out", help="output folder (must not exist)")
    p.add_argument("--board", default="checkerboard:4x7:60", help="board for intrinsics and extrinsics "
                   "(checkerboard:COLSxROWS:SQUARE_MM or charuco:...; default checkerboard:4x7:60)")
    p.add_argument("--wand", default="t", help="wand for the wand wave: t, linear:LENGTH_MM or linear:A_MM:LENGTH_MM")
    p.add_argument("--cameras", type=int, default=6, help="cameras on a ring (default 6)")
    p.add_argument("--size", type=int, default=800, help="image width in px (height = 3/4; default 800)")
    p.add_argument("--intrinsic-views", type=int, default=12, help="board images per camera for intrinsics")
    p.add_argument("--frames", type=int, default=16, help="synchronized board frames (3 on the floor first)")
    p.add_argument("--wand-seconds", type=float, default=3.0, help="length of the wand wave at 50 fps")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_synth_calibration)


def register_bench(subparsers) -> None:
    p = subparsers.add_parser("calibration", help="synthetic 6-camera board calibration + wand co-registration")
    p.add_argument("--size", type=int, default=1024, help="image width in px (height = 3/4; default 1024)")
    p.add_argument("--intrinsic-views", type=int, default=20)
    p.add_argument("--frames", type=int, default=24)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--checkerboard", default="checkerboard:4x7:120", help="checkerboard of the checkerboard row")
    p.add_argument("--wand", default="t", help="wand of the wand-wave row (t or linear:...)")
    p.add_argument("--wand-seconds", type=float, default=4.0, help="wand wave length at 50 fps")
    p.add_argument("--out", default="bench_calibration.json", help="JSON with the numbers")
    p.set_defaults(func=_bench)

    p = subparsers.add_parser("calibration-session", help="the studio's board session (inverted ChArUco, turned "
                              "cameras, 6 fps, strong distortion, motion blur) calibrated from its videos alone")
    p.add_argument("--size", type=int, nargs=2, default=[960, 540], help="landscape image size in px (default 960 540)")
    p.add_argument("--frames", type=int, default=96, help="frames per camera at 6 fps (default 96: 16 s)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--out", default="bench_calibration_session.json", help="JSON with the numbers")
    p.set_defaults(func=_bench_session)


# ---------------------------------------------------------------------- handlers
def _intrinsics(args: argparse.Namespace) -> int:
    from calibration.boards import BoardSpec
    from calibration.formats import write_rig
    from calibration.intrinsics import calibrate_intrinsics, iter_images
    from spinemocap.camera import Rig

    board = BoardSpec.parse(args.board)
    source = args.images[0] if len(args.images) == 1 else args.images
    name = args.name or Path(args.images[0]).stem
    result = calibrate_intrinsics(iter_images(source, args.max_frames), board, name, source=str(args.images[0]),
                                  fix_k3=not args.k3)
    print(result.summary())
    write_rig(Rig([result.camera]), args.out)
    print(f"wrote {args.out}")
    return 0


def _extrinsics(args: argparse.Namespace) -> int:
    from calibration.boards import MAX_BLUR_SIGMA_PX, BoardSpec

    from ..app.calibrate import calibrate_recordings, read_cameras, write_calibration

    floor = parse_frames(",".join(args.floor_frames), parameter="--floor-frames") if args.floor_frames else None
    board = BoardSpec.parse(args.board)
    intrinsics = read_cameras(args.intrinsics) if args.intrinsics else None
    max_blur = MAX_BLUR_SIGMA_PX if args.max_blur is None else args.max_blur
    calibrated = calibrate_recordings(args.views, board, intrinsics, args.pair_by, args.max_frames,
                                      floor, not args.fixed_intrinsics, args.ba, max_blur)
    print(calibrated.summary())
    files = write_calibration(calibrated, args.out, args.format, args.plot)
    print(f"wrote {files.rig}, {files.residual_plot} and {files.rig_3d}")
    return 0


def _wand_wave(args: argparse.Namespace) -> int:
    from calibration.wand import WandSpec

    from ..app.calibrate import calibrate_wand_wave_videos, read_cameras, write_wand_wave

    floor = parse_frames(args.floor_frames, parameter="--floor-frames") if args.floor_frames else None
    result = calibrate_wand_wave_videos(args.videos, read_cameras(args.intrinsics), WandSpec.parse(args.wand), floor,
                                        backend=args.ba, refine_intrinsics=not args.fixed_intrinsics)
    print(result.summary())
    files = write_wand_wave(result, args.out, args.format, args.plot)
    print(f"wrote {files.rig}, {files.length_plot} and {files.residual_plot}")
    return 0


def _synth_calibration(args: argparse.Namespace) -> int:
    from calibration.boards import BoardSpec
    from calibration.wand import WandSpec

    from ..bench.calibration_scenes import write_calibration_session

    readme = write_calibration_session(args.out, BoardSpec.parse(args.board), WandSpec.parse(args.wand),
                                       args.cameras, (args.size, args.size * 3 // 4), args.intrinsic_views,
                                       args.frames, args.wand_seconds, args.seed)
    print(readme)
    return 0


def _wand(args: argparse.Namespace) -> int:
    from calibration.formats import read_rig, write_rig
    from calibration.wand import WandSpec, coregister, synchronized_frames

    from ..app.c3d_inputs import read_vicon_wand

    rig = read_rig(args.rig)
    frames, fps = synchronized_frames(args.videos, len(rig))
    result = coregister(rig, frames, args.fps or fps, read_vicon_wand(args.vicon, WandSpec()), max_offset_s=args.max_offset,
                        refine_extrinsics=args.refine_extrinsics)
    print(result.summary())
    if result.rig_in_vicon is None:
        raise RuntimeError("the wand registration gave no rig in the Vicon frame")
    write_rig(result.rig_in_vicon, args.out)
    print(f"wrote {args.out}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from calibration.formats import read_rig, write_rig

    rig = read_rig(args.input)
    write_rig(rig, args.output, args.format)
    print(f"converted {len(rig)} cameras: {args.input} -> {args.output}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from calibration.boards import BoardSpec
    from calibration.check import (
        Residuals,
        camera_table,
        compare_rigs,
        load_residuals,
        plot_residuals,
        residuals_from_views,
        residuals_path,
    )
    from calibration.formats import read_rig
    from spinemocap.fileio import InputError

    from ..app.calibrate import load_view_detections

    rig = read_rig(args.rig)
    if args.against:
        comparison = compare_rigs(rig, read_rig(args.against))
        print(f"{args.rig} against {args.against}:")
        print(comparison.summary())
        if not args.views:
            return 0 if comparison.agrees else 1
    residuals: Residuals | None
    if args.views:
        if not args.board:
            raise InputError("--views", "--board is needed to detect the board in --views")
        board = BoardSpec.parse(args.board)
        residuals = residuals_from_views(rig, board, load_view_detections(args.views, rig, board))
    else:
        residuals = load_residuals(args.rig)
    if residuals is None:
        print(camera_table(rig))
        print(f"no reprojection residuals: {residuals_path(args.rig).name} is absent (written by "
              "'calibrate extrinsics'); pass synchronized board views with --views and --board to measure them")
        return 0
    print(camera_table(rig, residuals))
    plot = args.plot or f"{args.rig}.check.png"
    plot_residuals(rig, residuals, plot)
    print(f"wrote {plot}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from ..bench.calibration import run_benchmark

    run_benchmark(args.size, args.intrinsic_views, args.frames, args.seeds, args.out,
                  checkerboard=args.checkerboard, wand=args.wand, wand_seconds=args.wand_seconds)
    return 0


def _bench_session(args: argparse.Namespace) -> int:
    from ..bench.board_session import run_session_benchmark

    run_session_benchmark(tuple(args.size), args.frames, tuple(args.seeds), args.out)
    return 0
