"""Marker sets a body fit recognises by label: Plug-in Gait (full body) and common trunk / spine
markers (spinous processes C7 ... S1, sacrum, scapula).

Each marker is placed on a body model by a rule in the body's rest pose (mm, studio frame: Z up,
facing ``-Y``, left ``+X``): a point inside the body (a canonical joint of
:data:`~spinemocap.bodymodel.base.CANONICAL_JOINTS`, a fraction of the way to a second joint, a
vertebral level on the spine, plus a fixed offset) and an outward direction; the marker sits on
the first skin vertex the ray from that point leaves the body through. The rules are
approximate by design: the fit adds a free per-marker offset with a prior (MoSh).

Labels are matched after dropping a Nexus subject prefix (``Subject:LASI``) and upper-casing.
Other labels map through a mapping file (TOML), see :func:`read_mapping`.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from ..fileio import InputError, read_toml
from ..skin import LEVELS, SURFACE_LEVELS, surface_level_heights
from .base import CANONICAL_JOINTS, RestBody


@dataclass(frozen=True)
class MarkerRule:
    """Where a marker sits: ``at`` a canonical joint or ``level:T10``; ``toward`` a second joint
    and ``fraction`` of the way there; ``offset_mm`` added; ``direction`` outward (unit-less)."""

    at: str
    direction: tuple[float, float, float]
    toward: str | None = None
    fraction: float = 0.0
    offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)


log = logging.getLogger(__name__)

# Left-side rules (right side mirrored in x); unpaired markers below.
_PAIRED = {
    "FHD": MarkerRule("head", (0.5, -1.0, 0.4), "head_top", 0.35),
    "BHD": MarkerRule("head", (0.5, 1.0, 0.3), "head_top", 0.35),
    "SHO": MarkerRule("shoulder", (0.3, 0.0, 1.0)),
    "UPA": MarkerRule("shoulder", (1.0, 0.4, 0.0), "elbow", 0.5),
    "ELB": MarkerRule("elbow", (1.0, 0.5, 0.0)),
    "FRM": MarkerRule("elbow", (1.0, 0.3, 0.0), "wrist", 0.5),
    "WRA": MarkerRule("wrist", (0.5, -0.5, 0.7)),
    "WRB": MarkerRule("wrist", (0.5, 0.5, -0.7)),
    "FIN": MarkerRule("hand", (0.3, 0.0, 1.0)),
    "ASI": MarkerRule("hip", (0.2, -1.0, 0.0), offset_mm=(-20.0, 0.0, 60.0)),
    "PSI": MarkerRule("hip", (0.1, 1.0, 0.0), offset_mm=(-55.0, 0.0, 70.0)),
    "THI": MarkerRule("hip", (1.0, 0.0, 0.0), "knee", 0.6),
    "KNE": MarkerRule("knee", (1.0, 0.0, 0.0)),
    "TIB": MarkerRule("knee", (1.0, 0.0, 0.0), "ankle", 0.6),
    "ANK": MarkerRule("ankle", (1.0, 0.0, 0.0)),
    "HEE": MarkerRule("ankle", (0.0, 1.0, -0.3), offset_mm=(0.0, 0.0, -40.0)),
    "TOE": MarkerRule("toe", (0.0, -0.2, 1.0)),
    "SCAP": MarkerRule("level:T7", (0.0, 1.0, 0.0), offset_mm=(70.0, 0.0, 0.0)),
}
_SINGLE = {
    "CLAV": MarkerRule("neck_base", (0.0, -1.0, 0.0), offset_mm=(0.0, 0.0, -30.0)),
    "STRN": MarkerRule("level:T9", (0.0, -1.0, 0.0)),
    "RBAK": MarkerRule("level:T7", (0.0, 1.0, 0.0), offset_mm=(-70.0, 0.0, 0.0)),
    "SACR": MarkerRule("hip_L", (0.0, 1.0, 0.0), "hip_R", 0.5, offset_mm=(0.0, 0.0, 70.0)),
    **{level: MarkerRule(f"level:{level}", (0.0, 1.0, 0.0)) for level in LEVELS},
}
_ALIASES = {"SACRUM": "SACR", "STER": "STRN", "STERNUM": "STRN", "IJ": "CLAV", "PX": "STRN",
            "LSCAP": "LSCAP", "RSCAP": "RSCAP", "C7SP": "C7"}
TRUNK_MARKERS = ("C7", "T10", "CLAV", "STRN", "RBAK", "LSCAP", "RSCAP", "SACR", "LPSI", "RPSI", "LASI",
                 "RASI") + LEVELS
PLUG_IN_GAIT = tuple(
    [f"{s}{n}" for n in ("FHD", "BHD") for s in "LR"] + ["C7", "T10", "CLAV", "STRN", "RBAK"]
    + [f"{s}{n}" for s in "LR" for n in ("SHO", "UPA", "ELB", "FRM", "WRA", "WRB", "FIN")]
    + [f"{s}{n}" for s in "LR" for n in ("ASI", "PSI")]
    + [f"{s}{n}" for s in "LR" for n in ("THI", "KNE", "TIB", "ANK", "HEE", "TOE")])
SPINE_MARKERS = ("C7", "T4", "T8", "T10", "L1", "L3", "S1")


def canonical_label(label: str) -> str:
    """``'Subject:lasi '`` -> ``'LASI'``; aliases resolved."""
    name = label.split(":")[-1].strip().upper()
    return _ALIASES.get(name, name)


def _sided(joint: str, side: str) -> str:
    """``'elbow'`` -> ``'elbow_L'``; unpaired joints (head, levels) unchanged."""
    return f"{joint}_{side}" if f"{joint}_L" in CANONICAL_JOINTS else joint


def rule_for(label: str) -> MarkerRule | None:
    """The placement rule of a known marker label (after :func:`canonical_label`), else None."""
    name = canonical_label(label)
    if name in _SINGLE:
        return _SINGLE[name]
    if len(name) > 1 and name[0] in "LR" and name[1:] in _PAIRED:
        rule = _PAIRED[name[1:]]
        side = name[0]
        sign = 1.0 if side == "L" else -1.0
        return MarkerRule(_sided(rule.at, side), (sign * rule.direction[0], *rule.direction[1:]),
                          None if rule.toward is None else _sided(rule.toward, side), rule.fraction,
                          (sign * rule.offset_mm[0], *rule.offset_mm[1:]))
    return None


def _vector3(values) -> tuple[float, float, float]:
    """Three numbers of a mapping file's entry; ValueError for another count."""
    x, y, z = (float(v) for v in values)
    return x, y, z


def read_mapping(path: str | os.PathLike) -> dict[str, MarkerRule]:
    """A mapping file (TOML) for labels the fit does not know. Under ``[markers]`` each entry is
    either the name of a known marker (``MyC7 = "C7"``) or a rule table
    (``Elbow = { at = "elbow_L", direction = [1, 0, 0], toward = "wrist_L", fraction = 0.2,
    offset_mm = [0, 0, 0] }``)."""
    data = read_toml(path).get("markers")
    if not isinstance(data, dict):
        raise InputError(path, "a marker mapping file needs a [markers] table")
    rules: dict[str, MarkerRule] = {}
    for label, entry in data.items():
        if isinstance(entry, str):
            rule = rule_for(entry)
            if rule is None:
                raise InputError(path, f"{label} = {entry!r}: {entry!r} is not a known marker")
        elif isinstance(entry, dict) and "at" in entry and "direction" in entry:
            try:
                rule = MarkerRule(str(entry["at"]), _vector3(entry["direction"]), entry.get("toward"),
                                  float(entry.get("fraction", 0.0)), _vector3(entry.get("offset_mm", (0, 0, 0))))
            except (TypeError, ValueError) as exc:
                raise InputError(path, f"marker {label}: {exc}") from exc
        else:
            raise InputError(path, f"marker {label}: expected a marker name or a table with 'at' and 'direction'")
        rules[label] = rule
    return rules


def level_heights(rest: RestBody) -> dict[str, float]:
    """Rest height z (mm) of each level of :data:`~spinemocap.skin.SURFACE_LEVELS` (S2 ... C7) on
    this body: the one level table the studio uses too (:func:`~spinemocap.skin.surface_level_heights`),
    placed from the body's hip joint centres (S2 at the PSIS) and its ``neck_base`` joint (C7)."""
    return surface_level_heights(rest.joints["hip_L"], rest.joints["hip_R"], rest.joints["neck_base"])


def level_point(rest: RestBody, level: str) -> np.ndarray:
    """(3,) rest point (mm) at a vertebral level's height (:func:`level_heights`) on the line
    through the body's ``spine_base`` and ``neck_base`` joints (inside the trunk)."""
    if level not in SURFACE_LEVELS:
        raise ValueError(f"unknown vertebral level {level!r}; known: {SURFACE_LEVELS}")
    a, b = rest.joints["spine_base"], rest.joints["neck_base"]
    fraction = (level_heights(rest)[level] - a[2]) / (b[2] - a[2])
    return a + fraction * (b - a)


def _origin(rest: RestBody, rule: MarkerRule) -> np.ndarray:
    def joint(name: str) -> np.ndarray:
        if name.startswith("level:"):
            return level_point(rest, name.split(":", 1)[1])
        if name not in rest.joints:
            raise ValueError(f"unknown joint {name!r}; known: {sorted(rest.joints)} or level:<L>")
        return rest.joints[name]

    p = joint(rule.at)
    if rule.toward:
        p = p + rule.fraction * (joint(rule.toward) - p)
    return p + np.asarray(rule.offset_mm, float)


def place_on_skin(rest: RestBody, origin: np.ndarray, direction: np.ndarray, radius_mm: float = 12.0,
                  max_depth_mm: float = 250.0) -> int:
    """Index of the skin vertex where the ray ``origin + t direction`` leaves the body: the
    nearest vertex (smallest ``t``) within ``radius_mm`` of the ray whose normal faces along it."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    w = rest.vertices - origin
    t = w @ d
    perp = np.linalg.norm(w - t[:, None] * d, axis=1)
    for radius in (radius_mm, 2 * radius_mm, 4 * radius_mm):
        ok = (t > 0) & (t < max_depth_mm) & (perp < radius) & (rest.normals @ d > 0.3)
        if ok.any():
            candidates = np.flatnonzero(ok)
            return int(candidates[np.argmin(t[candidates])])
    raise ValueError(f"no skin along the ray from {origin.round(1)} toward {d.round(2)}")


def place_markers(rest: RestBody, labels: list[str], extra_rules: dict[str, MarkerRule] | None = None
                  ) -> tuple[list[str], np.ndarray]:
    """The labels a fit can use and their skin vertices on ``rest``: (labels kept, (M,) vertex
    indices). Labels with neither a known name nor a mapping rule are left out, and so are those
    whose rule finds no skin on this body (logged)."""
    kept, vertices = [], []
    for label in labels:
        rule = (extra_rules or {}).get(label) or rule_for(label)
        if rule is None:
            continue
        try:
            vertex = place_on_skin(rest, _origin(rest, rule), np.asarray(rule.direction, float))
        except ValueError as exc:
            log.warning("marker %s left out: %s", label, exc)
            continue
        kept.append(label)
        vertices.append(vertex)
    return kept, np.array(vertices, dtype=np.int64)


def is_trunk(label: str) -> bool:
    return canonical_label(label) in TRUNK_MARKERS
