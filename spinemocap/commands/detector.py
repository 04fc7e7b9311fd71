"""``spinemocap detector train|finetune|adapt|run``: train the tape network, adapt it to a lab, apply it.

    spinemocap detector train --out runs/tape                   # render studio data, train
    spinemocap detector finetune --images lab/images --masks lab/masks --out runs/lab
    spinemocap detector finetune --images lab/images --coco lab/tape.json --out runs/lab
    spinemocap detector adapt capture/ --out runs/adapted --use   # learn from the capture's own tracked frames
    spinemocap detector run img1.png cam1.mp4 capture/ --out dots/   # dots CSV + overlay per image
    spinemocap detector run capture/ --frames 0:50 --out dots/  # every camera of a capture, frames 0-49

Training is resumable: run the same command again with the same ``--out``. Use the result with
``Detector("net", weights="runs/tape/weights.pt")``.
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from ..media import VIDEO_SUFFIXES


def _train_options(p: argparse.ArgumentParser, epochs: int, lr: float) -> None:
    from ..detect.train import TrainSettings

    d = TrainSettings()
    p.add_argument("--out", type=Path, required=True, help="output folder (checkpoint, weights.pt, weights.json, plot)")
    p.add_argument("--epochs", type=int, default=epochs)
    p.add_argument("--steps", type=int, default=d.steps, help="batches per epoch")
    p.add_argument("--batch", type=int, default=d.batch)
    p.add_argument("--crop", type=int, default=d.crop, help="training window side (px, working resolution)")
    p.add_argument("--lr", type=float, default=lr, help="peak learning rate (10 %% warm-up, then cosine decay)")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--threads", type=int, default=d.threads)


def register(subparsers) -> None:
    p = subparsers.add_parser("detector", help="train / fine-tune / apply the tape detector")
    sub = p.add_subparsers(dest="detector_command", metavar="ACTION", required=True)

    t = sub.add_parser("train", help="render synthetic-studio training data (if needed) and train the network")
    _train_options(t, epochs=15, lr=3e-3)
    t.add_argument("--data", type=Path, nargs="+",
                   help="training shards folders (default OUT/data); the studio renders into the first, "
                        "the others are used as they are (e.g. an earlier data set)")
    t.add_argument("--weights", type=Path, help="start from these weights instead of random ones")
    t.add_argument("--scenes", type=int, default=48, help="synthetic scenes to render")
    t.add_argument("--frames-per-scene", type=int, default=2)
    t.add_argument("--data-seed", type=int, default=0, help="studio seeds data_seed*1000 + scene")
    t.add_argument("--appearance", choices=("studio", "lab"), default="studio",
                   help="studio: dark tapes on plain backgrounds; lab: also beige, pink and red tape, other rolls "
                        "(hole sizes, spacings), woven and printed tape, skin marks (hair, freckles, moles, sweat, "
                        "tattoos), shorts and bra straps, painted lab rooms and lab camera looks (H.264/H.265, rolling "
                        "shutters; never the benchmark's held-out blue tape)")
    t.set_defaults(func=_train)

    f = sub.add_parser("finetune", help="fine-tune on a lab's labelled images (PNG masks or COCO polygons)")
    _train_options(f, epochs=8, lr=1e-3)
    f.add_argument("--images", type=Path, required=True, help="folder of images")
    group = f.add_mutually_exclusive_group(required=True)
    group.add_argument("--masks", type=Path, help="folder of mask PNGs named like the images")
    group.add_argument("--coco", type=Path, help="COCO JSON with polygon segmentations")
    f.add_argument("--weights", type=Path, help="starting weights (default: the shipped ones)")
    f.add_argument("--val-fraction", type=float, default=0.24, help="share of images for validation (paper: 631/2619)")
    f.set_defaults(func=_finetune)

    a = sub.add_parser("adapt", help="fine-tune on a capture's own frames, labelled by a first tracking pass")
    _train_options(a, epochs=4, lr=1e-3)
    a.set_defaults(steps=30)
    a.add_argument("capture", type=Path, metavar="CAPTURE", help="capture folder (capture.toml)")
    a.add_argument("--results", type=Path,
                   help="results folder of tracking CAPTURE (default: track it first into OUT/first_pass)")
    a.add_argument("--frames", help="frames the first pass tracks, e.g. 0:300 (default: all)")
    a.add_argument("--weights", type=Path, help="starting weights (default: those capture.toml names, else the shipped ones)")
    a.add_argument("--studio", type=Path, help="studio training shards to mix in (detector train's OUT/data; "
                                               "default: render --studio-scenes scenes into OUT/studio_data)")
    a.add_argument("--studio-scenes", type=int, default=8, help="studio scenes to render when --studio is not given")
    a.add_argument("--max-frames", type=int, help="vouched-for frames used as labels at most, evenly spread "
                                                  "(default 40)")
    a.add_argument("--use", action="store_true", help="name the new weights in CAPTURE's capture.toml "
                                                      "([capture] detector_weights)")
    a.set_defaults(func=_adapt)

    r = sub.add_parser("run", help="detect tape and dots in images, videos or capture folders; draw what was found")
    r.add_argument("inputs", type=Path, nargs="+", metavar="INPUT",
                   help="image files, video files (" + " ".join(VIDEO_SUFFIXES) + ") or capture folders (every camera)")
    r.add_argument("--frames", default="0:1", help="frames A:B of each video or capture (B exclusive; default the first)")
    r.add_argument("--name", choices=["net", "classical"], default="net")
    r.add_argument("--weights", type=Path, help="network weights (default: shipped)")
    r.add_argument("--dot-px", type=float, help="expected dot diameter in px (default: from the mask width)")
    r.add_argument("--out", type=Path, help="folder for <name>_dots.csv and <name>_overlay.png (the mask's outline, "
                                            "the dots, the counts) per image")
    r.set_defaults(func=_run)


def _adapt(args) -> int:
    from dataclasses import replace

    from ..app.adapt import LabelSettings, adapt_detector
    from ..app.training_data import SynthDataSettings
    from ..capture import set_detector_weights

    result = adapt_detector(args.capture, args.out, results=args.results,
                            label_settings=(replace(LabelSettings(), max_frames=args.max_frames) if args.max_frames
                                            else LabelSettings()),
                            train_settings=_settings(args), studio=args.studio,
                            studio_settings=SynthDataSettings(scenes=args.studio_scenes, layouts=("tiny", "artificial")),
                            weights=args.weights, frames=args.frames, provenance={"command": _command(args)})
    print(f"{len(result.frames)} vouched-for frames, {result.views} camera views labelled ({result.dots} dots; "
          f"{result.views_skipped} views left out: the tape not confirmed there), {result.studio_views} studio views "
          f"mixed in; best epoch {result.training['best_epoch']}: validation IoU {result.training['val_iou']:.4f}")
    print(f"weights: {result.weights}")
    if args.use:
        manifest = set_detector_weights(args.capture, result.weights)
        print(f"{manifest}: detector_weights names them; 'spinemocap track' now detects with them")
    else:
        print(f"to use them: add detector_weights = \"{result.weights.resolve()}\" to [capture] in "
              f"{args.capture / 'capture.toml'} (or run again with --use)")
    return 0


def _settings(args):
    from ..detect.train import TrainSettings

    return TrainSettings(epochs=args.epochs, steps=args.steps, batch=args.batch, crop=args.crop, lr=args.lr,
                         seed=args.seed, threads=args.threads)


def _command(args) -> str:
    """The command line with every option spelt out (defaults included), for the provenance."""
    parts = ["spinemocap", "detector", args.detector_command]
    for key, value in sorted(vars(args).items()):
        if key in ("func", "command", "detector_command", "verbose", "quiet") or value is None:
            continue
        values = value if isinstance(value, list) else [value]
        parts += [f"--{key.replace('_', '-')}"] + [shlex.quote(str(v)) for v in values]
    return " ".join(parts)


def _train(args) -> int:
    from ..app.training_data import SynthDataSettings, train_on_studio

    synth = SynthDataSettings(scenes=args.scenes, frames_per_scene=args.frames_per_scene, seed=args.data_seed,
                              appearance=args.appearance)
    meta = train_on_studio(args.out, _settings(args), synth, args.data or (), args.weights,
                           provenance={"command": _command(args)})
    print(f"best epoch {meta['best_epoch']}: validation IoU {meta['val_iou']:.4f}; weights: {args.out / 'weights.pt'}")
    return 0


def _finetune(args) -> int:
    from ..app.training_data import finetune_on_images

    meta, n_train, n_val = finetune_on_images(args.out, _settings(args), args.images, args.masks, args.coco,
                                              args.val_fraction, args.seed, args.weights,
                                              provenance={"command": _command(args)})
    print(f"{n_train} training / {n_val} validation images; best epoch {meta['best_epoch']}: "
          f"validation IoU {meta['val_iou']:.4f}; weights: {args.out / 'weights.pt'}")
    return 0


def _run(args) -> int:
    from ..app.detector_run import detect_inputs
    from ..detect import Detector

    options = {"weights": args.weights} if args.name == "net" and args.weights else {}
    for found in detect_inputs(Detector(args.name, **options), args.inputs, args.frames, args.dot_px, args.out):
        print(f"{found.name}: {len(found.dots)} dots, tape mask {found.tape_px} px ({found.tape_share:.2f} % of the image)")
    return 0
