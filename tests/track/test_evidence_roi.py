"""MRF2's evidence is built only around the tape: the cropped cost reads as the
whole-frame one where it matters, and a camera without tape costs one pixel, not a frame."""

import numpy as np

from spinemocap.track.evidence import build_evidence


def _image_and_tape():
    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, (480, 640), dtype=np.uint8)
    tape = np.zeros(grey.shape, bool)
    tape[200:260, 300:330] = True
    return grey, tape


def test_cropped_evidence_reads_as_the_whole_frame_one_on_and_near_the_tape():
    grey, tape = _image_and_tape()
    whole = build_evidence(grey, tape, crop_margin_px=None)
    cropped = build_evidence(grey, tape)
    assert cropped.cost.size < whole.cost.size / 4
    ys, xs = np.mgrid[190:270, 290:340]
    uv = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(float) + 0.25
    np.testing.assert_allclose(cropped.sample(uv), whole.sample(uv), rtol=1e-6)


def test_a_view_without_tape_costs_one_pixel_with_the_whole_frame_values():
    grey, tape = _image_and_tape()
    empty = np.zeros_like(tape)
    whole = build_evidence(grey, empty, crop_margin_px=None)
    small = build_evidence(grey, empty)
    assert small.cost.shape == (1, 1)
    uv = np.random.default_rng(2).uniform([0, 0], [640, 480], (200, 2))
    np.testing.assert_array_equal(small.sample(uv), whole.sample(uv))
