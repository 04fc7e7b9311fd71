"""How the tape's skin moves against the spine model: row tilt normalised, rows slipping along it.

Skin over the back stretches and slides over the spinous processes (about 10 mm between flexed and
extended postures on real backs: Zemp R et al. (2014) PLoS ONE 9:e95426; level- and
direction-specific: Xi X et al. (2022) Front Bioeng Biotechnol 10:960063), so markers fixed to the
vertebrae cannot follow the tape. Two assumptions, both stated in ``summary.json`` and the model:

- **Row tilt** (:func:`normalise_row_tilt`): a row keeps, within the tape's plane, its static-trial
  angle to the tape's midline. Bending the back strains the skin unevenly across the tape and tilts
  each row in the tape plane; a rigid row would read that tilt as lateral bending of its vertebra,
  while the midline (which carries the real lateral bending) is not moved by the correction. Each
  row's dots are turned about the row centre, about the tape's normal, back to the static angle;
  the out-of-plane twist (axial rotation) is untouched.
- **Slip** (:func:`slip_rows`): every row but the lowest ``pinned`` ones rides on a small body that
  translates along its vertebra's superior axis (the skin's tangent there); the translation is a
  model coordinate (``<row>_skin_slip``, m), clamped at :attr:`SlipPrior.limit_mm`. The tape itself
  shows each row's slip (:func:`geometric_slips`: the midline's lengthening up to the row minus
  what forward bending of the vertebrae, at the subject's joint depth, lengthens it by); how IK
  uses it is :attr:`SlipPrior.from_tape` (:data:`SlipFromTape`): ``held`` (each frame's slip
  prescribed at it: the coordinate locked, inverse kinematics solves the spine's rotations only),
  ``goal`` (a Gaussian prior centred on it, SD :attr:`SlipPrior.estimate_sd_mm`) or ``off`` (a
  Gaussian prior toward 0, SD :attr:`SlipPrior.sd_mm`, the slip solved from the markers). Where a
  row's slip is not shown in a frame (its dots not measured) the slip is solved, with a goal at
  the nearest measured row's slip and SD :attr:`SlipPrior.sd_mm`. The markers alone hardly tell
  slip from forward bending (the marker error is nearly flat along slip against flexion): solved
  from the markers, the solution depends on where the solver stops, and so on rounding in its
  path (:data:`spinemocap.opensim.tools.IK_ACCURACY`); held, it does not. The pinned rows (over the sacrum and the lowest lumbar levels, where
  the tape starts) carry the reference: slips are relative to their mean. This is the multibody
  kinematic optimisation with a soft-tissue model that Begon M et al. (2018) J Biomech Eng
  140:030801 review; OpenSim's moving path points exist only for muscle paths, so a sliding
  marker is a marker on a body on a joint.

Frames: every array here is in OpenSim ground (Y up), mm; rows are 0-based.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from ..tape import TapeSpec

SlipFromTape = Literal["held", "goal", "off"]
"""How inverse kinematics uses the slip the tape shows (:func:`geometric_slips`): ``held`` at it
(a prescribed coordinate), a ``goal`` around it, or ``off`` (a prior toward 0)."""


@dataclass(frozen=True)
class SlipPrior:
    """A row's slip: ``from_tape`` how the slip the tape shows is used (:data:`SlipFromTape`;
    ``goal``: a Gaussian centred on it with standard deviation ``estimate_sd_mm``); where the tape
    does not show it, or with ``off``, a Gaussian with ``sd_mm`` (around the nearest measured row's
    slip, or 0 with ``off``); an IK goal's weight is (``marker_sd_mm`` / SD)^2 against a marker of
    weight 1. ``limit_mm`` the clamped range (+/-), ``pinned`` the lowest seen rows without slip
    (the reference)."""

    sd_mm: float = 25.0
    limit_mm: float = 80.0
    pinned: int = 2
    marker_sd_mm: float = 1.0
    from_tape: SlipFromTape = "held"
    # SD (mm) of the goal around the slip the tape shows, with from_tape "goal"
    estimate_sd_mm: float = 3.0

    @property
    def weight(self) -> float:
        """IK coordinate-goal weight (per m^2, beside marker errors in m^2) where the tape does not
        show the slip."""
        return (self.marker_sd_mm / self.sd_mm) ** 2

    @property
    def estimate_weight(self) -> float:
        """IK coordinate-goal weight (per m^2) of the goal at the slip the tape shows (with
        ``held``: the weight ``setup_ik.xml`` gives it, OpenSim's setup holding no per-frame lock)."""
        return (self.marker_sd_mm / self.estimate_sd_mm) ** 2


def prior_text(prior: SlipPrior) -> str:
    """The prior in words, for the model file and ``summary.json``."""
    fallback = f"SD {prior.sd_mm:g} mm (IK coordinate goal of weight {prior.weight:.6g} per m^2)"
    if prior.from_tape == "off":
        return f"Gaussian, mean 0, {fallback}"
    unknown = f"where a row's dots are not measured, Gaussian around the nearest measured row's slip, {fallback}"
    shown = ("the slip the tape's lengthening shows in each frame (its midline's lengthening from the pinned rows "
             "minus joint depth x forward turn; skin_slip_goals.sto, m)")
    if prior.from_tape == "held":
        return (f"held at {shown}: a prescribed (locked) coordinate in that frame's inverse kinematics "
                f"(setup_ik.xml approximates it by a goal of SD {prior.estimate_sd_mm:g} mm, weight "
                f"{prior.estimate_weight:.6g} per m^2); {unknown}")
    return (f"Gaussian around {shown}, SD {prior.estimate_sd_mm:g} mm (IK coordinate goal of weight "
            f"{prior.estimate_weight:.6g} per m^2); {unknown}")


def slip_coordinate(row: int) -> str:
    """``R06_skin_slip`` for row index 5: the coordinate (m) of a row's slip along its vertebra."""
    return f"R{row + 1:02d}_skin_slip"


def skin_body(row: int) -> str:
    """``R06_skin``: the small body that carries a slipping row's markers."""
    return f"R{row + 1:02d}_skin"


def slip_rows(seen: np.ndarray, prior: SlipPrior) -> np.ndarray:
    """Row indices that get a slip coordinate: the seen rows (R,) bool above the lowest
    ``prior.pinned`` seen ones."""
    return np.flatnonzero(seen)[prior.pinned:]


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def row_sides(positions: np.ndarray, tape: TapeSpec) -> tuple[np.ndarray, np.ndarray]:
    """(..., R, 3) ``L`` and ``R`` dot of every row from (..., D, 3) positions (NaN where unseen)."""
    graph = tape.graph
    column = np.array(graph.column)
    shape = positions.shape[:-2] + (tape.n_rows, 3)
    left, right = np.full(shape, np.nan), np.full(shape, np.nan)
    for r in range(tape.n_rows):
        for side, out in (("L", left), ("R", right)):
            index = np.flatnonzero((graph.row == r) & (column == side))
            if len(index):
                out[..., r, :] = positions[..., index[0], :]
    return left, right


def _shifted(centre: np.ndarray, k: int) -> np.ndarray:
    """``centre`` of the row ``k`` rows up (k > 0) or down, NaN beyond the tape."""
    out = np.full_like(centre, np.nan)
    if k > 0:
        out[..., :-k, :] = centre[..., k:, :]
    else:
        out[..., -k:, :] = centre[..., :k, :]
    return out


def _midline_tangents(centre: np.ndarray) -> np.ndarray:
    """(..., R, 3) unit midline tangent at every row from the neighbouring rows' centres: central
    difference, or the second-order one-sided difference at an end or beside an unseen row (a
    plain one-sided chord would be off by half a row's turn); NaN without two seen rows on a side."""
    up, up2, down, down2 = (_shifted(centre, k) for k in (1, 2, -1, -2))
    forward = -3.0 * centre + 4.0 * up - up2
    backward = 3.0 * centre - 4.0 * down + down2
    step = np.where(np.isfinite(up) & np.isfinite(down), 2.0 * (up - down),
                    np.where(np.isfinite(forward), forward, backward))
    return _unit(step)


def row_tilt(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-plane tilt (rad) of every row's L->R axis from the perpendicular to the midline, toward
    the midline's cranial tangent; with the unit tangent and the tape normal (tangent's
    perpendicular part x tangent). Inputs (..., R, 3); NaN where a row or its neighbours are unseen."""
    centre = 0.5 * (left + right)
    tangent = _midline_tangents(centre)
    axis = _unit(right - left)
    along = np.sum(axis * tangent, axis=-1)
    across = _unit(axis - along[..., None] * tangent)
    normal = _unit(np.cross(across, tangent))
    return np.arcsin(np.clip(along, -1.0, 1.0)), tangent, normal


def geometric_slips(positions: np.ndarray, static: np.ndarray, tape: TapeSpec, depth_mm: np.ndarray,
                    reference: int) -> np.ndarray:
    """(F, R) skin slip (mm, cranial positive) of every row against its vertebra, relative to row
    ``reference``, from the tape alone: the midline's lengthening from ``reference`` to the row
    (the steps between the row centres) minus what the vertebrae lengthen the skin by when bent
    forward (the skin lies ``depth_mm`` (R,) behind the joint centres, so a forward turn of the
    midline by ``a`` rad between two rows lengthens it by depth x ``a``; sideways bending and
    twisting leave the midline's length alone). ``positions`` (F, D, 3), ``static`` (D, 3):
    OpenSim ground, mm, NaN = not to be used. In each frame only the rows seen there and in the
    static trial count (a gap is bridged by the chord, in both); a row inside a gap gets the slip
    interpolated from its neighbours; NaN beyond the highest (lowest) seen row and in frames
    without ``reference`` (below ``reference``: the same sum downward)."""
    left, right = row_sides(positions, tape)
    s_left, s_right = row_sides(static[None], tape)
    out = np.full(positions.shape[:1] + (tape.n_rows,), np.nan)
    rows = np.arange(tape.n_rows)
    for f in range(len(positions)):
        now = _row_geometry(left[f], right[f])
        seen = np.isfinite(now[0]).all(axis=1) & np.isfinite(now[1]).all(axis=1)
        before = _row_geometry(np.where(seen[:, None], s_left[0], np.nan), np.where(seen[:, None], s_right[0], np.nan))
        seen &= np.isfinite(before[0]).all(axis=1) & np.isfinite(before[1]).all(axis=1)
        if not seen[reference] or seen.sum() < 2:
            continue
        index = np.flatnonzero(seen)
        depth = depth_mm[index]
        stretch = (_lengthening(now[0][index], now[1][index], now[2][index], depth)
                   - _lengthening(before[0][index], before[1][index], before[2][index], depth))  # between seen rows
        along = np.concatenate([[0.0], np.cumsum(stretch)])
        along -= along[np.searchsorted(index, reference)]
        inside = (rows >= index[0]) & (rows <= index[-1])
        out[f, inside] = np.interp(rows[inside], index, along)
    return out


def _row_geometry(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R, 3) row centres (NaN where the row or its midline tangent is unknown), unit L->R axes
    and unit midline tangents of one frame's side dots (R, 3)."""
    centre = 0.5 * (left + right)
    tangent = _midline_tangents(centre)
    centre = np.where(np.isfinite(tangent).all(axis=1, keepdims=True), centre, np.nan)
    return centre, _unit(right - left), tangent


def _lengthening(centre: np.ndarray, across: np.ndarray, tangent: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(n - 1,) skin length between consecutive rows (n, 3) minus the skin's rigid part of it: the
    step between the centres less the mean depth x the forward turn of the tangent (rad) about the
    pair's mean L->R axis (both tangents projected across that axis; forward = the upper tangent
    tipped toward the front, about -right)."""
    step = np.linalg.norm(np.diff(centre, axis=0), axis=1)
    axis = _unit(across[:-1] + across[1:])

    def flat(t: np.ndarray) -> np.ndarray:
        return t - np.sum(t * axis, axis=-1, keepdims=True) * axis

    lower, upper = flat(tangent[:-1]), flat(tangent[1:])
    turn = -np.arctan2(np.sum(np.cross(lower, upper) * axis, axis=-1), np.sum(lower * upper, axis=-1))
    return step - 0.5 * (depth[:-1] + depth[1:]) * turn


def normalise_row_tilt(positions: np.ndarray, static: np.ndarray, tape: TapeSpec) -> tuple[np.ndarray, np.ndarray]:
    """Every row of (F, D, 3) positions turned about its centre (the L-R midpoint), about the tape
    normal, so that its in-plane tilt to the midline equals the static trial's (``static`` (D, 3));
    rows without both side dots, a seen neighbour or a static tilt stay as they are.
    Returns (positions, correction (F, R) deg: the turn applied, NaN where none)."""
    left, right = row_sides(positions, tape)
    tilt, _, normal = row_tilt(left, right)
    s_left, s_right = row_sides(static[None], tape)
    static_tilt = row_tilt(s_left, s_right)[0][0]
    turn = static_tilt[None, :] - tilt  # (F, R)
    centre = 0.5 * (left + right)
    out = positions.copy()
    graph = tape.graph
    ok = np.isfinite(turn) & np.isfinite(normal).all(axis=-1)
    for f, r in zip(*np.nonzero(ok)):
        rotation = Rotation.from_rotvec(normal[f, r] * turn[f, r]).as_matrix()
        dots = np.flatnonzero(graph.row == r)
        out[f, dots] = centre[f, r] + (positions[f, dots] - centre[f, r]) @ rotation.T
    return out, np.where(ok, np.degrees(turn), np.nan)
