"""A tape on a body model, per frame: the paper's body-model ground truth (its "MoSh" baseline).

The tape is laid on the fitted body in its rest pose as the studio lays it (a taut strip up the
back from a vertebral level: :func:`lay_tape`) or bound to the tracked dots of one chosen frame (:func:`bind_to_tracked`), and
read off the posed body in every frame: the dots' labels are the tracker's (``spec.graph``),
so the result is a marker table to export beside the tracked dots as ``REF_*`` markers. Units
mm, the studio frame.
"""

from __future__ import annotations

import numpy as np

from ..skin import FramedBinding, LaidTape, bind_to_nearest
from ..tape import TapeSpec
from .base import RestBody
from .markersets import level_heights


def lay_tape(rest: RestBody, spec: TapeSpec, start_level: str = "L4",
             levels: dict[str, float] | None = None) -> LaidTape:
    """Lay ``spec`` as a taut strip up the back of a rest body (the studio's laying, core
    :class:`~spinemocap.skin.LaidTape`), its first row at ``start_level``. ``levels``: vertebral
    level name -> rest height z (mm) in the rest body's frame; by default this body's own
    (:func:`~.markersets.level_heights`: the studio's surface-anatomy table, S2 at the PSIS from
    the hip joints, C7 at the neck joint)."""
    return LaidTape(rest.vertices, rest.faces, level_heights(rest) if levels is None else levels, spec, start_level)


def bind_to_tracked(vertices: np.ndarray, faces: np.ndarray, dots_mm: np.ndarray) -> tuple[FramedBinding, np.ndarray]:
    """Bind the tracked dots (D, 3) mm of one frame (NaN where missing) to the body posed in that
    frame (``vertices`` (V, 3) mm). Returns the binding of the finite dots and their indices."""
    dots_mm = np.asarray(dots_mm, float)
    present = np.flatnonzero(np.isfinite(dots_mm).all(axis=1))
    if len(present) == 0:
        raise ValueError("no tracked dot in the reference frame")
    return bind_to_nearest(vertices, faces, dots_mm[present]), present


def dots_over_frames(binding: FramedBinding, vertices: np.ndarray, faces: np.ndarray, n_dots: int | None = None,
                     present: np.ndarray | None = None) -> np.ndarray:
    """(F, D, 3) mm dot positions read off posed meshes (F, V, 3); dots not bound (``present``
    lists those bound) are NaN."""
    seq = binding.sequence(vertices, faces)
    if present is None:
        return seq
    out = np.full((len(vertices), n_dots or int(present.max()) + 1, 3), np.nan)
    out[:, present] = seq
    return out
