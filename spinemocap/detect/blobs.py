"""Dot detection: bright, roughly round blobs inside the tape mask, with sub-pixel centres.

The dots of perforated tape are holes through which skin shows, so each dot is a bright disc
(an ellipse when seen obliquely) on the darker tape. The detector works only in regions of
interest around the mask's connected components, so a full 2448x1600 frame costs little more
than its tape does.

Per region:
1. fill the mask's holes (a mask may or may not include the dots) and grow it by a small margin;
2. white top-hat with a square kernel larger than a dot: keeps the dots, removes the tape's
   shading and the large bright skin around the tape (so it never merges with an edge dot);
3. dot contrast = 99.5th percentile of the smoothed top-hat on the tape; no dots when it is weak
   or not well above the tape's own texture (median top-hat); threshold at half the contrast;
   spots fainter than that (above a quarter of it) and apart from the blobs are cut at half their
   own peak and kept where they are slivers beside dots that are themselves foreshortened (a dot
   seen nearly edge-on: :func:`_add_faint_spots`, :func:`_beside_oblique_dots`);
4. dot size: given, or the blobs' median long axis (the mask-width guess shrinks in oblique views);
5. keep blobs whose area (against a dot seen as obliquely as the blob: :func:`foreshortening`),
   axes and fill fit a dot, whose surrounding ring lies on the tape, which do not border a bright
   area the kernel fits in (the top-hat carves rim slivers off a bright disc larger than a dot,
   such as a lamp's LED), and which do not touch the frame border;
6. centre = centroid of the top-hat over the blob plus a rim, scaled by the blob's own interior
   level and clipped to [0, 1]: the inside weighs 1 (shading cannot pull it), anti-aliased rim
   pixels weigh their coverage (the sub-pixel part);
7. drop blobs unlike the blobs around them (:func:`_unlike_neighbours`): much shorter than
   their neighbours, or a sliver beside round dots (the tape's print, weave and specks);
8. merge blobs closer than half a dot diameter, so one dot never yields two blobs.

Coordinates: pixel centres at integer positions (OpenCV convention), ``uv = (x, y)`` in px.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from ..capture import to_grey

# Tape dot diameter / tape width (10 mm dots on 50 mm tape): used to guess the dot size from the
# mask width when the caller does not know it.
DEFAULT_DOT_TO_WIDTH = 0.2


@dataclass
class BlobParams:
    """Tuning of :func:`find_dots`; sizes are fractions of the expected dot diameter ``d``."""

    margin: float = 0.3            # mask grown by margin * d (dots on the mask's edge count)
    min_area: float = 0.15         # blob area in units of the expected area of a dot seen at the blob's obliquity
    max_area: float = 2.2
    max_major: float = 1.7         # longest ellipse axis <= max_major * d
    min_axis_ratio: float = 0.1    # minor / major axis (oblique views flatten dots)
    min_oblique_major: float = 0.4  # a flattened blob this * d long is a dot seen obliquely (the threshold trims its thin ends)
    min_fill: float = 0.65         # area / ellipse area from moments (rejects ragged shapes)
    merge_distance: float = 0.5    # centres closer than merge_distance * d are one dot
    min_ring_on_tape: float = 0.6  # share of the ring around a blob that must lie on the tape
    min_contrast: float = 8.0      # grey levels; weaker "dots" are noise
    min_contrast_to_texture: float = 5.0  # dot contrast / median top-hat over the tape
    faint_share: float = 0.25      # spots above this x the contrast, apart from the dots, are cut at half their own peak (0.5: none)
    faint_max_axis_ratio: float = 0.5  # ... and kept only as slivers (minor / major axis): a dot seen over 60 deg from face-on
    faint_max_neighbour_axis_ratio: float = 0.6  # ... beside dots seen obliquely: the median minor / major axis of
                                                 # its nearest blobs at most this (1: no test, :func:`_beside_oblique_dots`)
    faint_neighbours: int = 3      # ... of this many nearest blobs above half the contrast, of a dot's size
    # Each blob against its ``neighbours`` nearest blobs that pass the tests above (the tape's
    # print, its weave and specks on it are pieces shorter or flatter than the holes around them;
    # :func:`_unlike_neighbours`):
    min_major_to_neighbours: float = 0.6  # longest axis >= this x their median longest axis (0: no test)
    sliver_max_axis_ratio: float = 0.4    # a blob this flat (minor / major) is a dot only beside dots seen
                                          # obliquely (faint_max_neighbour_axis_ratio; 0: no test)
    neighbours: int = 3                   # (a region with no more blobs than this: no test)
    dot_to_width: float = DEFAULT_DOT_TO_WIDTH


def mask_box(mask: np.ndarray, margin: int = 0) -> tuple[slice, slice] | None:
    """The bounding box of ``mask``'s pixels grown by ``margin`` px (clipped to the mask), None
    when it is empty."""
    h, w = mask.shape
    if mask.size >= 1 << 20 and mask.flags.c_contiguous and w % 8 == 0:
        # a whole frame: its rows 8 pixels at a time, then OpenCV's pass over the rows with pixels
        rows = np.flatnonzero(mask.view(np.uint64).max(axis=1))
        if not len(rows):
            return None
        y, bh = int(rows[0]), int(rows[-1]) + 1 - int(rows[0])
        x, _, bw, _ = cv2.boundingRect(mask[y:y + bh].view(np.uint8))
    else:
        x, y, bw, bh = cv2.boundingRect(mask.view(np.uint8))  # one pass in OpenCV (numpy's any() takes two)
        if bw == 0:
            return None
    return (slice(max(0, y - margin), min(h, y + bh + margin)), slice(max(0, x - margin), min(w, x + bw + margin)))


def mask_box_within(mask: np.ndarray, within: tuple[slice, slice] | None, margin: int = 0) -> tuple[slice, slice] | None:
    """:func:`mask_box` (``margin`` px, clipped), measured in ``within``: a box known to hold
    every pixel of ``mask`` (the same box; one pass over that box, not the whole mask). None:
    measured on the whole mask."""
    if within is None:
        return mask_box(mask, margin)
    box = mask_box(mask[within])
    if box is None:
        return None
    h, w = mask.shape
    y0, x0 = within[0].start + box[0].start, within[1].start + box[1].start
    y1, x1 = within[0].start + box[0].stop, within[1].start + box[1].stop
    return (slice(max(0, y0 - margin), min(h, y1 + margin)), slice(max(0, x0 - margin), min(w, x1 + margin)))


def labelled_components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """8-connected components of a bool or uint8 mask: ``(n, labels, areas)``, ``n`` labels with
    the background's 0, ``areas`` (n,) int32 pixels per label. Labels are uint16 where they fit,
    their counts a histogram (exact below 2^24 px); OpenCV's component statistics would cost ~4x
    the labelling. A mask with more than 65535 components (speckle) is labelled in int32."""
    m = mask.view(np.uint8)
    if m.size < 1 << 24:
        try:
            n, labels = cv2.connectedComponentsWithAlgorithm(m, 8, cv2.CV_16U, cv2.CCL_DEFAULT)
        except cv2.error:  # OpenCV stops when the labels overflow uint16
            pass
        else:
            return n, labels, cv2.calcHist([labels], [0], None, [n], [0, n]).ravel().astype(np.int32)
    n, labels = cv2.connectedComponentsWithAlgorithm(m, 8, cv2.CV_32S, cv2.CCL_DEFAULT)
    return n, labels, np.bincount(labels.ravel(), minlength=n).astype(np.int32)


def fill_holes(mask: np.ndarray, box: tuple[slice, slice] | None = None) -> np.ndarray:
    """Fill the holes of every component of a bool mask (the dots, if the mask excludes them).
    Traced in the mask's box grown by 1 px (a zero frame around it, or the image's own border
    where the box reaches it): the same contours as in the whole image, shifted. ``box``: such
    a box when known (any box holding the mask's pixels and a 1 px frame, or the border)."""
    out = np.zeros(mask.shape, bool)
    box = mask_box(mask, 1) if box is None else box
    if box is None:
        return out
    m = mask[box].astype(np.uint8)
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    filled = np.zeros_like(m)
    cv2.drawContours(filled, contours, -1, 1, thickness=cv2.FILLED)
    out[box] = filled.view(bool)
    return out


def _area_cells(ssize: int, dsize: int) -> tuple[np.ndarray, ...]:
    """Per destination px of OpenCV's area resize along one axis (``ssize`` -> ``dsize``):
    its index, source span [fsx1, fsx2), cell width, first and last whole source px, and whether
    a partial source px comes before / after them (float64, OpenCV's expressions)."""
    scale = 1.0 / (dsize / ssize)
    dx = np.arange(dsize)
    fsx1 = dx * scale
    fsx2 = fsx1 + scale
    cell = np.minimum(scale, ssize - fsx1)
    sx2 = np.minimum(np.floor(fsx2), ssize - 1)
    sx1 = np.minimum(np.ceil(fsx1), sx2)
    return dx, fsx1, fsx2, cell, sx1, sx2, sx1 - fsx1 > 1e-3, fsx2 - sx2 > 1e-3


@functools.lru_cache(maxsize=512)
def _area_table_whole(ssize: int, dsize: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's ``computeResizeAreaTab`` along one axis (``ssize`` -> ``dsize`` px, a non-integer
    scale): destination index, source index and weight (float32, as OpenCV rounds it) of each
    entry, in OpenCV's order (by destination, then source): the reference form of the dense table
    :func:`_area_table` reads (:func:`_area_table_dense`, built directly; the tests compare them)."""
    dx, fsx1, fsx2, cell, sx1, sx2, pre, post = _area_cells(ssize, dsize)
    count = pre.astype(np.int64) + (sx2 - sx1).astype(np.int64) + post
    entry = np.repeat(dx, count)  # the destination of each entry
    rank = np.arange(len(entry)) - (np.cumsum(count) - count)[entry]
    first, last = pre[entry] & (rank == 0), post[entry] & (rank == count[entry] - 1)
    si = np.where(first, sx1[entry] - 1, np.where(last, sx2[entry], sx1[entry] + rank - pre[entry]))
    weight = np.where(first, ((sx1 - fsx1) / cell)[entry],
                      np.where(last, (np.minimum(np.minimum(fsx2 - sx2, 1.0), cell) / cell)[entry],
                               (1.0 / cell)[entry])).astype(np.float32)
    for a in (entry, si, weight):
        a.flags.writeable = False
    return entry, si.astype(np.int64), weight


@functools.lru_cache(maxsize=512)
def _area_table_dense(ssize: int, dsize: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_area_table_whole` as a dense table, cached: per destination (rows) its entries in
    OpenCV's order (columns), source index and weight, padded at the end with zero weights (source
    the destination's last one); and per destination its first and last source index. Built
    directly (a destination's sources are consecutive: the partial one before, the whole ones,
    the partial one after), with the same float64 expressions per destination as the whole table's."""
    dx, fsx1, fsx2, cell, sx1, sx2, pre, post = _area_cells(ssize, dsize)
    whole = (sx2 - sx1).astype(np.int64)
    count = pre.astype(np.int64) + whole + post
    first_source = sx1.astype(np.int64) - pre
    last_source = first_source + count - 1
    rank = np.arange(int(count.max()))[None]
    source = np.minimum(first_source[:, None] + rank, last_source[:, None])
    weight_pre, weight_whole = (sx1 - fsx1) / cell, 1.0 / cell
    weight_post = np.minimum(np.minimum(fsx2 - sx2, 1.0), cell) / cell
    weights = np.where(pre[:, None] & (rank == 0), weight_pre[:, None],
                       np.where(rank < (pre + whole)[:, None], weight_whole[:, None],
                                np.where(post[:, None] & (rank == count[:, None] - 1), weight_post[:, None], 0.0)))
    weights = weights.astype(np.float32)
    for v in (source, weights, first_source, last_source):
        v.flags.writeable = False
    return source, weights, first_source, last_source


def _area_table(ssize: int, dsize: int, lo: int, hi: int) -> tuple[int, np.ndarray, np.ndarray] | None:
    """:func:`_area_table_whole`'s entries whose source pixel lies in [``lo``, ``hi``) (the
    others weigh zero pixels: adding 0 changes no sum), as a dense table: the first destination
    index, and per destination (rows) its entries in OpenCV's order (columns): source index less
    ``lo`` and weight, the entries outside [``lo``, ``hi``) with zero weights (before and after
    the others: 0 + x is x, x + 0 is x for the non-negative sums this serves), and the padding's.
    None when no entry is left. From the cached whole-axis table (:func:`_area_table_dense`)."""
    source, weights, first_source, last_source = _area_table_dense(ssize, dsize)
    a, b = int(last_source.searchsorted(lo)), int(first_source.searchsorted(hi))
    if a >= b:
        return None
    source, weights = source[a:b] - lo, weights[a:b]
    outside = (source < 0) | (source >= hi - lo)
    if outside.any():
        weights = np.where(outside, np.float32(0), weights)
        source = np.minimum(np.maximum(source, 0), hi - lo - 1)
    return a, source, weights


_EPS = float(np.finfo(float).eps)


def area_shrink(columns: np.ndarray, shape: tuple[int, int], box: tuple[slice, slice], dsize: tuple[int, int]) -> np.ndarray:
    """``cv2.resize(image, dsize, interpolation=cv2.INTER_AREA)`` of float32 images of ``shape``
    (h, w) that are zero outside ``box``, given ``columns`` (box w, k, box h) float32, their pixels
    in the box, transposed (the summed axis first: whole rows are gathered, not strided picks):
    (k, dsize h, dsize w) float32, bit for bit OpenCV's (its weights, its order of
    float32 sums: each row's weighted sum across, then the rows'), at the cost of the box only.
    OpenCV's own call on the whole images where it takes another route (an integer scale)."""
    h, w = shape
    dw, dh = dsize
    k = columns.shape[1]
    sx, sy = 1.0 / (dw / w), 1.0 / (dh / h)
    if (abs(sx - round(sx)) < _EPS and abs(sy - round(sy)) < _EPS) or sx < 1 or sy < 1:
        whole = np.zeros((k, h, w), np.float32)
        whole[:, box[0], box[1]] = columns.transpose(1, 2, 0)
        return np.stack([cv2.resize(image, dsize, interpolation=cv2.INTER_AREA) for image in whole])
    y0, x0 = box[0].start, box[1].start
    across_table = _area_table(w, dw, x0, box[1].stop)
    down_table = _area_table(h, dh, y0, box[0].stop)
    out = np.zeros((k, dh, dw), np.float32)
    if across_table is None or down_table is None:
        return out
    # Across each row, then down, each as OpenCV adds: a destination pixel's weighted pixels one
    # after the other in its table's order (0 + x is x; the padding adds zeros at the end).
    c0, source, weights = across_table
    across = _weighted_rows(columns, source, weights)  # (shrunk w, k, box h)
    rows = np.ascontiguousarray(across.transpose(2, 1, 0))  # (box h, k, shrunk w)
    r0, source, weights = down_table
    down = _weighted_rows(rows, source, weights)  # (shrunk h, k, shrunk w)
    out[:, r0:r0 + down.shape[0], c0:c0 + down.shape[2]] = down.transpose(1, 0, 2)
    return out


def _weighted_rows(rows: np.ndarray, source: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per destination i: sum over j in order of ``rows[source[i, j]] * weights[i, j]`` (float32,
    one product and one sum at a time, as OpenCV's area resize adds them)."""
    out = rows[source[:, 0]]
    out *= weights[:, 0, None, None]
    for j in range(1, source.shape[1]):
        term = rows[source[:, j]]
        term *= weights[:, j, None, None]
        out += term
    return out


def estimate_dot_diameter(mask: np.ndarray, dot_to_width: float = DEFAULT_DOT_TO_WIDTH) -> float | None:
    """Guess the dot diameter in px from the width of a (filled) tape mask: in a stripe of width w
    the distance-to-edge values spread evenly over [0, w/2], so w ~ 2 x their 98th percentile."""
    if not mask.any():
        return None
    mask = mask.astype(bool, copy=False)
    dist = cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, 5)
    width = 2.0 * percentile(dist[mask], 98)  # np.percentile of dist > 0 (the mask's pixels), bit for bit
    return max(width * dot_to_width, 2.0)


def _disc(diameter: float) -> np.ndarray:
    k = max(3, int(round(diameter)) | 1)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))


def _regions(mask: np.ndarray, pad: int, stride: int = 8, within: tuple[slice, slice] | None = None
             ) -> list[tuple[slice, slice]]:
    """Padded bounding boxes of the mask's components. The components are found on a
    ``stride``-times smaller copy (a full-frame labelling would cost more than all the dot work
    together); each box is then the exact extent of the mask's pixels in it, so the boxes do not
    depend on where the mask lies on that coarse grid (a crop around the tape finds the dots the
    whole frame finds). ``within``: a box known to hold every pixel of the mask (its box is
    measured there: :func:`mask_box_within`)."""
    h, w = mask.shape
    hs, ws = -(-h // stride), -(-w // stride)
    sy, sx = h / hs, w / ws  # the coarse pixel's size (stride, or a little less at odd sizes)
    # x 255: a block with a single mask pixel stays non-zero (its area average is >= 255 / stride^2).
    # OpenCV's uint8 INTER_AREA of the mask: its float sums (area_shrink, on the mask's box only)
    # rounded to the nearest even integer, as OpenCV rounds them to uint8.
    box = mask_box_within(mask, within)
    if box is None:
        return []
    columns = cv2.transpose(mask[box].view(np.uint8)) * np.float32(255)  # (box w, box h)
    sums = area_shrink(columns[:, None], (h, w), box, (ws, hs))[0]
    coarse = (np.rint(sums) > 0).view(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
    boxes = []
    for x, y, bw, bh, _area in stats[1:]:
        ys = slice(int(y * sy), min(h, int(math.ceil((y + bh) * sy))))
        xs = slice(int(x * sx), min(w, int(math.ceil((x + bw) * sx))))
        extent = mask_box(mask[ys, xs])
        if extent is None:
            continue
        y0, y1 = ys.start + extent[0].start - pad, ys.start + extent[0].stop + pad
        x0, x1 = xs.start + extent[1].start - pad, xs.start + extent[1].stop + pad
        boxes.append((slice(max(0, y0), min(h, y1)), slice(max(0, x0), min(w, x1))))
    return boxes


def percentile(values: np.ndarray, q: float) -> float:
    """``float(np.percentile(values, q))`` (linear interpolation, ``q`` a Python number) of a 1-D
    array without NaNs, bit for bit as numpy >= 2.4 computes it (in the values' dtype), without
    numpy's general-purpose overhead: ~3 instead of ~120 us (a few calls per region of interest)."""
    n = values.size
    index = (n - 1) * (q / 100.0)
    lo = math.floor(index)
    if lo >= n - 1:
        return float(values.max())
    part = np.partition(values, (lo, lo + 1))
    return _between(part[lo], part[lo + 1], index - lo, values.dtype.type)


def _between(a, b, t: float, as_dtype) -> float:
    """numpy's linear interpolation from ``a`` to ``b`` at ``t`` in [0, 1), the weight rounded to
    the values' dtype as numpy rounds it."""
    diff = b - a
    return float(b - diff * as_dtype(1.0 - t) if t >= 0.5 else a + diff * as_dtype(t))


def _percentile_and_median(values: np.ndarray, q: float) -> tuple[float, float]:
    """``(percentile(values, q), float(median(values)))`` from one partition (the same order
    statistics, so the same values bit for bit)."""
    n = values.size
    index = (n - 1) * (q / 100.0)
    lo = math.floor(index)
    k = n // 2
    kth = {k, k - 1} if n % 2 == 0 else {k}
    kth |= {lo, lo + 1} if lo < n - 1 else {n - 1}
    part = np.partition(values, sorted(kth))
    # the maximum, or between the two order statistics as percentile() takes them
    pct = float(part[n - 1]) if lo >= n - 1 else _between(part[lo], part[lo + 1], index - lo, values.dtype.type)
    return pct, float(np.mean(part[k:k + 1]) if n % 2 else np.mean(part[k - 1:k + 1]))


def histogram_median(counts: np.ndarray) -> np.float32:
    """``np.median`` of the float32 values of the integer levels counted in ``counts`` (index =
    level), bit for bit: the middle value, or the float32 mean of the middle two (exact)."""
    cumulative = np.cumsum(counts)
    n = int(cumulative[-1])
    upper = int(cumulative.searchsorted(n // 2 + 1))  # the value of rank n // 2 (from 0)
    if n % 2:
        return np.float32(upper)
    lower = int(cumulative.searchsorted(n // 2))  # rank n // 2 - 1
    return np.float32((lower + upper) / 2)


def median(values: np.ndarray):
    """``np.median`` of a 1-D array without NaNs, bit for bit (the same partition and mean, in
    the values' dtype), without its general-purpose overhead."""
    n = values.size
    k = n // 2
    if n % 2:  # numpy takes the mean of the middle value too (an integer array's median is float64)
        return np.mean(np.partition(values, k)[k:k + 1])
    part = np.partition(values, (k - 1, k))
    return np.mean(part[k - 1:k + 1])


def _region_dots(
    grey: np.ndarray, filled: np.ndarray, region: np.ndarray, d: float, p: BlobParams, touches_border,
    size_from_blobs: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Dots in one region of interest: ``grey`` uint8 (or float32) crop, ``filled`` the hole-filled mask
    crop, ``region`` the mask grown by the margin (where dot pixels may lie); ``touches_border``
    tells whether a crop box (y, x, h, w) touches the frame border (a cut dot's centre is wrong).
    ``size_from_blobs``: ``d`` is only a guess from the mask width; measure it on the blobs.
    All blobs are measured together (:class:`_Blobs`, :func:`_ring_pixels`: array operations,
    no Python per blob beyond its scalar tests); the same dots as one blob at a time, to float
    rounding (sums in float64 instead of float32: < 1e-4 px)."""
    # The top-hat keeps bright structures smaller than its kernel: the dots. Skin around the tape
    # is a large bright area and vanishes, so it never merges with a dot at the tape's edge.
    # A square kernel: OpenCV decomposes it into two 1D passes (a disc costs ~10x more).
    k = int(round(1.4 * d + 2)) | 1
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    # On uint8 grey levels: the same top-hat values (integers: the grey less its opening) for a
    # quarter of the bytes, and their median from a histogram.
    tophat_levels = cv2.morphologyEx(grey, cv2.MORPH_TOPHAT, kernel) if grey.dtype == np.uint8 else None
    tophat = tophat_levels.astype(np.float32) if tophat_levels is not None else cv2.morphologyEx(grey, cv2.MORPH_TOPHAT, kernel)
    smooth = cv2.GaussianBlur(tophat, (0, 0), max(0.5, d / 10.0))
    # Dots must stand out from the tape's own texture/noise (the median of the top-hat over the
    # tape, which dots cover only in small part): pure noise has no such outliers.
    contrast, texture = _percentile_and_median(smooth[filled], 99.5)
    if contrast < max(p.min_contrast, p.min_contrast_to_texture * texture):
        return np.zeros((0, 2)), np.zeros(0)
    binary = np.greater(smooth, 0.5 * contrast)
    binary &= region
    _add_faint_spots(binary, smooth, region, contrast, d, p)
    binary = binary.view(np.uint8)  # 0 / 1
    # Top-hat of plain tape is noise-positive: measure that floor on tape pixels, subtract it.
    tape_px = filled & (binary == 0)
    if not tape_px.any():
        floor = 0.0
    elif tophat_levels is not None:  # np.median of the float32 values, bit for bit
        floor = float(histogram_median(cv2.calcHist([tophat_levels], [0], tape_px.view(np.uint8), [256], [0, 256]).ravel()))
    else:
        floor = float(median(tophat[tape_px]))
    scale = max(contrast - floor, 1e-3)
    n, labels = cv2.connectedComponents(binary, connectivity=8)  # statistics below: ~4x cheaper than OpenCV's
    if n <= 1:
        return np.zeros((0, 2)), np.zeros(0)
    blobs = _Blobs(labels, n, binary.view(bool))
    stats = blobs.stats
    if size_from_blobs:
        d = _typical_diameter(blobs, d)
    dot_area = math.pi * d * d / 4.0
    rim = max(2, int(math.ceil(0.3 * d)))
    area = stats[:, cv2.CC_STAT_AREA]
    x, y = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    # shapes measured in each blob's window (its box grown by the rim), as cv2.moments there
    major, minor = blobs.ellipse_axes(np.maximum(0, x - rim), np.maximum(0, y - rim))
    with np.errstate(divide="ignore", invalid="ignore"):
        fill = area / (math.pi * major * minor / 4.0)
    candidate = ((area >= p.min_area * dot_area * foreshortening(major, minor, d, p)) & (area <= p.max_area * dot_area)
                 & ~(major > p.max_major * d) & ~(minor < p.min_axis_ratio * major) & ~(fill < p.min_fill))
    candidate[0] = False
    # Each candidate's support: its pixels and the background within the rim of it (pixels of
    # other blobs excluded); supports of close dots share background pixels.
    c = np.flatnonzero(candidate)
    if not len(c):
        return np.zeros((0, 2)), np.zeros(0)
    # the candidates' box (their statistics): the rings are found there, grown by the rim
    cx, cy = x[c], y[c]
    box = (slice(int(cy.min()), int((cy + stats[c, cv2.CC_STAT_HEIGHT]).max())),
           slice(int(cx.min()), int((cx + stats[c, cv2.CC_STAT_WIDTH]).max())))
    ring = _ring_pixels(labels, candidate, _disc(2 * rim - 1), box)
    ring_share = blobs.ring_share(ring, filled)
    carved = _carved_from_larger_area(blobs, labels, candidate, box, grey, tophat, filled, 0.5 * contrast)
    level = blobs.percentiles(tophat, 60) - floor
    sums = blobs.weighted_sums(ring, candidate, tophat, floor, np.maximum(level, 1e-3))
    mean_smooth = blobs.means(smooth)
    # A dot is a hole in the tape: its surrounding ring lies on the tape. Bright slivers of skin
    # beside the tape's end or cut off by the frame border fail this. (All candidates at once:
    # ``touches_border`` takes arrays.)
    i = np.flatnonzero(candidate)
    bw, bh = stats[i, cv2.CC_STAT_WIDTH], stats[i, cv2.CC_STAT_HEIGHT]
    total = sums[i, 0]
    i = i[~(ring_share[i] < p.min_ring_on_tape) & ~carved[i] & ~np.asarray(touches_border(y[i], x[i], bh, bw), bool)
          & ~(total <= 0)]
    if len(i) > p.neighbours:
        i = i[~_unlike_neighbours(np.stack([blobs.sx[i], blobs.sy[i]], axis=1) / blobs.s1[i, None], major[i], minor[i], p)]
    if not len(i):
        return np.zeros((0, 2)), np.zeros(0)
    # Sub-pixel centre: top-hat intensity (floor removed, clipped) over the blob plus a rim, so
    # partially covered edge pixels weigh in proportion to their coverage, scaled by this blob's
    # own interior level (its inside saturates at 1 and shading across the dot cannot pull the centre).
    total, sx, sy = sums[i, 0], sums[i, 1], sums[i, 2]
    centres = np.stack([sx / total, sy / total], axis=1)
    mean_contrast = (mean_smooth[i] - floor) / scale
    scores = _confidences(area[i] / dot_area, minor[i] / major[i], fill[i], mean_contrast / 0.8)
    return merge_close(centres, scores, p.merge_distance * d)


def _add_faint_spots(binary: np.ndarray, smooth: np.ndarray, region: np.ndarray, contrast: float, d: float,
                     p: BlobParams) -> None:
    """Adds to ``binary`` (bool, in place; the smoothed top-hat ``smooth`` above half the
    region's ``contrast``, in ``region``) each spot of ``region`` brighter than
    ``p.faint_share * contrast`` that lies apart from ``binary``'s blobs (more than a third of
    the dot size ``d``, so that it never joins one), cut at half its own peak, where what is
    left is a sliver (minor / major axis at most ``p.faint_max_axis_ratio``) beside blobs of
    ``binary`` that are foreshortened too (:func:`_beside_oblique_dots`).

    A dot seen nearly edge-on (70-78 deg from face-on) is a sliver a few px wide, on skin that
    the light grazes: its smoothed peak falls under half the face-on dots' contrast, which would
    lose it whole. Cut at half its own peak, it keeps the outline the blob tests judge. A dot seen
    that obliquely is always a sliver, so a rounder faint spot is something else."""
    if not p.faint_share < 0.5:
        return
    apart = 2 * math.ceil(d / 3) + 1  # a square: OpenCV dilates by it in two 1D passes
    faint = np.greater(smooth, p.faint_share * contrast)
    faint &= region
    faint &= ~cv2.dilate(binary.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (apart, apart))).view(bool)
    if not faint.any():
        return
    n, labels, _ = labelled_components(faint)
    if n <= 1:
        return
    ys, xs = _nonzero(faint)
    lab = labels[ys, xs]
    peak = np.zeros(n, np.float32)
    np.maximum.at(peak, lab, smooth[ys, xs])
    bright = smooth[ys, xs] > np.float32(0.5) * peak[lab]
    ys, xs, lab = ys[bright], xs[bright], lab[bright]
    shapes = _moment_ellipses(ys, xs, lab, n)
    sliver = shapes.axis_ratio <= p.faint_max_axis_ratio
    if p.faint_max_neighbour_axis_ratio < 1 and sliver.any():
        candidates = np.flatnonzero(sliver)
        sliver[candidates] = _beside_oblique_dots(shapes.centre[candidates], _dot_shapes(binary, d, p), p)
    keep = sliver[lab]
    binary[ys[keep], xs[keep]] = True


class _Ellipses(NamedTuple):
    """Per label (n,): ``axis_ratio`` minor / major axis of its moment ellipse (1 for an empty
    label), ``centre`` (n, 2) px (x, y; NaN for an empty label) and ``major`` the full major
    axis (px)."""

    axis_ratio: np.ndarray
    centre: np.ndarray
    major: np.ndarray


def _moment_ellipses(ys: np.ndarray, xs: np.ndarray, lab: np.ndarray, n: int) -> _Ellipses:
    """The moment ellipse of each label over the pixels (``ys``, ``xs``) labelled ``lab`` (a
    pixel's own variance 1/12 per axis as the floor)."""
    fx, fy = xs.astype(np.float64), ys.astype(np.float64)
    count = np.bincount(lab, minlength=n).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        mx, my = np.bincount(lab, fx, n) / count, np.bincount(lab, fy, n) / count
        cxx = np.bincount(lab, fx * fx, n) / count - mx * mx
        cyy = np.bincount(lab, fy * fy, n) / count - my * my
        cxy = np.bincount(lab, fx * fy, n) / count - mx * my
        half_gap = np.sqrt(((cxx - cyy) / 2) ** 2 + cxy ** 2)
        major = np.maximum((cxx + cyy) / 2 + half_gap, 1 / 12)
        minor = np.maximum((cxx + cyy) / 2 - half_gap, 1 / 12)
        return _Ellipses(np.where(count > 0, np.sqrt(minor / major), 1.0), np.stack([mx, my], axis=1), 4 * np.sqrt(major))


def _dot_shapes(binary: np.ndarray, d: float, p: BlobParams) -> _Ellipses:
    """The moment ellipses of the 8-connected blobs of ``binary`` (bool) of a dot's size: at least
    ``p.min_area`` of a face-on dot of diameter ``d`` px, their major axis at most ``p.max_major *
    d`` (the blob tests' bounds; specks and long streaks left out)."""
    n, labels, area = labelled_components(binary)
    ys, xs = _nonzero(binary)
    shapes = _moment_ellipses(ys, xs, labels[ys, xs], n)
    dots = np.flatnonzero((area >= p.min_area * math.pi * d * d / 4) & (shapes.major <= p.max_major * d))
    dots = dots[dots > 0]  # label 0: the background
    return _Ellipses(shapes.axis_ratio[dots], shapes.centre[dots], shapes.major[dots])


def _beside_oblique_dots(centre: np.ndarray, dots: _Ellipses, p: BlobParams) -> np.ndarray:
    """Per faint sliver (K,) at ``centre`` (K, 2) px (x, y): the median axis ratio (minor / major)
    of the ``p.faint_neighbours`` ``dots`` nearest it (fewer where there are fewer) is at most
    ``p.faint_max_neighbour_axis_ratio``; False where there is no dot.

    A dot seen nearly edge-on lies where the tape turns away from the camera, and the rows beside
    it are seen obliquely too: their dots are ellipses (a ratio of 0.6: 53 deg from face-on).
    The faint slivers that are not dots lie beside round, face-on dots: the tape's print between
    two rows, the shaded rim of a ball over the tape, a spot where the mask spills onto the room."""
    if not len(dots.axis_ratio):
        return np.zeros(len(centre), bool)
    k = min(p.faint_neighbours, len(dots.axis_ratio))
    gap = dots.centre[None] - centre[:, None]  # (K, M, 2)
    nearest = np.argsort(np.hypot(gap[..., 0], gap[..., 1]), axis=1)[:, :k]
    return np.median(dots.axis_ratio[nearest], axis=1) <= p.faint_max_neighbour_axis_ratio


def _unlike_neighbours(centre: np.ndarray, major: np.ndarray, minor: np.ndarray, p: BlobParams) -> np.ndarray:
    """Per blob (N,) of a region: True where it is unlike its ``p.neighbours`` nearest other blobs
    (centres ``centre`` (N, 2) px, ellipse axes ``major``, ``minor`` (N,) px): its long axis is
    shorter than ``p.min_major_to_neighbours`` x their median long axis, or it is a sliver (minor
    / major at most ``p.sliver_max_axis_ratio``) whose neighbours are not seen obliquely (their
    median axis ratio above ``p.faint_max_neighbour_axis_ratio``). False for all when there are
    not that many other blobs (a piece of tape showing a few dots, some cut by the piece's edge,
    tells nothing about its holes' shape).

    A hole seen from any side is an ellipse whose long axis is the hole's diameter: foreshortening
    shortens its other axis only, and holes side by side are seen at nearly the same scale and
    slant (the tape is smooth), so they keep nearly the same long axis and axis ratio. A letter's
    stroke, a thread of the weave or a speck on the tape is a piece far shorter than the holes
    around it, or a sliver between round holes."""
    n = len(centre)
    k = p.neighbours
    if n <= k or k < 1:
        return np.zeros(n, bool)
    gap = centre[None] - centre[:, None]  # (N, N, 2)
    distance = np.hypot(gap[..., 0], gap[..., 1])
    np.fill_diagonal(distance, np.inf)  # a blob is not its own neighbour
    nearest = np.argsort(distance, axis=1)[:, :k]
    with np.errstate(divide="ignore", invalid="ignore"):
        axis_ratio = np.where(major > 0, minor / major, 1.0)
    short = major < p.min_major_to_neighbours * np.median(major[nearest], axis=1)
    round_around = np.median(axis_ratio[nearest], axis=1) > p.faint_max_neighbour_axis_ratio
    sliver = (axis_ratio <= p.sliver_max_axis_ratio) & round_around
    return short | sliver


def _carved_from_larger_area(blobs: "_Blobs", labels: np.ndarray, candidate: np.ndarray, box: tuple[slice, slice],
                             grey: np.ndarray, tophat: np.ndarray, filled: np.ndarray, half_contrast: float) -> np.ndarray:
    """Per label: a candidate blob that borders (8-connected), on the tape mask ``filled``, a
    pixel of a bright area the top-hat's kernel fits in: its opening (``grey`` less ``tophat``)
    exceeds the blob's own by ``half_contrast`` (the threshold that cut the blobs).

    A hole in the tape is enclosed by tape, whose opening is the tape's level; the square top-hat
    also keeps the rim segments of a bright disc larger than a dot (a lamp, an LED ring's lights)
    where no square fits, and each borders the disc's bright inside."""
    ys, xs, owner = _ring_pixels(labels, candidate, np.ones((3, 3), np.uint8), box)
    blob_opening = blobs.means(grey) - blobs.means(tophat)
    lit = (grey[ys, xs].astype(np.float32) - tophat[ys, xs] > blob_opening[owner] + half_contrast) & filled[ys, xs]
    return np.bincount(owner, weights=lit, minlength=blobs.n) > 0


def foreshortening(major: np.ndarray, minor: np.ndarray, d: float, p: BlobParams) -> np.ndarray:
    """Per blob, the share of a face-on dot's area (``pi d^2 / 4``) that a dot seen as this
    blob covers: a circle seen at angle a from face-on is an ellipse whose major axis keeps the
    diameter and whose minor axis and area shrink by cos a. ``major``, ``minor``: the blobs'
    ellipse axes (px), ``d`` the expected dot diameter (px). A blob whose major axis is at least
    ``p.min_oblique_major * d`` is taken for such an ellipse (its axis ratio, at most 1); a
    shorter one (a speck, a fragment) counts as face-on (1)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.minimum(minor / major, 1.0)
    return np.where((major >= p.min_oblique_major * d) & (ratio > 0), ratio, 1.0)


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.nonzero`` of a 2-D bool array (rows, columns; row-major order), from one flat pass:
    numpy's 2-D nonzero costs several times more."""
    return np.divmod(mask.ravel().nonzero()[0], max(1, mask.shape[1]))  # np.flatnonzero without its wrappers


class _Blobs:
    """Per-label sums over a label image (label 0: background), all labels at once: pixel
    counts and exact integer coordinate moments (float64 holds them exactly). ``foreground``:
    the bool mask of the labelled pixels when at hand (found from it: a bool pass is cheaper)."""

    def __init__(self, labels: np.ndarray, n: int, foreground: np.ndarray | None = None):
        self.n = n
        ys, xs = _nonzero(labels != 0 if foreground is None else foreground)
        self.ys, self.xs = ys, xs
        self.lab = labels[ys, xs]
        fx, fy = xs.astype(np.float64), ys.astype(np.float64)
        count = lambda w=None: np.bincount(self.lab, weights=w, minlength=self.n)  # noqa: E731
        self.s1, self.sx, self.sy = count(), count(fx), count(fy)
        self.sxx, self.syy, self.sxy = count(fx * fx), count(fy * fy), count(fx * fy)
        # OpenCV's component statistics (left, top, width, height, area; int32) of labels >= 1; the
        # background's row (label 0) holds the whole image's box and its pixel count
        h, w = labels.shape
        low = np.full((2, n), np.iinfo(np.int64).max)
        high = np.full((2, n), -1)
        for k, v in enumerate((xs, ys)):
            np.minimum.at(low[k], self.lab, v)
            np.maximum.at(high[k], self.lab, v)
        stats = np.stack([low[0], low[1], high[0] + 1 - low[0], high[1] + 1 - low[1], self.s1.astype(np.int64)], axis=1)
        stats[0] = (0, 0, w, h, labels.size - len(ys))
        self.stats = stats.astype(np.int32)

    def ellipse_axes(self, ox: np.ndarray, oy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full major/minor axes (px) of each label's moment ellipse, the moments taken with
        the origin at (``ox``, ``oy``) per label: the ellipse of ``cv2.moments`` of the blob in
        that window, bit for bit (the same exact integer raw moments, OpenCV's formulas for the
        central ones); a single pixel has variance 1/12 per axis (pixel quantisation)."""
        ox, oy = ox.astype(np.float64), oy.astype(np.float64)
        m00 = self.s1
        m10, m01 = self.sx - ox * m00, self.sy - oy * m00
        m20 = self.sxx - 2 * ox * self.sx + ox * ox * m00
        m02 = self.syy - 2 * oy * self.sy + oy * oy * m00
        m11 = self.sxy - ox * self.sy - oy * self.sx + ox * oy * m00
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / m00
            cx, cy = m10 * inv, m01 * inv
            mu20, mu11, mu02 = (m20 - m10 * cx) / m00, (m11 - m10 * cy) / m00, (m02 - m01 * cy) / m00
        # Python's float ** 2 (C pow) is not always x * x to the last bit: squared as the one-blob pass squared
        squared = np.array([v ** 2 for v in (mu20 - mu02).tolist()], dtype=np.float64)
        common = np.sqrt(np.maximum(0.0, 4 * mu11 * mu11 + squared))
        l1 = (mu20 + mu02 + common) / 2
        l2 = (mu20 + mu02 - common) / 2
        return 4 * np.sqrt(np.maximum(l1, 1 / 12)), 4 * np.sqrt(np.maximum(l2, 1 / 12))

    def means(self, image: np.ndarray) -> np.ndarray:
        """Mean of ``image`` over each label's pixels (float64 sums)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.bincount(self.lab, weights=image[self.ys, self.xs], minlength=self.n) / self.s1

    def percentiles(self, image: np.ndarray, q: float) -> np.ndarray:
        """:func:`percentile` ``q`` of ``image`` over each label's pixels, bit for bit (NaN for
        an empty label)."""
        values = image[self.ys, self.xs]
        if values.dtype == np.float32 and not np.signbit(values).any():
            # label, then value, as one int64 key (a non-negative float32's bits ascend with it): one sort
            key = np.sort((self.lab.astype(np.int64) << 32) | values.view(np.uint32))
            v = (key & 0xFFFFFFFF).astype(np.uint32).view(np.float32)
        else:
            v = values[np.lexsort((values, self.lab))]
        counts = self.s1.astype(np.int64)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        index = (counts - 1) * (q / 100.0)
        lo = np.floor(index).astype(np.int64)
        t = index - lo
        out = np.full(self.n, np.nan)
        ok = counts > 0
        top = ok & (lo >= counts - 1)
        out[top] = v[start[top] + counts[top] - 1]  # the maximum
        mid = ok & ~top
        a, b = v[start[mid] + lo[mid]], v[start[mid] + lo[mid] + 1]
        diff = b - a
        tm = t[mid]
        as_dtype = values.dtype.type  # numpy rounds the weight to the values' dtype
        out[mid] = np.where(tm >= 0.5, b - diff * (1.0 - tm).astype(as_dtype), a + diff * tm.astype(as_dtype))
        return out

    def ring_share(self, ring: tuple[np.ndarray, np.ndarray, np.ndarray], filled: np.ndarray) -> np.ndarray:
        """Per label: the share of its ring pixels (``ring``: ys, xs, label) on the tape (1 when it has none)."""
        ys, xs, owner = ring
        n_ring = np.bincount(owner, minlength=self.n)
        on = np.bincount(owner, weights=filled[ys, xs], minlength=self.n)
        return np.where(n_ring > 0, on / np.maximum(n_ring, 1), 1.0)

    def weighted_sums(self, ring: tuple[np.ndarray, np.ndarray, np.ndarray], candidate: np.ndarray,
                      tophat: np.ndarray, floor: float, level: np.ndarray) -> np.ndarray:
        """Per candidate label (total, sum x w, sum y w) of the centre weights over its support
        (its pixels and its ``ring`` pixels): the top-hat less ``floor``, over the label's
        ``level``, clipped to [0, 1] (float32 per pixel as numpy computes it with Python
        scalars; float64 sums)."""
        own = candidate[self.lab]
        ys = np.concatenate([self.ys[own], ring[0]])
        xs = np.concatenate([self.xs[own], ring[1]])
        owner = np.concatenate([self.lab[own], ring[2]])
        lv = level.astype(np.float32)
        # clipped to [0, 1] (np.clip's values; a -0.0 it would make +0.0 adds nothing to the sums either)
        w = np.minimum(np.maximum((tophat[ys, xs] - np.float32(floor)) / lv[owner], np.float32(0)), np.float32(1)).astype(np.float64)
        return np.stack([np.bincount(owner, weights=w, minlength=self.n),
                         np.bincount(owner, weights=w * xs, minlength=self.n),
                         np.bincount(owner, weights=w * ys, minlength=self.n)], axis=1)


def _ring_pixels(labels: np.ndarray, candidate: np.ndarray, grow: np.ndarray,
                 box: tuple[slice, slice] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The background pixels within ``grow`` (a symmetric structuring element) of each candidate
    blob, as (ys, xs, label) triples; a pixel within reach of several candidates appears once
    for each (what dilating each blob on its own gives, without a dilation per blob). Order: the
    pixels with one candidate in reach (row-major), then those with several (row-major, their
    labels ascending). ``box``: a box holding every candidate's pixels (e.g. their bounding box):
    the work is done there grown by the element's reach (no ring pixel lies farther; outside it
    no candidate is in reach), the same triples in the same order."""
    r = grow.shape[0] // 2
    if box is not None:
        h, w = labels.shape
        y0, x0 = max(0, box[0].start - r), max(0, box[1].start - r)
        labels = labels[y0:min(h, box[0].stop + r), x0:min(w, box[1].stop + r)]
    n = len(candidate)
    dtype = np.uint8 if n < 255 else np.uint16 if n < 65535 else np.float32
    if dtype == np.uint8:  # OpenCV's byte table lookup (labels < 255): cheaper than indexing by int32 labels
        table = np.zeros(256, np.uint8)
        table[:n] = np.where(candidate, np.arange(n), 0)
        cand = cv2.LUT(labels.astype(np.uint8), table)
    else:
        cand = np.where(candidate, np.arange(n), 0).astype(dtype)[labels]
    highest = cv2.dilate(cand, grow)
    if dtype != np.float32:  # the lowest candidate label within reach, less 1: 0 wraps to the top (none)
        lowest = cv2.erode(cand - dtype(1), grow) + dtype(1)  # none wraps back to 0
    else:
        lowest = cv2.erode(np.where(cand > 0, cand, np.float32(n + 1)).astype(dtype), grow)
    # the reached pixels once (one pass), then split: one candidate within reach or several
    ys, xs = _nonzero((labels == 0) & (highest > 0))
    high = highest[ys, xs]
    several = high != lowest[ys, xs]
    one = ~several
    ys1, xs1, owner1 = ys[one], xs[one], high[one].astype(np.int64)  # one candidate: the dilation's label
    ys2, xs2 = ys[several], xs[several]  # several: every candidate label within the element around it
    if box is not None:
        ys1 += y0
        xs1 += x0
    if not len(ys2):
        return ys1, xs1, owner1
    dy, dx = np.nonzero(grow)
    padded = cv2.copyMakeBorder(cand, r, r, r, r, cv2.BORDER_CONSTANT, value=0)  # outside: no candidate
    width = padded.shape[1]
    offsets = (dy - r) * width + (dx - r)
    flat = padded.ravel()
    starts = (ys2 + r) * width + xs2 + r
    # each pixel's distinct candidate labels in ascending order (as a sort of (pixel, label) keys gives them);
    # bit sets of one word (n <= 64): ~3x cheaper than the sort; of 2-4 words: ~3x dearer. In chunks of
    # pixels (the same pairs in the same order): a large element over many pixels would not fit in memory.
    step = max(1, _RING_CHUNK_ELEMENTS // len(offsets))
    which_parts, owner_parts = [], []
    for lo in range(0, len(starts), step):
        near = flat[starts[lo:lo + step, None] + offsets]
        which, owner = _distinct_labels(near, n) if n <= 64 else _distinct_labels_sorted(near)
        which_parts.append(which + lo)
        owner_parts.append(owner)
    which, owner2 = np.concatenate(which_parts), np.concatenate(owner_parts)
    if box is not None:
        ys2 += y0
        xs2 += x0
    return (np.concatenate([ys1, ys2[which]]), np.concatenate([xs1, xs2[which]]),
            np.concatenate([owner1, owner2]))


_RING_CHUNK_ELEMENTS = 1 << 22  # labels gathered at once by _ring_pixels (32 MiB of int64 indices)


def _distinct_labels_sorted(near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct non-zero labels of each row of ``near`` (N, K), ascending: (row, label int64)
    pairs, rows ascending (a sort of each row: the reference of :func:`_distinct_labels`)."""
    near = np.sort(near, axis=1)
    first = near > 0
    first[:, 1:] &= near[:, 1:] != near[:, :-1]
    return _nonzero(first)[0], near[first].astype(np.int64)


def _distinct_labels(near: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_distinct_labels_sorted` of uint8 labels below ``n`` (<= 256), the same pairs in the
    same order: each row's labels as the bits of one little-endian bit set ((n + 63) // 64 uint64
    words, OR-ed across the row; no sort), read back in ascending bit order."""
    words = (n + 63) // 64
    bits = np.zeros((n, words), "<u8")
    labels = np.arange(1, n)  # label 0 (no candidate): no bit
    bits[labels, labels // 64] = np.left_shift(np.uint64(1), (labels % 64).astype(np.uint64))
    rows = np.bitwise_or.reduce(bits[near], axis=1)  # (N, words)
    which, owner = _nonzero(np.unpackbits(rows.view(np.uint8), axis=1, bitorder="little").view(bool))
    return which, owner.astype(np.int64)


def _typical_diameter(blobs: "_Blobs", d_guess: float) -> float:
    """Median longest axis of the blobs plausibly dots. Seen obliquely, the tape (and the width
    guess) shrinks across but not along the tape, so the dots' long axis keeps the true size."""
    guess_area = math.pi * d_guess * d_guess / 4.0
    stats = blobs.stats
    area = stats[:, cv2.CC_STAT_AREA]
    plausible = (0.3 * guess_area <= area) & (area <= 6 * guess_area)
    plausible[0] = False
    majors, _ = blobs.ellipse_axes(stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP])  # moments in the blob's box
    majors = majors[plausible]
    return max(d_guess, float(median(majors))) if len(majors) >= 3 else d_guess  # np.median, bit for bit


def _confidence(area_ratio: float, axis_ratio: float, fill: float, contrast_ratio: float) -> float:
    """In [0, 1]: 1 for a full-contrast disc of the expected size, lower for odd ones."""
    size = math.exp(-(math.log(max(area_ratio, 1e-3)) ** 2) / (2 * 0.6 ** 2))
    round_ = min(1.0, axis_ratio / 0.6)
    solid = min(1.0, max(0.0, (fill - 0.5) / 0.4))
    bright = min(1.0, max(0.0, contrast_ratio))
    return float(size * round_ * solid * bright) ** 0.5


_SIZE_SPREAD = 2 * 0.6 ** 2  # the same float as _confidence's folded constant


def _confidences(area_ratio: np.ndarray, axis_ratio: np.ndarray, fill: np.ndarray, contrast_ratio: np.ndarray) -> np.ndarray:
    """:func:`_confidence` of each element (float64 arrays), bit for bit: its ``min`` / ``max``
    (as Python picks: the first argument unless the second is strictly smaller / larger) and
    divisions as array operations, only ``math.exp``, ``math.log`` and the powers per element
    (one list comprehension: numpy's exp and log may round differently), the product in the
    same left-to-right order."""
    size_in = np.where(1e-3 > area_ratio, 1e-3, area_ratio).tolist()
    q = axis_ratio / 0.6
    round_ = np.where(q < 1.0, q, 1.0)
    f = (fill - 0.5) / 0.4
    f = np.where(f > 0.0, f, 0.0)
    solid = np.where(f < 1.0, f, 1.0)
    c = np.where(contrast_ratio > 0.0, contrast_ratio, 0.0)
    bright = np.where(c < 1.0, c, 1.0)
    return np.array([(math.exp(-(math.log(a) ** 2) / _SIZE_SPREAD) * r * s * b) ** 0.5
                     for a, r, s, b in zip(size_in, round_.tolist(), solid.tolist(), bright.tolist())], float)


def merge_close(uv: np.ndarray, score: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy: keep the best-scoring blob, drop others within ``radius`` of a kept one."""
    order = np.argsort(-score)
    dx, dy = uv[:, None, 0] - uv[None, :, 0], uv[:, None, 1] - uv[None, :, 1]
    near = np.sqrt(dx * dx + dy * dy) < radius  # (N, N): np.linalg.norm's values, not N^2 Python
    if np.count_nonzero(near) == np.count_nonzero(near.diagonal()):
        keep = order  # no blob near another (the usual case): the greedy pass keeps them all, in this order
    else:
        covered = np.zeros(len(uv), bool)
        kept: list[int] = []
        for i in order.tolist():
            if not covered[i]:
                kept.append(i)
                covered |= near[i]
        keep = np.array(kept, np.int64)
    # by (y, x), ties in the greedy order: a stable sort, as Python's sort by the (y, x) tuples
    keep = keep[np.lexsort((uv[keep, 0], uv[keep, 1]))]
    return uv[keep], score[keep]


def find_dots(
    image: np.ndarray,
    mask: np.ndarray,
    expected_dot_px: float | None = None,
    params: BlobParams | None = None,
    memo: dict | None = None,
    hole_free: bool = False,
    within: tuple[slice, slice] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Bright round dots inside ``mask``.

    ``image``: BGR or grey uint8 (H, W[, 3]); ``mask``: (H, W) bool tape mask (holes allowed);
    ``expected_dot_px``: dot diameter in px, estimated from the mask width when None.
    Returns ``uv`` (N, 2) float px sub-pixel centres (x, y) and ``confidence`` (N,) in [0, 1].
    ``memo``: a dict shared by calls on the same ``image`` with the same ``expected_dot_px`` and
    ``params`` (e.g. one mask and the same mask less a few components): a region of interest
    whose box and mask pixels an earlier call saw is not searched again (its dots are those of
    that call: the search reads nothing else). ``hole_free``: ``mask`` has no holes (e.g.
    :func:`fill_holes`' answer): the regions' hole filling is skipped (any box of a hole-free
    mask is hole-free: a hole there would be one of the mask). ``within``: a box known to hold
    every pixel of ``mask`` (the mask's box is measured there), when the caller has one.
    """
    p = params or BlobParams()
    grey = to_grey(image)
    mask = np.asarray(mask, bool)
    if mask.shape != grey.shape:
        raise ValueError(f"mask shape {mask.shape} differs from image shape {grey.shape}")
    empty = (np.zeros((0, 2)), np.zeros(0))
    H, W = grey.shape
    uvs, confs = [], []
    # Coarse boxes first (cheap on the whole frame); all further work happens inside them.
    d_global = expected_dot_px
    pad = int(math.ceil(p.margin * (d_global or 8.0))) + 4
    for ys, xs in _regions(mask, pad, within=within):
        key = None
        if memo is not None:
            key = (ys.start, ys.stop, xs.start, xs.stop, mask[ys, xs].tobytes())
            if key in memo:
                uv, conf = memo[key]
                if len(uv):
                    uvs.append(uv)
                    confs.append(conf)
                continue
        uv, conf = _roi_dots(grey, mask, ys, xs, d_global, p, hole_free)
        if len(uv):
            uv = uv + [xs.start, ys.start]
            uvs.append(uv)
            confs.append(conf)
        if key is not None and memo is not None:
            memo[key] = uv, conf
    if not uvs:
        return empty
    uv, conf = np.concatenate(uvs), np.concatenate(confs)
    if len(uvs) > 1:  # regions may overlap: a dot must not be reported twice
        uv, conf = merge_close(uv, conf, p.merge_distance * (d_global or 4.0))
    return uv, conf


def _roi_dots(grey: np.ndarray, mask: np.ndarray, ys: slice, xs: slice, d_global: float | None,
              p: BlobParams, hole_free: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """:func:`find_dots`' search of one region of interest (``ys``, ``xs``): uv in the region's px."""
    H, W = grey.shape
    filled = mask[ys, xs].copy() if hole_free else fill_holes(mask[ys, xs])
    d = d_global or estimate_dot_diameter(filled, p.dot_to_width)
    if d is None or np.count_nonzero(filled) < 0.5 * math.pi * d * d / 4:
        return np.zeros((0, 2)), np.zeros(0)
    region = cv2.dilate(filled.view(np.uint8), _disc(2 * p.margin * d + 1)).view(bool)

    def touches_border(y, x, bh, bw):  # numbers or arrays
        return (ys.start + y <= 0) | (xs.start + x <= 0) | (ys.start + y + bh >= H) | (xs.start + x + bw >= W)

    return _region_dots(grey[ys, xs], filled, region, d, p, touches_border, size_from_blobs=d_global is None)
