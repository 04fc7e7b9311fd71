"""The full marker table as CSV or Parquet: one row per (frame, label) with
``frame, time, label, x, y, z, status, n_views, residual`` (mm, s, px), the tracker's quality
columns ``confidence, stretch`` and ``missing_cameras`` (the cameras that had no image in the
row's frame, separated by ``;``, empty where none: ``meta['missing_cameras']``) (the last three
optional on reading), nothing lost.

CSV is plain (no comment lines, so any spreadsheet or ``pandas.read_csv`` opens it; strings
quoted); floats are written with the shortest text that reads back exactly. The frame rate is recovered from the time column; other metadata
(subject, source ...) travels only in Parquet, in the schema metadata key ``spinemocap``.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Iterable

import numpy as np
import pandas as pd

from spinemocap.fileio import InputError, atomic_path, reading
from spinemocap.markers import (
    ALL_COLUMNS,
    COLUMNS,
    MISSING,
    MISSING_CAMERAS,
    DenseMarkers,
    MarkerTable,
    missing_from_frames,
    missing_per_frame,
)

from .common import (
    ExportWarning,
    checked_table,
    dense_mm,
    mm_per_unit,
    sampled,
    table_from_dense,
    warn_empty_markers,
    warn_unseen,
)
from .registry import Exporter

META_KEY = b"spinemocap"


def _mm_frame(table: MarkerTable, path: Path) -> tuple[pd.DataFrame, np.ndarray]:
    """The table's rows with coordinates in mm (whatever ``meta['units']`` said), and which
    markers have a finite sample (:func:`~exporters.common.sampled`)."""
    arrays = dense_mm(table, path)
    seen = sampled(arrays.positions)
    df = table.data.loc[:, list(ALL_COLUMNS)].copy()
    df[["x", "y", "z"]] *= mm_per_unit(table.meta.get("units", "mm"), path)
    df["status"] = df["status"].astype(str)
    frames = df["frame"].to_numpy()
    unique, where = np.unique(frames, return_inverse=True)
    per_frame = np.array(missing_per_frame(table.meta.get(MISSING_CAMERAS) or {}, unique.tolist()), dtype=object)
    df[MISSING_CAMERAS] = per_frame[where] if len(unique) else np.zeros(0, object)
    return df, seen


def _table(df: pd.DataFrame, path: Path, meta: dict) -> MarkerTable:
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise InputError(path, f"marker table lacks columns {missing} (found {list(df.columns)})")
    if df.empty:
        raise InputError(path, "marker table has no rows")
    df = df.copy()
    df["status"] = df["status"].fillna(MISSING)
    meta = {**meta, "source": str(path), "units": "mm"}
    if MISSING_CAMERAS in df.columns:
        with reading(path, "missing_cameras column"):
            fields = df.drop_duplicates("frame")
            meta[MISSING_CAMERAS] = missing_from_frames(pd.to_numeric(fields["frame"]).astype(np.int64).tolist(),
                                                        fields[MISSING_CAMERAS].tolist())
    with reading(path, "marker table"), np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        table = MarkerTable(df, meta)
        if "fps" not in table.meta and table.n_frames > 1:
            table.meta["fps"] = round(table.fps, 9)
        elif "fps" not in table.meta and table.n_frames == 1:
            table.meta.update(_one_frame_rate(table))
        table = checked_table(table, path)
        arrays = table.to_arrays()
        table = _complete(table, arrays, path)
    warn_empty_markers(list(arrays.labels), arrays.positions, path)
    return table


def _one_frame_rate(table: MarkerTable) -> dict:
    """``{"fps": ...}`` of a one-frame table whose time is its frame number over the frame rate
    (as the tracker writes it: frame k at k / fps s), else ``{}`` (frame 0 at 0 s tells no rate)."""
    frame = float(table.data["frame"].iloc[0])
    time = float(table.data["time"].iloc[0])
    return {"fps": round(frame / time, 9)} if frame > 0 and np.isfinite(time) and time > 0 else {}


def _complete(table: MarkerTable, arrays: DenseMarkers, path: Path) -> MarkerTable:
    """The table with a ``missing`` row for every (frame, label) the file lacks (warned)."""
    F, D = arrays.positions.shape[:2]
    absent = F * D - len(table.data)
    if not absent:
        return table
    warnings.warn(f"{path}: {absent} (frame, label) rows are absent; read as missing", ExportWarning, stacklevel=4)
    return table_from_dense(list(arrays.labels), arrays.frames, arrays.time, arrays.positions,
                            table.meta, arrays.status, arrays.n_views, arrays.residual)


def write_csv(table: MarkerTable, path: str | os.PathLike) -> Path:
    """Write the full long table as CSV (atomically)."""
    return write_csv_parts([table], path)


def write_csv_parts(parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int | None = None) -> Path:
    """:func:`write_csv` of a table given as consecutive ``parts`` (the same labels and meta), one
    part in memory at a time: the file :func:`write_csv` writes of their concatenation
    (``n_frames``, the frames in all, is not needed: the CSV has no header count)."""
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    path = Path(path)
    writer, schema, seen, labels = None, None, None, []
    with atomic_path(path) as tmp:  # pyarrow: ~8x faster than pandas, same shortest exact floats
        try:
            for table in parts:
                frame, part_seen = _mm_frame(table, path)
                labels, seen = table.labels, part_seen if seen is None else seen | part_seen
                arrow = pa.Table.from_pandas(frame, preserve_index=False)
                if writer is None:
                    schema = arrow.schema
                    writer = pa_csv.CSVWriter(tmp, schema)
                writer.write_table(arrow.cast(schema))
        finally:
            if writer is not None:
                writer.close()
        if writer is None:
            raise InputError(path, "marker table has no frames to write")
    if seen is not None:  # None: no part held a frame (refused above)
        warn_unseen(labels, seen, path)
    return path


def read_csv(path: str | os.PathLike) -> MarkerTable:
    path = Path(path)
    try:
        df = pd.read_csv(path, dtype={"label": str, MISSING_CAMERAS: str})
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeError, ValueError,
            OverflowError, MemoryError) as exc:
        raise InputError(path, f"cannot read CSV: {exc}") from exc
    return _table(df, path, {})


def write_parquet(table: MarkerTable, path: str | os.PathLike) -> Path:
    """Write the full long table as Parquet with ``meta`` as JSON in the schema (atomically)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    frame, seen = _mm_frame(table, path)
    warn_unseen(table.labels, seen, path)
    arrow = pa.Table.from_pandas(frame, preserve_index=False)
    meta = {**table.meta, "units": "mm"}
    arrow = arrow.replace_schema_metadata({**(arrow.schema.metadata or {}),
                                           META_KEY: json.dumps(meta, default=str).encode()})
    with atomic_path(path) as tmp:
        pq.write_table(arrow, tmp)
    return path


def read_parquet(path: str | os.PathLike) -> MarkerTable:
    import pyarrow.parquet as pq

    path = Path(path)
    try:  # pyarrow raises several types for corrupt files, some only while converting columns
        arrow = pq.read_table(path)
        with reading(path, "Parquet marker table"):
            meta = json.loads((arrow.schema.metadata or {}).get(META_KEY, b"{}"))
            if not isinstance(meta, dict):
                raise InputError(path, f"the {META_KEY.decode()} metadata must be a JSON object")
            return _table(arrow.to_pandas(), path, meta)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(path, f"cannot read Parquet: {type(exc).__name__}: {exc}") from exc


class CsvExporter(Exporter):
    name = "csv"
    extensions = (".csv",)
    options = ()
    description = "full marker table (frame, time, label, x, y, z, status, n_views, residual) as CSV"

    def write(self, table: MarkerTable, path: str | os.PathLike, **options) -> Path:
        return write_csv(table, path, **options)

    def write_parts(self, parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, **options) -> Path:
        return write_csv_parts(parts, path, n_frames, **options)

    def read(self, path: str | os.PathLike) -> MarkerTable:
        return read_csv(path)


class ParquetExporter(Exporter):
    name = "parquet"
    extensions = (".parquet", ".pq")
    options = ()
    description = "full marker table as Parquet, with metadata"

    def write(self, table: MarkerTable, path: str | os.PathLike, **options) -> Path:
        return write_parquet(table, path, **options)

    def read(self, path: str | os.PathLike) -> MarkerTable:
        return read_parquet(path)
