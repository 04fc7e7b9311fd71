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
- ``MISSING_CAMERAS`` (only where a camera had no image in some frames, ``meta['missing_cameras']``):
  ``USED`` (int16, the number of spans), ``CAMERAS`` (char, the camera names) and ``SPANS``
  (float32, 3 x USED: camera number, 1-based into ``CAMERAS``; first and last C3D frame number of
  a run of frames that camera lacks; more than 255 spans continue in ``SPANS2``, ``SPANS3`` ...).
  ezc3d and the ``c3d`` package read it as any parameter group.

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

Note: ezc3d (<= 1.7) decodes that fourth word of float files with the two bytes swapped;
coordinates and invalid samples agree with the ``c3d`` package,
residuals and camera masks of float files do not.
"""

from __future__ import annotations

import inspect
import itertools
import os
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import c3d as c3dlib
import numpy as np

from spinemocap.fileio import InputError, atomic_path
from spinemocap.markers import (
    INFERRED,
    MAX_ABS_MM,
    MISSING,
    MISSING_CAMERAS,
    OBSERVED,
    DenseMarkers,
    MarkerTable,
    camera_gaps,
    missing_from_gaps,
)
from spinemocap.version import __version__

from .common import (
    ExportWarning,
    deduplicate_labels,
    dense_mm,
    frame_rate,
    mm_per_unit,
    table_from_dense,
    warn_empty_markers,
    warn_unseen,
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
    valid = finite & (status != MISSING)
    n_views = np.asarray(n_views, np.int64)
    if (n_views[valid] > MASK_BITS).any():
        warnings.warn(f"{source}: view counts above {MASK_BITS} saturate at {MASK_BITS} in the C3D camera mask",
                      ExportWarning, stacklevel=3)
    mask = (1 << np.clip(n_views, 0, MASK_BITS)) - 1
    res = np.asarray(residual, float) / residual_scale
    res_byte = np.clip(np.rint(np.nan_to_num(res, nan=1.0)), 1, 255).astype(np.int64)
    res_byte[status == INFERRED] = 0
    word = (res_byte | (mask << 8)).astype(np.float32)
    word[~valid] = -1.0
    return word


class _FrameView:
    """Just enough of a frame list for ``c3d.Writer.write``: its length and frame 0's shape."""

    def __init__(self, n_frames: int, n_points: int):
        self._n_frames, self._n_points = n_frames, n_points

    def __len__(self) -> int:
        return self._n_frames

    def __getitem__(self, i: int):
        return np.zeros((self._n_points, 4), np.float32), np.zeros(0, np.float32)

    def __bool__(self) -> bool:
        return self._n_frames > 0


class _BlockWriter(c3dlib.Writer):
    """``c3d.Writer`` that writes the (F, D, 4) float32 point blocks ``blocks`` yields (consecutive
    frames, ``n_frames`` in all) as they come (and writes invalid samples as 0, 0, 0, -1 instead of
    reusing a stale buffer)."""

    def __init__(self, blocks: Iterable[np.ndarray], n_frames: int, n_points: int, **kwargs):
        super().__init__(**kwargs)
        self._blocks = blocks
        self._frames = _FrameView(n_frames, n_points)

    @property
    def first_frame(self) -> int:
        # (``c3d`` 0.6 multiplies the start field's high word by 65535, not 65536)
        start = _frame_field(self, "TRIAL:ACTUAL_START_FIELD")
        return start if start is not None else int(self.header.first_frame)

    def _write_frames(self, handle) -> None:
        assert handle.tell() == 512 * (int(self._header.data_block) - 1)
        written = 0
        for block in self._blocks:
            handle.write(np.ascontiguousarray(block, dtype="<f4").tobytes())
            written += len(block)
        if written != len(self._frames):
            raise ValueError(f"the parts hold {written} frames, not the {len(self._frames)} announced")
        if written < 65535:
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


def _fill_missing_cameras(writer: _BlockWriter, missing: dict, frames: np.ndarray) -> None:
    """The ``MISSING_CAMERAS`` group (see the module docstring) for the gaps within ``frames``
    (the table's, 0-based); nothing where no camera lacks a frame."""
    gaps = camera_gaps(missing, frames)
    if not gaps:
        return
    cameras = sorted({camera for camera, _, _ in gaps})
    group = writer.get_create(MISSING_CAMERAS.upper())
    group.set("USED", "spans of frames a camera had no image in", 2, "<h", min(len(gaps), 32767))
    names = fit_labels(cameras, 255, "MISSING_CAMERAS:CAMERAS")
    _set_strings(group, "CAMERAS", names, max(len(name) for name in names))
    spans = np.array([(cameras.index(camera) + 1, first + 1, last + 1) for camera, first, last in gaps], "<f4")
    for k in range(0, len(spans), PER_PARAM):
        chunk = spans[k:k + PER_PARAM]
        key = "SPANS" if k == 0 else f"SPANS{k // PER_PARAM + 1}"
        group.add(key, "camera number, first and last C3D frame it had no image in", 4, "", chunk.tobytes(), 3,
                  len(chunk))


def _read_missing_cameras(reader: c3dlib.Reader, path: Path) -> dict[str, list[int]]:
    """The ``MISSING_CAMERAS`` group as camera -> frames (0-based); {} where the file has none.
    A damaged group is left out with a warning (the points are still read)."""
    if reader.get(MISSING_CAMERAS.upper()) is None:
        return {}
    try:
        cameras = _strings(reader, MISSING_CAMERAS.upper(), "CAMERAS")
        gaps = []
        k = 1
        while (param := _param(reader, f"{MISSING_CAMERAS.upper()}:SPANS{'' if k == 1 else k}")) is not None:
            raw = param.bytes[: len(param.bytes) // 12 * 12]
            values = (c3dlib.c3d.DEC_to_IEEE_BYTES(raw) if reader._dtypes.is_dec
                      else np.frombuffer(raw, reader._dtypes.float32)).reshape(-1, 3)
            for number, first, last in values:
                if not (np.isfinite([number, first, last]).all() and 1 <= number <= len(cameras) and 1 <= first <= last
                        and last - first < 2**31):
                    raise ValueError(f"span {number:g}, {first:g}, {last:g} is not a camera and frame range")
                gaps.append((cameras[int(number) - 1], int(first) - 1, int(last) - 1))
            k += 1
        return missing_from_gaps(gaps)
    except (ValueError, IndexError, TypeError, OverflowError) as exc:
        warnings.warn(f"{path}: the MISSING_CAMERAS group is damaged ({exc}); which cameras were missing is "
                      "not read", ExportWarning, stacklevel=4)
        return {}


def _with_reference(arrays: DenseMarkers, reference: MarkerTable, prefix: str, path: Path
                    ) -> tuple[DenseMarkers, list[str]]:
    """Append reference markers (aligned on frame numbers, NaN where the reference lacks a
    frame) with ``prefix`` on their labels; return the arrays and the new labels' descriptions."""
    ref = dense_mm(reference, path)
    frames = arrays.frames
    F, R = len(frames), len(ref.labels)
    rows = np.searchsorted(ref.frames, frames)
    hit = (rows < len(ref.frames)) & (ref.frames[np.minimum(rows, len(ref.frames) - 1)] == frames)
    joined: dict[str, np.ndarray] = {}
    for key, fill in (("positions", np.nan), ("status", MISSING), ("n_views", 0), ("residual", np.nan)):
        own, theirs = getattr(arrays, key), getattr(ref, key)
        extra = np.full((F, R) + theirs.shape[2:], fill, dtype=theirs.dtype)
        extra[hit] = theirs[rows[hit]]
        joined[key] = np.concatenate([own, extra], axis=1)
    labels = np.concatenate([arrays.labels, [prefix + str(l) for l in ref.labels]])
    return replace(arrays, labels=labels, **joined), [f"reference marker {l}" for l in ref.labels]


def write_c3d(table: MarkerTable, path: str | os.PathLike, units: str = "mm", residual_scale: float = 0.01,
              reference: MarkerTable | None = None, reference_prefix: str = "REF_", subject: str | None = None,
              marker_set: str | None = None) -> Path:
    """Write ``table`` as a C3D file (float data), atomically.

    ``units``: mm or m. ``residual_scale``: px per residual count (|POINT:SCALE|; Nexus uses
    0.01). ``reference``: markers (e.g. ground truth) written alongside, labels prefixed with
    ``reference_prefix``. ``subject``/``marker_set`` default to ``table.meta['subject']`` /
    ``meta['marker_set']``; marker descriptions come from ``meta['descriptions']`` (label -> text).
    """
    return write_c3d_parts([table], path, table.n_frames, units, residual_scale, reference, reference_prefix,
                           subject, marker_set)


@dataclass
class _PointBlock:
    """One part's points as C3D stores them: ``block`` (F, D, 4) float32, its ``frames`` (F,),
    ``labels`` and ``descriptions`` (D,), ``seen`` (D,) markers with a finite sample."""

    block: np.ndarray
    frames: np.ndarray
    labels: list[str]
    descriptions: list[str]
    seen: np.ndarray


def _point_block(table: MarkerTable, factor: float, residual_scale: float, reference: MarkerTable | None,
                 reference_prefix: str, path: Path) -> _PointBlock:
    arrays = dense_mm(table, path)
    given = table.meta.get("descriptions", {}) or {}
    descriptions = [str(given.get(str(l), "")) for l in arrays.labels]
    if reference is not None:
        arrays, ref_descriptions = _with_reference(arrays, reference, reference_prefix, path)
        descriptions += ref_descriptions
    positions = arrays.positions
    finite = np.isfinite(positions).all(axis=2)
    word = encode_fourth_word(arrays.status, arrays.n_views, arrays.residual, finite,
                              residual_scale, path)
    F, D = finite.shape
    block = np.zeros((F, D, 4), np.float32)
    valid = word >= 0
    block[..., :3][valid] = positions[valid] / factor
    block[..., 3] = word
    return _PointBlock(block, arrays.frames, [str(l) for l in arrays.labels], descriptions, finite.any(axis=0))


def write_c3d_parts(parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, units: str = "mm",
                    residual_scale: float = 0.01, reference: MarkerTable | None = None,
                    reference_prefix: str = "REF_", subject: str | None = None,
                    marker_set: str | None = None) -> Path:
    """:func:`write_c3d` of a table given as consecutive ``parts`` (the same labels and meta;
    ``n_frames`` frames in all), one part in memory at a time: the file :func:`write_c3d` writes
    of their concatenation."""
    path = Path(path)
    units = units.lower()
    factor = mm_per_unit(units, path)
    if not 0 < residual_scale:
        raise InputError(path, f"residual_scale must be positive, got {residual_scale}")
    tables = iter(parts)
    head = next(tables, None)
    if head is None:
        raise InputError(path, "marker table has no frames to write")
    first = _point_block(head, factor, residual_scale, reference, reference_prefix, path)
    if len(first.labels) > 32767:
        raise InputError(path, f"{len(first.labels)} markers: C3D holds at most 32767 points")
    seen = first.seen.copy()
    contiguous = [True]

    def blocks() -> Iterator[np.ndarray]:
        expected = int(first.frames[0])
        for k, table in enumerate(itertools.chain([head], tables)):
            part = first if k == 0 else _point_block(table, factor, residual_scale, reference, reference_prefix, path)
            contiguous[0] &= bool(np.array_equal(part.frames, np.arange(expected, expected + len(part.frames))))
            expected += len(part.frames)
            seen[:] |= part.seen
            yield part.block

    fps = frame_rate(head, path)
    writer = _BlockWriter(blocks(), n_frames, len(first.labels), point_rate=fps, point_scale=-float(residual_scale),
                          point_units=units)
    _fill_groups(writer, fit_labels(first.labels, LABEL_WIDTH, path), fit_descriptions(first.descriptions), units,
                 fps, int(first.frames[0]) + 1, str(subject or head.meta.get("subject") or "subject"),
                 str(marker_set or head.meta.get("marker_set") or "spinemocap tape"))
    _fill_missing_cameras(writer, head.meta.get(MISSING_CAMERAS) or {},
                          np.arange(int(first.frames[0]), int(first.frames[0]) + n_frames))
    with atomic_path(path) as tmp, open(tmp, "wb") as handle, warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="No analog data found", module="c3d")
        writer.write(handle)
    warn_unseen(first.labels, seen, path)
    if not contiguous[0]:
        warnings.warn(f"{path}: frames are not contiguous; C3D numbers them consecutively from "
                      f"{int(first.frames[0]) + 1}", ExportWarning, stacklevel=2)
    return path


def fit_descriptions(descriptions: Sequence[str]) -> list[str]:
    """Descriptions as C3D holds them: ASCII, cut to the Nexus width (no uniqueness needed)."""
    return [d.encode("ascii", "replace").decode()[:DESCRIPTION_WIDTH] for d in descriptions]


# ---------------------------------------------------------------------------------- reading
MAX_ABS_OTHER = 1.0e9    # the same for non-marker points (angles, forces, moments ...) in their own units
SATURATED = 65535        # 16-bit frame fields (header, POINT:FRAMES) hold this beyond 65534 frames
PROCESSORS = {84: "Intel", 85: "DEC", 86: "SGI/MIPS"}
PRIMARY_FIELDS = ("POINT:FRAMES", "header first/last frame")


class _Reader(c3dlib.Reader):
    """``c3d.Reader`` used for the header and the parameters only. Its consistency checks are
    asserts that refuse files every other reader opens (header and parameters disagree in many
    real files); :func:`read_c3d` decides between them itself."""

    def _check_metadata(self) -> None:
        pass


def _param(reader: c3dlib.Reader, key: str):
    """The parameter ``GROUP:NAME``, or None when absent or empty."""
    param = reader.get(key)
    return param if param is not None and len(param.bytes) > 0 else None


def _number(reader: c3dlib.Reader, key: str) -> float | None:
    """The first value of a numeric parameter (4-byte elements read as float, 2-byte as unsigned
    16-bit, 1-byte as unsigned 8-bit), or None when absent, empty or of another kind."""
    param = _param(reader, key)
    size = abs(int(param.bytes_per_element)) if param is not None else 0
    if param is None or len(param.bytes) < size:
        return None
    if size == 4:
        return _float32(param.bytes[:4], reader._dtypes)
    if size == 2:
        return int(param.uint16_value)
    return int(param.uint8_value) if size == 1 else None


def _float32(raw: bytes, dtypes) -> float:
    """One 32-bit float in the file's format (the ``c3d`` package's scalar DEC conversion turns
    0 into -1.7e38; its array conversion is right)."""
    if dtypes.is_dec:
        return float(c3dlib.c3d.DEC_to_IEEE_BYTES(raw)[0])
    return float(np.frombuffer(raw, dtypes.float32, count=1)[0])


def _frame_field(reader: c3dlib.Manager, key: str) -> int | None:
    """TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD: a frame number stored as two 16-bit words
    (low, high); one word or a 4-byte element are read too."""
    param = _param(reader, key)
    if param is None:
        return None
    if abs(int(param.bytes_per_element)) == 4 and len(param.bytes) >= 4:
        value = _float32(param.bytes[:4], reader._dtypes)
        return int(value) if np.isfinite(value) and 0 <= value < 2 ** 32 else None
    words = param.uint16_array.ravel() if param.dimensions else [param.uint16_value]
    return int(words[0]) + (65536 * int(words[1]) if len(words) > 1 else 0)


def _strings(reader: c3dlib.Reader, group: str, name: str) -> list[str]:
    """A char-array parameter and its continuations (NAME2, NAME3 ...), entries stripped."""
    out: list[str] = []
    k = 1
    while (param := reader.get(f"{group}:{name}{'' if k == 1 else k}")) is not None:
        values = param.string_array
        out += [str(v).strip() for v in np.ravel(values)] if np.ndim(values) else [str(values).strip()]
        k += 1
    return out


@dataclass(frozen=True)
class C3dLayout:
    """Where the frames of a C3D file lie: per frame ``4 * points`` point words, then
    ``analog_words`` analog samples (all channels); words are 4-byte floats (POINT:SCALE < 0) or
    16-bit integers. Frames run from byte ``data_start`` to at most ``data_end`` (the end of
    the file, or the start of a rotation section)."""

    points: int
    analog_words: int
    word_bytes: int
    data_start: int
    data_end: int

    @property
    def frame_bytes(self) -> int:
        return self.word_bytes * (4 * self.points + self.analog_words)

    @property
    def available(self) -> int:
        """Complete frames the file holds (padding of the last 512-byte block included)."""
        return max(self.data_end - self.data_start, 0) // self.frame_bytes

    def holds_exactly(self, count: int) -> bool:
        """True when ``count`` frames fill the data section up to its 512-byte padding."""
        return count <= self.available and (self.available - count) * self.frame_bytes < 512

    @property
    def ends_cleanly(self) -> bool:
        """True when the data section ends after whole frames and at most its 512-byte padding
        (a file cut inside a frame leaves a partial frame behind)."""
        return 0 <= max(self.data_end - self.data_start, 0) - self.available * self.frame_bytes < 512


@dataclass(frozen=True)
class DeclaredFrames:
    """What one set of C3D fields says about the frames: ``first`` (1-based frame number, None
    when not given) and ``count`` (None when not given or saturated at 65535; then
    ``at_least`` is the lower bound it still implies)."""

    fields: str
    text: str
    first: int | None = None
    count: int | None = None
    at_least: int = 0

    def __str__(self) -> str:
        return f"{self.fields} {self.text}"


def declared_frames(reader: c3dlib.Reader) -> list[DeclaredFrames]:
    """The frame fields of a C3D file, most trusted first: POINT:FRAMES (what ezc3d follows),
    the header's first/last frame, POINT:LONG_FRAMES, TRIAL:ACTUAL_START/END_FIELD."""
    out = []
    frames = _number(reader, "POINT:FRAMES")
    if frames is not None and np.isfinite(frames) and frames >= 1:
        size = abs(int(reader.get("POINT:FRAMES").bytes_per_element))
        saturated = size == 2 and frames == SATURATED
        out.append(DeclaredFrames("POINT:FRAMES", f"= {frames:g}", count=None if saturated else int(frames),
                                  at_least=SATURATED if saturated else 0))
    first, last = int(reader.header.first_frame), int(reader.header.last_frame)
    header = DeclaredFrames(PRIMARY_FIELDS[1], f"{first}..{last}", first=max(first, 1))
    if last == SATURATED:
        header = replace(header, at_least=SATURATED - max(first, 1) + 1)
    elif last >= first and last > 0:        # a first frame of 0: a 0-based writer (ezc3d reads it so too)
        header = replace(header, count=last - first + 1)
    out.append(header)
    long_frames = _number(reader, "POINT:LONG_FRAMES")
    if long_frames is not None and np.isfinite(long_frames) and long_frames >= 1:
        out.append(DeclaredFrames("POINT:LONG_FRAMES", f"= {long_frames:g}", count=int(long_frames)))
    start, end = _frame_field(reader, "TRIAL:ACTUAL_START_FIELD"), _frame_field(reader, "TRIAL:ACTUAL_END_FIELD")
    if start is not None:
        count = end - start + 1 if end is not None and end >= start else None
        out.append(DeclaredFrames("TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD", f"{start}..{end}",
                                  first=start, count=count))
    return out


def _truncated(path: Path, fields: Sequence[DeclaredFrames], count: int, layout: C3dLayout) -> InputError:
    names = ", ".join(str(d) for d in fields)
    return InputError(path, f"truncated C3D: {names} declare{'s' if len(fields) == 1 else ''} {count} frames "
                            f"but the file holds {layout.available}")


def frame_count(declared: Sequence[DeclaredFrames], layout: C3dLayout,
                path: Path) -> tuple[int, list[DeclaredFrames]]:
    """How many frames to read, and the fields that say so.

    When the header and POINT:FRAMES agree, that is the count (the C3D specification; a file
    holding fewer frames is truncated). Otherwise the first field (in the order of
    :func:`declared_frames`) whose count the data fills exactly, else the first the data holds;
    when every field declares more than the file holds, it is truncated, unless no POINT field
    declares a count and the data ends after whole frames: then the header's or TRIAL's range
    is taken as stale and the data decides, as it does without usable fields (saturated 16-bit
    fields, nothing else), as in ezc3d.

    Raises:
        InputError: the file is truncated (names ``path``, the fields and the frames it holds)."""
    given = [d for d in declared if d.count is not None]
    at_least = max((d.at_least for d in declared), default=0)
    primary = [d for d in given if d.fields in PRIMARY_FIELDS]
    if len(primary) == 2 and primary[0].count == primary[1].count:
        count = int(primary[0].count or 0)
        if count > layout.available:
            raise _truncated(path, primary, count, layout)
        return count, primary
    for fits in (layout.holds_exactly, lambda n: n <= layout.available):
        for d in given:
            if d.count is not None and d.count >= at_least and fits(d.count):
                return d.count, [e for e in given if e.count == d.count]
    if _only_frame_range_fields(given) and layout.ends_cleanly and layout.available >= max(at_least, 1):
        # POINT:FRAMES absent and only the header's or TRIAL's frame range claims more: exporters
        # that never update those fields are common, and ezc3d reads the frames the data holds
        return layout.available, []
    if given:
        raise _truncated(path, given[:1], int(given[0].count or 0), layout)
    if at_least > layout.available:
        raise _truncated(path, [d for d in declared if d.at_least][:1], at_least, layout)
    return layout.available, []


def _only_frame_range_fields(given: Sequence[DeclaredFrames]) -> bool:
    """True when no POINT:FRAMES / POINT:LONG_FRAMES count is among ``given``: only the header's
    first/last frame or the TRIAL fields declare how many frames there are."""
    return bool(given) and all(not d.fields.startswith("POINT:") for d in given)


def first_frame(declared: Sequence[DeclaredFrames], chosen: Sequence[DeclaredFrames]) -> int:
    """The 1-based number of the first frame: the header's (as ezc3d), unless it is saturated
    or the count came from the TRIAL fields alone; then TRIAL:ACTUAL_START_FIELD."""
    header = next(d for d in declared if d.fields == PRIMARY_FIELDS[1])
    trial = next((d for d in declared if d.fields.startswith("TRIAL") and d.first is not None), None)
    use_trial = trial is not None and (header.first == SATURATED or (trial in chosen and header not in chosen))
    if use_trial and trial is not None and trial.first is not None:
        return int(trial.first)
    return int(header.first or 1)


def _warn_disagreement(path: Path, declared: Sequence[DeclaredFrames], count: int, first: int,
                       chosen: Sequence[DeclaredFrames], layout: C3dLayout) -> None:
    """Warn (naming the file and the fields) when a field disagrees with the frames read."""
    odd = [d for d in declared if (d.count is not None and d.count != count) or count < d.at_least or
           (d.first is not None and d.first != first and not (d.first == SATURATED and first > SATURATED))]
    if not odd:
        return
    data = ("the data section holds exactly these" if layout.holds_exactly(count) else
            f"the data section has room for {layout.available}")
    basis = f"as {' and '.join(d.fields for d in chosen)} say" if chosen else "as the file's size says"
    warnings.warn(f"{path}: C3D frame fields disagree ({'; '.join(str(d) for d in declared)}): "
                  f"{', '.join(d.fields for d in odd)} do not match. Read {count} frames from frame {first}, "
                  f"{basis}; {data}", ExportWarning, stacklevel=3)


def _layout(reader: c3dlib.Reader, n_points: int, rate: float, scale: float, file_size: int,
            path: Path) -> C3dLayout:
    """The frame layout from the parameters (ANALOG:USED channels x ANALOG:RATE / POINT:RATE
    samples, as ezc3d; the header's samples per frame when the rates are missing)."""
    channels = int(_number(reader, "ANALOG:USED") or 0)
    analog_rate = _number(reader, "ANALOG:RATE")
    if channels and analog_rate is not None and np.isfinite(analog_rate) and analog_rate > 0:
        ratio = analog_rate / rate
        per_frame = round(ratio) if abs(ratio - round(ratio)) < 1e-4 * max(ratio, 1.0) else int(ratio)
    else:
        per_frame = int(reader.header.analog_per_frame)
    data_block = int(reader.header.data_block)
    if data_block < 2:
        data_block = int(_number(reader, "POINT:DATA_START") or 0)
        if data_block < 2:
            raise InputError(path, f"C3D data start block {data_block} is not after the header")
    data_end = file_size
    rotation_block = _number(reader, "ROTATION:DATA_START") if reader.get("ROTATION") is not None else None
    if rotation_block is not None and rotation_block > data_block:
        data_end = min(file_size, 512 * (int(rotation_block) - 1))
    return C3dLayout(n_points, channels * per_frame, 4 if scale < 0 else 2, 512 * (data_block - 1), data_end)


def _decode_points(raw: bytes, layout: C3dLayout, dtypes, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The point words of whole frames: coordinates (F, P, 3) in file units (float64) and the
    fourth word (F, P) as an integer, negative where a sample is invalid. Float data: a negative
    (sign bit set, as ezc3d reads it) or non-finite fourth word is invalid; integer data: the
    16-bit word is negative."""
    F, P = len(raw) // layout.frame_bytes, layout.points
    words = layout.frame_bytes // layout.word_bytes
    if layout.word_bytes == 4:
        values = c3dlib.c3d.DEC_to_IEEE_BYTES(raw) if dtypes.is_dec else np.frombuffer(raw, dtypes.float32)
        with np.errstate(invalid="ignore"):     # signalling NaNs in damaged files; validated later
            block = values.reshape(F, words)[:, :4 * P].reshape(F, P, 4).astype(np.float64)
        fourth = block[..., 3]
        bad = np.signbit(fourth) | ~np.isfinite(fourth) | (fourth >= 2.0 ** 31)
        word = np.where(bad, -1, np.trunc(np.where(bad, 0.0, fourth))).astype(np.int64)
        return block[..., :3], word
    ints = np.frombuffer(raw, dtypes.int16).reshape(F, words)[:, :4 * P].reshape(F, P, 4)
    return ints[..., :3].astype(np.float64) * abs(scale), ints[..., 3].astype(np.int64)


def _header_float(reader: c3dlib.Reader, offset: int) -> float:
    """The float at byte ``offset`` of the header (12: scale factor, 20: frame rate)."""
    reader._handle.seek(offset)
    return _float32(reader._handle.read(4), reader._dtypes)


def _point_scale(reader: c3dlib.Reader) -> float:
    """POINT:SCALE (negative: float data), else the header's scale factor."""
    scale = _number(reader, "POINT:SCALE")
    return _header_float(reader, 12) if scale is None else scale


def _point_rate(reader: c3dlib.Reader, path: Path) -> float:
    """POINT:RATE (Hz), else the header's rate; InputError when neither is positive and finite."""
    for source, rate in (("POINT:RATE", _number(reader, "POINT:RATE")),
                         ("header frame rate", _header_float(reader, 20))):
        if rate is not None and np.isfinite(rate) and rate > 0:
            if source != "POINT:RATE":
                warnings.warn(f"{path}: POINT:RATE missing or not positive; using the {source} {rate:g} Hz",
                              ExportWarning, stacklevel=4)
            return float(rate)
    raise InputError(path, "C3D frame rate unknown: POINT:RATE and the header rate are not positive numbers")


def _open_reader(handle, path: Path) -> c3dlib.Reader:
    """Header and parameters; InputError for anything that is not a C3D file of a known processor."""
    head = handle.read(512)
    if len(head) < 512 or head[1] != 0x50:
        raise InputError(path, "not a C3D file (no C3D header: too short or wrong key byte)")
    handle.seek(512 * (max(head[0], 1) - 1) + 3)
    processor = handle.read(1)
    if not processor or processor[0] not in PROCESSORS:
        raise InputError(path, f"not a readable C3D file: the parameter section (block {head[0]}) names processor "
                               f"type {processor[0] if processor else None}, none of {PROCESSORS}")
    handle.seek(0)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # the c3d package's remarks on missing optional parameters
            return _Reader(handle)
    except Exception as exc:  # struct.error, KeyError (a parameter twice), ValueError ...
        raise InputError(path, f"not a readable C3D file: damaged or cut parameter section "
                               f"({type(exc).__name__}: {exc})") from exc


def read_c3d(path: str | os.PathLike) -> MarkerTable:
    """Read the 3D points of a C3D file into a :class:`MarkerTable` (mm, frames 0-based:
    C3D frame 1 is frame 0).

    Any file ezc3d reads: integer or float data, Intel, DEC or SGI/MIPS processor, analog
    channels and rotation sections beside the points, more than 65535 frames. The frame range
    follows :func:`frame_count` / :func:`first_frame`; when the header, POINT:FRAMES and the
    TRIAL fields disagree the file's data decides and an :class:`ExportWarning` names the fields.
    Invalid samples are NaN/``missing``; samples with non-finite or absurd coordinates (beyond
    ``MAX_ABS_MM``) too, with a warning saying how many. See the module docstring for status,
    n_views and residual. Non-marker points (Vicon angles, forces ...) are read in their own
    units, unconverted; ``meta['point_types']`` names them. A file without 3D points (analog or
    rotation data only) is an :class:`InputError`."""
    path = Path(path)
    try:
        handle = open(path, "rb")  # noqa: SIM115 (closed by the with below; only open's error is caught here)
    except OSError as exc:
        raise InputError(path, f"cannot open: {exc}") from exc
    with handle:
        try:
            reader = _open_reader(handle, path)
            used = _number(reader, "POINT:USED")
            n_points = int(reader.header.point_count if used is None else used)
            if n_points == 0:
                raise InputError(path, f"C3D file holds no 3D points (POINT:USED = 0){_other_data(reader)}")
            rate = _point_rate(reader, path)
            scale = _point_scale(reader)
            layout = _layout(reader, n_points, rate, scale, os.fstat(handle.fileno()).st_size, path)
            declared = declared_frames(reader)
            count, chosen = frame_count(declared, layout, path)
            if count == 0:
                raise InputError(path, "C3D file holds no frames")
            first = first_frame(declared, chosen)
            _warn_disagreement(path, declared, count, first, chosen, layout)
            handle.seek(layout.data_start)
            xyz, word = _decode_points(handle.read(count * layout.frame_bytes), layout, reader._dtypes, scale)
            return _table_from_reader(reader, xyz, word, abs(scale), rate, first, path)
        except InputError:
            raise
        except Exception as exc:  # struct.error, ValueError, KeyError ... from a damaged file
            raise InputError(path, f"not a readable C3D file ({type(exc).__name__}: {exc})") from exc


def _other_data(reader: c3dlib.Reader) -> str:
    """What a file without 3D points holds instead, for the error message."""
    held = [f"{int(_number(reader, key) or 0)} {what}" for key, what in
            (("ANALOG:USED", "analog channels"), ("ROTATION:USED", "rotations")) if _number(reader, key)]
    return f"; it holds {' and '.join(held)} only" if held else ""


def _mark_implausible(positions: np.ndarray, invalid: np.ndarray, is_marker: np.ndarray, path: Path) -> None:
    """Samples with non-finite coordinates or beyond ``MAX_ABS_MM`` (markers, in mm) /
    ``MAX_ABS_OTHER`` (other points) become invalid (in place), with a warning saying how many."""
    bound = np.where(is_marker, MAX_ABS_MM, MAX_ABS_OTHER)[None, :]
    with np.errstate(invalid="ignore"):
        absurd = ~invalid & ~(np.abs(positions).max(axis=2, initial=0.0) <= bound)
    if absurd.any():
        warnings.warn(f"{path}: {int(absurd.sum())} of {absurd.size} C3D samples have non-finite or absurd "
                      f"coordinates (beyond {MAX_ABS_MM:g} mm for markers); read as missing",
                      ExportWarning, stacklevel=4)
        invalid |= absurd


def _table_from_reader(reader: c3dlib.Reader, xyz: np.ndarray, word: np.ndarray, scale: float, fps: float,
                       first: int, path: Path) -> MarkerTable:
    """The marker table from decoded point words (see :func:`_decode_points`); ``first`` is the
    1-based number of the first frame, ``scale`` |POINT:SCALE| (residual units per count)."""
    n_frames, n_points = word.shape
    labels = _strings(reader, "POINT", "LABELS")
    if len(labels) < n_points:
        warnings.warn(f"{path}: POINT:LABELS names {len(labels)} of {n_points} points; the rest are "
                      f"called POINT_<n>", ExportWarning, stacklevel=3)
        labels += [f"POINT_{i + 1}" for i in range(len(labels), n_points)]
    labels = deduplicate_labels(labels[:n_points], path)
    units_param = reader.get("POINT:UNITS")
    units = units_param.string_value.strip() if units_param is not None and units_param.bytes else "mm"
    factor = mm_per_unit(units or "mm", path)
    point_types = {label: kind for group, kind in NON_MARKER_LISTS.items()
                   for label in _strings(reader, "POINT", group) if label in labels}
    is_marker = np.array([label not in point_types for label in labels])

    invalid = word < 0
    positions = xyz.copy()
    positions[:, is_marker] *= factor
    _mark_implausible(positions, invalid, is_marker, path)
    positions[invalid] = np.nan
    residual = np.where(invalid, np.nan, (word & 0xFF) * scale)
    cameras = (word >> 8) & 0x7F
    n_views = np.where(invalid, 0, np.array([c.bit_count() for c in range(128)])[cameras])
    status = np.where(invalid, MISSING, np.where((word & 0xFF) == 0, INFERRED, OBSERVED))
    warn_empty_markers([l for l, m in zip(labels, is_marker) if m], positions[:, is_marker], path)

    frames = np.arange(first - 1, first - 1 + n_frames)
    subject = _strings(reader, "SUBJECTS", "NAMES")
    software = _strings(reader, "MANUFACTURER", "SOFTWARE")
    meta = {"fps": fps, "source": str(path), "file_units": units, "point_types": point_types,
            "subject": subject[0] if subject else None,
            "software": software[0] if software else None,
            "processor": PROCESSORS.get(int(reader._dtypes._proc_type)),
            "descriptions": {l: d for l, d in zip(labels, _strings(reader, "POINT", "DESCRIPTIONS")) if d}}
    missing = _read_missing_cameras(reader, path)
    if missing:
        meta[MISSING_CAMERAS] = missing
    return table_from_dense(labels, frames, frames / fps, positions, meta, status=status, n_views=n_views,
                            residual=residual)


class C3dExporter(Exporter):
    name = "c3d"
    extensions = (".c3d",)
    options = tuple(inspect.signature(write_c3d).parameters)[2:]
    description = "C3D (Vicon Nexus, Mokka, Visual3D ...): float points, residuals, camera masks"

    def write(self, table: MarkerTable, path: str | os.PathLike, **options) -> Path:
        return write_c3d(table, path, **options)

    def write_parts(self, parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, **options) -> Path:
        return write_c3d_parts(parts, path, n_frames, **options)

    def read(self, path: str | os.PathLike) -> MarkerTable:
        return read_c3d(path)
