"""``spinemocap track CAPTURE --out DIR``: labelled 3D tape dots from a capture folder."""

from __future__ import annotations

import argparse
import logging
import time
import warnings
from pathlib import Path

from spinemocap.capture import Capture
from spinemocap.markers import STATUSES

log = logging.getLogger(__name__)


def add_refresh_arguments(p: argparse.ArgumentParser) -> None:
    """Sequence mode's schedule of full tape searches (``SpeedOptions.refresh*``); unset: the pipeline's."""
    p.add_argument("--refresh-every", type=int, default=None,
                   help="sequence mode: frames between full tape searches (between them the detector searches "
                        "only the tape box predicted from the previous frames; default: the pipeline's)")
    p.add_argument("--refresh", choices=("frame", "camera"), default=None,
                   help="sequence mode: full searches of all cameras in the same frame, or each camera on its own "
                        "schedule, the cameras spread over the period (default: the pipeline's)")
    p.add_argument("--refresh-settled-every", type=int, default=None,
                   help="with --refresh camera: frames between full searches of a camera that found all its dots "
                        "well inside its image (0: as --refresh-every; default: the pipeline's)")


def refresh_options(args: argparse.Namespace) -> dict:
    """The ``SpeedOptions`` fields :func:`add_refresh_arguments` set (the ones given)."""
    given = {"refresh_every": args.refresh_every, "refresh": args.refresh,
             "refresh_settled_every": args.refresh_settled_every}
    return {k: v for k, v in given.items() if v is not None}


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "track", help="track the tape dots of a capture folder into labelled 3D markers",
        description="Detect the tape dots in every view, triangulate, select the tape's edges (LP), "
                    "align and refine the tape model (MRF1, MRF2) and write DIR/markers.csv, "
                    "markers.trc and markers.c3d (mm, world Z up), and DIR/tracking.log (every frame's "
                    "conditions). Synthetic captures (groundtruth.npz) also get their accuracy printed. Exit "
                    "status 3 where the tape is not found in most frames (no markers written), 2 for bad input.")
    p.add_argument("capture", type=Path, help="capture folder (capture.toml, rig.toml, images/ or videos/)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--mode", choices=("sequence", "paper"), default="sequence",
                   help="sequence: carry identities frame to frame (default); paper: every frame on its own")
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net",
                   help="tape/dot detector; 'mask' finds dots inside the capture's masks/ (synthetic captures)")
    p.add_argument("--config", type=Path, help="tracker settings (TOML, see spinemocap.track.config)")
    p.add_argument("--frames", help="consecutive frames A:B (B exclusive; A or B may be left out), default all")
    p.add_argument("--workers", type=int, default=0,
                   help="processes or threads for the cameras (default 0: one per CPU core, at most one per camera; "
                        "1: one camera after the other)")
    p.add_argument("--parallel", choices=("threads", "processes"), default="threads",
                   help="cameras in worker processes (one detector each, images through shared memory; falls back "
                        "to threads with a warning where processes cannot start) or in threads (default: as fast or "
                        "faster on 2 and 16 cores)")
    p.add_argument("--lookahead", type=int, default=None,
                   help="sequence mode: frames detection may run ahead of the tracker (0: frame t+1 is detected "
                        "after frame t is solved, the exact serial order; 1: while frame t is solved, predicting "
                        "its tape boxes from frame t-1; default: the pipeline's)")
    add_refresh_arguments(p)
    p.add_argument("--frames-at-once", type=int, default=1,
                   help="frames detected at the same time, each searched in full (no predicted boxes): for a machine "
                        "with more cores than cameras; --workers 0 then means one per CPU core (default 1)")
    p.add_argument("--candidate-workers", type=int, default=0,
                   help="with --frames-at-once: processes that build the tracker's candidate points a few frames "
                        "ahead of it (the same output; for a machine with cores to spare; default 0)")
    p.add_argument("--opencv-threads", type=int, default=1,
                   help="OpenCV's own threads per camera thread while the cameras are detected in parallel "
                        "(default 1; 0: OpenCV's setting, one per core)")
    p.add_argument("--device", default="auto",
                   help="where the tape network runs: auto (a CUDA GPU when torch sees one, else the CPU), cpu, cuda "
                        "(on the CPU through ONNX Runtime where it is installed, else torch)")
    p.add_argument("--precision", default=None,
                   help="the tape network's arithmetic: float32, int8 (ONNX Runtime on the CPU), bfloat16 (torch); "
                        "default: the pipeline's")
    p.add_argument("--serial", action="store_true",
                   help="the serial pipeline (one camera after the other, no prefetching, full tape "
                        "search in every frame): for comparisons")
    p.add_argument("--refine-rig", action="store_true",
                   help="bundle-adjust the camera poses (and a focal scale per camera) on the tracked dots, "
                        "write DIR/rig_refined.toml with the residuals before/after in DIR/rig_refine.json and "
                        "re-triangulate the observed dots with it")
    p.add_argument("--reference", type=Path, metavar="FILE",
                   help="with --refine-rig: a reference object of known geometry in view (reference.toml: markers in "
                        "its own frame and its pose in the world, see spinemocap.reference) whose markers fix the "
                        "refined rig's world frame; default: the one capture.toml names, if any")
    p.add_argument("--refine-sync", action="store_true",
                   help="with --refine-rig: also estimate a clock offset per camera (ms, against the first)")
    p.add_argument("--chunk-frames", type=int, metavar="N",
                   help="long captures: track N frames at a time (memory bounded by the chunk); a run that is "
                        "stopped or killed resumes from its last completed chunk with the same output "
                        "(saved chunks in DIR/.chunks)")
    p.add_argument("--warmup-frames", type=int, default=25,
                   help="with --chunk-frames: frames tracked before each chunk and dropped, so that the tracker has "
                        "settled when the chunk begins (default 25)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_track)


def run_track(args: argparse.Namespace) -> int:
    from spinemocap.app.run import TrackingWarning, track_capture_result
    from spinemocap.app.streaming import SERIAL, SpeedOptions
    from spinemocap.fileio import InputError
    from spinemocap.track.config import TrackerConfig
    from spinemocap.track.rig_check import CalibrationWarning
    from spinemocap.track.rig_refine import RigRefineConfig

    config = TrackerConfig.from_toml(args.config) if args.config else None
    if args.refine_sync and not args.refine_rig:
        raise InputError("--refine-sync", "needs --refine-rig")
    if args.reference and not args.refine_rig:
        raise InputError("--reference", "needs --refine-rig (the reference fixes the refined rig's world frame)")
    refine = RigRefineConfig(sync=args.refine_sync) if args.refine_rig else None
    chosen: dict = {} if args.lookahead is None else {"lookahead": args.lookahead}  # else the pipeline's defaults
    if args.precision is not None:
        chosen["precision"] = args.precision
    chosen.update(refresh_options(args))
    speed = SERIAL if args.serial else SpeedOptions(workers=args.workers, parallel=args.parallel,
                                                    device=args.device, frames_at_once=args.frames_at_once,
                                                    predict=args.frames_at_once <= 1,
                                                    opencv_threads=args.opencv_threads or None,
                                                    candidate_workers=args.candidate_workers, **chosen)
    if args.chunk_frames is not None:
        return run_chunked(args, config, speed)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TrackingWarning)
        warnings.simplefilter("ignore", CalibrationWarning)  # in the summary below
        try:
            result = track_capture_result(args.capture, args.out, mode=args.mode, config=config,
                                          detector=args.detector, frames=args.frames,
                                          progress=not args.no_progress, refine=refine, speed=speed,
                                          reference=args.reference)
        except InputError:
            raise
        except ValueError as exc:
            if refine is None:
                raise
            raise InputError(args.capture, f"--refine-rig: {exc}") from exc
    table = result.table
    for w in caught:
        if not issubclass(w.category, TrackingWarning):  # frames' conditions: in the summary below
            log.warning("%s", w.message)
    elapsed = time.perf_counter() - start
    counts = table.data["status"].value_counts()
    print(f"tracked {table.n_frames} frames in {elapsed:.1f} s ({table.n_frames / elapsed:.2f} frames/s): "
          + ", ".join(f"{counts.get(s, 0)} {s}" for s in STATUSES))
    print(f"markers written to {Path(args.out) / 'markers.csv'} (+ .trc, .c3d)")
    print(result.summary())
    if Capture.open(args.capture).has_groundtruth:
        print(accuracy_summary(table, args.capture))
    return 0


def run_chunked(args: argparse.Namespace, config, speed) -> int:
    """``track --chunk-frames``: a long capture chunk by chunk, resumable (app.long_capture)."""
    from spinemocap.app.long_capture import Chunking, track_in_chunks
    from spinemocap.fileio import InputError

    if args.refine_rig:
        raise InputError("--chunk-frames", "cannot be combined with --refine-rig (the refinement needs every frame "
                                           "at once): refine the rig on a shorter part first, then track with it")
    start = time.perf_counter()
    result = track_in_chunks(args.capture, args.out, Chunking(args.chunk_frames, args.warmup_frames), mode=args.mode,
                             config=config, detector=args.detector, frames=args.frames,
                             progress=not args.no_progress, speed=speed)
    elapsed = time.perf_counter() - start
    counts = result.status_counts
    print(f"tracked {result.n_frames} frames in {elapsed:.1f} s: "
          + ", ".join(f"{counts.get(s, 0)} {s}" for s in STATUSES))
    print(f"markers written to {Path(args.out) / 'markers.csv'} (+ .trc, .c3d)")
    print(result.summary())
    if Capture.open(args.capture).has_groundtruth:
        from spinemocap.app.results import read_results

        print(accuracy_summary(read_results(args.out), args.capture))
    return 0


def accuracy_summary(table, capture_dir: Path) -> str:
    """One paragraph of accuracy vs a synthetic capture's ground truth (groundtruth.npz)."""
    from spinemocap.track.evaluate import evaluate_tracking

    capture = Capture.open(capture_dir)
    groundtruth_path = capture.groundtruth_path
    ev = evaluate_tracking(table, capture.groundtruth(), capture.tape.graph.min_spacing_mm)
    obs, inf = ev.observed, ev.inferred
    return (f"accuracy vs ground truth ({groundtruth_path.name}): mean {ev.mean_error_mm:.2f} mm, "
            f"median {ev.median_error_mm:.2f} mm, p95 {ev.p95_error_mm:.2f} mm; "
            f"observed {obs.mean:.2f} mm (n={obs.n}), inferred {inf.mean:.2f} mm (n={inf.n}); "
            f"label swaps {ev.label_swaps}; frames without solution {ev.frames_without_solution}")

