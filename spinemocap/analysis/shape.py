"""The spine's shape: segmental (per-level) angles and the tape midline in the subject's planes.

Pipeline position: marker table -> row centres -> midline curve (:mod:`curve`) -> segment frames
at **every vertebra** the level map places on the tape (:func:`angles.level_frames`) -> the
angle of each vertebra's frame relative to the one below (:func:`segmental_angles`), and the
midline itself in the subject's anatomical axes at chosen frames (:func:`midline_profiles`).

Segmental angles use the same Cardan sequence and signs as the lumbar angle (flexion positive
forward, lateral bending positive to the subject's right, axial rotation positive to the left);
the segments' flexion between S1 and T12/L1 adds up to about the lumbar flexion (exactly when the
levels coincide). With one tape row per vertebra (the 25 mm row pitch), a segmental angle rests
on the spline between two or three rows: read it as the distribution of the motion along the
spine, not as one joint's motion.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..markers import MarkerTable
from ..tape import TapeSpec
from .angles import AngleSettings, level_frames, midlines
from .frames import cardan_angles, neutral_frame
from .levels import LevelMap, vertebra_index

#: Vertebrae from the skull down (vertebra_index 1..29).
VERTEBRAE = tuple([f"C{i}" for i in range(1, 8)] + [f"T{i}" for i in range(1, 13)]
                  + [f"L{i}" for i in range(1, 6)] + [f"S{i}" for i in range(1, 6)])
SEGMENT_ANGLES = ("flexion", "lateral", "rotation")


def vertebrae_on_tape(levels: LevelMap) -> list[str]:
    """Every whole vertebra between the most sacral and the most cranial level of the map,
    sacral first (the levels :meth:`LevelMap.row_of` can place without extrapolating)."""
    index = [vertebra_index(name) for name in levels.rows]
    low, high = max(index), min(index)  # sacral end has the larger index
    return [v for v in reversed(VERTEBRAE) if high <= vertebra_index(v) <= low]


def segment_name(lower: str, upper: str) -> str:
    """``"L5", "L4"`` -> ``"L4-L5"`` (cranial vertebra first, as clinicians name a segment)."""
    return f"{upper}-{lower}"


def segmental_angles(markers: MarkerTable, tape: TapeSpec, levels: LevelMap,
                     settings: AngleSettings | None = None) -> pd.DataFrame:
    """Per frame, the angles (deg) of each vertebra's segment frame relative to the vertebra
    below: columns ``frame``, ``time`` and ``<segment>_<angle>`` (e.g. ``L4-L5_flexion``) for
    consecutive vertebrae on the tape, sacral segments first. NaN where a level's frame is not
    supported by the data (rows not seen near it; the reasons are those of the lumbar angle)."""
    settings = settings or AngleSettings()
    names = vertebrae_on_tape(levels)
    arrays = markers.to_arrays()
    table = pd.DataFrame({"frame": arrays.frames, "time": arrays.time})
    frames = level_frames(markers, tape, levels, names, settings)
    columns = {}
    for lower, upper in zip(names[:-1], names[1:]):
        values = cardan_angles(frames[lower][0], frames[upper][0])
        for k, angle in enumerate(SEGMENT_ANGLES):
            columns[f"{segment_name(lower, upper)}_{angle}"] = values[:, k]
    return pd.concat([table, pd.DataFrame(columns, index=table.index)], axis=1)


def segments_of(table: pd.DataFrame, angle: str = "flexion") -> list[str]:
    """The segment names of a :func:`segmental_angles` table, sacral first."""
    suffix = f"_{angle}"
    return [c[: -len(suffix)] for c in table.columns if c.endswith(suffix)]


def key_frames(angles: pd.DataFrame, column: str = "lumbar_flexion") -> dict[str, int]:
    """Row indices of the frames a report pictures: ``neutral`` (the first frame), ``peak
    flexion`` (largest ``column``) and ``peak extension`` (smallest); frames without the angle
    are skipped, and only ``neutral`` is given when the angle is NaN throughout."""
    values = angles[column].to_numpy(float) if column in angles else np.array([np.nan])
    out = {"neutral": 0}
    if np.isfinite(values).any():
        out["peak flexion"] = int(np.nanargmax(values))
        out["peak extension"] = int(np.nanargmin(values))
    return out


def midline_profiles(markers: MarkerTable, tape: TapeSpec, frames: dict[str, int],
                     up=(0.0, 0.0, 1.0), facing=(0.0, -1.0, 0.0), settings: AngleSettings | None = None,
                     step_mm: float = 5.0) -> dict[str, dict[str, list[float]]]:
    """The tape midline at the named frames (row indices of the marker table) in the subject's
    anatomical axes of the first frame (``up``/``facing``: :func:`frames.neutral_frame`), origin
    at the midline's sacral end (row 1) of that frame: ``{name: {"anterior": [...], "superior":
    [...], "right": [...]}}`` in mm, points every ``step_mm`` of arc length. A frame without a
    midline (too few rows seen) is left out."""
    _, curves = midlines(markers, tape, settings or AngleSettings())
    axes = neutral_frame(np.asarray(up, float), np.asarray(facing, float))
    out: dict[str, dict[str, list[float]]] = {}
    for name, index in frames.items():
        curve = curves[index] if 0 <= index < len(curves) else None
        if curve is None:
            continue
        _, points, _ = curve.resample(step_mm)
        local = (points - points[0]) @ axes
        out[name] = {axis: np.round(local[:, k], 2).tolist() for k, axis in enumerate(("anterior", "superior", "right"))}
    return out
