"""Per-camera image evidence for MRF2 (paper Eq. 10): a cost image I_c sampled at projections.

Inside the tape mask the cost is the inverted, normalised grey image (bright skin dots -> low
cost, dark tape -> high), outside it grows with the distance to the mask (distance transform),
so a point drifting off the tape is pulled back. Beyond the paper, the grey image is blurred
with a Gaussian of about the dot's radius first: a dot's flat bright disc then becomes a peaked
bowl whose minimum is the dot's centre, which is what lets MRF2 place dots to sub-pixel accuracy.
``downscale`` < 1 builds the cost at a lower resolution (faster, coarser).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from ..capture import to_grey


@dataclass
class EvidenceImage:
    """Cost image ``cost`` (h, w) float32 covering a window of the camera image: cost pixel
    (i, j) is full-resolution pixel ``(origin[0] + j / scale, origin[1] + i / scale)``. Points
    outside the window read ``outside_cost`` (at least the window's largest cost)."""

    cost: np.ndarray
    scale: float
    outside_cost: float
    origin: tuple[float, float] = (0.0, 0.0)

    @property
    def shape(self) -> tuple[int, int]:
        return self.cost.shape

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear cost at (N, 2) full-resolution pixel coordinates."""
        uv = torch.from_numpy(np.asarray(uv, dtype=np.float64).reshape(1, -1, 2))
        with torch.no_grad():
            return EvidenceStack([self]).sample_torch(uv)[0].numpy()


class EvidenceStack:
    """All cameras' cost images on one canvas (C, 1, H, W) for batched, differentiable bilinear
    sampling with ``grid_sample`` (one call for all cameras; far cheaper than per-camera indexing).
    Each image sits at offset (1, 1) in a canvas filled with its ``outside_cost``; cameras without
    evidence (None) read 0 everywhere."""

    def __init__(self, evidence: list[EvidenceImage | None]):
        present = [e for e in evidence if e is not None]
        h = max((e.shape[0] for e in present), default=1) + 2
        w = max((e.shape[1] for e in present), default=1) + 2
        # float32 where the cost images and outside costs are (build_evidence's: each outside cost is
        # a cost image's maximum): the samples promote each corner exactly to float64, so the same
        # values from half the memory
        single = all(e.cost.dtype == np.float32 and float(np.float32(e.outside_cost)) == e.outside_cost for e in present)
        canvas = np.zeros((len(evidence), 1, h, w), dtype=np.float32 if single else np.float64)
        scale, origin = np.ones(len(evidence)), np.zeros((len(evidence), 2))
        for c, e in enumerate(evidence):
            if e is None:
                continue
            canvas[c, 0] = e.outside_cost
            canvas[c, 0, 1 : 1 + e.shape[0], 1 : 1 + e.shape[1]] = e.cost
            scale[c], origin[c] = e.scale, e.origin
        self.shape = (h, w)
        self._flat = torch.from_numpy(canvas.reshape(-1))
        self._base = torch.arange(len(evidence))[:, None] * (h * w)
        self._scale = torch.from_numpy(scale)[:, None]
        self._origin = torch.from_numpy(origin)[:, None, :]

    def sample_torch(self, uv: torch.Tensor) -> torch.Tensor:
        """uv (C, N, 2) full-resolution pixels, camera c in row c -> (C, N) bilinear costs,
        differentiable in uv; points off the canvas read the border (the outside cost)."""
        return self.sample_uv(uv[..., 0], uv[..., 1])

    def sample_uv(self, u: torch.Tensor, v: torch.Tensor, cams: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`sample_torch` of the pixel columns ``u`` and rows ``v`` (C, N) each; ``cams``
        (C_all,) bool: ``u`` and ``v`` hold those cameras' rows only."""
        h, w = self.shape
        origin, scale, base = (self._origin, self._scale, self._base) if cams is None else \
            (self._origin[cams], self._scale[cams], self._base[cams])
        x = torch.nan_to_num(((u - origin[..., 0]) * scale + 1.0), nan=-1.0).clamp(0, w - 1)
        y = torch.nan_to_num(((v - origin[..., 1]) * scale + 1.0), nan=-1.0).clamp(0, h - 1)
        x0 = x.detach().floor().clamp(max=w - 2)
        y0 = y.detach().floor().clamp(max=h - 2)
        fx, fy = x - x0, y - y0
        idx = base + y0.long() * w + x0.long()
        flat = self._flat
        gx = 1 - fx
        top = flat[idx] * gx + flat[idx + 1] * fx
        bottom = flat[idx + w] * gx + flat[idx + w + 1] * fx
        return top * (1 - fy) + bottom * fy


def estimate_dot_radius_px(mask: np.ndarray, dot_to_width: float = 0.2) -> float:
    """Dot radius (px) guessed from the tape mask: its half-width is about the 95th percentile of
    the inside distance transform; ``dot_to_width`` = dot diameter / tape width (10/50 default)."""
    inside = np.ascontiguousarray(mask, dtype=np.uint8)
    if not inside.any():
        return 3.0
    dist = cv2.distanceTransform(inside, cv2.DIST_L2, 5)
    half_width = float(np.percentile(dist[inside > 0], 95))
    return max(1.0, dot_to_width * half_width)


def build_evidence(
    image: np.ndarray,
    mask: np.ndarray | None,
    downscale: float = 1.0,
    blur_sigma_px: float | None = None,
    outside_slope: float = 0.05,
    dot_to_width: float = 0.2,
    crop_margin_px: float | None = 64.0,
) -> EvidenceImage:
    """Cost image of one camera view.

    ``image``: grey (H, W) or BGR (H, W, 3) uint8/float; ``mask``: (H, W) bool tape mask or None
    (whole image counts as tape). Inside the mask the cost is ``1 - normalised brightness`` in
    [0, 1] (1st/99.5th brightness percentiles inside the mask, after the blur, map to 1/0); outside it is
    ``1 + outside_slope * distance_px``. ``blur_sigma_px`` (full-resolution px) defaults to 0.6 of
    the dot radius estimated from the mask width. With ``crop_margin_px`` the cost is built only
    in the mask's bounding box grown by that margin (the rest reads the outside cost): the tape
    fills a small part of a frame, so this saves most of the work; None keeps the whole image."""
    # a colour image is converted to grey after the crop, in the window only (the conversion is per
    # pixel: the same grey values as the window of the whole frame's grey image)
    grey = np.asarray(image)
    h, w = grey.shape[:2]
    tape = np.ones((h, w), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if tape.shape != (h, w):
        raise ValueError(f"mask shape {tape.shape} differs from image shape {(h, w)}")
    origin = (0.0, 0.0)
    if crop_margin_px is not None and mask is not None and not tape.any():
        # no tape in view: the cost is the same everywhere (the outside cost), so one pixel holds
        # it (building it over the whole frame cost more than all the cameras that see the tape)
        grey, tape = grey[:1, :1], tape[:1, :1]
    elif crop_margin_px is not None and mask is not None:
        rows = np.flatnonzero(tape.any(axis=1))
        cols = np.flatnonzero(tape[rows[0] : rows[-1] + 1].any(axis=0))  # the tape's columns lie in its rows
        m = int(np.ceil(crop_margin_px))
        y0, y1 = max(rows[0] - m, 0), min(rows[-1] + m + 1, h)
        x0, x1 = max(cols[0] - m, 0), min(cols[-1] + m + 1, w)
        grey, tape = grey[y0:y1, x0:x1], tape[y0:y1, x0:x1]
        origin = (float(x0), float(y0))
    if grey.ndim == 3:
        grey = to_grey(np.ascontiguousarray(grey))
    h, w = grey.shape
    grey = grey.astype(np.float32)  # after the crop: converting the whole frame cost more than the rest
    tape = np.ascontiguousarray(tape)
    if blur_sigma_px is None:
        # the mask as 0/1 bytes without a copy: what estimate_dot_radius_px makes of it
        blur_sigma_px = 0.6 * estimate_dot_radius_px(tape.view(np.uint8), dot_to_width) if mask is not None else 1.5
    if downscale != 1.0:
        size = (max(1, int(round(w * downscale))), max(1, int(round(h * downscale))))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        tape = cv2.resize(tape.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    sigma = blur_sigma_px * downscale
    any_tape = bool(tape.any())
    off = np.logical_not(tape)
    if sigma > 0.3 and any_tape:
        # off-tape pixels take the tape's dark level first, so bright skin beside the tape does not
        # bleed into the blurred tape border and pose as a dot (grey is this function's own copy)
        dark = np.float32(np.percentile(grey[tape], 1))
        np.copyto(grey, dark, where=off)
        grey = cv2.GaussianBlur(grey, (0, 0), sigma)
    elif sigma > 0.3:
        grey = cv2.GaussianBlur(grey, (0, 0), sigma)
    if any_tape:
        lo, hi = np.percentile(grey[tape], [1, 99.5])
    else:
        lo, hi = float(grey.min()), float(grey.max())
    # 1 - clip((grey - lo) / max(hi - lo, 1e-6), 0, 1) in place, in the type numpy gives grey - lo
    # (float64 from the percentiles, float32 from the Python floats of an image without tape)
    cost = np.subtract(grey, lo, dtype=np.result_type(grey, lo))
    cost /= max(hi - lo, 1e-6)
    np.clip(cost, 0.0, 1.0, out=cost)
    np.subtract(1.0, cost, out=cost)
    if not tape.all():
        outside = cv2.distanceTransform(off.view(np.uint8), cv2.DIST_L2, 5)
        if downscale != 1.0:  # x / 1.0 is x
            outside /= downscale
        outside *= outside_slope  # 1 + outside_slope * outside, in float32 as the distances are
        outside += 1.0
        np.copyto(cost, outside, where=off)
    outside_cost = float(cost.max()) if cost.size else 1.0
    return EvidenceImage(cost=cost.astype(np.float32), scale=float(downscale), outside_cost=outside_cost,
                         origin=origin)
