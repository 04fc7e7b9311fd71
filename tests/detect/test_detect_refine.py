"""Full-resolution mask clean-up (spinemocap.detect.refine) on drawn tapes with exact masks."""

import cv2
import numpy as np
import pytest

from spinemocap.detect.blobs import find_dots
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.refine import extend_along_tape, keep_dotted, snap_to_edges


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


@pytest.fixture(scope="module")
def drawn():
    """A vertical-ish 9-row tape, dots ~14 px, on skin; grey background."""
    sample = draw_sample(np.random.default_rng(3), size=(480, 640), px_per_mm=1.4, n_rows=9)
    skin = np.median(sample.image[~sample.mask], axis=0)
    tape = np.median(sample.image[sample.mask], axis=0)
    assert skin.mean() > tape.mean() + 40  # the drawing is what the tests assume
    return sample


@pytest.mark.parametrize("grow", [2, -2])
def test_snap_moves_a_too_wide_or_too_narrow_outline_onto_the_edge(drawn, grow):
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * abs(grow) + 1,) * 2)
    off = (cv2.dilate if grow > 0 else cv2.erode)(drawn.mask.astype(np.uint8), k).astype(bool)
    before = iou(off, drawn.mask)
    after = iou(snap_to_edges(drawn.image, off), drawn.mask)
    assert before < 0.95 and after > 0.98


def test_extension_restores_a_tape_the_mask_stops_short_of(drawn):
    ys = np.flatnonzero(drawn.mask.any(axis=1))
    cut = drawn.mask.copy()
    cut[: ys[0] + (ys[-1] - ys[0]) // 2] = False  # the network saw only the lower half
    assert iou(cut, drawn.mask) < 0.6
    out = extend_along_tape(drawn.image, cut).mask
    assert iou(snap_to_edges(drawn.image, out), drawn.mask) > 0.97
    assert len(find_dots(drawn.image, out)[0]) == len(drawn.uv)


def test_extension_ignores_dark_regions_without_dots_and_skin_coloured_occluders(drawn):
    image = drawn.image.copy()
    tape_colour = np.median(drawn.image[drawn.mask], axis=0)
    skin_colour = np.median(drawn.image[~drawn.mask & (np.arange(640)[:, None] > 100)], axis=0)
    ys, xs = np.nonzero(drawn.mask)
    # a dark patch as wide as the tape beside it (shadow, hair, garment), touching the tape ...
    patch = np.zeros_like(drawn.mask)
    patch[ys.mean().astype(int) - 60: ys.mean().astype(int) + 60, xs.max() - 5: xs.max() + 60] = True
    patch &= ~drawn.mask
    image[patch] = tape_colour
    # ... and a skin-coloured ball over the tape's middle, outside the mask
    ball = np.zeros_like(drawn.mask)
    cv2.circle(ball.view(np.uint8), (int(xs.mean()), int(ys.min() + 60)), 30, 1, -1)
    image[ball] = skin_colour
    mask = drawn.mask & ~ball
    out = extend_along_tape(image, mask).mask
    assert not (out & patch).any()
    assert (out & ball).sum() < 0.1 * ball.sum()  # only what the filled tape outline encloses


def test_components_without_dots_are_dropped(drawn):
    stray = np.zeros_like(drawn.mask)
    stray[10:40, 10:200] = True  # e.g. a weak answer along a body silhouette
    dots, _ = find_dots(drawn.image, drawn.mask)
    out = keep_dotted(drawn.mask | stray, dots)
    assert not (out & stray).any() and (out == drawn.mask).all()


def test_a_tape_lighter_than_the_skin_is_left_to_the_network(drawn):
    light = 255 - drawn.image  # light tape, dark dots and skin
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    off = cv2.dilate(drawn.mask.astype(np.uint8), k).astype(bool)
    assert (snap_to_edges(light, off) == off).all()
    half = drawn.mask & (np.arange(drawn.mask.shape[0])[:, None] > drawn.mask.shape[0] // 2)
    assert (extend_along_tape(light, half).mask == half).all()


def test_a_dropped_dotless_component_leaves_the_tapes_snap_dots_and_levels_as_without_it(drawn):
    # a dark stripe without dots far from the tape (a shadow the network answered on): dropped,
    # and the tape's snapped outline, dots and levels are (nearly) those of the tape alone, though
    # they are not measured again without it (the first snap and levels are kept, less the stripe)
    from spinemocap.capture import to_grey
    from spinemocap.detect.refine import RefineParams, _kept_levels, _levels, _near

    image = drawn.image.copy()
    stray = np.zeros_like(drawn.mask)
    stray[20:60, 20:300] = True
    image[stray] = np.median(drawn.image[drawn.mask], axis=0)
    alone, with_stray = extend_along_tape(image, drawn.mask), extend_along_tape(image, drawn.mask | stray)
    assert not (with_stray.mask & stray).any() and not (with_stray.snapped & stray).any()
    assert (with_stray.mask == alone.mask).all()
    assert (with_stray.snapped != alone.snapped).sum() <= 0.01 * alone.snapped.sum()
    assert len(with_stray.uv) == len(alone.uv) >= 20
    assert np.abs(np.sort(with_stray.uv, axis=0) - np.sort(alone.uv, axis=0)).max() < 0.2
    grey, p = to_grey(image), RefineParams()
    both = _levels(grey, drawn.mask | stray, p.band_px, p.min_contrast)
    kept = _kept_levels(grey, both, drawn.mask, _near(drawn.mask, 0), p)
    own = _levels(grey, drawn.mask, p.band_px, p.min_contrast)
    assert kept is not None and not (kept.tape[stray[kept.box]]).any()
    assert abs(float(kept.tape_median) - float(own.tape_median)) <= 2
    assert abs(float(kept.ring_median) - float(own.ring_median)) <= 2


def test_a_tape_grown_along_the_dark_region_reports_the_new_regions_dots_and_snapped_outline(drawn):
    # the network saw only the lower half: the upper half joins, its dots (found while testing the
    # region, in the region's own crop) come back at their place in the box, with the known ones
    ys = np.flatnonzero(drawn.mask.any(axis=1))
    cut = drawn.mask.copy()
    cut[: ys[0] + (ys[-1] - ys[0]) // 2] = False
    out = extend_along_tape(drawn.image, cut)
    assert iou(out.snapped, drawn.mask) > 0.97 and (out.mask >= cut).all()
    assert len(out.uv) == len(drawn.uv) and len(out.confidence) == len(out.uv)
    distance = np.linalg.norm(out.uv[:, None] - np.asarray(drawn.uv)[None], axis=2)
    assert distance.min(axis=1).max() < 1.0 and distance.min(axis=0).max() < 1.0  # each drawn dot found once


@pytest.mark.parametrize("share", [0.3, 0.45])
def test_extension_follows_the_tape_to_its_end_against_a_mid_grey_backdrop(drawn, share):
    # the tape runs over the body's outline into a backdrop darker than midway between the tape and
    # the skin (a grey studio wall beside a black tape): the network saw only the lower half; the
    # upper half joins, the backdrop does not
    from spinemocap.detect.refine import RefineParams

    ys = np.flatnonzero(drawn.mask.any(axis=1))
    tape_colour = np.median(drawn.image[drawn.mask], axis=0)
    skin_colour = np.median(drawn.image[~drawn.mask & (np.arange(640)[:, None] > 100)], axis=0)
    backdrop = np.zeros_like(drawn.mask)
    backdrop[: ys[0] + 8] = True  # the tape's first few px lie on it
    backdrop &= ~drawn.mask
    image = drawn.image.copy()
    image[backdrop] = np.round(tape_colour + share * (skin_colour - tape_colour)).astype(np.uint8)
    cut = drawn.mask.copy()
    cut[: ys[0] + (ys[-1] - ys[0]) // 2] = False
    out = extend_along_tape(image, cut)
    assert iou(out.snapped, drawn.mask) > 0.97
    assert (out.mask & backdrop).sum() < 0.01 * drawn.mask.sum()
    assert len(out.uv) == len(drawn.uv)
    # a threshold midway to the skin takes the backdrop with the tape's end: too wide, nothing joins
    midway = extend_along_tape(image, cut, RefineParams(extend_dark_share=0.5))
    assert iou(midway.snapped, drawn.mask) < 0.6
