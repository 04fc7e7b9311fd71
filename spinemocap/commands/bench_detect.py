"""``spinemocap bench detect``: arguments and printing; the benchmark is :mod:`spinemocap.bench.detect`."""

from __future__ import annotations

from pathlib import Path

from ..bench.detect import DEFAULT_SETS, TAPE_FREE, TAPE_FREE_ROOMS, TEST_SETS


def register_bench(subparsers) -> None:
    p = subparsers.add_parser("detect", help="tape IoU, dot recall/precision/centroid error, time; peer: SimpleBlobDetector")
    p.add_argument("--json", type=Path, required=True, help="results file")
    p.add_argument("--sets", nargs="+", choices=sorted([*TEST_SETS, TAPE_FREE]), default=DEFAULT_SETS)
    p.add_argument("--scenes", type=int, help="override scenes per test set")
    p.add_argument("--rooms", type=int, default=TAPE_FREE_ROOMS,
                   help=f"painted lab rooms in the {TAPE_FREE} set (besides scikit-image's photographs)")
    p.add_argument("--weights", type=Path, help="network weights (default: shipped)")
    p.add_argument("--threads", type=int, default=1, help="torch threads for the network (1 = one core per camera)")
    p.add_argument("--plot", type=Path, help="PNG with recall/precision, centroid error and time per method")
    p.set_defaults(func=run)



def run(args) -> int:
    from ..bench.detect import plot, run_detect_benchmark, save

    results = run_detect_benchmark(args.sets, args.scenes, args.weights, args.threads, rooms=args.rooms)
    save(results, args.json)
    print(f"results: {args.json}")
    if args.plot:
        plot(results, args.plot)
        print(f"plot: {args.plot}")
    return 0
