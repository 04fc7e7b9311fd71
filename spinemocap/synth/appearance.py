"""Appearance options of the studio beyond the body and the lighting: the tape's colour and the
room behind the subject.

- :data:`TAPE_COLOURS`: kinesiology tape as labs buy it (RGB 0..1, the diffuse colour the renderer
  shades): ``black`` (the studio's tape so far), ``beige``, ``blue``, ``pink``, ``red``.
- :data:`BACKDROPS`: ``plain`` (the renderer's uniform background) or ``room``: a painted
  motion-capture room (:func:`spinemocap.synth.rooms.paint_room`, one view per camera, seeded by
  the scene and the camera) wherever the render shows the empty background; the subject, the
  tape and everything else drawn keep their pixels, and the tape mask and ground truth do not
  change.
"""

from __future__ import annotations

import functools
from typing import Literal, get_args

import numpy as np

from .rooms import paint_room

TapeColour = Literal["black", "beige", "blue", "pink", "red"]
TAPE_COLOURS: dict[str, tuple[float, float, float]] = {
    "black": (0.08, 0.08, 0.10),
    "beige": (0.78, 0.64, 0.50),
    "blue": (0.10, 0.30, 0.72),
    "pink": (0.90, 0.42, 0.60),
    "red": (0.72, 0.10, 0.12),
}
assert tuple(TAPE_COLOURS) == get_args(TapeColour)
Backdrop = Literal["plain", "room"]
BACKDROPS: tuple[str, ...] = get_args(Backdrop)


@functools.lru_cache(maxsize=16)
def room_view(size: tuple[int, int], scene_seed: int, camera: int) -> np.ndarray:
    """The room one camera sees behind the subject: RGB uint8 (H, W, 3) for ``size`` (width, height)
    (cached: the same array for the same arguments; read it, do not change it)."""
    bgr = paint_room(size, seed=int(np.random.default_rng([scene_seed, 7, camera]).integers(1 << 31)))
    return np.ascontiguousarray(bgr[..., ::-1])


def behind_subject(rgb: np.ndarray, empty_pixel: np.ndarray, room_rgb: np.ndarray) -> np.ndarray:
    """``rgb`` (H, W, 3; uint8 or float32 grey levels) with ``room_rgb`` (H, W, 3 uint8) wherever it
    shows exactly the renderer's empty background ``empty_pixel`` ((3,) uint8), in ``rgb``'s dtype."""
    empty = np.all(rgb == empty_pixel.astype(rgb.dtype), axis=2)
    out = rgb.copy()
    out[empty] = room_rgb[empty]
    return out
