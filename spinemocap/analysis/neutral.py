"""Angles relative to standing: a neutral posture defines zero.

A spine angle is absolute by construction (e.g. the lumbar flexion of a lordotic standing back is
negative, about -20 to -40 deg), so "peak flexion -14 deg, peak extension -29 deg" of a trial that
starts lordotic reads as a contradiction. Labs report motion *from neutral*: the angles of a
neutral (static, standing) trial, or of the first frames of the trial when the subject starts
standing, are subtracted, and then

- ``flexion from neutral`` = the largest forward bend beyond neutral (deg, >= 0),
- ``extension from neutral`` = the largest backward bend beyond neutral (deg, >= 0),
- ``ROM`` = the range of motion, max - min (deg; the same absolute or relative),

and likewise lateral bending to the right / left and axial rotation to the left / right (signs of
:mod:`spinemocap.analysis.angles`). The absolute angles stay available beside them (``*_neutral``
is the absolute angle of the neutral posture).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .angles import ANGLE_COLUMNS

#: The start of a trial that defines its neutral when no static trial is given (s from its first
#: frame; 0 = the first frame alone, which the row tracks' low-pass already smooths). A longer
#: window (a median) suits trials that begin with the subject standing still; a trial that starts
#: moving at once would have its neutral shifted into the motion.
NEUTRAL_FIRST_S = 0.0

#: Words for the positive and negative direction of each angle, as a report writes them.
DIRECTION_WORDS: dict[str, tuple[str, str]] = {
    "lumbar_flexion": ("flexion", "extension"),
    "thoracic_flexion": ("flexion", "extension"),
    "lumbar_lateral": ("right bending", "left bending"),
    "thoracic_lateral": ("right bending", "left bending"),
    "lumbar_rotation": ("left rotation", "right rotation"),
    "thoracic_rotation": ("left rotation", "right rotation"),
    "lordosis": ("more lordosis", "less lordosis"),
    "kyphosis": ("more kyphosis", "less kyphosis"),
    "pelvis_tilt": ("anterior tilt", "posterior tilt"),
    "pelvis_obliquity": ("right up", "right down"),
    "pelvis_rotation": ("left rotation", "right rotation"),
}

#: Trial or condition names (case-insensitive prefixes) that mark a neutral (static) trial.
STATIC_NAMES = ("static", "neutral", "standing")


def is_static_name(*names: str) -> bool:
    """Whether any of ``names`` (trial, condition) marks a neutral standing trial."""
    return any(str(n).strip().lower().startswith(STATIC_NAMES) for n in names if n)


@dataclass(frozen=True)
class Neutral:
    """The absolute angles (deg) of the neutral posture per angle column (NaN where the neutral
    frames had none), and where they came from (``source``, a phrase for a report)."""

    angles: dict[str, float]
    source: str

    def value(self, column: str) -> float:
        return float(self.angles.get(column, float("nan")))


def neutral_from_angles(table: pd.DataFrame, first_s: float | None = NEUTRAL_FIRST_S,
                        source: str | None = None) -> Neutral:
    """The neutral posture of an angles table (:attr:`SpineAngles.table`): the median of each
    angle over its first ``first_s`` seconds (0: the first frame), or over the whole table when
    ``first_s`` is None (a static trial)."""
    if table.empty:
        return Neutral({c: float("nan") for c in ANGLE_COLUMNS}, source or "an empty trial")
    t = table["time"].to_numpy(float)
    if first_s is None:
        chosen = np.ones(len(t), bool)
        phrase = source or "the static trial"
    else:
        chosen = t <= t[0] + first_s + 1e-9
        chosen[0] = True
        phrase = source or (f"the first {first_s:g} s of the trial" if first_s > 0 else "the trial's first frame")
    angles = {}
    for column in ANGLE_COLUMNS:
        values = table[column].to_numpy(float)[chosen] if column in table else np.array([np.nan])
        finite = values[np.isfinite(values)]
        angles[column] = float(np.median(finite)) if finite.size else float("nan")
    return Neutral(angles, phrase)


def relative_to_neutral(table: pd.DataFrame, neutral: Neutral) -> pd.DataFrame:
    """A copy of an angles table with every angle column minus its neutral value (deg)."""
    out = table.copy()
    for column in ANGLE_COLUMNS:
        if column in out:
            out[column] = out[column].to_numpy(float) - neutral.value(column)
    return out


def neutral_summary(table: pd.DataFrame, neutral: Neutral) -> dict[str, float]:
    """Per angle column (deg): ``<col>_neutral`` (absolute angle at neutral),
    ``<col>_pos_from_neutral`` / ``<col>_neg_from_neutral`` (largest excursion beyond neutral in
    the positive / negative direction, >= 0; words in :data:`DIRECTION_WORDS`, e.g. flexion /
    extension), ``<col>_rom`` and the absolute ``<col>_max`` / ``<col>_min``. NaN where the
    trial or its neutral has no value for the angle."""
    out: dict[str, float] = {}
    for column in ANGLE_COLUMNS:
        values = table[column].to_numpy(float) if column in table else np.array([np.nan])
        finite = values[np.isfinite(values)]
        zero = neutral.value(column)
        has = finite.size > 0
        out[f"{column}_neutral"] = zero
        out[f"{column}_max"] = float(finite.max()) if has else float("nan")
        out[f"{column}_min"] = float(finite.min()) if has else float("nan")
        out[f"{column}_rom"] = float(np.ptp(finite)) if has else float("nan")
        out[f"{column}_pos_from_neutral"] = _beyond(float(finite.max()) - zero if has else float("nan"))
        out[f"{column}_neg_from_neutral"] = _beyond(zero - float(finite.min()) if has else float("nan"))
    return out


def _beyond(excursion: float) -> float:
    """An excursion past neutral, 0 when the trial never went that way, NaN when unknown."""
    return max(0.0, excursion) if np.isfinite(excursion) else float("nan")
