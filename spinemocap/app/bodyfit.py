"""Fitting a body model to the markers of a C3D/TRC file and writing the results
(``spinemocap bodyfit``): reads with the one marker reader (``exporters.read``), fits with
:mod:`spinemocap.bodymodel.fit`, writes with :mod:`spinemocap.bodymodel.results`."""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

import exporters

from ..bodymodel import load_model
from ..bodymodel.fit import FitOptions, MarkerFitter
from ..bodymodel.markersets import place_markers, read_mapping
from ..bodymodel.results import BodyFitSummary, write_fit
from ..bodymodel.tape import lay_tape
from ..capture import Capture
from ..fileio import InputError
from ..frames import parse_frames
from ..markers import MarkerTable
from ..tape import TapeSpec

log = logging.getLogger(__name__)


def marker_arrays(path: str | os.PathLike, frames: str | None = None
                  ) -> tuple[list[str], np.ndarray, np.ndarray, float]:
    """(labels, frame numbers (F,), positions (F, D, 3) mm, fps) of the markers (not the modelled
    outputs such as angles or joint centres a C3D may carry) of a marker file.

    ``frames``: a selection of the file's own frame numbers in the syntax of
    :mod:`spinemocap.frames` (``A:B``, ``A:B:S``, ``N`` or lists); ``None`` keeps every frame.
    Raises :class:`InputError` naming ``frames`` when the selection is not of the syntax, and naming
    ``path`` when it keeps no frame the file holds."""
    table = exporters.read(path)
    point_types = table.meta.get("point_types") or {}
    labels = [label for label in table.labels if label not in point_types]
    arrays = table.select(labels=labels).to_arrays()
    frame_numbers, positions = arrays.frames, arrays.positions
    if frames is not None:
        wanted = parse_frames(frames, int(frame_numbers[-1]) + 1, "frames")
        keep = np.isin(frame_numbers, wanted)
        if not keep.any():
            raise InputError(path, f"frame selection {frames!r} keeps none of its frames "
                                   f"({frame_numbers[0]}..{frame_numbers[-1]})")
        frame_numbers, positions = frame_numbers[keep], positions[keep]
    return list(arrays.labels), frame_numbers, positions, table.fps


def frame_step(frame_numbers: np.ndarray) -> int:
    """The frame numbers' common step (1 for a single frame).

    Raises ValueError when they are not evenly spaced (a body fit's frames share one clock)."""
    steps = np.unique(np.diff(frame_numbers))
    if len(steps) > 1:
        raise ValueError(f"frames {frame_numbers[0]}..{frame_numbers[-1]} are not evenly spaced (steps {steps.tolist()})")
    return int(steps[0]) if len(steps) else 1


def tape_reference(model, fit, frame_numbers: np.ndarray, fps: float, spec: TapeSpec, start_level: str
                   ) -> MarkerTable:
    """The tape laid on the fitted body (first row at ``start_level``) and read off the posed
    body in every fitted frame: a marker table with the tracker's labels (the paper's body-model
    ground truth; write it beside tracked dots with ``reference=`` to get ``REF_*`` markers).
    Frames fitted every ``step`` file frames become a table at ``fps / step`` whose times are the
    file's (``frame_numbers / fps`` s)."""
    step = frame_step(np.asarray(frame_numbers))
    laid = lay_tape(model.rest(fit.shape), spec, start_level)
    dots = laid.dots.sequence(model.vertices(fit.poses, fit.shape), model.faces)
    meta = {"source": "body-model tape (spinemocap bodyfit)", "row_levels": laid.row_levels}
    table = MarkerTable.from_arrays(laid.labels, dots, fps / step, meta=meta)
    table.data["frame"] = np.repeat(np.asarray(frame_numbers) // step, len(laid.labels))
    table.data["time"] = np.repeat(np.asarray(frame_numbers) / fps, len(laid.labels))
    return MarkerTable(table.data, table.meta)


def fit_marker_file(markers: str | os.PathLike, out: str | os.PathLike, model_name: str = "anny",
                    model_path: str | os.PathLike | None = None, gender: str = "neutral",
                    static: str | os.PathLike | None = None, frames: str | None = None,
                    mapping: str | os.PathLike | None = None, key_frames: int = 5,
                    save_vertices: bool = False, progress: bool = True,
                    tape_capture: str | os.PathLike | None = None, tape_start: str = "L4") -> BodyFitSummary:
    """Fit and write ``out``/body.npz, summary.json, residuals.csv, residuals.png (and, with
    ``tape_capture`` (a capture folder or a tape TOML), that tape laid on the fitted body:
    tape_dots.c3d/.csv); returns
    the summary (see :func:`spinemocap.bodymodel.results.fit_summary`).

    ``frames``: the file's frames to fit (:func:`marker_arrays`); they must be evenly spaced.
    Raises :class:`InputError` for an unreadable file, a selection of no or unevenly spaced frames,
    or fewer than four known marker labels."""
    import torch

    torch.set_num_threads(1)
    labels, frame_numbers, positions, fps = marker_arrays(markers, frames)
    try:
        frame_step(frame_numbers)
    except ValueError as exc:
        raise InputError("frames", f"{exc}: a body fit needs one regular clock; select A:B or A:B:S") from None
    rules = read_mapping(mapping) if mapping else None
    model = load_model(model_name, model_path, gender)
    kept, vertices = place_markers(model.rest(), labels, rules)
    if len(kept) < 4:
        raise InputError(markers, f"only {len(kept)} of its {len(labels)} marker labels are known ({kept}); "
                                  "pass `mapping=FILE` to name the others")
    skipped = [label for label in labels if label not in kept]
    if skipped:
        log.info("markers not used (unknown labels): %s", ", ".join(skipped))
    columns = [labels.index(label) for label in kept]
    static_markers = None
    if static:
        static_labels, _, static_positions, _ = marker_arrays(static)
        static_markers = np.full((len(static_positions), len(kept), 3), np.nan)
        for k, label in enumerate(kept):
            if label in static_labels:
                static_markers[:, k] = static_positions[:, static_labels.index(label)]
    fitter = MarkerFitter(model, vertices, FitOptions(n_key_frames=max(key_frames, 1)))
    fit = fitter.fit(positions[:, columns], static=static_markers, progress=progress, labels=kept)
    dense = model.vertices(fit.poses, fit.shape) if save_vertices else None
    summary = write_fit(Path(out), fit, frame_numbers, fps, str(markers), model.pose_joints, dense)
    if tape_capture:
        spec = Capture.open(tape_capture).tape if Path(tape_capture).is_dir() else TapeSpec.from_toml(tape_capture)
        try:
            reference = tape_reference(model, fit, frame_numbers, fps, spec, tape_start)
        except ValueError as exc:
            raise InputError(tape_capture, f"cannot lay its tape on the fitted body: {exc}") from exc
        exporters.write(reference, Path(out) / "tape_dots.c3d")
        exporters.write(reference, Path(out) / "tape_dots.csv")
        summary = replace(summary, tape_dots=str(Path(out) / "tape_dots.c3d"),
                          tape_row_levels=reference.meta["row_levels"])
        summary.write(out)
    return summary
