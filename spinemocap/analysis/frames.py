"""Anatomical frames: a segment frame at any level of the tape, and the pelvis frame.

Every frame is a (..., 3, 3) rotation whose **columns** are, in world coordinates:

- ``a``: anterior (the subject's front),
- ``s``: superior (toward the head; on the tape: the midline tangent),
- ``r``: the subject's right,

a right-handed triple with ``a x s = r`` (ISB's X anterior, Y superior, Z right).

Segment frame at a tape level: ``s`` = the midline tangent there, ``r`` = the tape's transverse
axis (L -> R dots) made orthogonal to ``s``, ``a = s x r``. Because the labels already say which
side is the subject's right, no facing direction is needed; :func:`check_facing` uses the
capture's ``facing`` to catch a mirrored or mislabelled tape.

Pelvis frame: from Vicon pelvis markers (LASI/RASI/LPSI/RPSI, Plug-in Gait definition: origin at
the ASIS midpoint, ``r`` along LASI -> RASI, ``a`` from the PSIS midpoint to the ASIS midpoint
made orthogonal to ``r``), or from the tape's sacral rows: the technical frame at the tape's
lowest rows, turned by the constant offset that aligns it with the subject's ``facing``/``up`` in
the neutral frame (an anatomical calibration on the first frame, as IMU systems do).

Relative angles between two frames use the Cardan sequence flexion (about ``r``), lateral bending
(about the floated ``a``), axial rotation (about ``s`` of the upper frame): see
:func:`cardan_angles`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..fileio import InputError
from ..markers import MarkerTable

PELVIS_MARKERS = ("LASI", "RASI", "LPSI", "RPSI")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def frame_from_axes(superior: np.ndarray, right: np.ndarray) -> np.ndarray:
    """(..., 3, 3) frames with columns (a, s, r) from a superior and an approximate right axis
    (..., 3); ``right`` is made orthogonal to ``superior``. NaN inputs give NaN frames."""
    s = _unit(np.asarray(superior, float))
    right = np.asarray(right, float)
    r = _unit(right - np.sum(right * s, axis=-1, keepdims=True) * s)
    a = np.cross(s, r)
    return np.stack([a, s, r], axis=-1)


def cardan_angles(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Angles of the ``upper`` frame relative to the ``lower`` one, degrees, (..., 3):

    0. flexion: forward bending positive -- the upper ``s`` axis tilting toward the lower ``a``
       axis; equals the angle between the two ``s`` axes projected on the lower frame's sagittal
       plane (``a``-``s``);
    1. lateral bending: toward the subject's right positive; equals the elevation of the upper
       ``s`` axis out of that sagittal plane;
    2. axial rotation: toward the subject's left positive (counter-clockwise seen from above) --
       the twist of the upper ``r`` axis about ``s``.

    Sequence: R_rel = lower^T upper = Rz(-flexion) Rx(lateral) Ry(axial) in the (a, s, r) = (x,
    y, z) axes. NaN where either frame is NaN.
    """
    rel = np.einsum("...ji,...jk->...ik", lower, upper)
    shape = rel.shape[:-2]
    flat = rel.reshape(-1, 3, 3)
    out = np.full((flat.shape[0], 3), np.nan)
    ok = np.isfinite(flat).all(axis=(1, 2))
    if ok.any():
        zxy = Rotation.from_matrix(flat[ok]).as_euler("ZXY", degrees=True)
        out[ok] = np.column_stack([-zxy[:, 0], zxy[:, 1], zxy[:, 2]])
    return out.reshape(*shape, 3)


def neutral_frame(up: np.ndarray, facing: np.ndarray) -> np.ndarray:
    """The (3, 3) anatomical frame of a subject standing with ``up`` and ``facing`` (world)."""
    up = _unit(np.asarray(up, float))
    facing = np.asarray(facing, float)
    a = _unit(facing - np.dot(facing, up) * up)
    return np.stack([a, up, np.cross(a, up)], axis=-1)


def pelvis_frame_from_tape(sacral_frames: np.ndarray, up: np.ndarray, facing: np.ndarray,
                           neutral: int = 0) -> np.ndarray:
    """Pelvis frames (F, 3, 3) from the tape's technical frames at the sacral rows (F, 3, 3).

    The constant offset ``T_neutral^T A`` with ``A`` = :func:`neutral_frame` (up, facing) is
    fixed at frame ``neutral`` (or the first frame with a finite sacral frame after it)."""
    finite = np.flatnonzero(np.isfinite(sacral_frames).all(axis=(1, 2)))
    finite = finite[finite >= neutral]
    if not len(finite):
        return np.full_like(sacral_frames, np.nan)
    offset = sacral_frames[finite[0]].T @ neutral_frame(up, facing)
    return sacral_frames @ offset


def pelvis_frame_from_markers(markers: dict[str, np.ndarray], source: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Plug-in Gait pelvis from (F, 3) trajectories of LASI, RASI, LPSI, RPSI (mm, world).

    Returns (origin (F, 3) = ASIS midpoint, frames (F, 3, 3)). NaN where a marker is missing."""
    absent = [m for m in PELVIS_MARKERS if m not in markers]
    if absent:
        raise InputError(source, f"pelvis markers {absent} not found (need {list(PELVIS_MARKERS)})")
    lasi, rasi, lpsi, rpsi = (np.asarray(markers[m], float) for m in PELVIS_MARKERS)
    mid_asis, mid_psis = 0.5 * (lasi + rasi), 0.5 * (lpsi + rpsi)
    r = _unit(rasi - lasi)
    fwd = mid_asis - mid_psis
    a = _unit(fwd - np.sum(fwd * r, axis=-1, keepdims=True) * r)
    s = np.cross(r, a)
    return mid_asis, np.stack([a, s, r], axis=-1)


def pelvis_markers(table: MarkerTable, source: str | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Pelvis marker trajectories from a marker table (e.g. a Vicon C3D read with
    ``exporters.read``): (time (F,) s from the first frame, {name: (F, 3) mm}).

    Missing samples are NaN; marker names are matched case-insensitively after stripping a
    ``Subject:`` prefix. Raises :class:`InputError` naming ``source`` if any is absent."""
    labels = [str(lab).strip().split(":")[-1].upper() for lab in table.labels]
    frames, data = table.dense()
    found = {name: data[:, labels.index(name)] for name in PELVIS_MARKERS if name in labels}
    if len(found) < len(PELVIS_MARKERS):
        raise InputError(source, f"C3D lacks pelvis markers {sorted(set(PELVIS_MARKERS) - set(found))}")
    return (frames - frames[0]) / float(table.fps), found


def check_facing(frames: np.ndarray, facing: np.ndarray, source: str | None = None) -> None:
    """Raise :class:`InputError` if the tape's anterior axis points away from the subject's
    ``facing`` (which holds for the first frame: median over the first 10 finite frames): the
    tape is mirrored or its L/R labels are swapped."""
    a = frames[..., :, 0]
    ok = np.isfinite(a).all(axis=-1)
    if not ok.any():
        return
    cos = np.median(a[ok][:10] @ _unit(np.asarray(facing, float)))
    if cos < 0:
        raise InputError(
            source,
            "the tape's anterior axis (tangent x L->R) points away from the subject's facing "
            "direction: L/R labels look swapped or the tape runs head-to-sacrum",
        )
