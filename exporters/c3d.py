"""C3D for Vicon Nexus, Mokka, Visual3D and co: writer and reader built on the ``c3d`` package.

What we write (float data, Intel byte order), parameters filled the way Vicon Nexus fills them:

- ``POINT``: ``USED``, ``FRAMES`` (+ ``LONG_FRAMES`` as float beyond 65534 frames), ``DATA_START``,
  ``SCALE`` (negative = float data; its magnitude is the residual resolution), ``RATE``,
  ``UNITS`` (mm or m), ``X_SCREEN``/``Y_SCREEN`` (+X/+Z: Z up), ``LABELS`` (30 characters
  wide, as Nexus; more than 255 markers continue in ``LABELS2``, ``LABELS3`` ...),
  ``DESCRIPTIONS`` (100 wide, same split).
- ``TRIAL``: ``ACTUAL_START_FIELD``/``ACTUAL_END_FIELD`` (1-based frame numbers as two 16-bit
  words, so any length works), ``CAMERA_RATE``, ``X/Y/Z_DIRECTION``.
- Beyond 65534 frames the header's frame fields saturate at 65535, ``POINT:FRAMES`` stays a
  16-bit integer (ezc3d rejects a float ``FRAMES``), ``POINT:LONG_FRAMES`` (float) and the TRIAL
  fields carry the count, and the last data block is not padded (ezc3d then counts frames from
  the file size).
- ``SUBJECTS``: ``USED``, ``IS_STATIC``, ``USES_PREFIXES``, ``NAMES``, ``MARKER_SETS``.
- ``MANUFACTURER``: ``COMPANY``, ``SOFTWARE``, ``VERSION_LABEL``.

Per sample, the C3D spec's fourth word holds a residual byte (low) and a camera-mask byte (high);
a negative word marks an invalid sample (coordinates written as 0, as Nexus does). Our
status/n_views/residual map onto it like this, and this is what survives a round trip:

- ``missing`` -> word -1 (reads back as NaN, ``missing``).
- ``observed`` -> residual byte = residual / |SCALE| rounded and clipped to 1..255 (so a residual
  of 0 never turns it into ``inferred``; unknown residuals become 1); camera mask = the lowest
  ``n_views`` bits. Lost: residual precision (|SCALE|, default 0.01 px), residuals above
  255 * |SCALE| (saturate), n_views above 7 (the mask has 7 bits), and which cameras (we only
  have a count).
- ``inferred`` -> residual byte 0 (the spec's "interpolated/modelled"), camera mask as above.
  Reads back as ``inferred`` with residual 0.

The residual we store is the mean reprojection error in px (the tracker's), not mm.
Reading follows the same rules for any file: Vicon's gap-filled/filtered trials store residual
0 everywhere and therefore read as ``inferred``.

Note: ezc3d (<= 1.7) decodes that fourth word of float files with the two bytes swapped
(pyomeca/ezc3d issue #386); coordinates and invalid samples agree with the ``c3d`` package,
residuals and camera masks of float files do not.
"""

from __future__ import annotations

import inspect
import os
import warnings
from pathlib import Path
from typing import Sequence

import c3d as c3dlib
import numpy as np

from spinemocap._version import __version__
from spinemocap.fileio import InputError, atomic_path
from spinemocap.markers import MarkerTable

from .common import (
    ExportWarning,
    deduplicate_labels,
    dense_mm,
    frame_rate,
    mm_per_unit,
    table_from_dense,
    warn_empty_markers,
)
from .registry import Exporter

LABEL_WIDTH = 30         # POINT:LABELS element width Vicon Nexus writes
DESCRIPTION_WIDTH = 100  # POINT:DESCRIPTIONS element width Vicon Nexus writes
NAME_WIDTH = 32          # SUBJECTS:NAMES / MARKER_SETS width
PER_PARAM = 255          # a parameter dimension is one byte: LABELS2, LABELS3 ... beyond this
MASK_BITS = 7            # camera mask bits in the fourth word
# POINT sub-lists Vicon uses for non-marker outputs stored as points (angles in deg etc.)
NON_MARKER_LISTS = {"ANGLES": "angle", "FORCES": "force", "MOMENTS": "moment", "POWERS": "power",
                    "SCALARS": "scalar", "REACTIONS": "reaction"}


# ---------------------------------------------------------------------------------- writing
def fit_labels(labels: Sequence[str], width: int, source: str | os.PathLike) -> list[str]:
    """Labels as C3D can hold them: ASCII, at most ``width`` characters, still unique after
    truncation (a clash ends in ``~2``, ``~3`` ...). Changes are warned about."""
    out: list[str] = []
    used: set[str] = set()
    changed = []
    for label in labels:
        fitted = label.encode("ascii", "replace").decode().replace("\x00", "?")[:width].rstrip()
        k = 2
        while fitted in used or not fitted:
            tail = f"~{k}"
            fitted = label.encode("ascii", "replace").decode()[: width - len(tail)].rstrip() + tail
            k += 1
        if fitted != label:
            changed.append(f"{label!r} -> {fitted!r}")
        used.add(fitted)
        out.append(fitted)
    if changed:
        warnings.warn(f"{source}: C3D labels must be ASCII and at most {width} characters, unique; "
                      f"renamed {', '.join(changed)}", ExportWarning, stacklevel=3)
    return out


def encode_fourth_word(status: np.ndarray, n_views: np.ndarray, residual: np.ndarray, finite: np.ndarray,
                       residual_scale: float, source: str | os.PathLike) -> np.ndarray:
    """The C3D fourth word per sample (F, D) as float32: -1 invalid, else residual byte |
    camera mask << 8 (see the module docstring for the mapping)."""
    status = np.asarray(status).astype(str)
    valid = finite & (status != "missing")
    n_views = np.asarray(n_views, np.int64)
    if (n_views[valid] > MASK_BITS).any():
        warnings.warn(f"{source}: view counts above {MASK_BITS} saturate at {MASK_BITS} in the C3D camera mask",
                      ExportWarning, stacklevel=3)
    mask = (1 << np.clip(n_views, 0, MASK_BITS)) - 1
    res = np.asarray(residual, float) / residual_scale
    res_byte = np.clip(np.rint(np.nan_to_num(res, nan=1.0)), 1, 255).astype(np.int64)
    res_byte[status == "inferred"] = 0
    word = (res_byte | (mask << 8)).astype(np.float32)
    word[~valid] = -1.0
    return word


class _FrameView:
    """Just enough of a frame list for ``c3d.Writer.write``: its length and frame 0's shape."""

    def __init__(self, block: np.ndarray):
        self._block = block

    def __len__(self) -> int:
        return len(self._block)

    def __getitem__(self, i: int):
        return self._block[i], np.zeros(0, np.float32)

    def __bool__(self) -> bool:
        return len(self._block) > 0


def _decode_frame_field(param) -> int:
    """TRIAL:ACTUAL_*_FIELD: an unsigned 32-bit frame number stored as two 16-bit words.
    (``c3d`` 0.6 multiplies the high word by 65535, not 65536, for the start field.)"""
    lo, hi = param.uint16_array[:2]
    return int(lo) + 65536 * int(hi)


class _BlockWriter(c3dlib.Writer):
    """``c3d.Writer`` that writes the whole (F, D, 4) float32 point block at once (and writes
    invalid samples as 0, 0, 0, -1 instead of reusing a stale buffer)."""

    def __init__(self, block: np.ndarray, **kwargs):
        super().__init__(**kwargs)
        self._block = np.ascontiguousarray(block, dtype="<f4")
        self._frames = _FrameView(self._block)

    @property
    def first_frame(self) -> int:
        param = self.get("TRIAL:ACTUAL_START_FIELD")
        return _decode_frame_field(param) if param is not None else int(self.header.first_frame)

    def _write_frames(self, handle) -> None:
        assert handle.tell() == 512 * (int(self._header.data_block) - 1)
        handle.write(self._block.tobytes())
        if len(self._block) < 65535:
            self._pad_block(handle)
        # else: no padding. With the header's frame fields saturated, ezc3d counts frames from
        # the file size and would read the padding as extra frames at the origin.


def _set_strings(group, name: str, values: Sequence[str], width: int) -> None:
    """A 2-D char parameter (``width`` x n), split into NAME, NAME2 ... every 255 entries."""
    chunks = [values[i:i + PER_PARAM] for i in range(0, max(len(values), 1), PER_PARAM)] or [[]]
    for k, chunk in enumerate(chunks):
        key = name if k == 0 else f"{name}{k + 1}"
        group.set_str(key, "", "".join(v.ljust(width)[:width] for v in chunk), width, len(chunk))


def _fill_groups(writer: _BlockWriter, labels: list[str], descriptions: list[str], units: str, fps: float,
                 first_frame: int, subject: str, marker_set: str) -> None:
    trial = writer.get_create("TRIAL")
    trial.set("CAMERA_RATE", "", 4, "<f", np.float32(fps))
    for axis, code in (("X_DIRECTION", 1), ("Y_DIRECTION", 3), ("Z_DIRECTION", 5)):
        trial.set(axis, "", 2, "<h", code)
    writer.set_start_frame(first_frame)

    subjects = writer.get_create("SUBJECTS")
    subjects.set("USED", "", 2, "<h", 1)
    subjects.set("IS_STATIC", "", 2, "<h", 0)
    subjects.set("USES_PREFIXES", "", 2, "<h", 0)
    _set_strings(subjects, "NAMES", [subject], NAME_WIDTH)
    _set_strings(subjects, "MARKER_SETS", [marker_set], NAME_WIDTH)

    point = writer.point_group
    point.set_str("X_SCREEN", "", "+X", 2)
    point.set_str("Y_SCREEN", "", "+Z", 2)
    point.set_str("UNITS", "", units, len(units))
    _set_strings(point, "LABELS", labels, LABEL_WIDTH)
    _set_strings(point, "DESCRIPTIONS", descriptions, DESCRIPTION_WIDTH)

    maker = writer.get_create("MANUFACTURER")
    for key, value in (("COMPANY", "spinemocap"), ("SOFTWARE", "spinemocap"), ("VERSION_LABEL", __version__)):
        maker.set_str(key, "", value, len(value))


def _with_reference(arrays: dict, reference: MarkerTable, prefix: str, path: Path) -> tuple[dict, list[str]]:
    """Append reference markers (aligned on frame numbers, NaN where the reference lacks a
    frame) with ``prefix`` on their labels; return the arrays and the new labels' descriptions."""
    ref = dense_mm(reference, path)
    frames = arrays["frames"]
    F, R = len(frames), len(ref["labels"])
    rows = np.searchsorted(ref["frames"], frames)
    hit = (rows < len(ref["frames"])) & (ref["frames"][np.minimum(rows, len(ref["frames"]) - 1)] == frames)
    out = dict(arrays)
    for key, fill in (("positions", np.nan), ("status", "missing"), ("n_views", 0), ("residual", np.nan)):
        extra = np.full((F, R) + ref[key].shape[2:], fill, dtype=ref[key].dtype)
        extra[hit] = ref[key][rows[hit]]
        out[key] = np.concatenate([arrays[key], extra], axis=1)
    out["labels"] = np.concatenate([arrays["labels"], [prefix + str(l) for l in ref["labels"]]])
    return out, [f"reference marker {l}" for l in ref["labels"]]


def write_c3d(table: MarkerTable, path: str | os.PathLike, units: str = "mm", residual_scale: float = 0.01,
              reference: MarkerTable | None = None, reference_prefix: str = "REF_", subject: str | None = None,
              marker_set: str | None = None) -> Path:
    """Write ``table`` as a C3D file (float data), atomically.

    ``units``: mm or m. ``residual_scale``: px per residual count (|POINT:SCALE|; Nexus uses
    0.01). ``reference``: markers (e.g. ground truth) written alongside, labels prefixed with
    ``reference_prefix``. ``subject``/``marker_set`` default to ``table.meta['subject']`` /
    ``meta['marker_set']``; marker descriptions come from ``meta['descriptions']`` (label -> text).
    """
    path = Path(path)
    units = units.lower()
    factor = mm_per_unit(units, path)
    if not 0 < residual_scale:
        raise InputError(path, f"residual_scale must be positive, got {residual_scale}")
    arrays = dense_mm(table, path)
    given = table.meta.get("descriptions", {}) or {}
    descriptions = [str(given.get(str(l), "")) for l in arrays["labels"]]
    if reference is not None:
        arrays, ref_descriptions = _with_reference(arrays, reference, reference_prefix, path)
        descriptions += ref_descriptions
    labels = [str(l) for l in arrays["labels"]]
    positions = arrays["positions"]
    warn_empty_markers(labels, positions, path)
    if len(labels) > 32767:
        raise InputError(path, f"{len(labels)} markers: C3D holds at most 32767 points")
    finite = np.isfinite(positions).all(axis=2)
    word = encode_fourth_word(arrays["status"], arrays["n_views"], arrays["residual"], finite,
                              residual_scale, path)
    F, D = finite.shape
    block = np.zeros((F, D, 4), np.float32)
    valid = word >= 0
    block[..., :3][valid] = positions[valid] / factor
    block[..., 3] = word
    fps = frame_rate(table, path)
    writer = _BlockWriter(block, point_rate=fps, point_scale=-float(residual_scale), point_units=units)
    _fill_groups(writer, fit_labels(labels, LABEL_WIDTH, path), fit_descriptions(descriptions), units, fps,
                 int(arrays["frames"][0]) + 1, str(subject or table.meta.get("subject") or "subject"),
                 str(marker_set or table.meta.get("marker_set") or "spinemocap tape"))
    if not np.array_equal(arrays["frames"], np.arange(arrays["frames"][0], arrays["frames"][0] + F)):
        warnings.warn(f"{path}: frames are not contiguous; C3D numbers them consecutively from "
                      f"{int(arrays['frames'][0]) + 1}", ExportWarning, stacklevel=2)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle, warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No analog data found", module="c3d")
        writer.write(handle)
    return path


def fit_descriptions(descriptions: Sequence[str]) -> list[str]:
    """Descriptions as C3D holds them: ASCII, cut to the Nexus width (no uniqueness needed)."""
    return [d.encode("ascii", "replace").decode()[:DESCRIPTION_WIDTH] for d in descriptions]


# ---------------------------------------------------------------------------------- reading
class _Reader(c3dlib.Reader):
    """``c3d.Reader`` with the start frame decoded as an unsigned 32-bit number."""

    @property
    def first_frame(self) -> int:
        param = self.get("TRIAL:ACTUAL_START_FIELD")
        return _decode_frame_field(param) if param is not None else int(self.header.first_frame)


def _strings(reader: c3dlib.Reader, group: str, name: str) -> list[str]:
    """A char-array parameter and its continuations (NAME2, NAME3 ...), entries stripped."""
    out: list[str] = []
    k = 1
    while (param := reader.get(f"{group}:{name}{'' if k == 1 else k}")) is not None:
        values = param.string_array
        out += [str(v).strip() for v in np.ravel(values)] if np.ndim(values) else [str(values).strip()]
        k += 1
    return out


def read_c3d(path: str | os.PathLike) -> MarkerTable:
    """Read the 3D points of a C3D file into a :class:`MarkerTable` (mm, frames 0-based:
    C3D frame 1 is frame 0). Invalid samples are NaN/``missing``; see the module docstring for
    status, n_views and residual. Non-marker points (Vicon angles, forces ...) are read too, in
    their own units and unconverted; ``meta['point_types']`` names them."""
    path = Path(path)
    try:
        handle = open(path, "rb")
    except OSError as exc:
        raise InputError(path, f"cannot open: {exc}") from exc
    with handle, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            reader = _Reader(handle)
            n_points = int(reader.point_used)
            expected = int(reader.last_frame) - int(reader.first_frame) + 1
            if n_points == 0:
                raise InputError(path, "C3D file holds no 3D points (POINT:USED = 0)")
            if float(reader.point_scale) < 0 and not reader._dtypes.is_dec:
                data = _float_points(reader, handle, expected)
            else:  # integer or DEC data: the c3d package's frame-by-frame decoder
                data = np.stack([p for _, p, _ in reader.read_frames(copy=True, check_nan=True)] or
                                [np.zeros((n_points, 5), np.float32)])[:expected]
        except InputError:
            raise
        except Exception as exc:  # struct.error, ValueError, KeyError ... from a damaged file
            raise InputError(path, f"not a readable C3D file ({type(exc).__name__}: {exc})") from exc
    eof = [str(w.message) for w in caught if "end of file" in str(w.message).lower()]
    if len(data) != expected or eof:
        found = len(data) if not eof else "fewer"
        raise InputError(path, f"truncated C3D: the parameters declare {expected} frames but the file holds "
                               f"{found}")
    return _table_from_reader(reader, data, path)


def _float_points(reader: c3dlib.Reader, handle, n_frames: int) -> np.ndarray:
    """All frames of a float (Intel or MIPS) file at once, decoded as ``c3d.Reader.read_frames``
    does: (F, D, 5) = x, y, z, residual (-1 invalid), camera mask. Fewer rows if truncated."""
    n_points = int(reader.point_used)
    n_analog = int(reader.analog_used) * int(reader.analog_per_frame)
    words = 4 * n_points + n_analog
    handle.seek((int(reader.header.data_block) - 1) * 512)
    raw = handle.read(4 * words * n_frames)
    complete = len(raw) // (4 * words)
    block = np.frombuffer(raw[: complete * 4 * words], dtype=reader._dtypes.float32)
    block = block.reshape(complete, words)[:, : 4 * n_points].reshape(complete, n_points, 4)
    fourth = block[..., 3].astype(np.int32)
    invalid = (fourth < 0) | ~np.isfinite(block).all(axis=2)
    out = np.zeros((complete, n_points, 5), np.float32)
    out[..., :3] = np.where(invalid[..., None], 0.0, block[..., :3])
    out[..., 3] = np.where(invalid, -1.0, (fourth & 0xFF) * np.float32(abs(reader.point_scale)))
    out[..., 4] = (fourth & 0x7F00) >> 8
    return out


def _table_from_reader(reader: c3dlib.Reader, data: np.ndarray, path: Path) -> MarkerTable:
    n_points = data.shape[1]
    labels = _strings(reader, "POINT", "LABELS")
    if len(labels) < n_points:
        warnings.warn(f"{path}: POINT:LABELS names {len(labels)} of {n_points} points; the rest are "
                      f"called POINT_<n>", ExportWarning, stacklevel=3)
        labels += [f"POINT_{i + 1}" for i in range(len(labels), n_points)]
    labels = deduplicate_labels(labels[:n_points], path)
    units_param = reader.get("POINT:UNITS")
    units = units_param.string_value.strip() if units_param is not None else "mm"
    factor = mm_per_unit(units, path)
    point_types = {label: kind for group, kind in NON_MARKER_LISTS.items()
                   for label in _strings(reader, "POINT", group) if label in labels}
    is_marker = np.array([label not in point_types for label in labels])

    word = data[..., 3]
    invalid = word < 0
    positions = data[..., :3].astype(float)
    positions[invalid] = np.nan
    positions[:, is_marker] *= factor
    residual = np.where(invalid, np.nan, word.astype(float))
    cameras = data[..., 4].astype(np.int64)
    n_views = np.where(invalid, 0, np.array([bin(c).count("1") for c in range(128)])[cameras & 0x7F])
    status = np.where(invalid, "missing", np.where(residual == 0, "inferred", "observed"))
    warn_empty_markers([l for l, m in zip(labels, is_marker) if m], positions[:, is_marker], path)

    first = int(reader.first_frame) - 1
    fps = float(reader.point_rate)
    frames = np.arange(first, first + len(data))
    subject = _strings(reader, "SUBJECTS", "NAMES")
    software = _strings(reader, "MANUFACTURER", "SOFTWARE")
    meta = {"fps": fps, "source": str(path), "file_units": units, "point_types": point_types,
            "subject": subject[0] if subject else None,
            "software": software[0] if software else None,
            "descriptions": {l: d for l, d in zip(labels, _strings(reader, "POINT", "DESCRIPTIONS")) if d}}
    return table_from_dense(labels, frames, frames / fps, positions, meta, status=status, n_views=n_views,
                            residual=residual)


class C3dExporter(Exporter):
    name = "c3d"
    extensions = (".c3d",)
    options = tuple(inspect.signature(write_c3d).parameters)[2:]
    description = "C3D (Vicon Nexus, Mokka, Visual3D ...): float points, residuals, camera masks"

    def write(self, table: MarkerTable, path: str | os.PathLike, **options) -> Path:
        return write_c3d(table, path, **options)

    def read(self, path: str | os.PathLike) -> MarkerTable:
        return read_c3d(path)
