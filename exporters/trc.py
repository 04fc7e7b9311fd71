"""OpenSim TRC (track row column) marker files: writer and reader.

Layout (tab separated), as OpenSim's ``TRCFileAdapter`` reads it::

    PathFileType  4  (X/Y/Z)  markers.trc  axes: <statement>  missing cameras: cam2:41-60,75
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    100       100         548        32          mm     100           1                   548
    Frame#  Time  R01L  <tab>  <tab>  R01R ...
                  X1    Y1     Z1     X2   ...
    <blank line>
    1       0.000000   12.34560  ...   NaN  NaN  NaN

Missing samples are written as ``NaN`` (OpenSim rejects rows with empty trailing fields). The
axes statement on the first line says which frame the numbers are in; OpenSim keeps that line
as the table's ``header`` metadata. Frame numbers in the file are 1-based (table frame + 1).

The first line's last field, ``missing cameras: ...``, names the cameras that had no image in
some frames and those frames as the file's ``Frame#`` numbers: ``cam2:41-60,75;cam3:7`` (camera
names percent-encoded), ``none`` where every camera was there (``meta['missing_cameras']``).
OpenSim's ``TRCFileAdapter`` keeps that line as the table's ``header`` metadata (it refuses a
ninth key on the second line, so the list cannot go there).

TRC carries positions only: status, view counts and residuals are not stored; on reading,
finite samples are ``observed`` and NaN samples ``missing``.
"""

from __future__ import annotations

import inspect
import os
import re
from pathlib import Path
from typing import Iterable
from urllib.parse import quote, unquote

import numpy as np

from spinemocap.fileio import InputError, atomic_write, reading
from spinemocap.markers import MAX_FRAME, MISSING_CAMERAS, MarkerTable, camera_gaps, missing_from_gaps

from .common import (
    checked_table,
    deduplicate_labels,
    dense_mm,
    drop_implausible,
    frame_rate,
    mm_per_unit,
    sampled,
    table_from_dense,
    warn_empty_markers,
    warn_unseen,
)
from .registry import Exporter

HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units",
               "OrigDataRate", "OrigDataStartFrame", "OrigNumFrames")
MISSING_CAMERAS_FIELD = "missing cameras: "
NO_CAMERA_MISSING = "none"
LAB_AXES = "axes: lab frame, Z up (as captured)"
AXES_PATTERN = re.compile(r"axes: OpenSim Y up, rotated from lab Z up: X=([+-][xyz]), Y=([+-][xyz]), Z=([+-][xyz])")
# OpenSim: X forward, Y up, Z = X x Y (to the subject's right). Lab: Z up; "forward" names the
# lab axis the subject faces. Each entry gives the OpenSim (X, Y, Z) as signed lab axes.
OPENSIM_FROM_LAB = {
    "+x": ("+x", "+z", "-y"),
    "-x": ("-x", "+z", "+y"),
    "+y": ("+y", "+z", "+x"),
    "-y": ("-y", "+z", "-x"),
}


def _signed_axes(spec: tuple[str, str, str]) -> tuple[np.ndarray, np.ndarray]:
    """("+x", "+z", "-y") -> source axis indices and signs (an exact signed permutation)."""
    index = np.array(["xyz".index(s[1]) for s in spec])
    sign = np.array([1.0 if s[0] == "+" else -1.0 for s in spec])
    return index, sign


def lab_to_opensim(positions: np.ndarray, forward: str = "+x") -> np.ndarray:
    """Rotate (..., 3) lab Z-up coordinates into OpenSim's Y-up frame (exact: permutation + signs)."""
    index, sign = _signed_axes(OPENSIM_FROM_LAB[forward.lower()])
    return positions[..., index] * sign


def opensim_to_lab(positions: np.ndarray, spec: tuple[str, str, str]) -> np.ndarray:
    """Inverse of :func:`lab_to_opensim` for the axes statement ``spec`` read from a file."""
    index, sign = _signed_axes(spec)
    out = np.empty_like(positions)
    out[..., index] = positions * sign
    return out


def axes_statement(forward: str | None) -> str:
    if forward is None:
        return LAB_AXES
    X, Y, Z = OPENSIM_FROM_LAB[forward.lower()]
    return f"axes: OpenSim Y up, rotated from lab Z up: X={X}, Y={Y}, Z={Z}"


def missing_cameras_field(missing: dict, frames: np.ndarray) -> str:
    """The ``missing cameras:`` field's value for the gaps within ``frames`` (the table's, 0-based;
    written as 1-based ``Frame#`` numbers)."""
    spans: dict[str, list[str]] = {}
    for camera, first, last in camera_gaps(missing, frames):
        spans.setdefault(camera, []).append(str(first + 1) if first == last else f"{first + 1}-{last + 1}")
    return ";".join(f"{quote(camera, safe='')}:{','.join(runs)}" for camera, runs in spans.items()) or NO_CAMERA_MISSING


def read_missing_cameras(value: str, path: Path) -> dict[str, list[int]]:
    """The ``missing cameras:`` field's value as camera -> frames (0-based); :class:`InputError`
    naming ``path`` when it is not of that form."""
    value = value.strip()
    if value in ("", NO_CAMERA_MISSING):
        return {}
    gaps = []
    try:
        for part in value.split(";"):
            camera, _, runs = part.rpartition(":")
            for run in runs.split(","):
                first, _, last = run.partition("-")
                start, stop = int(first), int(last or first)
                if not (camera and 1 <= start <= stop <= MAX_FRAME):
                    raise ValueError(run)
                gaps.append((unquote(camera), start - 1, stop - 1))
    except ValueError:
        raise InputError(path, f"TRC header '{MISSING_CAMERAS_FIELD}{value}' is not 'camera:first-last,...;camera:...' "
                               "(Frame# numbers) or 'none'") from None
    return missing_from_gaps(gaps)


def write_trc(table: MarkerTable, path: str | os.PathLike, units: str = "mm", opensim_axes: bool = False,
              forward: str = "+x", decimals: int | None = None, name: str | None = None) -> Path:
    """Write ``table`` as an OpenSim TRC file (atomically).

    ``units``: ``mm`` or ``m`` (``cm`` also accepted). ``opensim_axes``: rotate from our Z-up lab
    frame to OpenSim's Y-up frame, with the subject facing lab axis ``forward`` (+x, -x, +y, -y);
    the first header line states the rotation either way. ``decimals``: digits after the point
    (default 1 µm resolution: 3 in mm, 6 in m). ``name``: file name written in the header.
    """
    return write_trc_parts([table], path, table.n_frames, units, opensim_axes, forward, decimals, name)


def write_trc_parts(parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, units: str = "mm",
                    opensim_axes: bool = False, forward: str = "+x", decimals: int | None = None,
                    name: str | None = None) -> Path:
    """:func:`write_trc` of a table given as consecutive ``parts`` (the same labels and meta;
    ``n_frames`` frames in all), one part in memory at a time: the file :func:`write_trc` writes
    of their concatenation."""
    path = Path(path)
    units = units.lower()
    scale = mm_per_unit(units, path)
    if forward.lower() not in OPENSIM_FROM_LAB:
        raise InputError(path, f"unknown forward axis {forward!r}; expected one of {sorted(OPENSIM_FROM_LAB)}")
    if decimals is None:
        decimals = max(0, int(round(np.log10(scale))) + 3)
    seen, labels, written = None, [], 0
    with atomic_write(path, "w", newline="\n", encoding="utf-8") as handle:
        for table in parts:
            arrays = dense_mm(table, path)
            labels = [str(l) for l in arrays.labels]
            positions = arrays.positions / scale
            seen = sampled(positions) if seen is None else seen | sampled(positions)
            if opensim_axes:
                positions = lab_to_opensim(positions, forward)
            fps = frame_rate(table, path)
            frames, times = arrays.frames, arrays.time
            if not np.isfinite(times).all():
                times = frames / fps
            if not written:
                handle.write("\n".join(_trc_header(table, labels, fps, int(frames[0]), n_frames, units, path,
                                                     axes_statement(forward if opensim_axes else None), name)) + "\n")
            F, D = positions.shape[:2]
            row_format = "\t".join(["%d", "%.6f"] + [f"%.{decimals}f"] * (3 * D))
            table_rows = np.column_stack([frames + 1, times, positions.reshape(F, 3 * D)]).tolist()
            # one %-format per row is ~10x faster than per value; OpenSim wants NaN, Python writes nan
            handle.write("\n".join((row_format % tuple(row)).replace("nan", "NaN") for row in table_rows) + "\n")
            written += F
        if written != n_frames:
            raise ValueError(f"{path}: the parts hold {written} frames, not the {n_frames} announced")
    if seen is not None:  # None: no part held a frame (refused above)
        warn_unseen(labels, seen, path)
    return path


def _trc_header(table: MarkerTable, labels: list[str], fps: float, first: int, n_frames: int, units: str,
                path: Path, axes: str, name: str | None) -> list[str]:
    """The five header lines and the blank line after them; ``first``: the first frame (0-based)."""
    bad = [l for l in labels if not l or "\t" in l or "\n" in l]
    if bad:
        raise InputError(path, f"marker labels unusable in a TRC file (empty or containing tabs/newlines): {bad}")
    D = len(labels)
    missing = missing_cameras_field(table.meta.get(MISSING_CAMERAS) or {}, np.arange(first, first + n_frames))
    return [
        "\t".join(["PathFileType", "4", "(X/Y/Z)", name or path.name, axes, MISSING_CAMERAS_FIELD + missing]),
        "\t".join(HEADER_KEYS),
        "\t".join([f"{fps:.10g}", f"{float(table.meta.get('camera_rate', fps)):.10g}", str(n_frames), str(D), units,
                   f"{fps:.10g}", str(first + 1), str(n_frames)]),
        "\t".join(["Frame#", "Time"] + [f"{l}\t\t" for l in labels]),
        "\t".join(["", ""] + [f"X{i}\tY{i}\tZ{i}" for i in range(1, D + 1)]),
        "",
    ]


def _split(line: str) -> list[str]:
    return line.rstrip("\r\n").split("\t")


def read_trc(path: str | os.PathLike) -> MarkerTable:
    """Read a TRC file into a :class:`MarkerTable` in mm, lab frame (Z up); see :func:`_read_trc`.
    Any failure is an :class:`InputError` naming the file."""
    with reading(path, "TRC file"):
        return _read_trc(Path(path))


def _read_trc(path: Path) -> MarkerTable:
    """Read a TRC file into a :class:`MarkerTable` in mm, lab frame (Z up).

    A file whose first line carries our OpenSim axes statement is rotated back to the lab frame;
    other files are taken as they are (``meta['trc_axes']`` records which). Empty fields and
    ``NaN`` read as missing samples; rows whose column count differs from the header's raise
    :class:`InputError` naming the line.
    """
    try:
        text = path.read_text(encoding="utf-8-sig", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read TRC text: {exc}") from exc
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise InputError(path, "not a TRC file (expected 'PathFileType' header and 5 header lines)")
    keys, values = _split(lines[1]), _split(lines[2])
    header = {k.strip(): v.strip() for k, v in zip(keys, values)}
    for key in ("DataRate", "NumMarkers", "Units"):
        if key not in header:
            raise InputError(path, f"TRC header lacks {key} (keys found: {keys})")
    try:
        fps = float(header["DataRate"])
        n_markers = int(header["NumMarkers"])
        camera_rate = float(header.get("CameraRate") or fps)
    except ValueError as exc:
        raise InputError(path, f"bad number in TRC header: {exc}") from exc
    if not (np.isfinite(fps) and fps > 0) or n_markers < 1:
        raise InputError(path, f"TRC header needs a finite DataRate > 0 and NumMarkers >= 1 (got {fps}, {n_markers})")
    if not np.isfinite(camera_rate) or camera_rate <= 0:
        camera_rate = fps
    scale = mm_per_unit(header["Units"], path)
    names = [n.strip() for n in _split(lines[3])[2:] if n.strip()]
    if len(names) != n_markers:
        raise InputError(path, f"header declares NumMarkers={n_markers} but the names row has {len(names)} "
                               f"marker names")
    labels = deduplicate_labels(names, path)
    n_cols = 2 + 3 * n_markers
    frames, times, rows = [], [], []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        fields = _split(line)
        while len(fields) > n_cols and fields[-1] == "":  # tolerate a trailing tab
            fields.pop()
        if len(fields) != n_cols:
            raise InputError(path, f"line {number} has {len(fields)} columns; the header's {n_markers} markers "
                                   f"need {n_cols} (Frame#, Time, X/Y/Z per marker)")
        try:
            frame = float(fields[0])
            if not (np.isfinite(frame) and frame == int(frame) and abs(frame) <= MAX_FRAME):
                raise ValueError(f"Frame# {fields[0]!r} is not a whole frame number")
            frames.append(int(frame) - 1)
            times.append(float(fields[1]))
            rows.append([float(v) if v.strip() else np.nan for v in fields[2:]])
        except (ValueError, OverflowError) as exc:
            raise InputError(path, f"line {number}: not a number ({exc})") from exc
    if not rows:
        raise InputError(path, "TRC file has no data rows")
    positions = np.asarray(rows, float).reshape(len(rows), n_markers, 3)
    match = AXES_PATTERN.search(lines[0])
    if match:
        positions = opensim_to_lab(positions, (match[1], match[2], match[3]))
    with np.errstate(over="ignore", invalid="ignore"):
        positions = drop_implausible(positions * scale, path)
    warn_empty_markers(labels, positions, path)
    meta = {"fps": fps, "source": str(path), "file_units": header["Units"],
            "trc_axes": "opensim" if match else "as in file",
            "camera_rate": camera_rate}
    given = [f[len(MISSING_CAMERAS_FIELD):] for f in _split(lines[0]) if f.startswith(MISSING_CAMERAS_FIELD)]
    missing = read_missing_cameras(given[0], path) if given else {}
    if missing:
        meta[MISSING_CAMERAS] = missing
    return checked_table(table_from_dense(labels, np.asarray(frames), np.asarray(times), positions, meta), path)


class TrcExporter(Exporter):
    name = "trc"
    extensions = (".trc",)
    options = tuple(inspect.signature(write_trc).parameters)[2:]
    description = "OpenSim TRC marker trajectories (mm or m, optional Y-up rotation)"

    def write(self, table: MarkerTable, path: str | os.PathLike, **options) -> Path:
        return write_trc(table, path, **options)

    def write_parts(self, parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, **options) -> Path:
        return write_trc_parts(parts, path, n_frames, **options)

    def read(self, path: str | os.PathLike) -> MarkerTable:
        return read_trc(path)
