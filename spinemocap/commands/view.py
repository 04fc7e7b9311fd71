"""``spinemocap view CAPTURE RESULTS``: labelled camera videos and the tape in 3D in the browser."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view", help="labelled camera videos (MP4) and a 3D viewer (HTML) of tracked results",
        description="Draw the tracked dots, reprojected through the rig, on every camera's frames "
                    "(one H.264 MP4 per camera and a grid of all cameras) and write the tape in 3D as one "
                    "self-contained HTML page with a time slider. Colours: green observed, amber inferred by "
                    "the tape model, magenta flagged (the tracker could not vouch for the label).")
    p.add_argument("capture", type=Path, help="capture folder (capture.toml, rig.toml, images or videos)")
    p.add_argument("results", type=Path,
                   help="results folder of `spinemocap track` (markers.csv with its manifest) or a marker file "
                        "(.csv, .trc, .c3d)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: RESULTS/view, or beside a marker file)")
    p.add_argument("--frames", default=None, metavar="SELECTION",
                   help="capture frames to draw: A:B (B exclusive), A:B:S every S-th (the video still plays in "
                        "recorded time), N, or a comma list, e.g. 100:400:2 (default: all tracked)")
    p.add_argument("--scale", type=float, default=None,
                   help="resize factor of the camera images (default: 1/2, 1/3, ... as needed for a "
                        "longest side of at most 1280 px, e.g. 1224x800 from 2448x1600)")
    p.add_argument("--no-video", action="store_true", help="write only the 3D viewer")
    p.add_argument("--no-grid", action="store_true", help="no grid video of all cameras")
    p.set_defaults(func=run_view)


def default_out(results: Path) -> Path:
    from ..app.viewer.layout import view_folder

    return view_folder(results if results.is_dir() else results.parent)


def run_view(args: argparse.Namespace) -> int:
    from ..app.viewer.layout import VIEWER_NAME
    from ..app.viewer.scene3d import write_viewer
    from ..app.viewer.video import selected_frames, write_videos

    out = args.out or default_out(args.results)
    if not args.no_video:
        result = write_videos(args.capture, args.results, out, frames=args.frames, scale=args.scale,
                              grid=not args.no_grid)
        for camera, path in result.cameras.items():
            print(f"  {camera:<12} {path}  ({result.sizes[camera][0]}x{result.sizes[camera][1]})")
        if result.grid is not None:
            print(f"  {'all cameras':<12} {result.grid}")
        print(f"labelled videos: {len(result.frames)} frames in {result.seconds:.1f} s "
              f"({result.frames_per_s:.1f} frames/s, all cameras)")
        frames = result.frames
    else:
        from ..app.viewer.tracked import read_tracked
        from ..capture import Capture

        capture = Capture.open(args.capture)
        frames = selected_frames(read_tracked(args.results, capture.tape), args.frames, capture.n_frames)
    start = time.perf_counter()
    page = write_viewer(args.capture, args.results, out / VIEWER_NAME, frames=frames)
    print(f"3D viewer: {page}  ({time.perf_counter() - start:.1f} s; open it in a browser)")
    return 0
