"""``spinemocap bench speed``: arguments and printing; the benchmark is :mod:`spinemocap.bench.speed`."""

from __future__ import annotations

import argparse
from pathlib import Path

from .track import add_refresh_arguments, refresh_options


def register_bench(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "speed", help="end-to-end tracking frames/s (in memory, PNG, video) vs the serial pipeline",
        description="Render the synthetic studio once (not timed), then track it from frames in memory, from "
                    "PNG images and from lossless video with the pipeline, and from PNG and memory with "
                    "the serial one (one camera at a time, no prediction: the peer): frames/s, time per stage, "
                    "peak memory and accuracy per run.")
    p.add_argument("--preset", default="studio", choices=("tiny", "artificial", "studio"))
    p.add_argument("--frames", type=int, default=100, help="frames to render and track (default 100)")
    p.add_argument("--occlusion", default="none", choices=("none", "light", "heavy"))
    p.add_argument("--mode", choices=("sequence", "paper"), default="sequence")
    p.add_argument("--detector", choices=("net", "classical", "mask"), default="net")
    p.add_argument("--workers", type=int, default=0,
                   help="processes or threads for the cameras (0: one per CPU core, at most one per camera)")
    p.add_argument("--parallel", choices=("threads", "processes"), default="threads",
                   help="cameras in threads (the default) or worker processes; the in-memory and video runs are "
                        "repeated in the other mode as the peer")
    p.add_argument("--no-parallel-peer", action="store_true", help="skip the run in the other parallel mode")
    p.add_argument("--lookahead", type=int, default=None,
                   help="frames detection may run ahead of the tracker (default: the pipeline's; 0: frame t+1 "
                        "detected after frame t is solved, the exact serial order; 1: while it is solved)")
    p.add_argument("--no-lookahead-peer", action="store_true",
                   help="skip the runs with the other lookahead (0 when --lookahead > 0, else 1)")
    p.add_argument("--video-frames", type=int, default=0,
                   help="with --capture: also write the first so many replayed frames as lossless video (into "
                        "--workdir) and track them from it")
    add_refresh_arguments(p)
    p.add_argument("--no-predict", action="store_true", help="full detector search in every frame")
    p.add_argument("--frames-at-once", type=int, default=1,
                   help="frames detected at the same time, each searched in full (implies --no-predict; --workers 0 "
                        "then means one per CPU core); with --capture the pipeline's defaults run as the peer")
    p.add_argument("--candidate-workers", type=int, default=0,
                   help="processes that build the tracker's candidates a few frames ahead of it (the same output; "
                        "needs --frames-at-once or --no-predict); with --capture the same options without them run "
                        "as the peer (default 0: the tracker builds them)")
    p.add_argument("--no-budget", action="store_true",
                   help="with --capture: skip the detection's time per camera image by step")
    p.add_argument("--no-serial", action="store_true", help="skip the serial pipeline (the peer)")
    p.add_argument("--no-video", action="store_true", help="skip the video run")
    p.add_argument("--video-codec", default="utvideo", choices=("utvideo", "rawvideo"),
                   help="the video run's lossless codec: UT Video (what captures are written in by default) or "
                        "uncompressed BGR (1.77x the files, decoding is a copy)")
    p.add_argument("--no-memory", action="store_true", help="skip the in-memory runs")
    p.add_argument("--memory-frames", type=int, default=30,
                   help="decoded frames held for the in-memory runs, replayed forward and backward for --frames "
                        "frames (each 2448x1600 frame of six cameras holds 70 MB; default 30)")
    p.add_argument("--workdir", type=Path, help="keep the rendered captures here (reused when present)")
    p.add_argument("--capture", type=Path, help="instead of rendering: a synthetic capture folder whose frames are "
                                                 "replayed forward and backward in memory for --frames frames "
                                                 "(for a machine that cannot render)")
    p.add_argument("--sensor-noise", type=float, default=0.0,
                   help="with --capture: add this sensor noise (grey levels) to a capture rendered without it")
    p.add_argument("--opencv-threads", type=int, default=1,
                   help="OpenCV's own threads per camera thread while the cameras are detected in parallel "
                        "(default 1; 0: OpenCV's setting, one per core)")
    p.add_argument("--device", default="auto", help="where the network runs: auto (CUDA if torch sees it), cpu, cuda")
    p.add_argument("--precision", default=None,
                   help="the tape network's arithmetic: float32, int8 (ONNX Runtime on the CPU), bfloat16 (torch); "
                        "default: the pipeline's")
    p.add_argument("--no-cpu-peer", action="store_true",
                   help="with --capture on a GPU: skip the same pipeline on the CPU and the GPU-vs-CPU dot check")
    p.add_argument("--realism", default="lab", choices=("ideal", "skin", "lab"),
                   help="studio realism level (default lab: tape tension, skin strain, inexact rig, sync error)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, help="write all numbers to this JSON file")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..app.streaming import SpeedOptions
    from ..bench.speed import format_report, plot_stages, run_replay_benchmark, run_speed_benchmark, save
    from ..bench.speed_results import SpeedNumbers

    chosen: dict = {} if args.lookahead is None else {"lookahead": args.lookahead}  # else the pipeline's defaults
    if args.precision is not None:
        chosen["precision"] = args.precision
    chosen.update(refresh_options(args))
    speed = SpeedOptions(workers=args.workers, parallel=args.parallel, frames_at_once=args.frames_at_once,
                         predict=not args.no_predict and args.frames_at_once <= 1, device=args.device,
                         opencv_threads=args.opencv_threads or None, candidate_workers=args.candidate_workers,
                         **chosen)
    numbers: SpeedNumbers
    if args.capture:
        numbers = run_replay_benchmark(args.capture, args.frames, args.mode, args.detector, not args.no_serial,
                                       speed, args.sensor_noise, progress=not args.no_progress,
                                       cpu_peer=not args.no_cpu_peer, parallel_peer=not args.no_parallel_peer,
                                       video_frames=args.video_frames, workdir=args.workdir,
                                       lookahead_peer=not args.no_lookahead_peer, budget=not args.no_budget)
    else:
        numbers = run_speed_benchmark(args.preset, args.frames, args.occlusion, args.mode, args.detector, args.seed,
                                      args.workdir, serial_peer=not args.no_serial, video=not args.no_video,
                                      in_memory=not args.no_memory, speed=speed, progress=not args.no_progress,
                                      realism=args.realism, memory_frames=args.memory_frames,
                                      parallel_peer=not args.no_parallel_peer, lookahead_peer=not args.no_lookahead_peer,
                                      video_codec=args.video_codec)
    print(format_report(numbers))
    if args.json:
        save(numbers, args.json)
        plot = plot_stages(numbers, args.json.with_suffix(".png"))
        print(f"numbers written to {args.json}, time per stage plotted in {plot}")
    return 0
