"""``spinemocap bodyfit MARKERS --out DIR``: MoSh-like body-model fit to sparse skin markers
(Plug-in Gait, trunk/spine sets, or any set through a mapping file) from a C3D/TRC file."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def frame_range(text: str) -> tuple[int | None, int | None]:
    """``'A:B'`` -> (A, B) (either may be empty; B exclusive, file frame numbers 0-based)."""
    a, sep, b = text.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"--frames expects A:B, got {text!r}")
    try:
        return (int(a) if a.strip() else None, int(b) if b.strip() else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames expects integers A:B, got {text!r}") from None


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bodyfit", help="fit a body model (anny, SMPL, SMPL-X) to sparse skin markers (MoSh-like)",
        description="Fit a body model's shape, per-marker offsets and per-frame pose to the labelled "
                    "markers of a C3D/TRC file (Plug-in Gait and trunk/spine markers are recognised by "
                    "label; --mapping for others). Writes body.npz, summary.json (marker_rms_mm, "
                    "trunk_marker_rms_mm), residuals.csv and residuals.png into --out.")
    p.add_argument("markers", type=Path, help="marker file (C3D or TRC, any file the exporters read)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--model", default="anny", choices=("anny", "smpl", "smplh", "smplx"),
                   help="body model (default anny; the SMPL family needs --model-path)")
    p.add_argument("--model-path", type=Path, help="your SMPL/SMPL+H/SMPL-X model file or folder (licence-gated)")
    p.add_argument("--gender", default="neutral", help="SMPL-family model gender (neutral, female, male)")
    p.add_argument("--static", type=Path, help="static trial (C3D/TRC) for the shape stage")
    p.add_argument("--frames", type=frame_range, help="frame range A:B to fit (B exclusive)")
    p.add_argument("--step", type=int, default=1, help="fit every N-th frame (default 1)")
    p.add_argument("--key-frames", type=int, default=5, help="frames of the shape stage (default 5)")
    p.add_argument("--mapping", type=Path, help="TOML mapping unknown labels to markers or placement rules")
    p.add_argument("--save-vertices", action="store_true", help="also store all mesh vertices per frame in body.npz")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_bodyfit)


def marker_arrays(path: Path, frames: tuple[int | None, int | None] | None = None, step: int = 1):
    """(labels, frames (F,), positions (F, D, 3) mm, fps) of the markers (not the modelled
    outputs) of a C3D/TRC file."""
    import exporters
    from spinemocap.fileio import InputError

    table = exporters.read(path)
    point_types = table.meta.get("point_types") or {}
    labels = [label for label in table.labels if label not in point_types]
    arrays = table.select(labels=labels).to_arrays()
    frame_numbers, positions = arrays["frames"], arrays["positions"]
    if frames is not None:
        lo = frames[0] if frames[0] is not None else frame_numbers[0]
        hi = frames[1] if frames[1] is not None else frame_numbers[-1] + 1
        keep = (frame_numbers >= lo) & (frame_numbers < hi)
        if not keep.any():
            raise InputError(path, f"no frames in {lo}:{hi} (the file holds {frame_numbers[0]}..{frame_numbers[-1]})")
        frame_numbers, positions = frame_numbers[keep], positions[keep]
    return list(arrays["labels"]), frame_numbers[::step], positions[::step], table.fps


def run_bodyfit(args: argparse.Namespace) -> int:
    import torch

    from spinemocap.bodymodel import load_model
    from spinemocap.bodymodel.fit import FitOptions, MarkerFitter
    from spinemocap.bodymodel.markersets import place_markers, read_mapping
    from spinemocap.bodymodel.results import write_fit
    from spinemocap.fileio import InputError

    torch.set_num_threads(1)
    labels, frames, positions, fps = marker_arrays(args.markers, args.frames, max(args.step, 1))
    rules = read_mapping(args.mapping) if args.mapping else None
    model = load_model(args.model, args.model_path, args.gender)
    kept, vertices = place_markers(model.rest(), labels, rules)
    if len(kept) < 4:
        raise InputError(args.markers, f"only {len(kept)} of its {len(labels)} marker labels are known ({kept}); "
                                       "pass --mapping FILE to name the others")
    skipped = [label for label in labels if label not in kept]
    if skipped:
        log.info("markers not used (unknown labels): %s", ", ".join(skipped))
    columns = [labels.index(label) for label in kept]
    static = None
    if args.static:
        static_labels, _, static_positions, _ = marker_arrays(args.static)
        static = np.full((len(static_positions), len(kept), 3), np.nan)
        for k, label in enumerate(kept):
            if label in static_labels:
                static[:, k] = static_positions[:, static_labels.index(label)]
    fitter = MarkerFitter(model, vertices, FitOptions(n_key_frames=max(args.key_frames, 1)))
    fit = fitter.fit(positions[:, columns], static=static, progress=not args.no_progress, labels=kept)
    dense = model.vertices(fit.poses, fit.shape) if args.save_vertices else None
    summary = write_fit(args.out, fit, frames, fps, str(args.markers),
                        model.pose_joints, dense)
    print(f"{args.model} fit of {len(kept)} markers over {len(frames)} frames: marker RMS "
          f"{summary['marker_rms_mm']:.2f} mm" + (f", trunk markers {summary['trunk_marker_rms_mm']:.2f} mm"
                                                   if summary["trunk_marker_rms_mm"] is not None else ""))
    if summary["markers_flagged"]:
        print(f"WARNING: markers the body could not explain (RMS > 20 mm): {', '.join(summary['markers_flagged'])}")
    if summary["frames_without_fit"]:
        print(f"WARNING: {len(summary['frames_without_fit'])} frames had too few markers and keep the previous pose")
    print("note: the body fit is a baseline, not a truth (free marker offsets hide a misplaced back surface)")
    print(f"wrote {args.out}/body.npz, summary.json, residuals.csv, residuals.png")
    return 0
