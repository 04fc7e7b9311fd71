"""The clean-up's cheaper paths give what their reference paths give, bit
for bit, on varied inputs: the dark pieces joined to the mask by flood fills (the whole crop's
labelling is the reference), boxes measured inside a box known to hold the mask, and the whole
clean-up (``extend_along_tape``) with the reference paths swapped in."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spinemocap.detect import blobs, refine
from spinemocap.detect.blobs import find_dots, mask_box, mask_box_within
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.refine import (
    _joined_dark_pieces,
    _joined_dark_pieces_labelled,
    components_touching,
    extend_along_tape,
)


def _smooth_grey(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Blotchy grey levels over the whole range (dark regions of all sizes, touching each other)."""
    noise = rng.random((shape[0] // 8 + 2, shape[1] // 8 + 2)).astype(np.float32)
    big = cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    fine = rng.normal(0, 0.08, shape).astype(np.float32)
    return np.clip((big + fine) * 255, 0, 255).astype(np.uint8)


def _random_mask(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    for _ in range(int(rng.integers(1, 4))):  # strips (tapes), some running off the crop's border
        p0 = (int(rng.integers(-20, shape[1] + 20)), int(rng.integers(-20, shape[0] + 20)))
        p1 = (int(rng.integers(-20, shape[1] + 20)), int(rng.integers(-20, shape[0] + 20)))
        cv2.line(mask, p0, p1, 1, int(rng.integers(3, 30)))
    for _ in range(int(rng.integers(0, 5))):  # blobs, some with holes
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        cv2.circle(mask, centre, int(rng.integers(2, 25)), 1, -1)
        cv2.circle(mask, centre, int(rng.integers(0, 3)), 0, -1)
    return mask.astype(bool)


def test_dark_pieces_by_flood_fills_are_the_labelled_crops():
    rng = np.random.default_rng(29)
    checked = filled = 0
    for _ in range(60):
        shape = (int(rng.integers(20, 160)), int(rng.integers(20, 160)))
        grey = _smooth_grey(rng, shape)
        base = _random_mask(rng, shape)
        box = mask_box(base)
        if box is None:
            continue
        # thresholds across the range, beyond it and at fractions (below a level is below its ceiling)
        for threshold in (float(rng.uniform(0, 255)), float(rng.integers(1, 255)), -3.0, 0.0, 0.4, 255.2, 300.0):
            for g in (grey, _read_only(grey), _strided(grey, rng)):
                expected_box, expected = _joined_dark_pieces_labelled(g, base, threshold)
                before = g.copy()
                ours_box, ours = _joined_dark_pieces(g, base, box, threshold)
                assert np.array_equal(g, before)  # the fills write their mask only, never the image
                assert ours_box == expected_box
                assert ours.dtype == bool and np.array_equal(ours, expected)
                checked += 1
                filled += int(np.count_nonzero(expected)) > int(np.count_nonzero(base))
        # a float32 image takes the reference path
        f = grey.astype(np.float32) + 0.25
        b1, j1 = _joined_dark_pieces(f, base, box, 100.0)
        b2, j2 = _joined_dark_pieces_labelled(f, base, 100.0)
        assert b1 == b2 and np.array_equal(j1, j2)
    assert checked > 500 and filled > 100  # pieces were joined in many of them


def _read_only(grey: np.ndarray) -> np.ndarray:
    g = grey.copy()
    g.flags.writeable = False
    return g


def _strided(grey: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``grey`` as a view into a larger image (a box of a frame)."""
    h, w = grey.shape
    big = rng.integers(0, 256, (h + 10, w + 13), dtype=np.uint8)
    big[4:4 + h, 7:7 + w] = grey
    return big[4:4 + h, 7:7 + w]


def test_mask_boxes_measured_within_a_box_are_the_whole_masks():
    rng = np.random.default_rng(5)
    for _ in range(200):
        shape = (int(rng.integers(1, 90)), int(rng.integers(1, 90)))
        mask = rng.random(shape) < rng.uniform(0, 0.02)
        box = mask_box(mask)
        assert mask_box_within(mask, None) == box
        for margin in (0, 1, 4):
            whole = mask_box(mask, margin)
            if box is None:  # any box holds an empty mask's pixels
                assert mask_box_within(mask, (slice(0, shape[0] // 2), slice(1, shape[1]))) is None
                continue
            within = (slice(int(rng.integers(0, box[0].start + 1)), int(rng.integers(box[0].stop, shape[0] + 1))),
                      slice(int(rng.integers(0, box[1].start + 1)), int(rng.integers(box[1].stop, shape[1] + 1))))
            assert mask_box_within(mask, within, margin) == whole
            reference = rng.random(shape) < 0.05
            assert np.array_equal(components_touching(mask, reference, within), components_touching(mask, reference))


@pytest.fixture(scope="module")
def drawn_tapes():
    rng = np.random.default_rng(41)
    return [draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0)
            for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2), ((640, 480), 0.9), ((600, 700), 1.8)]]


def _damaged_masks(sample, rng: np.random.Generator):
    """The true mask, cut short, grown and shrunk, with dot-less specks: masks that make the
    clean-up drop components, extend along the tape and snap."""
    mask = sample.mask
    ys = np.flatnonzero(mask.any(axis=1))
    cut = mask.copy()
    cut[: ys[0] + (ys[-1] - ys[0]) // 2] = False
    yield cut
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    yield cv2.dilate(mask.astype(np.uint8), k).astype(bool)
    yield cv2.erode(mask.astype(np.uint8), k).astype(bool)
    specks = mask.copy()
    h, w = mask.shape
    for _ in range(4):
        cv2.circle(specks.view(np.uint8), (int(rng.integers(0, w)), int(rng.integers(0, h))), int(rng.integers(3, 12)), 1, -1)
    yield specks


def test_clean_up_with_the_cheaper_paths_is_the_reference_paths(drawn_tapes, monkeypatch):
    rng = np.random.default_rng(7)
    cases = [(s.image, m) for s in drawn_tapes for m in _damaged_masks(s, rng)]
    ours = [extend_along_tape(image, mask) for image, mask in cases]
    for (image, _), a in zip(cases, ours):  # find_dots with and without a box holding the mask
        box = mask_box(a.snapped, 3)
        assert all(np.array_equal(u, v) for u, v in zip(find_dots(image, a.snapped, within=box), find_dots(image, a.snapped)))
    # the reference paths: the whole crop labelled, boxes measured on the whole mask
    monkeypatch.setattr(refine, "_joined_dark_pieces", lambda grey, base, box, t: _joined_dark_pieces_labelled(grey, base, t))
    monkeypatch.setattr(blobs, "mask_box_within", lambda mask, within, margin=0: mask_box(mask, margin))
    monkeypatch.setattr(refine, "mask_box_within", lambda mask, within, margin=0: mask_box(mask, margin))
    dots = 0
    for (image, mask), a in zip(cases, ours):
        b = extend_along_tape(image, mask)
        assert np.array_equal(a.mask, b.mask) and np.array_equal(a.snapped, b.snapped)
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.confidence, b.confidence)
        dots += len(a.uv)
    assert dots > 100


def test_distinct_labels_from_bit_sets_are_the_sorted_rows():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 63, 64, 65, 100, 128, 129, 200, 254, 256):
        for shape in ((0, 5), (1, 1), (7, 21), (300, 45), (50, 97)):
            near = rng.integers(0, n, shape).astype(np.uint8)
            near[rng.random(shape) < rng.uniform(0, 1)] = 0  # many without a label, some rows empty
            which, owner = blobs._distinct_labels(near, n)
            ref_which, ref_owner = blobs._distinct_labels_sorted(near)
            assert np.array_equal(which, ref_which) and np.array_equal(owner, ref_owner)
            assert which.dtype == ref_which.dtype and owner.dtype == ref_owner.dtype
