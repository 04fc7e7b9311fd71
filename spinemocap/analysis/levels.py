"""Which tape row lies over which vertebra, as palpated when the tape was applied.

Given per subject in TOML (top level or under ``[levels]``), rows counted from the sacral end
starting at 1 as in the labels (``R01`` = row 1); a row may be fractional (between two rows)::

    [levels]
    S1 = 1
    L3 = 5
    "T12/L1" = 9        # a disc level: between T12 and L1
    T7 = 13

Level names: ``C1``..``C7``, ``T1``..``T12``, ``L1``..``L5``, ``S1``..``S5``, or a disc ``A/B``
of two adjacent vertebrae in either order (``T12/L1`` == ``L1/T12``). Levels not named are
placed by linear interpolation between named ones (vertebral index vs row), never extrapolated.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from ..fileio import InputError, read_toml, reading

_REGIONS = {"C": (0, 7), "T": (7, 12), "L": (19, 5), "S": (24, 5)}
_NAME = re.compile(r"^([CTLS])(\d{1,2})$")


def vertebra_index(name: str) -> float:
    """Position of a vertebra or disc from the skull down: C1 = 1 ... T12 = 19, L1 = 20,
    L5 = 24, S1 = 25; a disc ``A/B`` is the mean of its two (adjacent) vertebrae."""
    parts = [p.strip().upper() for p in str(name).split("/")]
    if len(parts) == 2:
        a, b = (vertebra_index(p) for p in parts)
        if abs(a - b) != 1:
            raise ValueError(f"{name!r}: a disc level joins two adjacent vertebrae")
        return 0.5 * (a + b)
    m = _NAME.match(parts[0]) if len(parts) == 1 else None
    if not m:
        raise ValueError(f"{name!r} is not a vertebral level (expected e.g. S1, L3, T12/L1, T7)")
    offset, count = _REGIONS[m.group(1)]
    number = int(m.group(2))
    if not 1 <= number <= count:
        raise ValueError(f"{name!r}: region {m.group(1)} has vertebrae 1..{count}")
    return float(offset + number)


def canonical_level(name: str) -> str:
    """``L1/T12`` -> ``T12/L1`` (cranial vertebra first); single vertebrae upper-cased."""
    parts = [p.strip().upper() for p in str(name).split("/")]
    vertebra_index(name)  # validates
    if len(parts) == 2:
        parts.sort(key=vertebra_index)
        return "/".join(parts)
    return parts[0]


@dataclass
class LevelMap:
    """Row (1-based, float) of each named vertebral level, checked against a tape of ``n_rows``."""

    rows: dict[str, float]
    n_rows: int
    source: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        clean: dict[str, float] = {}
        for name, row in self.rows.items():
            try:
                key = canonical_level(name)
            except ValueError as exc:
                raise InputError(self.source, str(exc)) from None
            if not isinstance(row, (int, float)) or isinstance(row, bool):
                raise InputError(self.source, f"level {name}: row must be a number, got {row!r}")
            if not 1 <= row <= self.n_rows:
                raise InputError(
                    self.source,
                    f"level {name} is mapped to row {row}, but the tape has rows 1..{self.n_rows}",
                )
            clean[key] = float(row)
        if len(clean) < 2:
            raise InputError(self.source, "a level map needs at least two levels")
        ordered = sorted(clean.items(), key=lambda kv: -vertebra_index(kv[0]))  # sacral first
        rows = [r for _, r in ordered]
        if any(b <= a for a, b in zip(rows[:-1], rows[1:])):
            raise InputError(
                self.source,
                "rows must increase from the sacral end toward the head: "
                + ", ".join(f"{k}={v:g}" for k, v in ordered),
            )
        self.rows = dict(ordered)

    @classmethod
    def from_toml(cls, path: str | os.PathLike, n_rows: int) -> "LevelMap":
        data = read_toml(path)
        with reading(path, "level map"):
            levels = data.get("levels", data)
            if not isinstance(levels, dict):
                raise InputError(path, f"[levels] must be a table of level = row, got {levels!r}")
            return cls(dict(levels), n_rows, source=str(path))

    @classmethod
    def from_row_levels(cls, row_levels: list[str], n_rows: int, source: str | None = None) -> "LevelMap":
        """From the nearest vertebral level of every row (the synthetic studio's ground truth):
        a level named by several rows sits at their mean row."""
        named: dict[str, list[int]] = {}
        for r, name in enumerate(row_levels, start=1):
            named.setdefault(canonical_level(str(name)), []).append(r)
        return cls({k: float(np.mean(v)) for k, v in named.items()}, n_rows, source=source)

    def row_of(self, level: str) -> float:
        """Row (1-based, fractional) of ``level``; interpolated between named levels.

        Raises KeyError with a reason when the level lies outside the mapped span of the tape."""
        key = canonical_level(level)
        if key in self.rows:
            return self.rows[key]
        idx = np.array([vertebra_index(k) for k in self.rows])  # decreasing
        target = vertebra_index(key)
        if not idx.min() <= target <= idx.max():
            raise KeyError(
                f"level {key} lies outside the mapped levels "
                f"({next(iter(self.rows))}..{list(self.rows)[-1]}) of this tape"
            )
        return float(np.interp(-target, -idx, list(self.rows.values())))

    def v_of(self, level: str, row_pitch_mm: float) -> float:
        """Rest position (mm along the tape from row 1) of ``level``."""
        return (self.row_of(level) - 1.0) * row_pitch_mm
