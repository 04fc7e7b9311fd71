"""Dot detection on drawn images with exact sub-pixel centres (no network, no studio)."""

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from spinemocap.detect.blobs import BlobParams, estimate_dot_diameter, fill_holes, find_dots
from spinemocap.detect.drawn import draw_sample


def _score(sample, uv):
    """Recall, precision (2 px) and RMS error against dots fully inside the frame."""
    h, w = sample.mask.shape
    m = sample.dot_px / 2 + 1
    gt = sample.uv[(sample.uv[:, 0] > m) & (sample.uv[:, 1] > m) & (sample.uv[:, 0] < w - m) & (sample.uv[:, 1] < h - m)]
    d_gt, _ = cKDTree(uv).query(gt)
    d_pred, _ = cKDTree(gt).query(uv)
    ok = d_gt < 2
    return ok.mean(), (d_pred < 2).mean(), float(np.sqrt(np.mean(d_gt[ok] ** 2)))


@pytest.mark.parametrize("noise, blur, max_rms", [(0.0, 0.0, 0.03), (4.0, 1.0, 0.1)])
def test_centres_match_exact_drawn_centres(noise, blur, max_rms):
    for seed in range(4):
        sample = draw_sample(np.random.default_rng(seed), px_per_mm=1.2, noise=noise, blur=blur)
        uv, conf = find_dots(sample.image, sample.mask, expected_dot_px=sample.dot_px)
        recall, precision, rms = _score(sample, uv)
        assert recall == 1.0 and precision == 1.0
        assert rms < max_rms
        assert np.all((conf > 0) & (conf <= 1))


def test_dot_size_estimated_from_mask_width_when_not_given():
    sample = draw_sample(np.random.default_rng(7), px_per_mm=1.0)
    assert estimate_dot_diameter(sample.mask) == pytest.approx(sample.dot_px, rel=0.2)
    uv, _ = find_dots(sample.image, sample.mask)
    recall, precision, rms = _score(sample, uv)
    assert recall == 1.0 and precision == 1.0 and rms < 0.05


def test_mask_with_holes_is_filled():
    sample = draw_sample(np.random.default_rng(3), px_per_mm=1.2)
    grey = cv2.cvtColor(sample.image, cv2.COLOR_BGR2GRAY)
    tape_only = sample.mask & (grey < 100)  # the physical tape: dots are holes in the mask
    assert fill_holes(tape_only).sum() > tape_only.sum()
    uv, _ = find_dots(sample.image, tape_only, expected_dot_px=sample.dot_px)
    assert _score(sample, uv)[:2] == (1.0, 1.0)


def test_a_dot_cut_by_a_dark_line_gives_one_blob():
    sample = draw_sample(np.random.default_rng(5), px_per_mm=1.5, size=(360, 300))
    u, v = sample.uv[len(sample.uv) // 2]
    image = sample.image.copy()
    cv2.line(image, (int(u) - 10, int(round(v))), (int(u) + 10, int(round(v))), (30, 30, 30), 1)
    uv, _ = find_dots(image, sample.mask, expected_dot_px=sample.dot_px)
    near = np.linalg.norm(uv - [u, v], axis=1) < sample.dot_px
    assert near.sum() == 1


def test_no_tape_no_dots_and_no_error():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    uv, conf = find_dots(image, np.zeros((240, 320), bool))
    assert uv.shape == (0, 2) and conf.shape == (0,)
    # A dark stripe without perforation: a mask, but nothing to find.
    plain = np.full((240, 320, 3), 180, np.uint8)
    mask = np.zeros((240, 320), bool)
    mask[40:200, 130:190] = True
    plain[mask] = 40
    noisy = np.clip(plain + rng.normal(0, 2, plain.shape), 0, 255).astype(np.uint8)
    uv, conf = find_dots(noisy, mask)
    assert len(uv) == 0


def test_full_resolution_frame():
    sample = draw_sample(np.random.default_rng(1), size=(2448, 1600), px_per_mm=1.2, n_rows=13, supersample=2, noise=2)
    uv, _ = find_dots(sample.image, sample.mask)
    recall, precision, rms = _score(sample, uv)
    assert recall == 1.0 and precision == 1.0 and rms < 0.1


def test_mask_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="mask shape"):
        find_dots(np.zeros((10, 10, 3), np.uint8), np.zeros((10, 11), bool))


def _tape_with_oblique_dot_and_speck(d: float, axis_ratio: float, speck_diameter: float) -> tuple[np.ndarray, np.ndarray]:
    """Dark tape (grey 70) with two face-on dots of diameter ``d`` px, a dot seen obliquely (an
    ellipse of major axis ``d`` and ``axis_ratio``, tilted 30 deg) at (140, 60) and a round speck
    of ``speck_diameter`` at (210, 60); anti-aliased by drawing at 8x and shrinking."""
    s, h, w = 8, 120, 260
    big = np.full((h * s, w * s), 70, np.uint8)
    for centre, axes, angle in (((30, 40), (d, d), 0), ((80, 40), (d, d), 0),
                                ((140, 60), (d, d * axis_ratio), 30), ((210, 60), (speck_diameter, speck_diameter), 0)):
        cv2.ellipse(big, ((centre[0] * s, centre[1] * s), (axes[0] * s, axes[1] * s), angle), 210, -1, cv2.LINE_AA)
    mask = np.zeros((h, w), bool)
    mask[10:110, 5:255] = True
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), mask


def test_an_obliquely_seen_dot_is_found_and_a_speck_of_its_area_is_not():
    d, axis_ratio = 24.0, 0.2
    # The detector's smoothing and half-contrast threshold keep ~60 % of so thin an ellipse: the
    # speck has the area of the ellipse's blob, below the face-on floor (0.15 of a dot's area).
    speck = d * np.sqrt(0.6 * axis_ratio)
    image, mask = _tape_with_oblique_dot_and_speck(d, axis_ratio, speck)
    uv, _ = find_dots(image, mask, expected_dot_px=d)
    near = lambda x, y: np.linalg.norm(uv - [x, y], axis=1) < 2  # noqa: E731
    assert near(30, 40).sum() == 1 and near(80, 40).sum() == 1
    assert near(140, 60).sum() == 1, "the dot seen obliquely is missed"
    assert not near(210, 60).any(), "the round speck passed for a dot"
    assert len(uv) == 3
    # one area floor for all blobs (a face-on dot's) loses the oblique dot
    face_on_only = BlobParams(min_axis_ratio=0.25, min_oblique_major=np.inf)
    uv, _ = find_dots(image, mask, expected_dot_px=d, params=face_on_only)
    assert len(uv) == 2


def _dark_panel_with_dots_and_a_lamp(d: float, lamp_diameter: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """A dark panel (the mask covers all of it) with a row of bright dots of diameter ``d`` and one
    bright disc (a lamp) of ``lamp_diameter``; returns (grey, mask, dot centres (N, 2), lamp centre)."""
    grey = np.full((120, 200), 30, np.uint8)
    dots = np.array([(30 + 2.5 * d * k, 40) for k in range(4)], float)
    for u, v in dots:
        cv2.circle(grey, (int(u), int(v)), int(d / 2), 230, -1, cv2.LINE_AA)
    lamp = (100, 90)
    cv2.circle(grey, lamp, int(lamp_diameter / 2), 230, -1, cv2.LINE_AA)
    return grey, np.ones(grey.shape, bool), dots, lamp


def test_slivers_the_top_hat_carves_off_a_bright_disc_larger_than_a_dot_are_not_dots():
    # The square top-hat (1.4 d + 2 wide) keeps the rim segments of a larger disc where no square
    # fits; their rings hold the disc's bright inside, so they are not holes in the tape.
    d = 8.0
    for lamp_diameter in (2.2 * d, 3.0 * d):
        grey, mask, dots, lamp = _dark_panel_with_dots_and_a_lamp(d, lamp_diameter)
        uv, _ = find_dots(grey, mask, expected_dot_px=d)
        assert len(uv) == len(dots)
        assert np.abs(np.sort(uv[:, 0]) - dots[:, 0]).max() < 0.6
        assert np.all(np.hypot(uv[:, 0] - lamp[0], uv[:, 1] - lamp[1]) > lamp_diameter / 2 + d)


def _tape_with_a_dim_edge_on_dot(d: float, level: int) -> tuple[np.ndarray, np.ndarray]:
    """A dark tape (grey 30, the mask covers it) with three face-on dots (grey 210) and, at (150,
    60), a dot seen nearly edge-on: an ellipse d x d/4 at grey ``level`` (the light grazes its
    skin); and a round speck of the same grey, d/4 across, at (210, 60). Anti-aliased, 8x
    supersampled."""
    s, (h, w) = 8, (120, 260)
    big = np.full((h * s, w * s), 30, np.uint8)
    for centre in ((30, 40), (80, 40), (130, 30)):
        cv2.circle(big, (centre[0] * s, centre[1] * s), int(d / 2 * s), 210, -1, cv2.LINE_AA)
    cv2.ellipse(big, ((150 * s, 60 * s), (d * s, d / 4 * s), 10), level, -1, cv2.LINE_AA)
    cv2.circle(big, (210 * s, 60 * s), int(d / 8 * s), level, -1, cv2.LINE_AA)
    mask = np.zeros((h, w), bool)
    mask[10:110, 5:255] = True
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), mask


# The two tests below judge the faint cut and the sliver shape alone: their face-on dots are round
# discs, so the test of the sliver's neighbours (below them) is off.
SHAPE_ONLY = BlobParams(faint_max_neighbour_axis_ratio=1.0)


def test_a_dim_dot_seen_edge_on_is_found_apart_from_the_face_on_dots_without_moving_them():
    d = 12.0
    image, mask = _tape_with_a_dim_edge_on_dot(d, level=110)
    uv, conf = find_dots(image, mask, expected_dot_px=d, params=SHAPE_ONLY)
    near = lambda x, y: np.linalg.norm(uv - [x, y], axis=1) < 1.0  # noqa: E731
    assert near(150, 60).sum() == 1, "the dim edge-on dot is missed"
    assert not (np.linalg.norm(uv - [210, 60], axis=1) < d).any(), "the dim speck passed for a dot"
    assert len(uv) == 4
    # the region's threshold alone (half the face-on dots' contrast) loses it, and finds the
    # face-on dots at the very same places
    only_bright, conf_bright = find_dots(image, mask, expected_dot_px=d,
                                         params=BlobParams(faint_share=0.5, faint_max_neighbour_axis_ratio=1.0))
    assert len(only_bright) == 3 and not (np.linalg.norm(only_bright - [150, 60], axis=1) < d).any()
    face_on = ~(np.linalg.norm(uv - [150, 60], axis=1) < d)
    assert np.array_equal(uv[face_on], only_bright) and np.array_equal(conf[face_on], conf_bright)


def test_a_dim_round_spot_is_not_taken_for_a_dot_seen_edge_on():
    d = 12.0
    image, mask = _tape_with_a_dim_edge_on_dot(d, level=110)
    cv2.circle(image, (200, 95), int(d / 2), 110, -1, cv2.LINE_AA)  # a round blotch of the tape's print, as dim
    uv, _ = find_dots(image, mask, expected_dot_px=d, params=SHAPE_ONLY)
    assert (np.linalg.norm(uv - [150, 60], axis=1) < 1.0).sum() == 1, "the dim edge-on dot is missed"
    assert not (np.linalg.norm(uv - [200, 95], axis=1) < d).any(), "a round dim spot passed for an oblique dot"
    any_shape, _ = find_dots(image, mask, expected_dot_px=d,
                             params=BlobParams(faint_max_axis_ratio=1.0, faint_max_neighbour_axis_ratio=1.0))
    assert (np.linalg.norm(any_shape - [200, 95], axis=1) < 1.5).sum() == 1  # the sliver test is what refuses it


def _tape_turning_away_with_two_dim_slivers(d: float) -> tuple[np.ndarray, np.ndarray, dict[str, tuple[float, float]]]:
    """A dark tape (grey 30) running along x that turns away from the camera at its right end:
    rows of dots (grey 210; 3 and 2 dots across, 1.5 d apart) at x = 30 and 60 seen face-on
    (discs), at x = 84 and 102 foreshortened along x (ellipses d/2 x d). Two dim slivers (d/4 x d,
    grey 110, long axis across the tape): ``edge-on`` beyond the last row (a dot seen nearly
    edge-on) and ``print`` beside the first row's outer dot, half-way to the next row. Anti-aliased,
    8x supersampled; the mask covers the tape."""
    s, (h, w) = 8, (100, 160)
    big = np.full((h * s, w * s), 30, np.uint8)
    centre = 50.0
    for k, (x, along) in enumerate(((30.0, d), (60.0, d), (84.0, d / 2), (102.0, d / 2))):
        for a in ((-1.5, 0.0, 1.5) if k % 2 == 0 else (-0.75, 0.75)):
            cv2.ellipse(big, ((x * s, (centre + a * d) * s), (along * s, d * s), 0), 210, -1, cv2.LINE_AA)
    slivers = {"edge-on": (116.0, centre), "print": (45.0, centre + 1.9 * d)}
    for u, v in slivers.values():
        cv2.ellipse(big, ((u * s, v * s), (d / 4 * s, d * s), 0), 110, -1, cv2.LINE_AA)
    mask = np.zeros((h, w), bool)
    mask[int(centre - 2.5 * d):int(centre + 2.5 * d), 10:140] = True
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), mask, slivers


def test_a_dim_sliver_is_a_dot_only_beside_dots_seen_obliquely():
    d = 12.0
    image, mask, slivers = _tape_turning_away_with_two_dim_slivers(d)
    uv, _ = find_dots(image, mask, expected_dot_px=d)
    near = {name: int((np.linalg.norm(uv - xy, axis=1) < 1.5).sum()) for name, xy in slivers.items()}
    assert near == {"edge-on": 1, "print": 0}
    assert len(uv) == 3 + 2 + 3 + 2 + 1  # the four rows and the edge-on dot
    # without the neighbours' test the print passes for a dot too: it is what refuses it
    every_sliver, _ = find_dots(image, mask, expected_dot_px=d, params=BlobParams(faint_max_neighbour_axis_ratio=1.0))
    assert all((np.linalg.norm(every_sliver - xy, axis=1) < 1.5).sum() == 1 for xy in slivers.values())


def _printed_tape_turning_away(d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, tuple[float, float]]]:
    """A dark tape (grey 30) along x with staggered rows of holes (grey 210; 3 and 2 across, 1.5 d
    apart): face-on discs at x = 30, 60, 90, then foreshortened along x where the tape turns away
    (ellipses d/2 x d at x = 114, d/3 x d at x = 132); printed in light ink (grey 200) between
    the face-on rows: the word "PRO" (0.6 d high) at (45, 50) and a stripe's dash (1.2 d x d/4, across
    the tape) at (75, 50). Anti-aliased (8x supersampled), then blurred as a lens blurs it (sigma
    1 px); the mask covers the tape. Returns (grey, mask, hole centres (N, 2) px, the print's
    centres {"word": (x, y), "dash": (x, y)})."""
    s, (h, w), centre = 8, (100, 160), 50.0
    big = np.full((h * s, w * s), 30, np.uint8)
    holes = []
    for k, (x, along) in enumerate(((30.0, d), (60.0, d), (90.0, d), (114.0, d / 2), (132.0, d / 3))):
        for a in ((-1.5, 0.0, 1.5) if k % 2 == 0 else (-0.75, 0.75)):
            cv2.ellipse(big, ((x * s, (centre + a * d) * s), (along * s, d * s), 0), 210, -1, cv2.LINE_AA)
            holes.append((x, centre + a * d))
    word = (45.0, centre)
    scale, thickness = 0.6 * d * s / 22, s  # FONT_HERSHEY_SIMPLEX capitals are ~22 px high at scale 1
    (tw, th), _ = cv2.getTextSize("PRO", cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    cv2.putText(big, "PRO", (int(word[0] * s - tw / 2), int(word[1] * s + th / 2)), cv2.FONT_HERSHEY_SIMPLEX,
                scale, 200, thickness, cv2.LINE_AA)
    dash = (75.0, centre)
    cv2.ellipse(big, ((dash[0] * s, dash[1] * s), (d / 4 * s, 1.2 * d * s), 0), 200, -1, cv2.LINE_AA)
    grey = cv2.GaussianBlur(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 1.0)
    mask = np.zeros((h, w), bool)
    mask[int(centre - 2.5 * d):int(centre + 2.5 * d), 10:150] = True
    return grey, mask, np.array(holes), {"word": word, "dash": dash}


def test_the_tapes_print_is_refused_and_the_holes_seen_obliquely_kept():
    d = 12.0
    grey, mask, holes, prints = _printed_tape_turning_away(d)
    uv, _ = find_dots(grey, mask, expected_dot_px=d)
    assert np.linalg.norm(holes[:, None] - uv[None], axis=2).min(axis=1).max() < 1.0, "a hole is missed"
    assert len(uv) == len(holes), "the print passed for a dot"

    def passed(params: BlobParams) -> set[str]:
        found, _ = find_dots(grey, mask, expected_dot_px=d, params=params)
        assert np.linalg.norm(holes[:, None] - found[None], axis=2).min(axis=1).max() < 1.0
        return {name for name, xy in prints.items() if (np.linalg.norm(found - xy, axis=1) < d / 2).any()}

    # each piece of print passes for a dot without the test that refuses it: the word's piece is
    # far shorter than the holes around it, the dash a sliver between round holes
    assert passed(BlobParams(min_major_to_neighbours=0.0, sliver_max_axis_ratio=0.0)) == {"word", "dash"}
    assert passed(BlobParams(min_major_to_neighbours=0.0)) == {"word"}
    assert passed(BlobParams(sliver_max_axis_ratio=0.0)) == {"dash"}
