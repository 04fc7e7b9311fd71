"""Helpers every format shares: units, dense arrays in and out of a :class:`MarkerTable`,
and the warnings for questionable but readable data (NaN-only markers, duplicate labels)."""

from __future__ import annotations

import os
import warnings
from dataclasses import replace
from typing import Sequence

import numpy as np
import pandas as pd

from spinemocap.fileio import InputError
from spinemocap.markers import MAX_ABS_MM, MISSING, OBSERVED, DenseMarkers, MarkerTable

UNITS_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


class ExportWarning(UserWarning):
    """Data that can be written or read but deserves a look (the message names the file)."""


def mm_per_unit(units: str, source: str | os.PathLike | None) -> float:
    """Millimetres per ``units`` (mm, cm, m); :class:`InputError` for anything else."""
    key = str(units).strip().lower()
    if key not in UNITS_TO_MM:
        raise InputError(source, f"unknown length units {units!r}; expected one of {sorted(UNITS_TO_MM)}")
    return UNITS_TO_MM[key]


def dense_mm(table: MarkerTable, source: str | os.PathLike | None = None) -> DenseMarkers:
    """:meth:`MarkerTable.to_arrays` with positions converted to mm from ``meta['units']`` and
    NaN wherever the status says ``missing``."""
    arrays = table.to_arrays()
    if len(arrays.frames) == 0:
        raise InputError(source, "marker table has no frames to write")
    positions = arrays.positions * mm_per_unit(table.meta.get("units", "mm"), source)
    positions[arrays.status == MISSING] = np.nan
    return replace(arrays, positions=positions)


def frame_rate(table: MarkerTable, source: str | os.PathLike | None = None) -> float:
    """The table's frame rate in Hz; :class:`InputError` when it is unknown or not positive."""
    try:
        fps = float(table.fps)
    except ValueError as exc:
        raise InputError(source, "frame rate unknown: set meta['fps'] (one frame and no rate)") from exc
    if not np.isfinite(fps) or fps <= 0:
        raise InputError(source, f"frame rate must be positive, got {fps}")
    return fps


def warn_empty_markers(labels: Sequence[str], positions: np.ndarray, source: str | os.PathLike) -> None:
    """Warn about markers that have no finite sample at all (positions (F, D, 3))."""
    warn_unseen(labels, sampled(positions), source)


def sampled(positions: np.ndarray) -> np.ndarray:
    """(D,) bool: markers with a finite sample in some frame of ``positions`` (F, D, 3)."""
    return np.isfinite(positions).all(axis=2).any(axis=0)


def warn_unseen(labels: Sequence[str], seen: np.ndarray, source: str | os.PathLike) -> None:
    """Warn about the markers ``seen`` (D,) says have no finite sample at all."""
    empty = [label for label, ok in zip(labels, seen) if not ok]
    if empty:
        warnings.warn(f"{source}: markers with no valid sample in any frame (all NaN): {empty}",
                      ExportWarning, stacklevel=4)


def deduplicate_labels(labels: Sequence[str], source: str | os.PathLike) -> list[str]:
    """Keep every column of a file whose labels repeat: the 2nd ``X`` becomes ``X_2`` (warned)."""
    seen: dict[str, int] = {}
    out = []
    for label in labels:
        if label in seen:
            seen[label] += 1
            new = f"{label}_{seen[label]}"
            while new in seen:
                seen[label] += 1
                new = f"{label}_{seen[label]}"
            warnings.warn(f"{source}: duplicate marker label {label!r}; this column is read as {new!r}",
                          ExportWarning, stacklevel=3)
            seen[new] = 1
            out.append(new)
        else:
            seen[label] = 1
            out.append(label)
    return out


def drop_implausible(positions_mm: np.ndarray, source: str | os.PathLike,
                     max_abs_mm: float = MAX_ABS_MM) -> np.ndarray:
    """(F, D, 3) positions with every sample that is not all-NaN (a missing sample) but has a
    non-finite coordinate or one beyond ``max_abs_mm`` set to NaN, with a warning naming the
    file and how many."""
    with np.errstate(invalid="ignore"):
        given = ~np.isnan(positions_mm).all(axis=2)
        absurd = given & ~(np.abs(positions_mm) <= max_abs_mm).all(axis=2)
    if absurd.any():
        positions_mm = positions_mm.copy()
        positions_mm[absurd] = np.nan
        warnings.warn(f"{source}: {int(absurd.sum())} of {absurd.size} samples have non-finite or absurd "
                      f"coordinates (beyond {max_abs_mm:g} mm); read as missing", ExportWarning, stacklevel=3)
    return positions_mm


def checked_table(table: MarkerTable, source: str | os.PathLike, max_abs_mm: float = MAX_ABS_MM) -> MarkerTable:
    """A reader's last step: a frame rate that is not finite and positive or a non-finite time
    is an :class:`InputError`; samples not ``missing`` whose coordinates are non-finite or beyond
    ``max_abs_mm`` become ``missing`` (NaN), negative view counts 0 and impossible residuals NaN,
    with one warning naming the file and how many. The result passes :meth:`MarkerTable.validate`."""
    fps = table.meta.get("fps")
    if not isinstance(fps, (int, float, np.number)) or isinstance(fps, bool) or not np.isfinite(fps) or fps <= 0:
        raise InputError(source, f"frame rate {fps!r} must be a finite positive number")
    table.meta["fps"] = float(fps)
    df = table.data
    if not np.isfinite(df["time"].to_numpy()).all():
        raise InputError(source, f"{int((~np.isfinite(df['time'].to_numpy())).sum())} rows have a non-finite time")
    xyz = df[["x", "y", "z"]].to_numpy()
    missing = (df["status"] == MISSING).to_numpy()
    with np.errstate(invalid="ignore"):
        absurd = ~missing & ~(np.abs(xyz) <= max_abs_mm).all(axis=1)
        residual = df["residual"].to_numpy()
        bad_residual = ~np.isnan(residual) & ~(np.isfinite(residual) & (residual >= 0))
    negative_views = df["n_views"].to_numpy() < 0
    fixes = []
    if absurd.any():
        df.loc[absurd, "status"] = MISSING
        fixes.append(f"{int(absurd.sum())} of {len(df)} samples have non-finite or absurd coordinates "
                     f"(beyond {max_abs_mm:g} mm) and are read as missing")
    missing = (df["status"] == MISSING).to_numpy()
    df.loc[missing, ["x", "y", "z"]] = np.nan
    if negative_views.any():
        df.loc[negative_views, "n_views"] = 0
        fixes.append(f"{int(negative_views.sum())} negative view counts read as 0")
    if bad_residual.any():
        df.loc[bad_residual, "residual"] = np.nan
        fixes.append(f"{int(bad_residual.sum())} negative or infinite residuals read as unknown")
    if fixes:
        warnings.warn(f"{source}: " + "; ".join(fixes), ExportWarning, stacklevel=3)
    return table.validate(str(source), max_abs_mm)


def table_from_dense(
    labels: Sequence[str],
    frames: np.ndarray,
    times: np.ndarray,
    positions_mm: np.ndarray,
    meta: dict,
    status: np.ndarray | None = None,
    n_views: np.ndarray | None = None,
    residual: np.ndarray | None = None,
) -> MarkerTable:
    """Build a :class:`MarkerTable` from dense (F, D, ...) arrays with the file's own frame
    numbers and times. ``status`` defaults to observed where finite, missing elsewhere."""
    F, D = positions_mm.shape[:2]
    finite = np.isfinite(positions_mm).all(axis=2)
    if status is None:
        status = np.where(finite, OBSERVED, MISSING)
    status = np.where(finite, np.asarray(status, dtype=object), MISSING)
    df = pd.DataFrame({
        "frame": np.repeat(np.asarray(frames, np.int64), D),
        "time": np.repeat(np.asarray(times, float), D),
        "label": np.tile(np.asarray(labels, dtype=object), F),
        "x": positions_mm[..., 0].ravel(),
        "y": positions_mm[..., 1].ravel(),
        "z": positions_mm[..., 2].ravel(),
        "status": status.ravel(),
        "n_views": (np.zeros((F, D), np.int64) if n_views is None else np.asarray(n_views)).ravel(),
        "residual": (np.full((F, D), np.nan) if residual is None else np.asarray(residual, float)).ravel(),
    })
    meta = dict(meta)
    meta["units"] = "mm"
    meta["labels"] = list(labels)
    return MarkerTable(df, meta)
