"""The marker table: labelled 3D marker trajectories in long form, with pandas at its heart.

One row per (frame, label): ``frame`` (int, 0-based), ``time`` (s), ``label`` (str), ``x, y, z``
(mm, world frame, Z up; NaN when missing), ``status`` (``observed`` | ``inferred`` |
``missing``), ``n_views`` (cameras that saw the marker), ``residual`` (mean reprojection error in
px for tracked data; for imported C3D data the file's residual; NaN when unknown).
Quality columns (optional on input, NaN when unknown; written by the CSV/Parquet exporters, not
by C3D/TRC which have no place for them): ``confidence`` (0..1, how sure the tracker is of the
label, see :mod:`spinemocap.track.quality`) and ``stretch`` (the tape's measured row pitch at
the dot over the roll's spec, 1 = as specified).

Metadata travels in :attr:`MarkerTable.meta` (``fps``, ``units``, ``subject``, ``source`` ...).
``meta['missing_cameras']`` (camera name -> the frames it had no image for, see
:data:`MISSING_CAMERAS`) is written by every built-in format in its own way: a
``missing_cameras`` column in CSV/Parquet, a ``MissingCameras`` header field in TRC, a
``MISSING_CAMERAS`` parameter group in C3D (:func:`camera_gaps` gives the spans they store).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Iterable, Literal, Mapping, Sequence
from urllib.parse import unquote

import numpy as np
import pandas as pd

from .fileio import InputError

#: A marker's status in a frame (the strings stored in every marker file): ``observed`` (seen by the
#: cameras), ``inferred`` (placed by the tape model or filled in time), ``missing`` (no position).
MarkerStatus = Literal["observed", "inferred", "missing"]
OBSERVED: Final = "observed"
INFERRED: Final = "inferred"
MISSING: Final = "missing"
STATUSES: tuple[MarkerStatus, ...] = (OBSERVED, INFERRED, MISSING)
MAX_ABS_MM = 1.0e6      # a marker more than 1 km from the lab origin is a damaged sample, not data
MAX_FRAME = 2**31 - 1   # frame numbers beyond this are damaged values (C3D and TRC count in 32 bits at most)
COLUMNS = ("frame", "time", "label", "x", "y", "z", "status", "n_views", "residual")
QUALITY_COLUMNS = ("confidence", "stretch")
ALL_COLUMNS = COLUMNS + QUALITY_COLUMNS
#: ``meta`` key: camera name -> sorted frame numbers (the table's) in which that camera had no
#: image (a recording that ends early or starts late, a damaged or missing frame); the dots of
#: those frames were triangulated from the other cameras
MISSING_CAMERAS = "missing_cameras"
#: separator of the camera names in one frame's ``missing_cameras`` field (CSV/Parquet)
CAMERA_SEPARATOR = ";"


def camera_gaps(missing: Mapping[str, Iterable[int]], frames: Iterable[int] | None = None
                ) -> list[tuple[str, int, int]]:
    """``(camera, first, last)`` runs of consecutive frames (inclusive) in which each camera of
    ``missing`` (camera -> frame numbers) had no image, by camera then first frame; ``frames``:
    only those frames count (None: all)."""
    kept = None if frames is None else {int(f) for f in frames}
    out: list[tuple[str, int, int]] = []
    for camera in sorted(missing):
        numbers = sorted({int(f) for f in missing[camera] if kept is None or int(f) in kept})
        for k, frame in enumerate(numbers):
            if k and frame == numbers[k - 1] + 1:
                out[-1] = (camera, out[-1][1], frame)
            else:
                out.append((camera, frame, frame))
    return out


def missing_from_gaps(gaps: Iterable[tuple[str, int, int]]) -> dict[str, list[int]]:
    """:func:`camera_gaps` back into camera -> sorted frame numbers."""
    out: dict[str, set[int]] = {}
    for camera, first, last in gaps:
        out.setdefault(str(camera), set()).update(range(int(first), int(last) + 1))
    return {camera: sorted(frames) for camera, frames in sorted(out.items())}


def missing_per_frame(missing: Mapping[str, Iterable[int]], frames: Sequence[int]) -> list[str]:
    """For each of ``frames``, the cameras that had no image in it, joined by
    :data:`CAMERA_SEPARATOR` (``""``: none; a ``%`` or ``;`` in a name written as ``%25``, ``%3B``)."""
    where: dict[int, list[str]] = {}
    for camera in sorted(missing):
        for frame in missing[camera]:
            where.setdefault(int(frame), []).append(camera.replace("%", "%25").replace(CAMERA_SEPARATOR, "%3B"))
    return [CAMERA_SEPARATOR.join(where.get(int(f), [])) for f in frames]


def missing_from_frames(frames: Sequence[int], fields: Sequence[object]) -> dict[str, list[int]]:
    """:func:`missing_per_frame` read back: frame numbers and their fields (empty, NaN or None:
    no camera missing) -> camera -> sorted frame numbers."""
    out: dict[str, set[int]] = {}
    for frame, text in zip(frames, fields):
        if isinstance(text, str) and text:
            for camera in text.split(CAMERA_SEPARATOR):
                if camera:
                    out.setdefault(unquote(camera), set()).add(int(frame))
    return {camera: sorted(numbers) for camera, numbers in sorted(out.items())}


@dataclass(frozen=True)
class DenseMarkers:
    """A marker table as dense arrays over its F frames and D labels: ``frames`` (F,) int,
    ``time`` (F,) s, ``labels`` (D,) str, ``positions`` (F, D, 3) mm (NaN where missing),
    ``status`` (F, D) str (:data:`MarkerStatus`; ``missing`` where the table has no row),
    ``n_views`` (F, D) int (0 where no row), ``residual``, ``confidence`` and ``stretch`` (F, D)
    (NaN where unknown; see the module docstring for their meaning)."""

    frames: np.ndarray
    time: np.ndarray
    labels: np.ndarray
    positions: np.ndarray
    status: np.ndarray
    n_views: np.ndarray
    residual: np.ndarray
    confidence: np.ndarray
    stretch: np.ndarray


@dataclass
class MarkerTable:
    """Long-form marker table. Build with :meth:`from_arrays`; read back with :meth:`to_arrays`."""

    data: pd.DataFrame
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.meta.setdefault("units", "mm")
        self.data = self._normalise(self.data, self.meta.get("source"))

    # ------------------------------------------------------------------ validation
    @staticmethod
    def _normalise(df: pd.DataFrame, source: str | None) -> pd.DataFrame:
        missing = [c for c in COLUMNS if c not in df.columns]
        if missing:
            raise InputError(source, f"marker table lacks columns {missing}")
        df = df.copy()
        for c in QUALITY_COLUMNS:
            if c not in df.columns:
                df[c] = np.nan
        df = df.loc[:, list(ALL_COLUMNS)]
        frames = pd.to_numeric(df["frame"], errors="coerce")
        if frames.isna().any() or not (frames.abs() <= MAX_FRAME).all() or not (frames == frames.round()).all():
            raise InputError(source, f"frame numbers must be whole numbers within +-{MAX_FRAME}")
        df["frame"] = frames.astype(np.int64)
        df["label"] = df["label"].astype(str)
        for c in ("time", "x", "y", "z", "residual", *QUALITY_COLUMNS):
            df[c] = pd.to_numeric(df[c], errors="raise").astype(float)
        df["n_views"] = pd.to_numeric(df["n_views"]).fillna(0).astype(np.int64)
        bad = set(df["status"].astype(str)) - set(STATUSES)
        if bad:
            raise InputError(source, f"unknown marker status {sorted(bad)}; expected {STATUSES}")
        df["status"] = pd.Categorical(df["status"].astype(str), categories=STATUSES)
        if df.duplicated(["frame", "label"]).any():
            dup = df.loc[df.duplicated(["frame", "label"]), ["frame", "label"]].iloc[0]
            raise InputError(source, f"duplicate row for frame {dup['frame']} label {dup['label']}")
        return df.sort_values(["frame", "label"], kind="stable").reset_index(drop=True)

    # ------------------------------------------------------------------ array views
    @classmethod
    def from_arrays(
        cls,
        labels: Sequence[str],
        positions_mm: np.ndarray,
        fps: float,
        status: np.ndarray | None = None,
        n_views: np.ndarray | None = None,
        residual: np.ndarray | None = None,
        first_frame: int = 0,
        meta: dict | None = None,
        confidence: np.ndarray | None = None,
        stretch: np.ndarray | None = None,
    ) -> "MarkerTable":
        """Build from (F, D, 3) positions; ``status`` (F, D) of str (default: observed where
        finite, missing elsewhere), ``n_views`` (F, D) int, ``residual`` (F, D) px,
        ``confidence`` (F, D) 0..1 and ``stretch`` (F, D) ratio to the tape spec (NaN: unknown)."""
        positions_mm = np.asarray(positions_mm, float)
        F, D = positions_mm.shape[:2]
        if len(labels) != D:
            raise ValueError(f"{len(labels)} labels for {D} markers")
        finite = np.isfinite(positions_mm).all(axis=2)
        if status is None:
            status = np.where(finite, OBSERVED, MISSING)
        status = np.where(finite, np.asarray(status, dtype=object), MISSING)
        frames = np.repeat(np.arange(F) + first_frame, D)
        df = pd.DataFrame(
            {
                "frame": frames,
                "time": frames / float(fps),
                "label": np.tile(np.asarray(labels, dtype=object), F),
                "x": positions_mm[..., 0].ravel(),
                "y": positions_mm[..., 1].ravel(),
                "z": positions_mm[..., 2].ravel(),
                "status": status.ravel(),
                "n_views": (np.zeros((F, D), int) if n_views is None else np.asarray(n_views)).ravel(),
                "residual": (np.full((F, D), np.nan) if residual is None else np.asarray(residual, float)).ravel(),
                "confidence": (np.full((F, D), np.nan) if confidence is None else np.asarray(confidence, float)).ravel(),
                "stretch": (np.full((F, D), np.nan) if stretch is None else np.asarray(stretch, float)).ravel(),
            }
        )
        meta = dict(meta or {})
        meta["fps"] = float(fps)
        meta.setdefault("labels", list(labels))
        return cls(df, meta)

    @property
    def fps(self) -> float:
        if "fps" in self.meta:
            return float(self.meta["fps"])
        frames = self.frames
        if len(frames) > 1:
            times = self.data.groupby("frame")["time"].first()
            return float((frames[-1] - frames[0]) / (times.iloc[-1] - times.iloc[0]))
        raise ValueError("frame rate unknown")

    @property
    def labels(self) -> list[str]:
        """Marker labels in their declared order (``meta['labels']``) or first-seen order."""
        declared = self.meta.get("labels")
        present = list(pd.unique(self.data["label"]))
        if declared and set(declared) == set(present):
            return list(declared)
        return present

    @property
    def frames(self) -> np.ndarray:
        return np.unique(self.data["frame"].to_numpy())

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    def to_arrays(self) -> DenseMarkers:
        """The table as :class:`DenseMarkers` (frames present in the table, labels in :attr:`labels`
        order)."""
        labels = self.labels
        frames = self.frames
        fi = np.searchsorted(frames, self.data["frame"].to_numpy())
        li = pd.Index(labels).get_indexer(self.data["label"])
        F, D = len(frames), len(labels)

        def grid(column: str) -> np.ndarray:
            values = np.full((F, D), np.nan)
            values[fi, li] = self.data[column].to_numpy()
            return values

        pos = np.full((F, D, 3), np.nan)
        pos[fi, li] = self.data[["x", "y", "z"]].to_numpy()
        status = np.full((F, D), MISSING, dtype=object)
        status[fi, li] = self.data["status"].astype(str).to_numpy()
        n_views = np.zeros((F, D), np.int64)
        n_views[fi, li] = self.data["n_views"].to_numpy()
        time = np.full(F, np.nan)
        time[fi] = self.data["time"].to_numpy()
        return DenseMarkers(frames=frames, time=time, labels=np.array(labels), positions=pos, status=status,
                            n_views=n_views, residual=grid("residual"), confidence=grid("confidence"),
                            stretch=grid("stretch"))

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """``(frames (F,), positions (F, D, 3) mm)`` over every frame from the first to the last
        (a frame absent from the table is a NaN row), labels in :attr:`labels` order."""
        arrays = self.to_arrays()
        frames = np.asarray(arrays.frames, int)
        if not len(frames):
            return frames, np.zeros((0, len(arrays.labels), 3))
        points = np.full((frames[-1] - frames[0] + 1, len(arrays.labels), 3), np.nan)
        points[frames - frames[0]] = arrays.positions
        return np.arange(frames[0], frames[-1] + 1), points

    def positions(self) -> np.ndarray:
        """(F, D, 3) positions in mm, NaN where missing, labels in :attr:`labels` order."""
        return self.to_arrays().positions

    def select(self, labels: Sequence[str] | None = None, frames: Sequence[int] | None = None) -> "MarkerTable":
        df = self.data
        if labels is not None:
            df = df[df["label"].isin(labels)]
        if frames is not None:
            df = df[df["frame"].isin(frames)]
        meta = dict(self.meta)
        if labels is not None:
            meta["labels"] = [l for l in self.labels if l in set(labels)]
        return MarkerTable(df, meta)

    def problems(self, max_abs_mm: float = MAX_ABS_MM) -> list[str]:
        """Why this table is not valid data (empty list: it is). See :func:`marker_table_problems`."""
        return marker_table_problems(self, max_abs_mm)

    def validate(self, source: str | None = None, max_abs_mm: float = MAX_ABS_MM) -> "MarkerTable":
        """Raise :class:`InputError` naming ``source`` (default ``meta['source']``) with every
        problem of :meth:`problems`; return the table when it has none."""
        found = self.problems(max_abs_mm)
        if found:
            raise InputError(source or self.meta.get("source"), "invalid marker data: " + "; ".join(found))
        return self

    def completeness(self) -> dict[str, float]:
        """Share of marker-frames per status (0..1)."""
        counts = self.data["status"].value_counts(normalize=True)
        return {s: float(counts.get(s, 0.0)) for s in STATUSES}


def marker_table_problems(table: MarkerTable, max_abs_mm: float = MAX_ABS_MM) -> list[str]:
    """The one check of marker data: finite frame rate > 0, finite times, coordinates finite and
    within ``max_abs_mm`` (in mm; ``meta['units']`` converted; points listed in
    ``meta['point_types']`` are exempt from the bound) wherever the status is not ``missing``,
    NaN wherever it is, non-negative view counts, residuals NaN or finite >= 0."""
    out = []
    data = table.data
    fps = table.meta.get("fps")
    if not isinstance(fps, (int, float, np.number)) or isinstance(fps, bool) or not np.isfinite(fps) or fps <= 0:
        out.append(f"frame rate {fps!r} must be a finite positive number")
    if not np.isfinite(data["time"].to_numpy()).all():
        out.append("non-finite times")
    scale = {"mm": 1.0, "cm": 10.0, "m": 1000.0}.get(str(table.meta.get("units", "mm")), 1.0)
    xyz = data[["x", "y", "z"]].to_numpy() * scale
    missing = (data["status"] == MISSING).to_numpy()
    others = set(table.meta.get("point_types") or {})
    bounded = ~data["label"].isin(others).to_numpy() if others else np.ones(len(data), bool)
    with np.errstate(invalid="ignore"):
        bad = ~missing & (~np.isfinite(xyz).all(axis=1) | (bounded & (np.abs(xyz) > max_abs_mm).any(axis=1)))
    if bad.any():
        out.append(f"{int(bad.sum())} samples not missing with non-finite coordinates or beyond {max_abs_mm:g} mm")
    if not np.isnan(xyz[missing]).all():
        out.append(f"{int((~np.isnan(xyz[missing])).any(axis=1).sum())} missing samples with coordinates")
    if (data["n_views"].to_numpy() < 0).any():
        out.append("negative view counts")
    residual = data["residual"].to_numpy()
    with np.errstate(invalid="ignore"):
        if not (np.isnan(residual) | (np.isfinite(residual) & (residual >= 0))).all():
            out.append("residuals neither NaN nor finite and >= 0")
    return out
