"""What a detector hands the tracker for one camera image: :class:`ViewDots` (core type, shared by
:mod:`spinemocap.detect` and :mod:`spinemocap.track`). Image coordinates in px."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ViewDots:
    """Dots detected in one camera image for one frame.

    ``uv``: (N, 2) distorted pixel centres; ``confidence``: (N,) in [0, 1];
    ``mask``: tape mask (H, W) bool or None; ``image``: the grey image (H, W) uint8 or None
    (kept for MRF2's image evidence)."""

    camera: int
    uv: np.ndarray
    confidence: np.ndarray
    mask: np.ndarray | None = None
    image: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.uv)
