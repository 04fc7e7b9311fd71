"""Full-resolution clean-up of the network's tape mask inside one stage-2 box.

The network sees each box at <= 256 px, so its outline, upsampled to full resolution, runs
~1-2 px outside the tape's edge, and it can stop short of the tape where the tape bends or lies
in shadow, or answer weakly along body silhouettes. Each step below tests what tape *is* (dark,
perforated by dots at the tape's own density, no wider than the tape) on the full-resolution
pixels of the box:

1. :func:`keep_dotted`: mask components that carry no dot are dropped;
2. :func:`extend_along_tape`: dark regions touching the mask join it when they look like more
   of the same tape (dots not yet found, at the tape's density, mostly dark, no wider than it).
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

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from ..capture import to_grey
from .blobs import DEFAULT_DOT_TO_WIDTH, BlobParams, fill_holes, find_dots, median, percentile


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
    min_contrast: float = 20.0      # grey levels the tape must be darker than the skin, else no change


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def _grow(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.dilate(mask.view(np.uint8), _disc(radius)).view(bool)


def _shrink(mask: np.ndarray, radius: int) -> np.ndarray:
    return cv2.erode(mask.view(np.uint8), _disc(radius)).view(bool)


def _near(mask: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """The bounding box of ``mask``'s pixels grown by ``margin`` px (clipped), None when empty.
    A dilation or erosion by a radius <= ``margin`` inside this box is the whole mask's (outside
    it both are empty), at a fraction of the cost: the stage-2 box is ~4x the tape's extent."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return None
    h, w = mask.shape
    return (slice(max(0, int(rows[0]) - margin), min(h, int(rows[-1]) + 1 + margin)),
            slice(max(0, int(cols[0]) - margin), min(w, int(cols[-1]) + 1 + margin)))


class _Levels(NamedTuple):
    """Where the tape and the skin are sampled (bool masks of the crop) and their median grey levels."""

    tape: np.ndarray
    ring: np.ndarray
    tape_median: np.floating
    ring_median: np.floating


def _levels(grey: np.ndarray, mask: np.ndarray, band: int, min_contrast: float) -> _Levels | None:
    """Pixels that sample the tape (inside the mask, away from its edge, darker than the median
    there, i.e. not a dot) and the skin (a ring just outside the mask). None when either is thin
    or the tape is not clearly darker than the skin (a light tape, a wrong mask): the steps
    that use them then leave the mask alone. ``grey`` float32."""
    near = _near(mask, 3 * band + 1)
    if near is None:
        return None
    m = mask[near]
    inner_near = _shrink(m, band + 1)
    ring_near = _grow(m, 3 * band + 1) & ~_grow(m, band + 1)
    if np.count_nonzero(inner_near) < 20 or np.count_nonzero(ring_near) < 20:
        return None
    g = grey[near]
    inner_grey = g[inner_near]
    tape_near = inner_near & (g <= median(inner_grey))
    tape_median, ring_median = median(g[tape_near]), median(g[ring_near])
    if ring_median - tape_median < min_contrast:
        return None
    tape, ring = np.zeros(mask.shape, bool), np.zeros(mask.shape, bool)
    tape[near], ring[near] = tape_near, ring_near
    return _Levels(tape, ring, tape_median, ring_median)


def dark_threshold(grey: np.ndarray, mask: np.ndarray, params: RefineParams) -> float | None:
    """Grey level midway between the tape (median of its dark pixels) and the skin around it."""
    return _midway(_levels(grey, mask, params.band_px, params.min_contrast))


def _midway(samples: _Levels | None) -> float | None:
    if samples is None:
        return None
    return 0.5 * (float(samples.tape_median) + float(samples.ring_median))


def _local_mean(grey: np.ndarray, weight: np.ndarray, sigma: float, fallback: float) -> np.ndarray:
    """Weighted Gaussian mean of ``grey`` over the pixels in ``weight``; computed on a 4x
    smaller grid (the levels vary slowly) and ``fallback`` where no weight is near."""
    h, w = grey.shape
    small = (max(1, w // 4), max(1, h // 4))
    g = cv2.resize(grey * weight, small, interpolation=cv2.INTER_AREA)
    wt = cv2.resize(weight, small, interpolation=cv2.INTER_AREA)
    s = max(sigma / 4, 0.5)
    num, den = cv2.GaussianBlur(g, (0, 0), s), cv2.GaussianBlur(wt, (0, 0), s)
    mean = np.where(den > 1e-3, num / np.maximum(den, 1e-6), fallback).astype(np.float32)
    return cv2.resize(mean, (w, h), interpolation=cv2.INTER_LINEAR)


def snap_to_edges(crop: np.ndarray, mask: np.ndarray, params: RefineParams | None = None) -> np.ndarray:
    """``mask`` with its outline moved onto the tape's edge (pixels within ``band_px`` of it are
    tape when darker than midway between the local tape and skin levels)."""
    p = params or RefineParams()
    if not mask.any():
        return mask
    grey = to_grey(crop).astype(np.float32)
    return _snap(grey, mask, p, _levels(grey, mask, p.band_px, p.min_contrast))


def _snap(grey: np.ndarray, mask: np.ndarray, p: RefineParams, samples: _Levels | None) -> np.ndarray:
    """:func:`snap_to_edges` given ``grey`` (float32) and the mask's :func:`_levels`."""
    if samples is None:
        return mask
    tape_level = _local_mean(grey, samples.tape.astype(np.float32), p.level_sigma_px, float(samples.tape_median))
    skin_level = _local_mean(grey, samples.ring.astype(np.float32), p.level_sigma_px, float(samples.ring_median))
    near = _near(mask, p.band_px)
    m = mask[near]
    band = _grow(m, p.band_px) & ~_shrink(m, p.band_px)
    snapped = mask.copy()
    snapped[near] = (m & ~band) | (band & (grey[near] < 0.5 * (tape_level[near] + skin_level[near])))
    return fill_holes(snapped)


def components_touching(mask: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The components of ``mask`` (8-connected) that overlap ``reference`` (both bool, same shape)."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    return _labelled(labels, n, labels[mask & reference])


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


def keep_dotted(mask: np.ndarray, dots_uv: np.ndarray) -> np.ndarray:
    """The components of ``mask`` that contain at least one of ``dots_uv`` ((N, 2) px, x y)."""
    ij = np.clip(np.round(dots_uv).astype(int), 0, [mask.shape[1] - 1, mask.shape[0] - 1]).reshape(-1, 2)
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    return _labelled(labels, n, labels[ij[:, 1], ij[:, 0]])


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
    grey_u8 = to_grey(crop)  # once: the snapping, the dots and the extension all read it
    grey = grey_u8.astype(np.float32)
    base = fill_holes(mask)

    def snapped_with_levels(m: np.ndarray) -> tuple[np.ndarray, _Levels | None]:
        # the tape and skin levels of ``m``: for the snap, and (of the kept mask) the extension's threshold
        if not m.any():
            return m, None
        samples = _levels(grey, m, p.band_px, p.min_contrast)
        return _snap(grey, m, p, samples), samples

    # The dots are found on the mask snapped onto the tape's edge, as the final mask will be:
    # their contrast and centres are measured on the tape's own pixels.
    snapped, samples = snapped_with_levels(base)
    dots, conf = find_dots(grey_u8, snapped, None, blob_params)
    base_area = int(np.count_nonzero(base))
    if base_area < 50 or len(dots) < 2:
        return Extended(base, dots, conf, snapped)
    dotted = keep_dotted(base, dots)
    answer = dots, conf
    if np.count_nonzero(dotted) < base_area:  # components without dots dropped: the edge levels change, find again
        base = dotted
        base_area = int(np.count_nonzero(base))
        snapped, samples = snapped_with_levels(base)
        answer = find_dots(grey_u8, snapped, None, blob_params)
    threshold = _midway(samples)
    if threshold is None:
        return Extended(base, *answer, snapped)
    dist = cv2.distanceTransform(base.view(np.uint8), cv2.DIST_L2, 5)
    width = 2.0 * percentile(dist[base], 98)  # as estimate_dot_diameter measures it (dist > 0 is base)
    d = max(width * DEFAULT_DOT_TO_WIDTH, 2.0)
    area_per_dot = base_area / len(dots)
    dark = grey < threshold
    # Candidate regions: dark pixels outside the mask that touch it, with what they enclose.
    n, labels = cv2.connectedComponents((dark & ~base).view(np.uint8), connectivity=8)
    pieces = _labelled(labels, n, labels[_grow(base, 1) & ~base])
    candidates = fill_holes(base | pieces) & ~base
    n, labels, stats, _ = cv2.connectedComponentsWithStats(candidates.view(np.uint8), connectivity=8)
    out = base.copy()
    for i in range(1, n):
        x, y, w, h, area = stats[i]
        if area < 0.5 * area_per_dot:
            continue
        box = (slice(y, y + h), slice(x, x + w))
        region = labels[box] == i
        if _looks_like_tape(grey_u8[box], region, dark[box], dots - [x, y], d, width, area_per_dot, p, blob_params):
            out[box] |= region
    if (out == base).all():
        return Extended(base, *answer, snapped)
    # The tape grew (rare): its dots on the joined mask, where a dot straddling a join counts.
    snapped, _ = snapped_with_levels(out)
    return Extended(out, *find_dots(grey_u8, snapped, None, blob_params), snapped)


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
    new, _ = find_dots(crop, region, None, blob_params)
    if len(new) and len(known_dots):  # dots on the known tape's edge are found again: skip them
        new = new[np.linalg.norm(new[:, None] - known_dots[None], axis=2).min(axis=1) > 0.5 * d]
    return (len(new) >= p.min_new_dots and len(new) / area >= p.min_density_ratio / area_per_dot
            and area <= p.max_area_per_dot * (len(new) + 1) * area_per_dot)
