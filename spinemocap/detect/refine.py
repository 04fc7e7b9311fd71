"""Full-resolution clean-up of the network's tape mask inside one stage-2 box.

The network sees each box at <= 256 px, so its outline, upsampled to full resolution, runs
~1-2 px outside the tape's edge, and it can stop short of the tape where the tape bends or lies
in shadow, or answer weakly along body silhouettes. Each step below tests what tape *is* (dark,
perforated by dots at the tape's own density, no wider than the tape) on the full-resolution
pixels of the box:

1. :func:`keep_dotted`: mask components that carry no dot are dropped;
2. :func:`extend_along_tape`: dark regions touching the mask join it when they look like more
   of the same tape (dots not yet found, at the tape's density, mostly dark, no wider than it);
   dark: nearer the tape's own level than the skin's (:attr:`RefineParams.extend_dark_share`).
   Skin-coloured occluders (balls, arms) are not dark, and dark background or shaded skin has
   no dots at the tape's density, so neither joins;
3. :func:`snap_to_edges`: pixels within a few px of the outline are re-decided by a local
   threshold midway between the tape's level and the skin's level just outside it.

The tests assume a tape darker than the skin around it (the paper's black tape); where the tape
is not clearly darker (a light tape, fine-tuned weights for another tape), every step leaves the
network's mask as it is.

All functions take the box crop (BGR or grey uint8, (h, w[, 3])) and a bool mask of the same
size, and return a bool mask; px are full-resolution image pixels.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import NamedTuple, overload

import cv2
import numpy as np

from ..capture import to_grey
from .blobs import (
    DEFAULT_DOT_TO_WIDTH,
    BlobParams,
    _nonzero,
    fill_holes,
    find_dots,
    histogram_median,
    labelled_components,
    mask_box,
    mask_box_within,
    median,
    percentile,
)


@dataclass
class RefineParams:
    """Tuning of the mask clean-up (sizes in full-resolution px unless stated)."""

    band_px: int = 3                # snap: outline pixels re-decided within this distance
    level_sigma_px: float = 12.0    # snap: smoothing of the local tape / skin levels
    min_new_dots: int = 2           # extend: a region must show at least this many new dots
    min_density_ratio: float = 0.4  # extend: its dots per px >= this x the tape's
    min_dark_share: float = 0.6     # extend: share of its pixels darker than the threshold
    max_width_ratio: float = 1.3    # extend: its width <= this x the tape's width
    max_area_per_dot: float = 3.0   # extend: its area <= this x (new dots + 1) x tape area per dot
    extend_dark_share: float = 0.3  # extend: dark = below the tape's level + this x (skin's level - tape's)
    min_contrast: float = 20.0      # grey levels the tape must be darker than the skin, else no change


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _grow(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.dilate(mask.view(np.uint8), _disc(radius)).view(bool)


def _shrink(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.erode(mask.view(np.uint8), _disc(radius)).view(bool)


@functools.lru_cache(maxsize=16)
def _disc_sum(radius: int, first: int) -> bool:
    """Is the disc of ``radius`` the disc of ``first`` grown by the disc of ``radius - first``,
    with every offset reached through a point between 0 and it (so that the two dilations in turn
    give the one dilation also at an image's border)? True for 10 = 3 + 7 (the levels' ring)."""
    outer, a, b = ({(int(y) - r, int(x) - r) for y, x in zip(*np.nonzero(_disc(r)))} for r in (radius, first, radius - first))
    def between(u, v):
        return all(min(0, vi) <= ui <= max(0, vi) for ui, vi in zip(u, v))
    sums = {(u[0] + v[0], u[1] + v[1]) for u in a for v in b}
    return sums == outer and all(any(between(u, v) and (v[0] - u[0], v[1] - u[1]) in b for u in a) for v in outer)


@overload
def _near(mask: np.ndarray, margin: int, box: tuple[slice, slice]) -> tuple[slice, slice]: ...
@overload
def _near(mask: np.ndarray, margin: int, box: None = None) -> tuple[slice, slice] | None: ...
def _near(mask: np.ndarray, margin: int, box: tuple[slice, slice] | None = None) -> tuple[slice, slice] | None:
    """The bounding box of ``mask``'s pixels grown by ``margin`` px (clipped), None when empty.
    A dilation or erosion by a radius <= ``margin`` inside this box is the whole mask's (outside
    it both are empty), at a fraction of the cost: the stage-2 box is ~4x the tape's extent.
    ``box``: the mask's own box (margin 0) when known (it is then grown, not measured again)."""
    if box is None:
        return mask_box(mask, margin)
    h, w = mask.shape
    return (slice(max(0, box[0].start - margin), min(h, box[0].stop + margin)),
            slice(max(0, box[1].start - margin), min(w, box[1].stop + margin)))


class _Levels(NamedTuple):
    """Where the tape and the skin are sampled and their median grey levels: ``tape`` and ``ring``
    are bool masks of the crop's part ``box`` (the mask's box grown by the ring's reach; neither
    has a pixel outside it)."""

    box: tuple[slice, slice]
    tape: np.ndarray
    ring: np.ndarray
    tape_median: np.floating
    ring_median: np.floating
    grown: np.ndarray  # the mask grown by the snap's band, in ``box`` (the snap reuses it)


def _levels(grey: np.ndarray, mask: np.ndarray, band: int, min_contrast: float,
            box: tuple[slice, slice] | None = None) -> _Levels | None:
    """Pixels that sample the tape (inside the mask, away from its edge, darker than the median
    there, i.e. not a dot) and the skin (a ring just outside the mask). None when either is thin
    or the tape is not clearly darker than the skin (a light tape, a wrong mask): the steps
    that use them then leave the mask alone. ``grey`` uint8 (the medians from grey-level
    histograms: ``np.median``'s values) or float32; ``box``: the mask's box, when known."""
    near = _near(mask, 3 * band + 1, box)
    if near is None:
        return None
    m = mask[near]
    inner = _shrink(m, band + 1)
    grown = _grow(m, band)
    # the ring's outer disc as the band's disc grown by the rest (10 = 3 + 7: half the work)
    outer = _grow(grown, 2 * band + 1) if _disc_sum(3 * band + 1, band) else _grow(m, 3 * band + 1)
    ring = outer & ~_grow(m, band + 1)
    if np.count_nonzero(inner) < 20 or np.count_nonzero(ring) < 20:
        return None
    g = grey[near]
    if g.dtype == np.uint8:
        inner_hist = _histogram(g, inner)
        inner_median = histogram_median(inner_hist)
        tape = inner & (g <= inner_median)
        inner_hist[int(inner_median) + 1:] = 0  # the tape's pixels: the inner ones up to the median
        tape_median = histogram_median(inner_hist)
    else:
        tape = inner & (g <= median(g[inner]))
        tape_median = median(g[tape])
    ring_median = _median_at(g, ring)
    if ring_median - tape_median < min_contrast:
        return None
    return _Levels(near, tape, ring, tape_median, ring_median, grown)


def _median_at(g: np.ndarray, where: np.ndarray) -> np.floating:
    """The median of ``g`` at ``where`` (from a grey-level histogram when ``g`` is uint8:
    ``np.median``'s value)."""
    return histogram_median(_histogram(g, where)) if g.dtype == np.uint8 else median(g[where])


def _kept_levels(grey: np.ndarray, samples: _Levels | None, kept: np.ndarray, kept_box: tuple[slice, slice] | None,
                 p: RefineParams) -> _Levels | None:
    """``samples`` (:func:`_levels` of a mask) less those of the components the mask lost, ``kept``
    its remaining components (bool, crop-sized; ``kept_box`` their box): the tape's samples on
    ``kept``, the skin's within the ring's reach of its box, their medians again (None, as
    :func:`_levels` answers, when either is thin or the tape is not clearly darker)."""
    if samples is None or kept_box is None:
        return None
    reach = _near(kept, 3 * p.band_px + 1, kept_box)
    on_kept = kept[samples.box]
    near_kept = np.zeros_like(on_kept)
    near_kept[max(0, reach[0].start - samples.box[0].start):reach[0].stop - samples.box[0].start,
              max(0, reach[1].start - samples.box[1].start):reach[1].stop - samples.box[1].start] = True
    tape, ring = samples.tape & on_kept, samples.ring & near_kept
    if np.count_nonzero(tape) < 10 or np.count_nonzero(ring) < 20:
        return None
    g = grey[samples.box]
    tape_median, ring_median = _median_at(g, tape), _median_at(g, ring)
    if ring_median - tape_median < p.min_contrast:
        return None
    return samples._replace(tape=tape, ring=ring, tape_median=tape_median, ring_median=ring_median)


def _histogram(grey: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Counts (256,) int64 of the uint8 ``grey`` levels at ``where`` (one OpenCV call)."""
    return cv2.calcHist([grey], [0], where.view(np.uint8), [256], [0, 256]).ravel().astype(np.int64)


def dark_threshold(grey: np.ndarray, mask: np.ndarray, params: RefineParams) -> float | None:
    """Grey level midway between the tape (median of its dark pixels) and the skin around it."""
    return _midway(_levels(grey, mask, params.band_px, params.min_contrast))


def _midway(samples: _Levels | None, share: float = 0.5) -> float | None:
    """The grey level ``share`` of the way from the tape's median level to the skin's (None
    without samples)."""
    if samples is None:
        return None
    if share == 0.5:
        return 0.5 * (float(samples.tape_median) + float(samples.ring_median))
    return float(samples.tape_median) + share * (float(samples.ring_median) - float(samples.tape_median))


_REMAP_MAX_SIDE = 32766  # cv2.remap's maps are below SHRT_MAX px a side


def _band_levels(grey: np.ndarray, samples: _Levels, sigma: float, ys: np.ndarray, xs: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The local tape and skin levels (float32, (N,)) at the crop pixels (``ys``, ``xs``) (the
    snap's band): for each, the Gaussian mean (``sigma`` px) of ``grey`` weighted by its sample
    pixels, and its median where no sample is near. The means live on a 4x smaller grid (the
    levels vary slowly): the samples' grey levels are summed into its cells straight from their
    pixels (each pixel in the cell that holds its top left corner: OpenCV's ``INTER_AREA`` shrink
    to within the cells' fractional edges), the grid blurred, and read bilinearly at the band's
    pixels only (``cv2.resize``'s ``INTER_LINEAR`` coordinates) instead of enlarged to the crop.
    About a fifth of the CPU of a whole-crop shrink, blur and enlargement; the
    levels within ~1 grey level of theirs (tests/detect/test_detect_cleanup.py)."""
    h, w = grey.shape
    sw, sh = max(1, w // 4), max(1, h // 4)
    s = max(sigma / 4, 0.5)
    (y0, y1), (x0, x1) = ((part.start, part.stop) for part in samples.box)
    # the grid's cells around the samples' box only, with the blur's reach (4 s, OpenCV's float
    # kernel) of empty cells round it: the band lies in the box, nothing is sampled outside it
    reach = math.ceil(4 * s) + 1
    cy0, cy1 = max(0, y0 * sh // h - reach), min(sh, (y1 - 1) * sh // h + 1 + reach)
    cx0, cx1 = max(0, x0 * sw // w - reach), min(sw, (x1 - 1) * sw // w + 1 + reach)
    gh, gw = cy1 - cy0, cx1 - cx0
    g = grey[samples.box]
    cell_row = (np.arange(y0, y1) * sh // h - cy0) * gw  # each pixel's cell, by row and by column
    cell_column = np.arange(x0, x1) * sw // w - cx0
    grid = np.empty((gh * gw, 4), np.float64)
    for k, weight in ((0, samples.tape), (2, samples.ring)):
        py, px = _nonzero(weight)
        cell = cell_row[py] + cell_column[px]
        grid[:, k] = np.bincount(cell, weights=g[py, px], minlength=gh * gw)
        grid[:, k + 1] = np.bincount(cell, minlength=gh * gw)
    grid *= (sh * sw) / (h * w)  # the cells' area averages
    blurred = cv2.GaussianBlur(grid.astype(np.float32).reshape(gh, gw, 4), (0, 0), s)
    num, den = blurred[..., 0::2], blurred[..., 1::2]
    fallback = np.array([samples.tape_median, samples.ring_median], np.float32)
    mean = np.where(den > 1e-3, num / np.maximum(den, 1e-6), fallback).astype(np.float32)
    # cv2.resize's INTER_LINEAR source coordinates (clamped at the whole grid's edges)
    map_x = (np.clip((xs + 0.5) * (sw / w) - 0.5, 0, sw - 1) - cx0).astype(np.float32)
    map_y = (np.clip((ys + 0.5) * (sh / h) - 0.5, 0, sh - 1) - cy0).astype(np.float32)
    # OpenCV's remap takes maps below 32767 px a side: the band's pixels as rows of at most that
    # (each output pixel is read on its own, so the rows give the same values as one long row)
    n = len(map_x)
    if n == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32)
    width = min(n, _REMAP_MAX_SIDE)
    rows = -(-n // width)
    map_x, map_y = (np.pad(m, (0, rows * width - n)).reshape(rows, width) for m in (map_x, map_y))
    at = cv2.remap(np.ascontiguousarray(mean), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    at = at.reshape(-1, 2)[:n]
    return at[:, 0], at[:, 1]


def snap_to_edges(crop: np.ndarray, mask: np.ndarray, params: RefineParams | None = None) -> np.ndarray:
    """``mask`` with its outline moved onto the tape's edge (pixels within ``band_px`` of it are
    tape when darker than midway between the local tape and skin levels)."""
    p = params or RefineParams()
    if not mask.any():
        return mask
    grey = to_grey(crop)
    return _snap(grey, mask, p, _levels(grey, mask, p.band_px, p.min_contrast))


def _snap(grey: np.ndarray, mask: np.ndarray, p: RefineParams, samples: _Levels | None,
          box: tuple[slice, slice] | None = None) -> np.ndarray:
    """:func:`snap_to_edges` given ``grey`` (uint8 or float32) and the mask's :func:`_levels`."""
    if samples is None:
        return mask
    near = _near(mask, p.band_px, box)
    if near is None:  # an empty mask: nothing to snap
        return mask
    m = mask[near]
    # the mask grown by the band: the levels' (their box holds this one: a wider margin)
    oy, ox = near[0].start - samples.box[0].start, near[1].start - samples.box[1].start
    grown = samples.grown[oy:oy + m.shape[0], ox:ox + m.shape[1]]
    band = grown & ~_shrink(m, p.band_px)
    inside = m & ~band
    # the band's pixels re-decided (a thin outline: the levels are measured there only)
    ys, xs = _nonzero(band)
    if len(ys):
        tape_level, skin_level = _band_levels(grey, samples, p.level_sigma_px, ys + near[0].start, xs + near[1].start)
        inside[ys, xs] = grey[near][ys, xs] < 0.5 * (tape_level + skin_level)
    # the snapped mask lies in ``near`` (the mask does: it is empty outside): its holes filled in
    # ``near`` grown by 1 px (a zero frame, or the crop's border), and the answer crop-sized
    reach = _near(mask, p.band_px + 1, box)
    assert reach is not None  # near is
    snapped = np.zeros((reach[0].stop - reach[0].start, reach[1].stop - reach[1].start), bool)
    snapped[near[0].start - reach[0].start:near[0].stop - reach[0].start,
            near[1].start - reach[1].start:near[1].stop - reach[1].start] = inside
    out = np.zeros(mask.shape, bool)
    out[reach] = fill_holes(snapped, (slice(0, snapped.shape[0]), slice(0, snapped.shape[1])))
    return out


def components_touching(mask: np.ndarray, reference: np.ndarray, within: tuple[slice, slice] | None = None) -> np.ndarray:
    """The components of ``mask`` (8-connected) that overlap ``reference`` (both bool, same shape).
    ``within``: a box known to hold every pixel of ``mask`` (its box is measured there)."""
    box = mask_box_within(mask, within)
    out = np.zeros(mask.shape, bool)
    if box is not None:  # components of the mask's box: the whole mask's
        n, labels = cv2.connectedComponents(mask[box].astype(np.uint8), connectivity=8)
        out[box] = _labelled(labels, n, labels[reference[box] & mask[box]])
    return out


def _labelled(labels: np.ndarray, n: int, chosen: np.ndarray) -> np.ndarray:
    """Where ``labels`` (n labels, 0 the background) is one of ``chosen``: a lookup table, not
    ``np.isin`` (a pass per label)."""
    table = np.zeros(max(n, 256), bool)
    table[chosen] = True
    table[0] = False
    if table[1:n].all():
        return labels > 0
    if n <= 256:  # OpenCV's table lookup on bytes: several times faster than indexing by int32 labels
        return cv2.LUT(labels.astype(np.uint8), table[:256].view(np.uint8)).view(bool)
    return table[labels]


def keep_dotted(mask: np.ndarray, dots_uv: np.ndarray, box: tuple[slice, slice] | None = None) -> np.ndarray:
    """The components of ``mask`` that contain at least one of ``dots_uv`` ((N, 2) px, x y)."""
    ij = np.clip(np.round(dots_uv).astype(int), 0, [mask.shape[1] - 1, mask.shape[0] - 1]).reshape(-1, 2)
    box = _near(mask, 0, box)
    out = np.zeros(mask.shape, bool)
    if box is None:
        return out
    # components labelled in the mask's box (the whole mask's); a dot outside it is on none
    n, labels = cv2.connectedComponents(mask[box].astype(np.uint8), connectivity=8)
    y, x = ij[:, 1] - box[0].start, ij[:, 0] - box[1].start
    inside = (y >= 0) & (y < labels.shape[0]) & (x >= 0) & (x < labels.shape[1])
    out[box] = _labelled(labels, n, labels[y[inside], x[inside]])
    return out


class Extended(NamedTuple):
    """:func:`extend_along_tape`'s answer: the mask and the dots it found on the way (the one blob
    pass over the box that the detector reuses): ``uv`` (N, 2) px (x, y) in the crop, ``confidence`` (N,)."""

    mask: np.ndarray
    uv: np.ndarray
    confidence: np.ndarray
    snapped: np.ndarray  # ``snap_to_edges`` of ``mask``: the dots were found on it


def extend_along_tape(crop: np.ndarray, mask: np.ndarray, params: RefineParams | None = None,
                      blob_params: BlobParams | None = None) -> Extended:
    """``mask`` (hole-filled), less its dot-less components, plus the dark regions touching it that
    look like more of the same tape (see the module docstring), with the dots of the result (those
    on the kept mask and the new ones of each region that joined it; ``blob_params`` for
    :func:`find_dots`). The mask is unchanged when it shows fewer than two dots (nothing to
    measure the tape by)."""
    p = params or RefineParams()
    grey = to_grey(crop)  # uint8, once: the snapping, the dots and the extension all read it
    # the mask's box, measured once: filling holes keeps it (a hole lies inside its outline)
    base_box = _near(mask, 0)
    base = fill_holes(mask, None if base_box is None else _near(mask, 1, base_box))
    memo: dict = {}  # find_dots' regions already searched on ``grey`` (a region whose mask is unchanged)

    def snapped_with_levels(m: np.ndarray, box: tuple[slice, slice] | None
                            ) -> tuple[np.ndarray, _Levels | None, tuple[slice, slice] | None]:
        # the tape and skin levels of ``m`` (its box ``box``): for the snap, and (of the kept mask)
        # the extension's threshold; and a box holding the snapped mask (the snap's reach)
        if box is None:
            return m, None, None
        samples = _levels(grey, m, p.band_px, p.min_contrast, box)
        return _snap(grey, m, p, samples, box), samples, _near(m, p.band_px + 1, box)

    # The dots are found on the mask snapped onto the tape's edge, as the final mask will be:
    # their contrast and centres are measured on the tape's own pixels. The snapped mask has no
    # holes (fill_holes' answer, or the filled mask itself, or some of its components).
    snapped, samples, snapped_within = snapped_with_levels(base, base_box)
    dots, conf = find_dots(grey, snapped, None, blob_params, memo, hole_free=True, within=snapped_within)
    base_area = int(np.count_nonzero(base[base_box])) if base_box is not None else 0  # base lies in its box
    if base_area < 50 or len(dots) < 2:
        return Extended(base, dots, conf, snapped)
    dotted = keep_dotted(base, dots, base_box)
    answer = dots, conf
    assert base_box is not None  # base has pixels
    if np.count_nonzero(dotted[base_box]) < base_area:  # some of base's components
        # components without dots dropped: their snapped outlines go, the dots stay (they had none)
        # and the tape and skin levels are those of the kept components' samples
        # (not snapped, levelled and searched again; the local levels are 12 px means)
        base = dotted
        base_box = mask_box_within(base, base_box)  # some of the components: in their box
        base_area = int(np.count_nonzero(base[base_box])) if base_box is not None else 0
        snapped = components_touching(snapped, base, snapped_within)
        samples = _kept_levels(grey, samples, base, base_box, p)
    # The tape's continuation is as dark as the tape: a threshold midway to the skin would also
    # take a mid-grey backdrop beside the tape's end (where the tape runs over the body's outline),
    # and the piece joined with it is then far wider than the tape.
    threshold = _midway(samples, p.extend_dark_share)
    if threshold is None:
        return Extended(base, *answer, snapped)
    # The tape's width from the distances to its edge, in the mask's box and a 2 px frame: the
    # 5 x 5 chamfer's steps reach 2 px, so every pixel's nearest background lies in there.
    near = _near(base, 2, base_box)
    inside = base[near]
    dist = cv2.distanceTransform(inside.view(np.uint8), cv2.DIST_L2, 5)
    width = 2.0 * percentile(dist[inside], 98)  # as estimate_dot_diameter measures it (dist > 0 is base)
    d = max(width * DEFAULT_DOT_TO_WIDTH, 2.0)
    area_per_dot = base_area / len(dots)
    # Candidate regions: dark pixels outside the mask that touch it, with what they enclose
    # (all of them within the box of the mask and the pieces, grown by 1 px: their holes too).
    assert base_box is not None  # base keeps the dotted components
    box, joined = _joined_dark_pieces(grey, base, base_box, threshold)
    oy, ox = box[0].start, box[1].start
    candidates = fill_holes(joined) & ~base[box]
    out, grew = base.copy(), False
    for x, y, w, h, region in _large_components(candidates, 0.5 * area_per_dot):
        x, y = x + ox, y + oy
        at = (slice(y, y + h), slice(x, x + w))
        if _looks_like_tape(grey[at], region, _darker(grey[at], threshold), dots - [x, y], d, width, area_per_dot, p,
                            blob_params):
            out[at] |= region
            grew = True
    if not grew:
        return Extended(base, *answer, snapped)
    # The tape grew (rare): its dots on the joined mask, where a dot straddling a join counts.
    snapped, _, snapped_within = snapped_with_levels(out, mask_box_within(out, box))  # ``out`` lies in ``box``
    return Extended(out, *find_dots(grey, snapped, None, blob_params, memo, within=snapped_within), snapped)


def _large_components(mask: np.ndarray, min_area: float):
    """(x, y, w, h, bool mask of the box) of each 8-connected component of ``mask`` with at least
    ``min_area`` pixels, in label order. Labels and areas (:func:`labelled_components`), then the
    boxes of the few large ones one at a time (with many large ones, OpenCV's statistics)."""
    _, labels, areas = labelled_components(mask)
    large = np.flatnonzero(areas[1:] >= min_area) + 1
    if len(large) <= 8:
        for i in large:
            own = labels == i
            x, y, w, h = cv2.boundingRect(own.view(np.uint8))
            yield x, y, w, h, own[y:y + h, x:x + w]
        return
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=8)
    for i in np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_area) + 1:
        x, y, w, h, _ = (int(v) for v in stats[i])
        yield x, y, w, h, labels[y:y + h, x:x + w] == i


def _joined_dark_pieces(grey: np.ndarray, base: np.ndarray, base_box: tuple[slice, slice], threshold: float
                        ) -> tuple[tuple[slice, slice], np.ndarray]:
    """``base`` (bool, crop-sized, non-empty; ``base_box`` its box) joined with the pieces of the
    dark pixels outside it (:func:`_darker` than ``threshold``, 8-connected components) that touch
    it (a pixel of ``base``'s 4-neighbourhood): the box of the joined mask grown by 1 px (clipped)
    and the joined mask in it. On uint8 grey levels by flood fills from the touching dark pixels
    (OpenCV's fixed range: the dark levels; ``base`` in the fill's mask), one per piece, at the
    cost of the pieces; else (:func:`_joined_dark_pieces_labelled`, the reference)
    from the labelled dark pixels of the whole crop."""
    if grey.dtype != np.uint8:
        return _joined_dark_pieces_labelled(grey, base, threshold)
    ceiling = min(math.ceil(float(np.float32(threshold))), 256)  # dark: levels 0 .. ceiling - 1 (see _darker)
    rim = _near(base, 1, base_box)
    ys, xs = _nonzero(_grow(base[rim], 1) & ~base[rim] & _darker(grey[rim], threshold))
    y0, x0, y1, x1 = base_box[0].start, base_box[1].start, base_box[0].stop, base_box[1].stop
    fills = None
    if len(ys):
        h, w = base.shape
        fills = np.zeros((h + 2, w + 2), np.uint8)  # the fill's mask: 1 px larger all round
        fills[1:-1, 1:-1] = base.view(np.uint8)  # base is never filled
        g = grey if grey.flags.writeable else grey.copy()  # OpenCV takes the image as an output (not written)
        flags = 8 | cv2.FLOODFILL_FIXED_RANGE | cv2.FLOODFILL_MASK_ONLY | (2 << 8)  # a filled pixel: 2
        for y, x in zip((ys + rim[0].start).tolist(), (xs + rim[1].start).tolist()):
            if fills[y + 1, x + 1]:
                continue  # base (never) or a piece filled from another seed
            level = int(g[y, x])
            _, _, _, (fx, fy, fw, fh) = cv2.floodFill(g, fills, (x, y), 0, level, ceiling - 1 - level, flags)
            y0, x0, y1, x1 = min(y0, fy), min(x0, fx), max(y1, fy + fh), max(x1, fx + fw)
    h, w = base.shape
    box = (slice(max(0, y0 - 1), min(h, y1 + 1)), slice(max(0, x0 - 1), min(w, x1 + 1)))
    if fills is None:
        return box, base[box].copy()
    return box, fills[box[0].start + 1:box[0].stop + 1, box[1].start + 1:box[1].stop + 1] != 0


def _joined_dark_pieces_labelled(grey: np.ndarray, base: np.ndarray, threshold: float
                                 ) -> tuple[tuple[slice, slice], np.ndarray]:
    """:func:`_joined_dark_pieces` from the labelled dark pixels of the whole crop (the reference)."""
    n, labels = cv2.connectedComponents((_darker(grey, threshold) & ~base).view(np.uint8), connectivity=8)
    rim = _near(base, 1)
    if rim is None:
        raise ValueError("an empty mask has no pieces to join")
    pieces = _labelled(labels, n, labels[rim][_grow(base[rim], 1) & ~base[rim]])
    joined = base | pieces
    box = _near(joined, 1)
    assert box is not None  # base is not empty
    return box, joined[box]


def _darker(grey: np.ndarray, threshold: float) -> np.ndarray:
    """``grey < np.float32(threshold)`` (the float32 comparison), as one uint8 comparison when
    ``grey`` is uint8 (its levels are integers: below the threshold is below its ceiling)."""
    t = np.float32(threshold)
    if grey.dtype != np.uint8:
        return grey < t
    ceiling = math.ceil(float(t))
    if ceiling > 255:
        return np.ones(grey.shape, bool)
    if ceiling <= 0:
        return np.zeros(grey.shape, bool)
    return grey < np.uint8(ceiling)


def _looks_like_tape(crop: np.ndarray, region: np.ndarray, dark: np.ndarray, known_dots: np.ndarray, d: float,
                     width: float, area_per_dot: float, p: RefineParams, blob_params: BlobParams | None = None) -> bool:
    """Does ``region`` (bool, crop-sized) look like more of the tape? ``known_dots``: dots already
    found on the tape, in this crop's px; ``d``, ``width``, ``area_per_dot``: the tape's dot
    diameter, width and area per dot, px."""
    area = float(region.sum())
    if (dark & region).sum() < p.min_dark_share * area:
        return False
    if 2.0 * cv2.distanceTransform(region.view(np.uint8), cv2.DIST_L2, 5).max() > p.max_width_ratio * width:
        return False
    # every dot-like blob counts: the region is cut at its outline, so the dots straddling its join
    # with the tape are cut pieces that the neighbours' test would refuse (the joined mask's dots
    # are found again with it)
    new, _ = find_dots(crop, region, None, replace(blob_params or BlobParams(), min_major_to_neighbours=0.0,
                                                   sliver_max_axis_ratio=0.0))
    if len(new) and len(known_dots):  # dots on the known tape's edge are found again: skip them
        new = new[np.linalg.norm(new[:, None] - known_dots[None], axis=2).min(axis=1) > 0.5 * d]
    return (len(new) >= p.min_new_dots and len(new) / area >= p.min_density_ratio / area_per_dot
            and area <= p.max_area_per_dot * (len(new) + 1) * area_per_dot)
