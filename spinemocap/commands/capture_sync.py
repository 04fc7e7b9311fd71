"""``spinemocap capture sync CAPTURE``: estimate the clock offsets of cameras that were not
synchronised, before tracking (the work is :mod:`spinemocap.app.sync`). The ``capture`` command
group adds this subcommand with :func:`add_sync_parser`; its handler is :func:`run_sync`."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_sync_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``sync`` to the ``capture`` group's subparsers; returns its parser."""
    p = subparsers.add_parser(
        "sync", help="estimate each camera's clock offset (cameras not synchronised) and optionally store it",
        description="Estimate each camera's clock offset against camera 1 (the capture's clock) before tracking: "
                    "from the tape dots' motion across views (the offset whose frame pairing puts every dot on "
                    "the other cameras' epipolar lines, to a fraction of a frame) or from a clap or beep on the "
                    "videos' audio tracks. Prints the offsets with their standard errors; --write stores them "
                    "as [camera.NAME] offset_s in capture.toml, which reading and tracking then honour.")
    p.add_argument("capture", type=Path, help="capture folder")
    p.add_argument("--method", choices=("motion", "audio", "auto"), default="auto",
                   help="motion: the dots' motion; audio: a clap on the audio tracks; auto (default): audio where "
                        "every video has it and it finds every camera, else motion")
    p.add_argument("--detector", choices=("net", "classical"), default="net",
                   help="dot detector for the motion estimate (default net)")
    p.add_argument("--seconds", type=float, default=6.0,
                   help="the first seconds of each camera's recording the motion estimate reads (default 6)")
    p.add_argument("--max-offset", type=float, default=2.0, metavar="S",
                   help="the largest offset of a camera against camera 1 searched, s (default 2)")
    p.add_argument("--write", action="store_true", help="store the offsets found in capture.toml")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_sync)
    return p


def run_sync(args: argparse.Namespace) -> int:
    """Estimate (and with ``--write`` store) the offsets; exit code 1 when a camera's offset was
    not found (then nothing is written for it)."""
    from ..app.sync import estimate_offsets, format_estimate, write_offsets
    from ..capture import Capture
    from ..fileio import InputError
    from ._flags import shown

    if not (args.seconds > 0 and args.max_offset > 0):
        raise InputError("spinemocap capture sync", "--seconds and --max-offset must be positive")
    capture = Capture.open(args.capture)
    estimate = estimate_offsets(capture, args.method, args.detector, args.seconds, args.max_offset,
                                progress=not args.no_progress)
    print(shown(format_estimate(estimate)))
    if args.write:
        path = write_offsets(capture, estimate)
        print(f"offsets written to {path}")
    return 0 if estimate.found.all() else 1
