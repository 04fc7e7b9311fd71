"""Spine angles per frame from a labelled tape marker table.

Pipeline: markers -> row centres (``curve.row_tracks``) -> per-frame midline spline
(``curve.fit_midline``) -> segment frames at vertebral levels (``frames``) -> angles.

All angles in degrees, columns of :attr:`SpineAngles.table`:

- ``lumbar_flexion``, ``lumbar_lateral``, ``lumbar_rotation``: the frame at the upper lumbar
  level (default ``T12/L1``) relative to the frame at the lower one (default ``S1``), Cardan
  sequence of :func:`frames.cardan_angles`: flexion = sagittal angle between the two curve
  tangents, **positive = forward bending** (a standing lordotic lumbar spine reads negative);
  lateral bending positive toward the subject's right; axial rotation = twist of the tape's
  transverse axis between the levels, positive toward the subject's left (counter-clockwise
  seen from above). This is the relative lumbar angle IMU systems report from sensors at T12
  and S2, but measured on the skin curve itself.
- ``thoracic_*``: the same between ``T12/L1`` and the upper thoracic level (default: the most
  cranial level of the subject's level map, e.g. ``T7``).
- ``lordosis``, ``kyphosis``: curvature-based angles from the inflection tangent. In the lower
  level's sagittal plane the tangent's flexion angle theta(v) falls through the lordotic part
  and rises through the kyphotic part; the inflection is where it is smallest. lordosis =
  theta(lower) - theta(inflection), kyphosis = theta(upper thoracic) - theta(inflection), both
  positive for the normal curves, over the part of the spine the tape covers. NaN when the
  inflection is not inside the tape (e.g. a fully flexed lumbar spine has no lordosis).
- ``pelvis_tilt``, ``pelvis_obliquity``, ``pelvis_rotation``: the pelvis frame relative to the
  subject's neutral frame (``up``/``facing``), same Cardan sequence (tilt positive = anterior).

NaN marks frames the data cannot support; the ``*_note`` columns say why (rows not seen near a
level, a level the map does not reach, ...). :attr:`SpineAngles.notes` counts them per group.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..markers import OBSERVED, MarkerTable
from ..tape import TapeSpec
from .curve import MIN_ROWS, MidlineCurve, RowTracks, fit_midline, row_tracks
from .frames import cardan_angles, check_facing, frame_from_axes, neutral_frame, pelvis_frame_from_tape
from .levels import LevelMap, vertebra_index

ANGLE_GROUPS = {
    "lumbar": ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation"),
    "thoracic": ("thoracic_flexion", "thoracic_lateral", "thoracic_rotation"),
    "curvature": ("lordosis", "kyphosis"),
    "pelvis": ("pelvis_tilt", "pelvis_obliquity", "pelvis_rotation"),
}
ANGLE_COLUMNS = tuple(c for cols in ANGLE_GROUPS.values() for c in cols)


@dataclass(frozen=True)
class AngleSettings:
    """Which levels bound the lumbar and thoracic angles, and how hard the data must be.

    ``max_gap_s``: row-centre gaps up to this long are bridged in time; ``level_reach_rows``: a
    level's tangent needs an observed row centre within this many row pitches of it (and at
    least two within 1.5 pitches) -- beyond that the spline would only guess.
    ``smoothing``: the midline spline's roughness penalty (None = interpolating spline);
    ``lowpass_hz``: cut-off of the zero-lag low-pass on row tracks (None = no filter).
    """

    lower: str = "S1"
    thoracolumbar: str = "T12/L1"
    upper: str | None = None  # None: the most cranial level in the level map
    max_gap_s: float = 0.1
    level_reach_rows: float = 1.0
    smoothing: float | None = None
    lowpass_hz: float | None = 10.0


@dataclass
class SpineAngles:
    """Per-frame angles (``table``: frame, time, angle columns, ``*_note`` columns, ``rows_seen``,
    ``curve_length_mm``) and the reasons for NaN counted per group (``notes``)."""

    table: pd.DataFrame
    notes: dict[str, dict[str, int]] = field(default_factory=dict)
    completeness: float = float("nan")

    def summary(self) -> dict[str, float]:
        """Peaks and ranges (deg) of the main angles: ``<angle>_max``, ``_min``, ``_rom``."""
        out: dict[str, float] = {}
        for col in ANGLE_COLUMNS:
            values = self.table[col].to_numpy(float)
            finite = values[np.isfinite(values)]
            out[f"{col}_max"] = float(finite.max()) if finite.size else float("nan")
            out[f"{col}_min"] = float(finite.min()) if finite.size else float("nan")
            out[f"{col}_rom"] = float(np.ptp(finite)) if finite.size else float("nan")
            out[f"{col}_valid"] = float(finite.size / max(len(values), 1))
        return out


class _LevelFrames:
    """Segment frames of one level over all frames, with a note where unsupported."""

    def __init__(self, n_frames: int):
        self.frames = np.full((n_frames, 3, 3), np.nan)
        self.notes = np.full(n_frames, "", dtype=object)


def compute_angles(markers: MarkerTable, tape: TapeSpec, levels: LevelMap,
                   up: npt.ArrayLike = (0.0, 0.0, 1.0), facing: npt.ArrayLike = (0.0, -1.0, 0.0),
                   settings: AngleSettings = AngleSettings(),
                   pelvis_frames: np.ndarray | None = None) -> SpineAngles:
    """Angles for every frame of ``markers`` (labels per :mod:`spinemocap.tape`).

    ``up``/``facing``: the subject's world directions in the first frame (capture.toml
    ``[subject]``); ``pelvis_frames``: optional (F, 3, 3) pelvis frames from Vicon markers
    (:func:`frames.pelvis_frame_from_markers`) aligned to the marker table's frames; without
    them the pelvis comes from the tape's lowest level.
    """
    if settings.upper is None:
        settings = replace(settings, upper=list(levels.rows)[-1])
    arrays = markers.to_arrays()
    F = len(arrays.frames)
    rows, curves = midlines(markers, tape, settings)

    level_v, missing_level = _level_positions(levels, tape, settings)
    names = level_roles(settings, levels)
    at = {role: _frames_at_level(rows, curves, v, settings, names[role]) for role, v in level_v.items()}

    table = pd.DataFrame({"frame": arrays.frames, "time": arrays.time})
    notes: dict[str, dict[str, int]] = {}

    def put(group: str, values: np.ndarray, note: np.ndarray) -> None:
        for k, col in enumerate(ANGLE_GROUPS[group]):
            table[col] = values[:, k]
        table[f"{group}_note"] = note
        notes[group] = dict(Counter(n for n in note if n))

    for group, (lo, hi) in {"lumbar": ("lower", "thoracolumbar"),
                            "thoracic": ("thoracolumbar", "upper")}.items():
        values, note = _relative(at, missing_level, lo, hi, F)
        put(group, values, note)
    put("curvature", *_curvature(at, curves, level_v, missing_level, settings, F))
    put("pelvis", *_pelvis(at, missing_level, settings, up, facing, pelvis_frames, F, markers.meta.get("source")))

    table["rows_seen"] = rows.observed.sum(axis=1)
    table["curve_length_mm"] = [c.length_mm if c is not None else np.nan for c in curves]
    status = arrays.status
    return SpineAngles(table=table, notes=notes, completeness=float(np.mean(status == OBSERVED)))


def midlines(markers: MarkerTable, tape: TapeSpec,
             settings: AngleSettings = AngleSettings()) -> tuple[RowTracks, list[MidlineCurve | None]]:
    """Row tracks and the per-frame midline curves (None where too few rows were seen) of a
    marker table: the first two steps of :func:`compute_angles`."""
    arrays = markers.to_arrays()
    rows = row_tracks(arrays.positions, list(arrays.labels), tape, markers.fps,
                      settings.max_gap_s, settings.lowpass_hz)
    curves = [fit_midline(rows.v, rows.centre[f], rows.v[-1], settings.smoothing) for f in range(rows.n_frames)]
    return rows, curves


def level_frames(markers: MarkerTable, tape: TapeSpec, levels: LevelMap, names: list[str],
                 settings: AngleSettings = AngleSettings()) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Segment frames (F, 3, 3) (columns a, s, r in world coordinates, see :mod:`frames`) at
    each vertebral level in ``names`` with the reason per frame where a frame is NaN (F,):
    ``{level: (frames, notes)}``. A level the map does not place gets all-NaN frames and its
    reason. Used for segmental angles and to validate angles against a known motion."""
    rows, curves = midlines(markers, tape, settings)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        try:
            v = levels.v_of(name, tape.row_pitch_mm)
        except KeyError as exc:
            out[name] = (np.full((rows.n_frames, 3, 3), np.nan), np.full(rows.n_frames, exc.args[0], dtype=object))
            continue
        at = _frames_at_level(rows, curves, v, settings, name)
        out[name] = (at.frames, at.notes)
    return out


def level_roles(settings: AngleSettings, levels: LevelMap) -> dict[str, str]:
    """The level named for each role (``lower``, ``thoracolumbar``, ``upper``); an unset
    ``upper`` is the most cranial level in ``levels``."""
    upper = settings.upper if settings.upper is not None else list(levels.rows)[-1]
    return {"lower": settings.lower, "thoracolumbar": settings.thoracolumbar, "upper": upper}


def _level_positions(levels: LevelMap, tape: TapeSpec, settings: AngleSettings) -> tuple[dict[str, float], dict[str, str]]:
    """Rest positions (mm) of the levels by role (lower, thoracolumbar, upper), and a reason
    for each role whose level the map does not place."""
    found, missing = {}, {}
    for role, name in level_roles(settings, levels).items():
        try:
            found[role] = levels.v_of(name, tape.row_pitch_mm)
        except KeyError as exc:
            missing[role] = exc.args[0]
    for low, high in (("lower", "thoracolumbar"), ("thoracolumbar", "upper")):
        a, b = level_roles(settings, levels)[low], level_roles(settings, levels)[high]
        if high not in missing and vertebra_index(b) >= vertebra_index(a):
            missing[high] = f"the level map names no level above {a}" if high == "upper" else \
                f"{b} is not above {a}"
            found.pop(high, None)
    return found, missing


def _frames_at_level(rows: RowTracks, curves: list[MidlineCurve | None], v: float,
                     settings: AngleSettings, name: str) -> _LevelFrames:
    pitch = float(np.diff(rows.v).mean()) if len(rows.v) > 1 else 1.0
    out = _LevelFrames(rows.n_frames)
    dist = np.abs(rows.v - v)
    reach = settings.level_reach_rows * pitch + 1e-6
    for f, curve in enumerate(curves):
        seen = np.isfinite(rows.centre[f]).all(axis=1)
        if curve is None:
            out.notes[f] = f"fewer than {MIN_ROWS} tape rows seen"
            continue
        if not (seen & (dist <= reach)).any() or (seen & (dist <= 1.5 * pitch + 1e-6)).sum() < 2:
            out.notes[f] = f"tape rows near {name} (row {v / pitch + 1:g}) not seen"
            continue
        across = rows.transverse[f]
        ok = np.isfinite(across).all(axis=1)
        if not (ok & (dist <= reach)).any():
            out.notes[f] = f"no full row (L and R dots) near {name}"
            continue
        right = np.array([np.interp(v, rows.v[ok], across[ok, k]) for k in range(3)])
        out.frames[f] = frame_from_axes(curve.tangent(v), right)
    return out


def _relative(at: dict[str, _LevelFrames], missing_level: dict[str, str], lo: str, hi: str,
              F: int) -> tuple[np.ndarray, np.ndarray]:
    for name in (lo, hi):
        if name in missing_level:
            return np.full((F, 3), np.nan), np.full(F, missing_level[name], dtype=object)
    values = cardan_angles(at[lo].frames, at[hi].frames)
    note = np.where(at[lo].notes != "", at[lo].notes, at[hi].notes)
    return values, note


def _curvature(at: dict[str, _LevelFrames], curves: list[MidlineCurve | None],
               level_v: dict[str, float], missing_level: dict[str, str], settings: AngleSettings,
               F: int) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = "lower", "upper"
    values = np.full((F, 2), np.nan)
    for name in (lo, hi):
        if name in missing_level:
            return values, np.full(F, missing_level[name], dtype=object)
    note = np.where(at[lo].notes != "", at[lo].notes, at[hi].notes).astype(object)
    v_lo, v_hi = level_v[lo], level_v[hi]
    grid = np.linspace(v_lo, v_hi, 101)
    margin = 0.1 * (v_hi - v_lo)
    for f in np.flatnonzero(note == ""):
        curve = curves[f]
        if curve is None:
            note[f] = f"fewer than {MIN_ROWS} tape rows seen"
            continue
        base = at[lo].frames[f]
        t = curve.tangent(grid) @ base  # components on (a, s, r)
        theta = np.degrees(np.arctan2(t[:, 0], t[:, 1]))
        k = int(np.argmin(theta))
        if not grid[0] + margin < grid[k] < grid[-1] - margin:
            note[f] = f"no inflection between {settings.lower} and {settings.upper} (spine curve not S-shaped here)"
            continue
        values[f] = theta[0] - theta[k], theta[-1] - theta[k]
    return values, note


def _pelvis(at: dict[str, _LevelFrames], missing_level: dict[str, str], settings: AngleSettings,
            up, facing, pelvis_frames: np.ndarray | None, F: int, source) -> tuple[np.ndarray, np.ndarray]:
    neutral = neutral_frame(np.asarray(up, float), np.asarray(facing, float))
    if pelvis_frames is not None:
        frames = np.asarray(pelvis_frames, float)
        note = np.where(np.isfinite(frames).all(axis=(1, 2)), "", "pelvis markers missing").astype(object)
    elif "lower" in missing_level:
        return np.full((F, 3), np.nan), np.full(F, missing_level["lower"], dtype=object)
    else:
        sacral = at["lower"]
        check_facing(sacral.frames, np.asarray(facing, float), source)
        frames = pelvis_frame_from_tape(sacral.frames, np.asarray(up, float), np.asarray(facing, float))
        note = sacral.notes.copy()
    return cardan_angles(np.broadcast_to(neutral, frames.shape), frames), note
