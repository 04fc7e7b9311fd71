"""The detector's clean-up made cheaper (issue 15) computes what it computed before: the blob pass
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
from spinemocap.detect.blobs import _Blobs, _ring_pixels, fill_holes, median, merge_close
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.instances import kept_instances, split_instances, union
from spinemocap.detect.refine import RefineParams, _levels, _local_mean, _snap


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
    """The blob pass before issue 15's clean-up round: one blob at a time, numpy's percentile."""
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
        if not p.min_area * dot_area <= area <= p.max_area * dot_area:
            continue
        ys, xs = slice(max(0, y - rim), y + bh + rim), slice(max(0, x - rim), x + bw + rim)
        window = labels[ys, xs]
        blob = window == i
        major, minor = _ellipse_shape(blob)
        fill = area / (math.pi * major * minor / 4.0)
        if major > p.max_major * d or minor < p.min_axis_ratio * major or fill < p.min_fill:
            continue
        support = cv2.dilate(blob.astype(np.uint8), grow).astype(bool) & ((window == 0) | blob)
        ring = support & ~blob
        if ring.any() and filled[ys, xs][ring].mean() < p.min_ring_on_tape:
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


def test_all_blobs_moments_are_cv2_moments_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n, labels, stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng), connectivity=8)
        rim = int(rng.integers(2, 6))
        x0, y0 = np.maximum(0, stats[:, 0] - rim), np.maximum(0, stats[:, 1] - rim)
        major, minor = _Blobs(labels, stats).ellipse_axes(x0, y0)
        for i in range(1, n):
            x, y, bw, bh, _area = stats[i]
            window = labels[y0[i]:y + bh + rim, x0[i]:x + bw + rim] == i
            assert (major[i], minor[i]) == _ellipse_shape(window)


def test_per_label_percentiles_are_numpys():
    rng = np.random.default_rng(4)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(_random_blobs(rng), connectivity=8)
    values = rng.normal(20, 10, labels.shape).astype(np.float32)
    for q in (0, 37.5, 60, 99.5, 100):
        ours = _Blobs(labels, stats).percentiles(values, q)
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
    """Detect ``images`` with the shipped network; every region's blob pass is also done the
    old way. Returns (dots, largest px difference, largest confidence difference)."""
    from spinemocap.detect import Detector

    real = blobs._region_dots
    worst = {"dots": 0, "px": 0.0, "conf": 0.0}

    def both(grey, filled, region, d, p, touches_border, size_from_blobs=False):
        uv, conf = real(grey, filled, region, d, p, touches_border, size_from_blobs)
        ref_uv, ref_conf = _reference_region_dots(grey, filled, region, d, p, touches_border, size_from_blobs)
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


@pytest.mark.parametrize("shift", [0, 30, -30])
def test_levels_and_snap_in_the_masks_box_are_the_whole_crops(shift):
    # the drawn tape's mask, too wide, moved so that it also touches the crop's border (shift != 0)
    sample = draw_sample(np.random.default_rng(3), size=(480, 640), px_per_mm=1.4, n_rows=9)
    grey = cv2.cvtColor(sample.image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    mask = np.roll(sample.mask, shift, axis=1)
    mask = fill_holes(cv2.dilate(mask.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool))
    p = RefineParams()
    ours = _levels(grey, mask, p.band_px, p.min_contrast)
    tape, ring = _reference_levels(grey, mask, p.band_px, p.min_contrast)
    assert (ours.tape == tape).all() and (ours.ring == ring).all()
    assert ours.tape_median == np.median(grey[tape]) and ours.ring_median == np.median(grey[ring])
    # the snap on the band in the mask's box: the whole crop's snap
    tape_level = _local_mean(grey, tape.astype(np.float32), p.level_sigma_px, float(np.median(grey[tape])))
    skin_level = _local_mean(grey, ring.astype(np.float32), p.level_sigma_px, float(np.median(grey[ring])))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * p.band_px + 1,) * 2)
    band = cv2.dilate(mask.view(np.uint8), disc).view(bool) & ~cv2.erode(mask.view(np.uint8), disc).view(bool)
    expected = fill_holes((mask & ~band) | (band & (grey < 0.5 * (tape_level + skin_level))))
    snapped = _snap(grey, mask, p, ours)
    assert (snapped == expected).all() and snapped.sum() < mask.sum()  # the too-wide outline moved in


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
