"""The detector's clean-up's fast paths compute what the straightforward paths compute: the blob pass
measures all blobs together (moments, percentiles, rings) and must give the dots of the one blob
at a time pass it replaced (kept below as the reference); the tape/skin levels and the snap work
in the mask's box only and must equal the whole crop's; the kept instances' union is the union
of the instances. On a studio image (quarter size) and on drawn tapes. With CUDA, the network on
the GPU must find the CPU's dots (skipped without a GPU)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from spinemocap.detect import blobs
from spinemocap.detect.blobs import _Blobs, _ring_pixels, fill_holes, find_dots, median, merge_close
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.instances import kept_instances, split_instances, union
from spinemocap.detect.refine import RefineParams, _band_levels, _levels, _snap


# ---------------------------------------------------------------- the pass before (reference)
def _ellipse_shape(blob: np.ndarray) -> tuple[float, float] | None:
    m = cv2.moments(blob.astype(np.uint8), binaryImage=True)
    if m["m00"] <= 0:
        return None
    mu20, mu02, mu11 = m["mu20"] / m["m00"], m["mu02"] / m["m00"], m["mu11"] / m["m00"]
    common = math.sqrt(max(0.0, 4 * mu11 * mu11 + (mu20 - mu02) ** 2))
    l1, l2 = (mu20 + mu02 + common) / 2, (mu20 + mu02 - common) / 2
    return 4 * math.sqrt(max(l1, 1 / 12)), 4 * math.sqrt(max(l2, 1 / 12))


def _reference_region_dots(grey, filled, region, d, p, touches_border, size_from_blobs=False):
    """The reference blob pass: one blob at a time, numpy's percentile."""
    k = int(round(1.4 * d + 2)) | 1
    tophat = cv2.morphologyEx(grey, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    smooth = cv2.GaussianBlur(tophat, (0, 0), max(0.5, d / 10.0))
    contrast = float(np.percentile(smooth[filled], 99.5))
    texture = float(np.median(smooth[filled]))
    if contrast < max(p.min_contrast, p.min_contrast_to_texture * texture):
        return np.zeros((0, 2)), np.zeros(0)
    binary = ((smooth > 0.5 * contrast) & region).astype(np.uint8)
    tape_px = filled & (binary == 0)
    floor = float(np.median(tophat[tape_px])) if tape_px.any() else 0.0
    scale = max(contrast - floor, 1e-3)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if size_from_blobs:
        guess_area = math.pi * d * d / 4.0
        majors = [_ellipse_shape(labels[y:y + bh, x:x + bw] == i)[0]
                  for i, (x, y, bw, bh, area) in enumerate(stats) if i and 0.3 * guess_area <= area <= 6 * guess_area]
        d = max(d, float(np.median(majors))) if len(majors) >= 3 else d
    dot_area = math.pi * d * d / 4.0
    rim = max(2, int(math.ceil(0.3 * d)))
    grow = blobs._disc(2 * rim - 1)
    centres, scores = [], []
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        ys, xs = slice(max(0, y - rim), y + bh + rim), slice(max(0, x - rim), x + bw + rim)
        window = labels[ys, xs]
        blob = window == i
        major, minor = _ellipse_shape(blob)
        # a blob at least min_oblique_major * d long: a dot seen obliquely, its area shrunk by its axis ratio
        seen_share = min(minor / major, 1.0) if major >= p.min_oblique_major * d else 1.0
        if not p.min_area * dot_area * seen_share <= area <= p.max_area * dot_area:
            continue
        fill = area / (math.pi * major * minor / 4.0)
        if major > p.max_major * d or minor < p.min_axis_ratio * major or fill < p.min_fill:
            continue
        support = cv2.dilate(blob.astype(np.uint8), grow).astype(bool) & ((window == 0) | blob)
        ring = support & ~blob
        if ring.any() and filled[ys, xs][ring].mean() < p.min_ring_on_tape:
            continue
        # a pixel next to it on the tape lies in a bright area the kernel fits in
        opening = grey[ys, xs] - tophat[ys, xs]
        beside = cv2.dilate(blob.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (window == 0)
        if (beside & filled[ys, xs] & (opening > float(opening[blob].mean()) + 0.5 * contrast)).any():
            continue
        if touches_border(y, x, bh, bw):
            continue
        level = float(np.percentile(tophat[ys, xs][blob], 60)) - floor
        weights = np.clip((tophat[ys, xs] - floor) / max(level, 1e-3), 0.0, 1.0) * support
        total = float(weights.sum())
        if total <= 0:
            continue
        cx = float(weights.sum(axis=0) @ np.arange(xs.start, xs.start + blob.shape[1])) / total
        cy = float(weights.sum(axis=1) @ np.arange(ys.start, ys.start + blob.shape[0])) / total
        centres.append((cx, cy))
        mean_contrast = (float(smooth[ys, xs][blob].mean()) - floor) / scale
        scores.append(blobs._confidence(area / dot_area, minor / major, fill, mean_contrast / 0.8))
    if not centres:
        return np.zeros((0, 2)), np.zeros(0)
    return merge_close(np.asarray(centres, float), np.asarray(scores, float), p.merge_distance * d)


# ---------------------------------------------------------------- images
@pytest.fixture(scope="module")
def studio_images():
    """The studio's six cameras at a quarter of the pixels, one frame (default realism)."""
    pytest.importorskip("pyvista")
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("studio", frames=1, size=(1224, 800)))
    return scene.render(0, with_masks=False).images


@pytest.fixture(scope="module")
def drawn_images():
    rng = np.random.default_rng(11)
    return [draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0).image
            for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2), ((640, 480), 0.9)]]


def _random_blobs(rng: np.random.Generator, shape=(240, 320), count=40) -> np.ndarray:
    image = np.zeros(shape, np.uint8)
    for _ in range(count):  # ellipses of all sizes, many close to or touching each other
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        axes = (int(rng.integers(1, 10)), int(rng.integers(1, 7)))
        cv2.ellipse(image, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    image[rng.random(shape) < 0.003] = 1  # single pixels
    return image


# ---------------------------------------------------------------- pieces, bit for bit
def test_median_is_numpys_bit_for_bit():
    rng = np.random.default_rng(2)
    for n in list(range(1, 12)) + [100, 101, 999]:
        for values in (rng.normal(100, 30, n).astype(np.float32), rng.integers(0, 255, n).astype(np.uint8),
                       rng.integers(0, 4, n).astype(np.float32)):
            ours, numpys = median(values), np.median(values)
            assert ours == numpys and np.asarray(ours).dtype == np.asarray(numpys).dtype, (n, values.dtype)
        # the levels' median of grey levels from their histogram: np.median of them as float32
        levels = rng.integers(0, 256, n).astype(np.uint8)
        ours = blobs.histogram_median(np.bincount(levels, minlength=256))
        numpys = np.median(levels.astype(np.float32))
        assert ours == numpys and type(ours) is type(numpys)


def test_percentile_and_median_from_one_partition_are_numpys():
    rng = np.random.default_rng(13)
    for n in list(range(1, 12)) + [200, 201, 5001]:
        values = rng.gamma(2.0, 3.0, n).astype(np.float32)
        for q in (60.0, 98.0, 99.5):
            pct, med = blobs._percentile_and_median(values, q)
            assert pct == float(np.percentile(values, q)) and med == float(np.median(values)), (n, q)


def _reference_regions(mask, pad, stride=8):
    # the coarse grid by OpenCV's uint8 INTER_AREA of the whole mask (the code before)
    h, w = mask.shape
    hs, ws = -(-h // stride), -(-w // stride)
    sy, sx = h / hs, w / ws
    coarse = (cv2.resize(mask.view(np.uint8) * np.uint8(255), (ws, hs), interpolation=cv2.INTER_AREA) > 0).view(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
    boxes = []
    for x, y, bw, bh, _area in stats[1:]:
        ys = slice(int(y * sy), min(h, int(math.ceil((y + bh) * sy))))
        xs = slice(int(x * sx), min(w, int(math.ceil((x + bw) * sx))))
        rows, cols = np.flatnonzero(mask[ys, xs].any(axis=1)), np.flatnonzero(mask[ys, xs].any(axis=0))
        if not len(rows):
            continue
        y0, y1 = ys.start + rows[0] - pad, ys.start + rows[-1] + 1 + pad
        x0, x1 = xs.start + cols[0] - pad, xs.start + cols[-1] + 1 + pad
        boxes.append((slice(max(0, y0), min(h, y1)), slice(max(0, x0), min(w, x1))))
    return boxes


def test_regions_from_the_masks_box_are_the_whole_masks():
    rng = np.random.default_rng(14)
    for trial in range(120):  # sparse specks: the coarse grid's partly covered cells decide
        h, w = (int(v) for v in rng.integers(8, 400, 2))
        if trial % 4 == 0:
            h, w = h // 8 * 8 + 8, w // 8 * 8 + 8  # integer scales: OpenCV's other route
        mask = np.zeros((h, w), bool)
        for _ in range(int(rng.integers(0, 25))):
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            mask[y:y + int(rng.integers(1, 6)), x:x + int(rng.integers(1, 6))] = True
        assert blobs._regions(mask, 5) == _reference_regions(mask, 5), (h, w)


def test_dot_size_guess_percentile_is_numpys():
    rng = np.random.default_rng(12)
    for _ in range(10):
        mask = _random_blobs(rng, count=60).astype(bool)
        dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
        expected = max(2.0 * float(np.percentile(dist[dist > 0], 98)) * 0.2, 2.0)
        assert blobs.estimate_dot_diameter(mask, 0.2) == expected


def test_all_blobs_moments_are_cv2_moments_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n, labels, stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng), connectivity=8)
        rim = int(rng.integers(2, 6))
        x0, y0 = np.maximum(0, stats[:, 0] - rim), np.maximum(0, stats[:, 1] - rim)
        ours = _Blobs(labels, n)
        assert (ours.stats[1:] == stats[1:]).all() and ours.stats.dtype == stats.dtype  # OpenCV's statistics
        major, minor = ours.ellipse_axes(x0, y0)
        for i in range(1, n):
            x, y, bw, bh, _area = stats[i]
            window = labels[y0[i]:y + bh + rim, x0[i]:x + bw + rim] == i
            assert (major[i], minor[i]) == _ellipse_shape(window)


def test_per_label_percentiles_are_numpys():
    rng = np.random.default_rng(4)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng), connectivity=8)
    signed = rng.normal(20, 10, labels.shape).astype(np.float32)  # sorted by label and value
    tophat = np.abs(np.round(signed))  # non-negative, with ties: sorted as one int64 key
    for values in (signed, tophat, np.abs(signed)):
        for q in (0, 37.5, 60, 99.5, 100):
            ours = _Blobs(labels, n).percentiles(values, q)
            for i in range(1, n):
                assert ours[i] == float(np.percentile(values[labels == i], q)), (i, q)


def test_ring_pixels_are_each_blobs_own_dilation():
    rng = np.random.default_rng(5)
    grow = blobs._disc(5)
    for _ in range(10):
        n, labels, _stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng, count=60), connectivity=8)
        candidate = rng.random(n) < 0.8
        candidate[0] = False
        ys, xs, owner = _ring_pixels(labels, candidate, grow)
        ours = sorted(zip(owner.tolist(), ys.tolist(), xs.tolist()))
        expected = []
        for i in np.flatnonzero(candidate):
            ring = cv2.dilate((labels == i).astype(np.uint8), grow).astype(bool) & (labels == 0)
            expected += [(int(i), int(y), int(x)) for y, x in zip(*np.nonzero(ring))]
        assert ours == sorted(expected)


# ---------------------------------------------------------------- the dots, the levels, the masks
def _detect_comparing_blob_passes(images, monkeypatch) -> tuple[int, float, float]:
    """Detect ``images`` with the shipped network; every region's blob pass is also done by the
    plain reference pass. Returns (dots, largest px difference, largest confidence difference)."""
    from spinemocap.detect import Detector

    real = blobs._region_dots
    worst = {"dots": 0, "px": 0.0, "conf": 0.0}

    def both(grey, filled, region, d, p, touches_border, size_from_blobs=False):
        uv, conf = real(grey, filled, region, d, p, touches_border, size_from_blobs)
        ref_uv, ref_conf = _reference_region_dots(grey.astype(np.float32), filled, region, d, p, touches_border, size_from_blobs)
        assert uv.shape == ref_uv.shape
        if len(uv):
            worst["px"] = max(worst["px"], float(np.abs(uv - ref_uv).max()))
            worst["conf"] = max(worst["conf"], float(np.abs(conf - ref_conf).max()))
        worst["dots"] += len(uv)
        return uv, conf

    monkeypatch.setattr(blobs, "_region_dots", both)
    detector = Detector("net", device="cpu")
    for camera, image in enumerate(images):
        detector.detect(image, camera=camera)
    return worst["dots"], worst["px"], worst["conf"]


def test_blob_pass_finds_the_one_blob_at_a_time_dots_on_a_studio_frame(studio_images, monkeypatch):
    dots, px, conf = _detect_comparing_blob_passes(studio_images, monkeypatch)
    assert dots > 100  # the frame shows the tape in several cameras
    assert px < 1e-3 and conf < 1e-5  # float64 instead of float32 sums: rounding only


def test_blob_pass_finds_the_one_blob_at_a_time_dots_on_drawn_tapes(drawn_images, monkeypatch):
    dots, px, conf = _detect_comparing_blob_passes(drawn_images, monkeypatch)
    assert dots > 30
    assert px < 1e-3 and conf < 1e-5


def _reference_levels(grey, mask, band, min_contrast):
    disc = lambda r: cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))  # noqa: E731
    m = mask.view(np.uint8)
    inner = cv2.erode(m, disc(band + 1)).view(bool)
    ring = cv2.dilate(m, disc(3 * band + 1)).view(bool) & ~cv2.dilate(m, disc(band + 1)).view(bool)
    if inner.sum() < 20 or ring.sum() < 20:
        return None
    tape = inner & (grey <= np.median(grey[inner]))
    if np.median(grey[ring]) - np.median(grey[tape]) < min_contrast:
        return None
    return tape, ring


def _reference_local_mean(grey, weight, sigma, fallback):
    # the levels on the whole crop (the code before): OpenCV's INTER_AREA shrink of the whole crop
    h, w = grey.shape
    small = (max(1, w // 4), max(1, h // 4))
    g = cv2.resize(grey * weight, small, interpolation=cv2.INTER_AREA)
    wt = cv2.resize(weight, small, interpolation=cv2.INTER_AREA)
    s = max(sigma / 4, 0.5)
    num, den = cv2.GaussianBlur(g, (0, 0), s), cv2.GaussianBlur(wt, (0, 0), s)
    mean = np.where(den > 1e-3, num / np.maximum(den, 1e-6), fallback).astype(np.float32)
    return cv2.resize(mean, (w, h), interpolation=cv2.INTER_LINEAR)


@pytest.mark.parametrize("shift", [0, 30, -30])
def test_levels_in_the_masks_box_are_the_whole_crops_and_the_band_levels_and_snap_are_close(shift):
    # the drawn tape's mask, too wide, moved so that it also touches the crop's border (shift != 0)
    sample = draw_sample(np.random.default_rng(3), size=(480, 640), px_per_mm=1.4, n_rows=9)
    # 477 x 635: the 4x smaller grid's scale is not an integer (OpenCV's general INTER_AREA route)
    grey = cv2.cvtColor(sample.image, cv2.COLOR_BGR2GRAY).astype(np.float32)[:477, :635]
    mask = np.roll(sample.mask, shift, axis=1)[:477, :635]
    mask = fill_holes(cv2.dilate(mask.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool))
    p = RefineParams()
    tape, ring = _reference_levels(grey, mask, p.band_px, p.min_contrast)
    for image in (grey, grey.astype(np.uint8)):  # medians by partition (float32) and by histogram (uint8)
        ours = _levels(image, mask, p.band_px, p.min_contrast)
        whole_tape, whole_ring = np.zeros_like(mask), np.zeros_like(mask)
        whole_tape[ours.box], whole_ring[ours.box] = ours.tape, ours.ring
        assert (whole_tape == tape).all() and (whole_ring == ring).all()
        assert ours.tape_median == np.median(grey[tape]) and ours.ring_median == np.median(grey[ring])
        assert type(ours.tape_median) is type(np.median(grey[tape]))
        # the levels measured at the band's pixels only (every second sample, the grid around the
        # samples' box): within a grey level of the whole crop's levels (OpenCV's shrink, blur, enlargement)
        tape_level = _reference_local_mean(grey, tape.astype(np.float32), p.level_sigma_px, float(np.median(grey[tape])))
        skin_level = _reference_local_mean(grey, ring.astype(np.float32), p.level_sigma_px, float(np.median(grey[ring])))
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * p.band_px + 1,) * 2)
        band = cv2.dilate(mask.view(np.uint8), disc).view(bool) & ~cv2.erode(mask.view(np.uint8), disc).view(bool)
        ys, xs = np.nonzero(band)
        tape_at, skin_at = _band_levels(image, ours, p.level_sigma_px, ys, xs)
        assert tape_at.shape == skin_at.shape == ys.shape
        assert np.median(skin_level[band]) - np.median(tape_level[band]) > 50  # far apart: a 1-level error is small
        for at, level in ((tape_at, tape_level[band]), (skin_at, skin_level[band])):
            error = np.abs(at - level)  # larger only where few samples are near (cells' fractional edges)
            assert error.mean() < 0.3 and np.percentile(error, 99) < 2.0  # the levels lie > 50 apart
    # the snap on the band in the mask's box: the whole crop's snap but for a few band pixels at the threshold
    expected = fill_holes((mask & ~band) | (band & (grey < 0.5 * (tape_level + skin_level))))
    snapped = _snap(grey, mask, p, ours)
    assert (snapped != expected).sum() <= 0.005 * band.sum() and snapped.sum() < mask.sum()  # the too-wide outline moved in


def test_area_shrink_of_a_box_is_opencvs_inter_area_bit_for_bit():
    rng = np.random.default_rng(8)
    for trial in range(150):
        h, w = (int(v) for v in rng.integers(1, 400, 2))
        y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
        y1, x1 = int(rng.integers(y0 + 1, h + 1)), int(rng.integers(x0 + 1, w + 1))
        parts = (rng.integers(0, 256, (2, y1 - y0, x1 - x0)) * rng.random((2, y1 - y0, x1 - x0))).astype(np.float32)
        parts[1] = parts[1] > 50  # a weight mask and a weighted image, as the levels shrink them
        whole = np.zeros((2, h, w), np.float32)
        whole[:, y0:y1, x0:x1] = parts
        size = (max(1, w // 4), max(1, h // 4)) if trial % 3 else (max(1, w // 8), max(1, h // 8))
        got = blobs.area_shrink(np.ascontiguousarray(parts.transpose(2, 0, 1)), (h, w), (slice(y0, y1), slice(x0, x1)), size)
        for k in range(2):
            assert np.array_equal(got[k], cv2.resize(whole[k], size, interpolation=cv2.INTER_AREA)), (h, w, y0, y1, x0, x1)


def _reference_fill_holes(mask):
    m = mask.astype(np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    filled = np.zeros_like(m)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    return filled.astype(bool)


def test_box_pieces_are_the_whole_images():
    # hole filling, dotted components, touching components and the distance transform in the
    # mask's box: the whole image's, also where the mask touches the image's border
    from spinemocap.detect.refine import _darker, components_touching, keep_dotted

    rng = np.random.default_rng(9)
    for trial in range(20):
        mask = np.zeros((200, 260), bool)
        y, x = (0, 0) if trial % 4 == 0 else (int(rng.integers(0, 60)), int(rng.integers(0, 80)))
        mask[y:y + 140, x:x + 180] = _random_blobs(rng, (140, 180), count=25).astype(bool)
        mask[y + 20:y + 60, x + 30:x + 90] ^= _random_blobs(rng, (40, 60), count=6).astype(bool)  # holes
        assert (fill_holes(mask) == _reference_fill_holes(mask)).all()
        dots = rng.uniform([-5, -5], [265, 205], (15, 2))
        n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
        ij = np.clip(np.round(dots).astype(int), 0, [259, 199])
        assert (keep_dotted(mask, dots) == np.isin(labels, labels[ij[:, 1], ij[:, 0]]) & mask).all()
        reference = rng.random(mask.shape) < 0.001
        assert (components_touching(mask, reference) == np.isin(labels, labels[mask & reference]) & mask).all()
        whole = cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, 5)
        box = blobs.mask_box(mask, 2)
        assert np.array_equal(cv2.distanceTransform(mask[box].view(np.uint8), cv2.DIST_L2, 5), whole[box])
    grey = rng.integers(0, 256, (50, 60)).astype(np.uint8)
    for t in (-3.0, 0.0, 0.25, 17.5, 99.75, 100.0, 254.5, 255.0, 255.25, 300.0):
        assert (_darker(grey, t) == (grey.astype(np.float32) < np.float32(t))).all()


def test_large_components_are_opencvs():
    from spinemocap.detect.refine import _large_components

    rng = np.random.default_rng(15)
    for count in (3, 12, 60):  # few large components (one at a time) and many (OpenCV's statistics)
        mask = _random_blobs(rng, (200, 300), count=count).astype(bool)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=8)
        expected = [(x, y, w, h, labels[y:y + h, x:x + w] == i) for i, (x, y, w, h, area) in enumerate(stats)
                    if i and area >= 20]
        got = list(_large_components(mask, 20))
        assert len(got) == len(expected) > 0
        for a, b in zip(got, expected):
            assert a[:4] == tuple(int(v) for v in b[:4]) and (a[4] == b[4]).all()


def test_component_labels_and_areas_are_opencvs_also_for_speckle_beyond_uint16():
    from spinemocap.detect.blobs import labelled_components

    rng = np.random.default_rng(16)
    speckle = np.zeros((600, 600), bool)
    speckle[::2, ::2] = True  # 90,000 one-pixel components: more labels than uint16 holds
    speckle[100:140, 100:140] = True  # and one large one (with the speckle it touches)
    for mask in (_random_blobs(rng, (200, 300), count=40).astype(bool), speckle):
        n, labels, areas = labelled_components(mask)
        m, expected_labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=8)
        assert n == m and (labels == expected_labels).all()
        assert (areas[1:] == stats[1:, cv2.CC_STAT_AREA]).all()
    # the detector's instance filter keeps the large component and drops the speckle, no error
    _, labels, _ = labelled_components(speckle)
    assert (kept_instances(speckle, min_share=0.02) == (labels == labels[120, 120])).all()


def test_kept_instances_are_the_union_of_the_instances():
    rng = np.random.default_rng(6)
    for _ in range(10):
        mask = np.zeros((300, 400), bool)
        mask[60:200, 100:300] = _random_blobs(rng, (140, 200), count=30).astype(bool)
        for min_share in (0.0, 0.02, 0.3):
            expected = union(split_instances(mask, min_share=min_share), mask.shape)
            assert (kept_instances(mask, min_share=min_share) == expected).all()
    assert not kept_instances(np.zeros((5, 5), bool)).any()


# ---------------------------------------------------------------- GPU
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")
def test_network_on_the_gpu_finds_the_cpus_dots(drawn_images):
    from spinemocap.detect import Detector

    on_cpu, on_gpu = Detector("net", device="cpu"), Detector("net", device="cuda")
    for camera, image in enumerate(drawn_images):
        a, b = on_cpu.detect(image, camera=camera), on_gpu.detect(image, camera=camera)
        assert len(a) == len(b) > 0
        assert np.abs(a.uv - b.uv).max() < 0.01


# ---------------------------------------------------------------- the same work on less
def _reference_ring_pixels(labels, candidate, grow):
    """The ring pixels as computed before (uint16 labels over the whole label image, the reached
    pixels split by two 2-D nonzero passes): the triples and their order."""
    n = len(candidate)
    cand = np.where(candidate, np.arange(n), 0).astype(np.uint16)[labels]
    highest = cv2.dilate(cand, grow)
    lowest = cv2.erode(cand - np.uint16(1), grow) + np.uint16(1)
    reached = (labels == 0) & (highest > 0)
    shared = reached & (highest != lowest)
    ys1, xs1 = np.nonzero(reached & ~shared)
    owner1 = highest[ys1, xs1].astype(np.int64)
    ys2, xs2 = np.nonzero(shared)
    r = grow.shape[0] // 2
    dy, dx = np.nonzero(grow)
    padded = cv2.copyMakeBorder(cand, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    width = padded.shape[1]
    near = np.sort(padded.ravel()[((ys2 + r) * width + xs2 + r)[:, None] + (dy - r) * width + (dx - r)], axis=1)
    first = near > 0
    first[:, 1:] &= near[:, 1:] != near[:, :-1]
    which, owner2 = np.nonzero(first)[0], near[first].astype(np.int64)
    return (np.concatenate([ys1, ys2[which]]), np.concatenate([xs1, xs2[which]]), np.concatenate([owner1, owner2]))


@pytest.mark.parametrize("count, shape", [(30, (120, 160)), (500, (400, 600))])  # byte labels; beyond 255 labels
def test_ring_pixels_in_the_candidates_box_are_the_whole_images_in_the_same_order(count, shape):
    # the order matters: the centre weights are summed in it (float64 bincount)
    rng = np.random.default_rng(21)
    for radius in (1, 2, 4):
        grow = blobs._disc(2 * radius + 1)
        for _ in range(4):
            n, labels, stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng, shape, count=count), connectivity=8)
            assert (n >= 255) == (count == 500)
            candidate = rng.random(n) < 0.7
            candidate[0] = False
            if rng.random() < 0.5:  # candidates in one part of the image only: a small box
                candidate &= stats[:, cv2.CC_STAT_LEFT] < shape[1] // 3
            expected = _reference_ring_pixels(labels, candidate, grow)
            c = np.flatnonzero(candidate)
            x, y, w, h = (stats[c, k] for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
            box = (slice(int(y.min()), int((y + h).max())), slice(int(x.min()), int((x + w).max())))
            for ours in (_ring_pixels(labels, candidate, grow), _ring_pixels(labels, candidate, grow, box)):
                for a, b in zip(ours, expected):
                    assert a.dtype == b.dtype and np.array_equal(a, b)


def test_nonzero_from_one_flat_pass_is_numpys():
    rng = np.random.default_rng(2)
    arrays = [np.zeros((0, 5), bool), np.zeros((5, 0), bool), np.ones((1, 1), bool), np.zeros((7, 9), bool)]
    arrays += [rng.random((int(rng.integers(1, 90)), int(rng.integers(1, 90)))) < rng.uniform(0, 1) for _ in range(30)]
    arrays.append((rng.random((60, 80)) < 0.3)[5:50:2, 3:70])  # not contiguous
    for a in arrays:
        ys, xs = blobs._nonzero(a)
        ref_ys, ref_xs = np.nonzero(a)
        assert np.array_equal(ys, ref_ys) and np.array_equal(xs, ref_xs) and ys.dtype == ref_ys.dtype


def test_find_dots_memo_and_hole_free_mask_give_the_dots_found_without_them(monkeypatch):
    from spinemocap.detect.blobs import find_dots

    rng = np.random.default_rng(13)
    searched = []
    real = blobs._roi_dots
    monkeypatch.setattr(blobs, "_roi_dots", lambda *a: (searched.append(a[2:4]), real(*a))[1])
    for size, ppm in [((480, 640), 1.4), ((800, 600), 2.2)]:
        sample = draw_sample(rng, size=size, px_per_mm=ppm, noise=2.0)
        grey = cv2.cvtColor(sample.image, cv2.COLOR_BGR2GRAY)
        tape = fill_holes(sample.mask)
        specks = np.zeros_like(tape)
        for _ in range(3):  # dot-less specks away from the tape: regions of their own
            y, x = int(rng.integers(0, size[1] - 12)), int(rng.integers(0, size[0] - 12))
            if not cv2.dilate(tape.view(np.uint8), np.ones((61, 61), np.uint8))[y:y + 12, x:x + 12].any():
                specks[y:y + 6, x:x + 9] = True
        assert specks.any()
        memo: dict = {}
        for mask in (tape | specks, tape):  # the mask, then the mask less its specks (extend_along_tape's passes)
            expected = find_dots(grey, mask)
            searched.clear()
            ours = find_dots(grey, mask, None, None, memo, hole_free=True)
            assert np.array_equal(ours[0], expected[0]) and np.array_equal(ours[1], expected[1])
            assert len(expected[0]) > 10
        assert not searched  # the tape's regions were searched in the first call: found in the memo


def test_clean_up_from_the_grey_image_is_the_clean_up_from_the_colour_image(drawn_images):
    from spinemocap.capture import to_grey
    from spinemocap.detect import Detector

    detector = Detector("net", device="cpu")
    for image in drawn_images:
        boxes = detector.tape_boxes([image])[0]
        a = detector._segment_with_dots(image, boxes)
        b = detector._segment_with_dots(image, boxes, to_grey(image))
        assert len(a.uv) > 10 and np.array_equal(a.uv, b.uv) and np.array_equal(a.confidence, b.confidence)
        assert np.array_equal(a.mask, b.mask)


def test_any_box_of_a_filled_mask_has_no_holes():
    # find_dots(hole_free=True) skips the regions' hole filling on fill_holes' answer
    rng = np.random.default_rng(17)
    for _ in range(300):
        h, w = int(rng.integers(3, 100)), int(rng.integers(3, 100))
        mask = rng.random((h, w)) < rng.uniform(0.2, 0.8)  # speckle: many holes, components, border contacts
        filled = fill_holes(mask)
        assert np.array_equal(fill_holes(filled), filled)
        for _ in range(5):
            y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
            y1, x1 = int(rng.integers(y0 + 1, h + 1)), int(rng.integers(x0 + 1, w + 1))
            box = filled[y0:y1, x0:x1]
            assert np.array_equal(fill_holes(box), box)


def test_area_table_from_the_cached_dense_table_keeps_opencvs_entries_in_order():
    """The restricted table (zero weights for the entries outside the box, before and after the
    others) holds exactly the whole table's entries with a source in the box, in OpenCV's order,
    and the box's destinations; the shrink from it is OpenCV's (the test above)."""
    rng = np.random.default_rng(15)
    for _ in range(400):
        ssize = int(rng.integers(2, 900))
        dsize = max(1, ssize // int(rng.choice([4, 8])) + int(rng.integers(0, 2)))
        lo = int(rng.integers(0, ssize))
        hi = int(rng.integers(lo + 1, ssize + 1))
        di, si, weight = blobs._area_table_whole(ssize, dsize)
        keep = (si >= lo) & (si < hi)
        got = blobs._area_table(ssize, dsize, lo, hi)
        if not keep.any():
            assert got is None
            continue
        first, source, weights = got
        assert first == int(di[keep][0]) and first + len(source) == int(di[keep][-1]) + 1
        assert (source >= 0).all() and (source < hi - lo).all()
        for row in range(len(source)):
            own = keep & (di == first + row)
            nonzero = weights[row] != 0
            assert np.array_equal(source[row][nonzero], si[own] - lo) and np.array_equal(weights[row][nonzero], weight[own])


def test_confidences_of_arrays_are_confidence_per_blob_bit_for_bit():
    rng = np.random.default_rng(16)
    n = 5000
    area = np.concatenate([rng.random(n) * 3, [0.0, 1e-3, 1e-4, 1.0, 2.5]])
    axis = np.concatenate([rng.random(n), [0.6, 0.0, 1.0, 0.59999, 0.3]])
    fill = np.concatenate([rng.random(n) * 1.2, [0.5, 0.9, 0.3, 1.0, -0.0]])
    contrast = np.concatenate([rng.random(n) * 2 - 0.5, [0.0, -0.0, 1.0, 1.2, np.nan]])
    expected = np.array([blobs._confidence(*v) for v in zip(area.tolist(), axis.tolist(), fill.tolist(), contrast.tolist())])
    got = blobs._confidences(area, axis, fill, contrast)
    assert got.dtype == np.float64 and np.array_equal(got.view(np.uint64), expected.view(np.uint64))


def test_dense_area_table_is_the_whole_table_densified():
    """The directly built dense table holds the whole table's entries per destination, in order,
    then zero-weight padding (its source the destination's last one)."""
    for ssize in list(range(1, 120)) + [401, 517, 1000, 1601, 2448]:
        for dsize in sorted({max(1, ssize // 4), max(1, ssize // 8), max(1, ssize // 4 + 1), max(1, ssize // 3)}):
            if dsize > ssize:
                continue
            di, si, weight = blobs._area_table_whole(ssize, dsize)
            source, weights, first_source, last_source = blobs._area_table_dense(ssize, dsize)
            assert source.shape[0] == dsize and weights.dtype == np.float32
            for d in range(dsize):
                own = di == d
                n = int(own.sum())
                assert np.array_equal(source[d, :n], si[own]) and np.array_equal(weights[d, :n], weight[own]), (ssize, dsize, d)
                assert (weights[d, n:] == 0).all() and (source[d, n:] == si[own][-1]).all()
                assert first_source[d] == si[own][0] and last_source[d] == si[own][-1]


def _reference_merge_close(uv, score, radius):
    """The greedy merge one blob at a time (the code before its array form)."""
    order = np.argsort(-score)
    keep: list[int] = []
    for i in order:
        if all(np.linalg.norm(uv[i] - uv[j]) >= radius for j in keep):
            keep.append(int(i))
    keep.sort(key=lambda i: (uv[i, 1], uv[i, 0]))
    return uv[keep], score[keep]


def test_merge_close_fast_path_and_greedy_path_keep_the_reference_blobs_in_its_order():
    rng = np.random.default_rng(17)
    cases = []
    for n in (1, 2, 5, 30, 80):
        spread = np.full((n, 2), 400.0)
        cases.append((rng.random((n, 2)) * spread, rng.random(n), 3.0))        # far apart: the fast path
        cases.append((rng.random((n, 2)) * 20.0, rng.random(n), 3.0))          # crowded: the greedy pass
        cases.append((np.round(rng.random((n, 2)) * 10.0), np.round(rng.random(n), 1), 2.0))  # ties in score and position
    cases.append((np.array([[5.0, 5.0], [5.0, 5.0], [1.0, 5.0]]), np.array([0.5, 0.5, 0.9]), 0.0))  # radius 0: all kept
    fast = 0
    for uv, score, radius in cases:
        d = np.sqrt(((uv[:, None] - uv[None]) ** 2).sum(axis=2))
        fast += int(np.count_nonzero(d < radius) == np.count_nonzero(np.diagonal(d < radius)))
        got_uv, got_score = merge_close(uv, score, radius)
        want_uv, want_score = _reference_merge_close(uv, score, radius)
        assert np.array_equal(got_uv, want_uv) and np.array_equal(got_score, want_score)
    assert 4 <= fast < len(cases)  # both paths were taken


def test_band_levels_of_more_pixels_than_opencvs_remap_takes_in_a_row(monkeypatch):
    # a large tape region's band holds more than 32767 px (OpenCV's remap refuses such a map):
    # read in rows, each pixel's level is the one it gets in a short call of its own
    import spinemocap.detect.refine as refine

    sample = draw_sample(np.random.default_rng(3), size=(480, 640), px_per_mm=1.4, n_rows=9)
    grey = cv2.cvtColor(sample.image, cv2.COLOR_BGR2GRAY)
    mask = fill_holes(cv2.dilate(sample.mask.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool))
    p = RefineParams()
    samples = _levels(grey, mask, p.band_px, p.min_contrast)
    ys, xs = np.nonzero(np.ones_like(mask))  # every pixel of the crop: 307200 > 32767
    tape_at, skin_at = _band_levels(grey, samples, p.level_sigma_px, ys, xs)
    monkeypatch.setattr(refine, "_REMAP_MAX_SIDE", 1000)
    pick = np.random.default_rng(0).choice(len(ys), 3000, replace=False)
    tape_few, skin_few = _band_levels(grey, samples, p.level_sigma_px, ys[pick], xs[pick])
    np.testing.assert_array_equal(tape_at[pick], tape_few)
    np.testing.assert_array_equal(skin_at[pick], skin_few)


def test_ring_pixels_in_chunks_are_the_same(monkeypatch):
    # a large dot size over a large region would gather gigabytes of labels at once: in chunks, the same dots
    sample = draw_sample(np.random.default_rng(8), size=(480, 360), px_per_mm=1.2)
    whole = find_dots(sample.image, sample.mask)
    monkeypatch.setattr(blobs, "_RING_CHUNK_ELEMENTS", 64)
    chunked = find_dots(sample.image, sample.mask)
    assert len(whole[0]) >= len(sample.uv) - 1
    for a, b in zip(whole, chunked):
        np.testing.assert_array_equal(a, b)
