"""Axes, the static trial and the subject's spine geometry, from the tape alone (no OpenSim here).

Frames. The lab frame is the capture's (mm, Z up). OpenSim's ground frame is built from the
capture's ``[subject] up/facing``: X = facing (made horizontal), Y = up, Z = X x Y (the subject's
right). All arrays in this module after :func:`to_opensim` are in that frame, still in mm.

Geometry (:func:`spine_geometry`): the static tape's midline (row centres, a cubic in arc length)
gives the skin point of every vertebral level the level map places; levels beyond the map are
continued along the midline's end tangent with the generic centre spacings of
:mod:`spinemocap.anatomy`, scaled by the ratio of the tape's arc length between the
outermost mapped vertebrae to the generic spacing between them. Each vertebral body centre sits
``skin_depth x scale`` in front of its skin point, along the anterior axis of the subject's
sagittal plane. That plane is the tape's own (:func:`tape_front`: tangent x L->R, horizontal),
once :func:`check_facing` has found it within :data:`FACING_LIMIT_DEG` of the declared ``facing``
(further off is an error): a subject standing a little turned still gets joint axes that match
its spine (with the declared plane, 40 deg off, pure flexion read 2.6 deg of lateral bending). A
vertebra's frame is the ISB triple (X anterior, Y superior along the midline's sagittal tangent,
Z right).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from ..anatomy import ANATOMY, VERTEBRAE, centre_spacing, skin_depth
from ..fileio import InputError
from ..tape import TapeSpec

# caudal -> cranial: the model's chain of vertebral bodies (the pelvis carries S1)
CHAIN = tuple(reversed(VERTEBRAE))  # S1, L5, ..., T1
HEAD_NECK = "head_neck"  # the segment above T1, centred one T1 spacing above it
FACING_LIMIT_DEG = 45.0  # the tape's front may differ this much from the declared facing


class LevelRows(Protocol):
    """The row-to-level map of :mod:`spinemocap.analysis.levels` (passed in, not imported)."""

    @property
    def rows(self) -> Mapping[str, float]: ...

    def row_of(self, level: str) -> float: ...


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def opensim_axes(up: npt.ArrayLike, facing: Sequence[float], source: str | None = None) -> np.ndarray:
    """(3, 3) rotation whose rows are OpenSim's X (facing, horizontal), Y (up), Z (right) in lab
    coordinates: ``p_opensim = R @ p_lab``."""
    given_up = np.asarray(up, float)
    f = np.asarray(facing, float)
    if given_up.shape != (3,) or f.shape != (3,) or not np.linalg.norm(given_up) > 0:
        raise InputError(source, f"[subject] up/facing must be 3-vectors, got up={given_up.tolist()} facing={list(facing)}")
    y = _unit(given_up)
    x = f - np.dot(f, y) * y
    if np.linalg.norm(x) < 0.3 * np.linalg.norm(f):
        raise InputError(source, f"[subject] facing {list(facing)} is (nearly) parallel to up {given_up.tolist()}")
    x = _unit(x)
    return np.stack([x, y, np.cross(x, y)])


def to_opensim(positions_mm: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Lab (..., 3) mm -> OpenSim ground (..., 3) mm (NaN stays NaN)."""
    return np.asarray(positions_mm, float) @ axes.T


def static_positions(positions: np.ndarray) -> np.ndarray:
    """(D, 3) per-marker median over the frames of a static trial (F, D, 3); NaN if never seen."""
    with np.errstate(all="ignore"):
        out = np.full(positions.shape[1:], np.nan)
        seen = np.isfinite(positions).all(axis=2).any(axis=0)
        if seen.any():
            out[seen] = np.nanmedian(positions[:, seen], axis=0)
    return out


@dataclass
class RowFrames:
    """Per tape row (static, OpenSim axes, mm): centre (L/R mid), unit L->R axis, arc length of
    the centre along the midline from row 1; NaN for rows without both side dots."""

    centre: np.ndarray  # (R, 3)
    right: np.ndarray  # (R, 3)
    arc: np.ndarray  # (R,)

    @property
    def seen(self) -> np.ndarray:
        return np.isfinite(self.centre).all(axis=1)


def row_frames(static: np.ndarray, tape: TapeSpec, source: str | None = None) -> RowFrames:
    """Row centres and transverse axes of the static tape; arc lengths between seen rows are
    measured along the centres (rows not seen are interpolated in row index)."""
    graph = tape.graph
    R = tape.n_rows
    centre = np.full((R, 3), np.nan)
    right = np.full((R, 3), np.nan)
    for r in range(R):
        left = static[(graph.row == r) & (np.array(graph.column) == "L")]
        rgt = static[(graph.row == r) & (np.array(graph.column) == "R")]
        if len(left) and len(rgt) and np.isfinite(left[0]).all() and np.isfinite(rgt[0]).all():
            centre[r] = 0.5 * (left[0] + rgt[0])
            right[r] = _unit(rgt[0] - left[0])
    seen = np.isfinite(centre).all(axis=1)
    if seen.sum() < 3:
        raise InputError(source, f"the static trial shows only {int(seen.sum())} tape rows with both side dots; "
                                 "need at least 3 to place the spine")
    idx = np.flatnonzero(seen)
    steps = np.linalg.norm(np.diff(centre[idx], axis=0), axis=1)
    arc_seen = np.concatenate([[0.0], np.cumsum(steps)])
    per_row = np.interp(np.arange(R), idx, arc_seen, left=np.nan, right=np.nan)
    # rows beyond the first/last seen one: the mean spacing of the seen rows
    pitch = arc_seen[-1] / max(idx[-1] - idx[0], 1)
    out = np.where(np.isfinite(per_row), per_row, arc_seen[0] + (np.arange(R) - idx[0]) * pitch)
    return RowFrames(centre, right, out - out[0])


def tape_front(rows: RowFrames) -> np.ndarray:
    """Unit horizontal direction (OpenSim ground, Y up) the subject faces by the static tape: the
    median over rows of the midline tangent x the L->R axis, made horizontal."""
    idx = np.flatnonzero(rows.seen)
    tangent = _unit(np.gradient(rows.centre[idx], rows.arc[idx], axis=0))
    front = np.median(_unit(np.cross(tangent, rows.right[idx])), axis=0)
    return _unit(np.array([front[0], 0.0, front[2]]))


def check_facing(rows: RowFrames, axes: np.ndarray, source: str | None = None) -> float:
    """Angle (deg) between the tape's front (midline tangent x L->R axis, in OpenSim ground) and
    OpenSim's X (the declared facing). Raises :class:`InputError` naming the facing the data shows
    when it exceeds :data:`FACING_LIMIT_DEG`, or when the tape does not run upward."""
    idx = np.flatnonzero(rows.seen)
    tangent = _unit(np.gradient(rows.centre[idx], rows.arc[idx], axis=0))
    up = float(np.median(tangent[:, 1]))
    if up < 0.3:
        raise InputError(source, f"the tape does not run upward in the static trial (median tangent . up = {up:.2f}): "
                                 "check [subject] up in capture.toml or the row labels (R01 at the sacral end)")
    horizontal = tape_front(rows)
    angle = float(np.degrees(np.arctan2(abs(horizontal[2]), horizontal[0])))
    if angle > FACING_LIMIT_DEG:
        lab = axes.T @ _unit(horizontal)
        raise InputError(
            source,
            f"[subject] facing does not match the data: the tape's front (tangent x L->R) points "
            f"{angle:.0f} deg away from the declared facing; the subject faces about "
            f"[{lab[0]:.2f}, {lab[1]:.2f}, {lab[2]:.2f}] in lab coordinates. Fix facing in capture.toml "
            f"(or the L/R labels if the tape is mirrored)")
    return angle


@dataclass
class SpineGeometry:
    """The subject's vertebrae in the static posture (OpenSim ground, mm).

    ``names``: the chain caudal -> cranial (``S1`` ... ``T1``, ``head_neck``); ``centre`` (N, 3)
    vertebral body centres; ``frame`` (N, 3, 3) columns (anterior, superior, right); ``arc`` (N,)
    skin arc length of each level from row 1 (mm, negative below the tape); ``mapped``: names the
    level map places; ``scale``: subject / generic column length; ``row_body`` (R,) chain index
    of the vertebra under each tape row."""

    names: list[str]
    centre: np.ndarray
    frame: np.ndarray
    arc: np.ndarray
    skin: np.ndarray
    mapped: list[str]
    scale: float
    row_body: np.ndarray
    depth: np.ndarray  # (N,) mm, skin to body centre

    def index(self, name: str) -> int:
        return self.names.index(name)

    def disc_centre(self, k: int) -> np.ndarray:
        """Centre (mm) of the joint between chain bodies k-1 and k: the middle of the disc between
        them (generic body and disc heights; the head-neck joint sits half-way)."""
        lower, upper = self.names[k - 1], self.names[k]
        share = 0.5
        if upper in ANATOMY:
            gap = 0.5 * ANATOMY[lower].body_height + 0.5 * ANATOMY[upper].disc_below
            share = gap / centre_spacing(upper, lower)
        return self.centre[k - 1] + share * (self.centre[k] - self.centre[k - 1])


class _Midline:
    """The static midline as a function of arc length: a cubic through the row centres inside the
    tape, straight along the end tangents beyond it."""

    def __init__(self, rows: RowFrames):
        idx = np.flatnonzero(rows.seen)
        self.a0, self.a1 = float(rows.arc[idx[0]]), float(rows.arc[idx[-1]])
        degree = min(3, len(idx) - 1)
        self.coef = [np.polyfit(rows.arc[idx], rows.centre[idx, d], degree) for d in range(3)]

    def _poly(self, a: np.ndarray, deriv: int = 0) -> np.ndarray:
        return np.stack([np.polyval(np.polyder(c, deriv) if deriv else c, a) for c in self.coef], axis=-1)

    def tangent(self, a: np.ndarray) -> np.ndarray:
        return _unit(self._poly(np.clip(a, self.a0, self.a1), 1))

    def point(self, a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, float)
        inside = self._poly(np.clip(a, self.a0, self.a1))
        below = np.minimum(a - self.a0, 0.0)[..., None] * self.tangent(np.full_like(a, self.a0))
        above = np.maximum(a - self.a1, 0.0)[..., None] * self.tangent(np.full_like(a, self.a1))
        return inside + below + above


def _sagittal_frame(tangent: np.ndarray, front: np.ndarray) -> np.ndarray:
    """(3, 3) columns (anterior, superior, right): right = horizontal, perpendicular to the
    subject's ``front``; superior = the tangent in the sagittal plane."""
    r = _unit(np.cross(front, np.array([0.0, 1.0, 0.0])))
    s = _unit(tangent - np.dot(tangent, r) * r)
    return np.stack([np.cross(s, r), s, r], axis=-1)


def level_arcs(levels: LevelRows, rows: RowFrames, source: str | None = None) -> tuple[dict[str, float], float]:
    """Skin arc length (mm) of every vertebra in :data:`CHAIN` and the subject/generic scale.

    Vertebrae the level map reaches take their row's arc length; the others are continued from
    the nearest mapped one with the generic centre spacings times the scale."""
    mapped: dict[str, float] = {}
    R = len(rows.arc)
    for name in CHAIN:
        try:
            row = levels.row_of(name)
        except KeyError:
            continue
        mapped[name] = float(np.interp(row - 1.0, np.arange(R), rows.arc))
    if len(mapped) < 2:
        raise InputError(source, "the level map places fewer than two vertebrae between S1 and T1 on this tape "
                                 f"(levels: {dict(levels.rows)}); name at least two levels the tape covers")
    order = [n for n in CHAIN if n in mapped]
    lo, hi = CHAIN.index(order[0]), CHAIN.index(order[-1])
    generic = sum(centre_spacing(CHAIN[k + 1], CHAIN[k]) for k in range(lo, hi))
    scale = (mapped[order[-1]] - mapped[order[0]]) / generic
    if not 0.5 < scale < 2.0:
        raise InputError(source, f"the level map puts {order[0]}..{order[-1]} {mapped[order[-1]] - mapped[order[0]]:.0f} mm "
                                 f"apart on the tape, {scale:.2f} x the generic adult column: check the level map")
    arcs = dict(mapped)
    for k in range(lo - 1, -1, -1):  # below the map, toward S1
        arcs[CHAIN[k]] = arcs[CHAIN[k + 1]] - scale * centre_spacing(CHAIN[k + 1], CHAIN[k])
    for k in range(hi + 1, len(CHAIN)):  # above the map, toward T1
        arcs[CHAIN[k]] = arcs[CHAIN[k - 1]] + scale * centre_spacing(CHAIN[k], CHAIN[k - 1])
    arcs[HEAD_NECK] = arcs["T1"] + scale * centre_spacing("T1", "T2")
    return arcs, scale


def spine_geometry(rows: RowFrames, levels: LevelRows, depth_scale: float = 1.0,
                   source: str | None = None) -> SpineGeometry:
    """Vertebral centres and frames of the subject in the static posture; see the module docstring.

    ``depth_scale`` multiplies the published skin-to-body-centre depths: 1 = anatomical (the
    pipeline takes it from its settings, with the source written in its summary)."""
    arcs, scale = level_arcs(levels, rows, source)
    names = list(CHAIN) + [HEAD_NECK]
    arc = np.array([arcs[n] for n in names])
    midline = _Midline(rows)
    skin = midline.point(arc)
    front = tape_front(rows)
    frames = np.array([_sagittal_frame(t, front) for t in midline.tangent(arc)])
    depth = depth_scale * scale * np.array([skin_depth(n if n in ANATOMY else "T1") for n in names])
    centre = skin + depth[:, None] * frames[:, :, 0]
    # the vertebra under each row: nearest level by skin arc length (the pelvis carries S1)
    row_body = np.argmin(np.abs(rows.arc[:, None] - arc[None, :]), axis=1)
    mapped = [n for n in CHAIN if _maps(levels, n)]
    return SpineGeometry(names, centre, frames, arc, skin, mapped, float(scale), row_body, depth)


def _maps(levels: LevelRows, name: str) -> bool:
    try:
        levels.row_of(name)
    except KeyError:
        return False
    return True


def expected_marker_locations(geometry: SpineGeometry, rows: RowFrames, tape: TapeSpec) -> np.ndarray:
    """(D, 3) anatomical marker locations (mm) in the frame of the vertebra under each dot: on the
    skin over the spinous process at the row's level, ``u`` to the side (tape spec)."""
    graph = tape.graph
    out = np.zeros((graph.n_dots, 3))
    for d in range(graph.n_dots):
        k = geometry.row_body[graph.row[d]]
        R = geometry.frame[k]
        a_row = rows.arc[graph.row[d]]
        on_skin = geometry.skin[k] + (a_row - geometry.arc[k]) * R[:, 1] + graph.uv_mm[d, 0] * R[:, 2]
        out[d] = R.T @ (on_skin - geometry.centre[k])
    return out

