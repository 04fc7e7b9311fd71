"""ViewDots: the grey image is made from a colour image on first read, once; a view holds one
image or the other; the tape mask is required where a caller reads it."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.capture import to_grey
from spinemocap.views import ViewDots


def _colour() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)


def test_the_grey_image_is_made_from_the_colour_image_on_first_read():
    colour = _colour()
    view = ViewDots(1, np.zeros((2, 2)), np.ones(2), colour=colour)
    assert view.held_image is colour  # nothing converted yet
    grey = view.image
    assert grey is not None and grey.shape == (6, 8)
    np.testing.assert_array_equal(grey, to_grey(colour))
    assert view.image is grey and view.held_image is grey  # converted once, the colour image dropped
    assert len(view) == 2


def test_a_view_holds_one_image_and_setting_the_grey_one_drops_the_colour():
    with pytest.raises(ValueError, match="not both"):
        ViewDots(0, np.zeros((0, 2)), np.zeros(0), image=np.zeros((2, 2), np.uint8), colour=_colour())
    view = ViewDots(0, np.zeros((0, 2)), np.zeros(0), colour=_colour())
    view.image = np.full((2, 2), 7, np.uint8)
    assert view.held_image is not None and view.held_image.shape == (2, 2)
    assert ViewDots(0, np.zeros((0, 2)), np.zeros(0)).held_image is None


def test_the_tape_mask_is_refused_where_none_was_given():
    with pytest.raises(ValueError, match="camera 3's view has no tape mask"):
        _ = ViewDots(3, np.zeros((0, 2)), np.zeros(0)).tape_mask
    mask = np.ones((2, 2), bool)
    assert ViewDots(3, np.zeros((0, 2)), np.zeros(0), mask=mask).tape_mask is mask
