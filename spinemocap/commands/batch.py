"""``spinemocap batch ROOT --out DIR``: spine angles for every trial of a study."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys

log = logging.getLogger("spinemocap.batch")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "batch", help="track (if needed) and compute spine angles for every trial of a study",
        description="Find every capture under ROOT (subject/session/trial folders with capture.toml, "
                    "or a CSV manifest with a 'path' column), get its markers, compute spine angles and "
                    "write per-trial results to OUT. Up-to-date trials are skipped; a failing trial is "
                    "recorded with its reason and the others go on.")
    p.add_argument("root", help="study folder or CSV manifest")
    p.add_argument("--out", required=True, help="output folder (per-trial results, batch.log, batch.json)")
    p.add_argument("--source", choices=("tracked", "groundtruth"), default="tracked",
                   help="markers from the tracker (default) or the synthetic studio's ground truth")
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net",
                   help="the tracker's dot detector (mask: inside the synthetic captures' exact tape masks)")
    p.add_argument("--workers", type=int, default=min(4, os.cpu_count() or 1),
                   help="local worker processes (default: min(4, CPUs); 1 = in this process)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="run the trials on this Dask distributed scheduler's workers instead")
    p.add_argument("--levels", help="row-to-level map (TOML) for trials that carry none of their own")
    p.add_argument("--force", action="store_true", help="redo trials whose results are up to date")
    p.add_argument("--lowpass-hz", type=float, default=10.0,
                   help="low-pass cut-off for the tape's row tracks, Hz (0 = off; default 10)")
    p.add_argument("--lumbar", nargs=2, metavar=("LOWER", "UPPER"), default=("S1", "T12/L1"),
                   help="levels bounding the lumbar angles (default S1 T12/L1)")
    p.add_argument("--upper-level", help="top of the thoracic angles (default: the level map's top level)")
    p.add_argument("--report", action="store_true", help="write the HTML/CSV/XLSX report afterwards")
    p.add_argument("--view", action="store_true",
                   help="also write each tracked trial's labelled camera videos and 3D viewer (`spinemocap view`, "
                        "into <trial>/view); the report links them")
    p.add_argument("--opensim", action="store_true",
                   help="also run `spinemocap opensim` per trial (model, MarkerPlacer, IK into <trial>/opensim; "
                        "needs spinemocap[opensim]); the report shows the IK angles beside the tape's")
    p.set_defaults(func=run)


def register_bench(subparsers) -> None:
    p = subparsers.add_parser(
        "batch", help="batch wall time: in-process vs local process pool vs Dask LocalCluster",
        description="Times the same synthetic study (analytic-rod captures, ground-truth markers) "
                    "processed serially, on a process pool and on a Dask LocalCluster.")
    p.add_argument("--trials", type=int, default=16)
    p.add_argument("--frames", type=int, default=300, help="frames per trial (default 300 = 3 s at 100 fps)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", help="write the numbers here")
    p.set_defaults(func=run_bench)


def run_bench(args: argparse.Namespace) -> int:
    import json

    from ..bench.analysis import bench_batch
    from ..fileio import atomic_write

    result = bench_batch(args.trials, args.frames, args.workers)
    for name, seconds in result.seconds.items():
        print(f"{name:<20}{seconds:>8.2f} s  {result.trials_per_s[name]:>6.2f} trials/s  "
              f"x{result.speedup_vs_serial[name]:.2f} vs serial")
    print(f"every trial's angles identical on all three: {'yes' if result.identical_results else 'NO'}")
    if args.json:
        with atomic_write(args.json) as handle:
            json.dump(result.to_dict(), handle, indent=1)
    return 0 if result.identical_results else 1


def _terminate_as_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from ..analysis.angles import AngleSettings
    from ..app.batch import run_batch

    settings = AngleSettings(lower=args.lumbar[0], thoracolumbar=args.lumbar[1], upper=args.upper_level,
                             lowpass_hz=args.lowpass_hz or None)
    previous = signal.signal(signal.SIGTERM, _terminate_as_interrupt)  # kill PID stops as cleanly as Ctrl-C
    try:
        result = run_batch(args.root, args.out, source=args.source, workers=args.workers,
                           scheduler=args.scheduler, levels_file=args.levels, settings=settings,
                           force=args.force, detector=args.detector, progress=not args.quiet,
                           opensim=args.opensim, view=args.view)
    except KeyboardInterrupt:
        print(f"spinemocap: batch interrupted; unfinished trials are listed in {args.out}/batch.log; "
              "run the same command again to resume", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    skipped = sum(t.skipped for t in result.trials)
    print(f"{len(result.trials)} trials: {len(result.trials) - len(result.failed)} ok "
          f"({skipped} up to date), {len(result.failed)} failed; results in {args.out}")
    for trial in result.failed:
        print(f"  FAILED {trial.summary.key}: {trial.summary.reason}")
    if args.report:
        from ..app.report import write_report

        print(f"report: {write_report(args.out)['html']}")
    return 1 if result.failed else 0
