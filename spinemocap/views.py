"""What a detector hands the tracker for one camera image: :class:`ViewDots` (core type, shared by
:mod:`spinemocap.detect` and :mod:`spinemocap.track`). Image coordinates in px."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .capture import to_grey


@dataclass(init=False)
class ViewDots:
    """Dots detected in one camera image for one frame.

    ``uv``: (N, 2) distorted pixel centres; ``confidence``: (N,) in [0, 1];
    ``mask``: tape mask (H, W) bool or None; ``image``: the grey image (H, W) uint8 or None
    (kept for MRF2's image evidence). Instead of ``image``, ``colour`` (the BGR uint8 image) may
    be given: the grey image is then made when :attr:`image` is first read (the same pixels), and
    the colour image is held until then (sequence tracking reads it in few frames: the conversion
    of a whole frame is skipped in the others)."""

    camera: int
    uv: np.ndarray
    confidence: np.ndarray
    mask: np.ndarray | None = None
    _image: np.ndarray | None = field(default=None, repr=False)
    _colour: np.ndarray | None = field(default=None, repr=False)

    def __init__(self, camera: int, uv: np.ndarray, confidence: np.ndarray, mask: np.ndarray | None = None,
                 image: np.ndarray | None = None, colour: np.ndarray | None = None):
        if image is not None and colour is not None:
            raise ValueError("give the grey image or the colour image, not both")
        self.camera, self.uv, self.confidence, self.mask = camera, uv, confidence, mask
        self._image, self._colour = image, colour

    @property
    def tape_mask(self) -> np.ndarray:
        """The tape mask (H, W) bool; ValueError for a view made without one."""
        if self.mask is None:
            raise ValueError(f"camera {self.camera}'s view has no tape mask")
        return self.mask

    @property
    def image(self) -> np.ndarray | None:
        """The grey image (H, W) uint8 or None (made from the colour image on the first read)."""
        colour = self._colour  # read once: another thread may convert it meanwhile (the same pixels)
        if self._image is None and colour is not None:
            self._image = to_grey(colour)
            self._colour = None
        return self._image

    @image.setter
    def image(self, value: np.ndarray | None) -> None:
        self._image, self._colour = value, None

    @property
    def held_image(self) -> np.ndarray | None:
        """The grey image when it is made, else the colour image (None when the view holds neither),
        without converting anything: for readers that need only a window of it (MRF2's evidence
        converts its window of the colour image, the same pixels as that window of :attr:`image`)."""
        colour = self._colour  # read first: a conversion in another thread sets the grey image before it drops the colour one
        grey = self._image
        return grey if grey is not None else colour

    def __len__(self) -> int:
        return len(self.uv)
