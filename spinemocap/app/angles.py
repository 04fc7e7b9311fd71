"""``spinemocap angles``: the spine angles of one labelled marker file, written as a CSV table
with a plot beside it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy.typing as npt

import exporters

from ..analysis.angles import AngleSettings, SpineAngles, compute_angles
from ..analysis.levels import LevelMap
from ..analysis.neutral import Neutral, neutral_from_angles, neutral_summary
from ..fileio import InputError, atomic_write
from ..tape import TapeSpec
from .report import angles_plot_png
from .results import find_markers


@dataclass(frozen=True)
class MarkerFileAngles:
    """The angles of one marker file: ``angles`` (the table, its NaN reasons and completeness),
    the ``neutral`` they are read against, ``from_neutral`` (:func:`~spinemocap.analysis.neutral.neutral_summary`:
    deg per angle column), and the files written: ``table_path`` (CSV) and ``plot_path`` (PNG)."""

    angles: SpineAngles
    neutral: Neutral
    from_neutral: dict[str, float]
    table_path: Path
    plot_path: Path


def tape_of_labels(labels: Sequence[str], source: str | Path) -> TapeSpec:
    """The tape whose rows the marker ``labels`` (``R01L``, ``R02C``, ...) name: as many rows as
    the highest row, rounded up to an odd count. InputError naming ``source`` when no label is a
    tape dot's."""
    rows = [int(label[1:3]) for label in labels if len(label) == 4 and label[0] == "R" and label[1:3].isdigit()]
    if not rows:
        raise InputError(source, "no tape labels (R01L, R02C, ...) in this marker file")
    return TapeSpec(n_rows=max(rows) if max(rows) % 2 else max(rows) + 1)


def marker_file_angles(markers: Path, levels: Path, out: Path | None = None,
                       lumbar: tuple[str, str] = ("S1", "T12/L1"), up: npt.ArrayLike = (0.0, 0.0, 1.0),
                       facing: npt.ArrayLike = (0.0, -1.0, 0.0), neutral: Path | None = None) -> MarkerFileAngles:
    """Angles of ``markers`` (a results folder or a marker file the exporters read) with the
    row-to-level map ``levels`` (TOML), the lumbar angle from ``lumbar[0]`` to ``lumbar[1]``, the
    subject's ``up`` and ``facing`` (world). Zero is the median of the static trial ``neutral``
    (same subject and tape), else the trial's first frame. Writes the table to ``out`` (default:
    ``<markers>_angles.csv`` beside the markers) and its plot beside it (.png)."""
    table = exporters.read(find_markers(markers))
    tape = tape_of_labels(table.labels, markers)
    level_map = LevelMap.from_toml(levels, tape.n_rows)
    settings = AngleSettings(lower=lumbar[0], thoracolumbar=lumbar[1])
    result = compute_angles(table, tape, level_map, up=up, facing=facing, settings=settings)
    if neutral is not None:
        static = compute_angles(exporters.read(neutral), tape, level_map, up=up, facing=facing, settings=settings)
        zero = neutral_from_angles(static.table, first_s=None, source=f"the static trial {neutral.name}")
    else:
        zero = neutral_from_angles(result.table)
    table_path = out or markers.with_name(markers.stem + "_angles.csv")
    with atomic_write(table_path) as handle:
        result.table.to_csv(handle, index=False, float_format="%.4f")
    plot_path = table_path.with_suffix(".png")
    with atomic_write(plot_path, "wb") as handle:
        handle.write(angles_plot_png(result.table, zero))
    return MarkerFileAngles(result, zero, neutral_summary(result.table, zero), table_path, plot_path)
