"""``spinemocap bench adapt``: arguments and printing; the benchmark is :mod:`spinemocap.bench.adapt`."""

from __future__ import annotations

from pathlib import Path


def register_bench(subparsers) -> None:
    p = subparsers.add_parser("adapt", help="detector adapt on a tape and skin the starting weights handle poorly: "
                                            "dot recall/precision and tracked error before and after")
    p.add_argument("--work", type=Path, required=True, help="folder for the rendered captures, weights and tracks "
                                                            "(captures already there are reused)")
    p.add_argument("--json", type=Path, required=True, help="results file")
    p.add_argument("--frames", type=int, default=30, help="frames per capture (tiny preset)")
    p.add_argument("--epochs", type=int, default=4)
    p.add_argument("--steps", type=int, default=30, help="batches per epoch")
    p.add_argument("--studio-scenes", type=int, default=6, help="studio scenes mixed into the fine-tuning")
    p.add_argument("--weights", type=Path, help="the weights the lab starts from, scored beside the adapted ones "
                                                "(default: the studio-only weights tape_unet.pt shipped beside the default)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..bench.adapt import format_table, run_adapt_benchmark, save

    numbers = run_adapt_benchmark(args.work, frames=args.frames, epochs=args.epochs, steps=args.steps,
                                  studio_scenes=args.studio_scenes, progress=not args.no_progress, start_weights=args.weights)
    save(numbers, args.json)
    print(format_table(numbers))
    print(f"results: {args.json}")
    return 0
