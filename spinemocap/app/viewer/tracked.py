"""Tracked dots as the viewers draw them: a results folder (or one marker file) read through the
project's readers, ordered as the capture's tape, each dot sorted into a :class:`DotClass`.

A dot is ``flagged`` when its label confidence sits below 0.6 x its status factor
(:func:`spinemocap.track.quality.flagged_from_confidence` asked dot by dot): the tracker could
not vouch for its label (a doubting frame flag, or a dot placed by extrapolation). Otherwise it is
``observed`` (triangulated from >= 2 views) or ``inferred`` (placed by the tape model). Files
without a confidence column (TRC, C3D, older CSVs) never flag.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path

import numpy as np

import exporters

from ...capture import Capture
from ...fileio import InputError
from ...markers import INFERRED, MISSING, OBSERVED, MarkerTable
from ...tape import TapeSpec
from ...track.quality import flagged_from_confidence
from ..levels import find_level_map
from ..results import results_run_id

#: The marker file of a results folder that carries the quality columns (status, confidence).
RESULTS_TABLE = "markers.csv"


class DotClass(IntEnum):
    """How a dot is drawn (the same colours in the videos and the 3D viewer)."""

    MISSING = 0
    OBSERVED = 1
    INFERRED = 2
    FLAGGED = 3


#: Colours as (B, G, R) for OpenCV; the 3D viewer takes the same as CSS ``rgb()``.
CLASS_COLOURS_BGR: dict[DotClass, tuple[int, int, int]] = {
    DotClass.OBSERVED: (0, 220, 0),       # green
    DotClass.INFERRED: (0, 170, 255),     # amber
    DotClass.FLAGGED: (255, 0, 255),      # magenta
}
CLASS_WORDS = {DotClass.OBSERVED: "observed", DotClass.INFERRED: "inferred (tape model)",
               DotClass.FLAGGED: "flagged (label not vouched for)"}


@dataclass
class TrackedDots:
    """Tracked dots of one capture, frame by frame, in the tape's label order.

    ``frames`` (F,) capture frame numbers; ``times`` (F,) s; ``labels`` (D,) the tape's labels;
    ``positions`` (F, D, 3) mm, world frame (NaN where missing); ``classes`` (F, D)
    :class:`DotClass` values; ``confidence`` (F, D) 0..1 (NaN unknown); ``frame_flagged`` (F,)
    frames whose labels the tracker could not vouch for; ``row`` (D,) 0-based row of each dot;
    ``source`` the file read."""

    frames: np.ndarray
    times: np.ndarray
    labels: list[str]
    positions: np.ndarray
    classes: np.ndarray
    confidence: np.ndarray
    frame_flagged: np.ndarray
    row: np.ndarray
    source: str

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def index_of(self, frame: int) -> int:
        """Index of capture frame ``frame`` in :attr:`frames`; KeyError when it was not tracked."""
        k = int(np.searchsorted(self.frames, frame))
        if k >= len(self.frames) or self.frames[k] != frame:
            raise KeyError(frame)
        return k

    def row_segments(self) -> np.ndarray:
        """(S, 2) dot index pairs joining neighbouring dots of each row (L-C, C-R; L-R in a
        2-dot row), in label order."""
        pairs = [(i, i + 1) for i in range(len(self.labels) - 1) if self.row[i] == self.row[i + 1]]
        return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def results_file(results: str | os.PathLike) -> Path:
    """The marker file to read: ``results`` itself when it is a file, else the results folder's
    ``markers.csv`` once :func:`~spinemocap.app.results.results_run_id` has checked the folder's
    files are one complete set (:class:`InputError` naming the folder otherwise)."""
    path = Path(results)
    if path.is_dir():
        results_run_id(path)
        return path / RESULTS_TABLE
    if not path.is_file():
        raise InputError(path, "results not found: give a results folder (markers.csv with its manifest, "
                               "as `spinemocap track` writes) or a marker file (.csv, .trc, .c3d)")
    return path


def read_tracked(results: str | os.PathLike, tape: TapeSpec) -> TrackedDots:
    """The tracked dots of ``results`` (a results folder or marker file, read by
    :func:`exporters.read`) in the order of ``tape``'s labels. :class:`InputError` naming the file
    when it holds no frame or labels that are not this tape's (results of another capture)."""
    path = results_file(results)
    table = exporters.read(path)
    if not isinstance(table, MarkerTable) or not table.n_frames:
        raise InputError(path, "the marker file holds no frame")
    arrays = table.to_arrays()
    labels = tape.labels
    foreign = sorted(set(arrays.labels) - set(labels))
    if foreign:
        raise InputError(path, f"labels {foreign[:6]} are not dots of the capture's tape ({len(labels)} dots "
                               f"{labels[0]}..{labels[-1]}): these results belong to another capture")
    take = [list(arrays.labels).index(label) if label in arrays.labels else -1 for label in labels]
    F, D = len(arrays.frames), len(labels)
    positions = np.full((F, D, 3), np.nan)
    status = np.full((F, D), MISSING, dtype=object)
    confidence = np.full((F, D), np.nan)
    for d, k in enumerate(take):
        if k >= 0:
            positions[:, d] = arrays.positions[:, k]
            status[:, d] = arrays.status[:, k]
            confidence[:, d] = arrays.confidence[:, k]
    return TrackedDots(
        frames=np.asarray(arrays.frames, np.int64), times=np.asarray(arrays.time, float), labels=labels,
        positions=positions, classes=dot_classes(status, confidence), confidence=confidence,
        frame_flagged=flagged_from_confidence(status, confidence), row=np.asarray(tape.graph.row),
        source=str(path))


def dot_classes(status: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """(F, D) :class:`DotClass` values from a marker table's (F, D) status and confidence."""
    status = np.asarray(status, dtype=object)
    flagged = flagged_from_confidence(status.reshape(-1, 1), np.asarray(confidence, float).reshape(-1, 1))
    classes = np.full(status.shape, DotClass.MISSING, dtype=np.int8)
    classes[status == OBSERVED] = DotClass.OBSERVED
    classes[status == INFERRED] = DotClass.INFERRED
    classes[flagged.reshape(status.shape) & (classes != DotClass.MISSING)] = DotClass.FLAGGED
    return classes


def level_labels(capture: Capture) -> tuple[dict[str, float], str]:
    """The capture's vertebral levels as ``{level: 1-based row}`` and where the map came from
    (:func:`spinemocap.app.levels.find_level_map`); ``({}, reason)`` when the capture has none."""
    try:
        levels, source = find_level_map(capture)
    except InputError as exc:
        return {}, exc.problem
    return dict(levels.rows), source
