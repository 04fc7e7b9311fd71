"""The classical segmentation: a dark region is tape only when perforated (holes alike, a
plausible share of its area), its holes are filled into the mask, and a frame reduced to
``work_width`` still gives a full-resolution mask."""

from __future__ import annotations

import cv2
import numpy as np

from spinemocap.detect.classical import segment_classical
from spinemocap.detect.drawn import draw_sample


def _dark_strip(holes: bool) -> tuple[np.ndarray, np.ndarray]:
    """A bright grey image (240 x 320) with a dark 60 x 200 px strip, perforated by a grid of
    bright 8 px discs or plain; returns the image and the strip's mask."""
    image = np.full((240, 320), 190, np.uint8)
    image[20:220, 130:190] = 35
    truth = np.zeros(image.shape, bool)
    truth[20:220, 130:190] = True
    if holes:
        for v in range(40, 210, 25):
            for u in (145, 175):
                cv2.circle(image, (u, v), 4, 200, -1)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), truth


def test_a_perforated_dark_strip_is_tape_with_its_holes_filled():
    image, truth = _dark_strip(holes=True)
    mask = segment_classical(image)
    assert mask.shape == truth.shape and mask.dtype == bool
    assert (mask & truth).sum() / (mask | truth).sum() > 0.95
    assert mask[40, 145] and mask[190, 175]  # the holes belong to the tape


def test_a_plain_dark_region_is_not_tape():
    image, _ = _dark_strip(holes=False)
    assert not segment_classical(image).any()


def test_a_reduced_frame_gives_a_full_resolution_mask():
    sample = draw_sample(np.random.default_rng(2), size=(480, 360), px_per_mm=1.2, noise=2)
    full = segment_classical(sample.image)
    reduced = segment_classical(sample.image, work_width=400)
    assert reduced.shape == sample.mask.shape
    for mask in (full, reduced):
        assert (mask & sample.mask).sum() / (mask | sample.mask).sum() > 0.85
