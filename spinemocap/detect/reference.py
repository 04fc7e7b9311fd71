"""The reference object's markers in one image (``spinemocap track --refine-rig`` with a reference,
see :mod:`spinemocap.reference`).

The object stands still at a known pose and the given rig is calibrated to a few px, so each
marker is searched for only near where the given camera projects its known world position
(within ``search_px``): bright round blobs found by the tape's own dot finder
(:func:`spinemocap.detect.blobs.find_dots`: white top-hat, size and shape checks, sub-pixel
centroid) inside a disc around the prediction, the expected size from the marker's diameter at its
depth. A marker counts as found only when exactly one blob lies within ``search_px`` of its
prediction; a marker hidden (a ball, the image border) or doubled is NaN in this image.

The dot finder's centre comes from a top-hat, which measures brightness against the darkest
surround within a kernel: a marker seen with the dark bar on one side and bright skin on the
other comes out 0.2-0.8 px off. The centre is
therefore refined on the image itself (:func:`disc_centre`): each rim pixel weighs its coverage
by the disc, ``(grey - surround) / (interior - surround)`` with the surround read just outside the
disc along the same radius, so a bright background on one side does not pull the centre.
Where the surround is nearly as bright as the marker (light skin of the arm behind it: its edge
is not in the image) no estimate can find the edge: a marker whose rim lacks contrast
(:data:`MIN_RIM_CONTRAST`) over more than :data:`MAX_FAINT_RIM` of its circumference is not taken
from that image.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera
from ..capture import to_grey
from ..reference import ReferenceObject
from .blobs import BlobParams, find_dots

SEARCH_PX = 25.0  # a calibration off by ~3 px RMS still predicts the markers well inside this
MIN_RIM_CONTRAST = 40.0  # grey levels between the disc and its surround for an edge to count
MAX_FAINT_RIM = 0.1  # share of the rim allowed below that


def find_reference_markers(image: np.ndarray, camera: Camera, reference: ReferenceObject,
                           search_px: float = SEARCH_PX) -> np.ndarray:
    """(N, 2) distorted px centres of ``reference``'s markers in ``image`` (BGR or grey) as seen
    by ``camera`` (the given rig's camera: its projection of the known world positions says where
    to look); NaN for markers not found (see module)."""
    grey = to_grey(image)
    world = reference.world_mm
    out = np.full((len(world), 2), np.nan)
    depth = camera.depth(world)
    predicted = camera.project(world)
    focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    h, w = grey.shape
    for k in range(len(world)):
        if not depth[k] > reference.marker_diameter_mm or not np.isfinite(predicted[k]).all():
            continue
        u, v = predicted[k]
        if not (-search_px <= u < w + search_px and -search_px <= v < h + search_px):
            continue
        diameter = focal * reference.marker_diameter_mm / depth[k]
        mask = np.zeros((h, w), np.uint8)
        cv2.circle(mask, (int(round(u)), int(round(v))), int(np.ceil(search_px + diameter)), 1, thickness=-1)
        uv, _ = find_dots(grey, mask.astype(bool), expected_dot_px=diameter, params=BlobParams())
        near = uv[np.linalg.norm(uv - predicted[k], axis=1) <= search_px] if len(uv) else uv
        if len(near) == 1:
            out[k] = disc_centre(grey, near[0], diameter / 2)
    return out


def faint_rim_share(grey: np.ndarray, centre: np.ndarray, radius_px: float, samples: int = 64) -> float:
    """Share of a disc's circumference (at ``centre``, ``radius_px``) where the disc stands less than
    :data:`MIN_RIM_CONTRAST` above its surround (inside at 0.6 r, outside at r + 2 px; bilinear)."""
    angles = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    inside = (centre + 0.6 * radius_px * ring).astype(np.float32)
    outside = (centre + (radius_px + 2.0) * ring).astype(np.float32)
    image = grey.astype(np.float32)
    level_in = cv2.remap(image, inside[:, 0:1], inside[:, 1:2], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    level_out = cv2.remap(image, outside[:, 0:1], outside[:, 1:2], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return float(np.mean((level_in - level_out).ravel() < MIN_RIM_CONTRAST))


def disc_centre(grey: np.ndarray, start: np.ndarray, radius_px: float, rounds: int = 3) -> np.ndarray:
    """Sub-pixel centre (x, y) px of a uniform bright disc of about ``radius_px`` near ``start``
    (see module): coverage-weighted centroid, the surround of each rim pixel sampled 2 px outside
    the disc along its radius, ``rounds`` times from the updated centre. ``start`` unchanged when
    the disc does not stand out (interior not 15 grey levels above the surround) or touches the
    image border; NaN when its edge is not in the image over more than :data:`MAX_FAINT_RIM` of
    its rim (see module)."""
    h, w = grey.shape
    centre = np.asarray(start, float).copy()
    reach = radius_px + 2.0
    for _ in range(rounds):
        x0, y0 = int(np.floor(centre[0] - reach - 4)), int(np.floor(centre[1] - reach - 4))
        x1, y1 = int(np.ceil(centre[0] + reach + 4)) + 1, int(np.ceil(centre[1] + reach + 4)) + 1
        if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
            return np.asarray(start, float)
        patch = grey[y0:y1, x0:x1].astype(np.float32)
        ys, xs = np.mgrid[y0:y1, x0:x1]
        dx, dy = xs - centre[0], ys - centre[1]
        dist = np.hypot(dx, dy)
        interior = float(np.median(patch[dist <= max(radius_px - 1.5, 0.5 * radius_px)]))
        rim = dist <= reach
        # the surround of each pixel: 2 px outside the disc along the pixel's radius (bilinear)
        scale = (radius_px + 2.0) / np.maximum(dist, 1e-6)
        sx = (centre[0] + dx * scale - x0).astype(np.float32)
        sy = (centre[1] + dy * scale - y0).astype(np.float32)
        surround = cv2.remap(patch, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        contrast = interior - surround
        if np.median(contrast[rim & (dist > radius_px - 1.0)]) < 15.0:
            return np.asarray(start, float)
        coverage = np.clip((patch - surround) / np.maximum(contrast, 15.0), 0.0, 1.0)
        coverage[dist <= radius_px - 1.5] = 1.0
        weights = np.where(rim, coverage, 0.0)
        total = float(weights.sum())
        if total <= 0:
            return np.asarray(start, float)
        centre = np.array([(weights * xs).sum() / total, (weights * ys).sum() / total])
    if faint_rim_share(grey, centre, radius_px) > MAX_FAINT_RIM:
        return np.full(2, np.nan)
    return centre
