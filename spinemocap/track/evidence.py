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


@dataclass
class EvidenceImage:
    """Cost image ``cost`` (h, w) float32 where pixel (i, j) covers full-resolution pixel
    ``(j / scale, i / scale)``; ``outside_cost`` is returned for points off the image."""

    cost: np.ndarray
    scale: float
    outside_cost: float

    def __post_init__(self) -> None:
        self._tensor = torch.from_numpy(np.ascontiguousarray(self.cost, dtype=np.float32)).double()

    @property
    def shape(self) -> tuple[int, int]:
        return self.cost.shape

    def sample_torch(self, uv: torch.Tensor) -> torch.Tensor:
        """Bilinear cost at (..., 2) full-resolution pixel coordinates (differentiable in uv)."""
        h, w = self.cost.shape
        x = uv[..., 0] * self.scale
        y = uv[..., 1] * self.scale
        inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1) & torch.isfinite(x) & torch.isfinite(y)
        xc = torch.where(inside, x, torch.zeros_like(x)).clamp(0, w - 1)
        yc = torch.where(inside, y, torch.zeros_like(y)).clamp(0, h - 1)
        x0 = xc.detach().floor().clamp(max=w - 2).long() if w > 1 else xc.detach().floor().long()
        y0 = yc.detach().floor().clamp(max=h - 2).long() if h > 1 else yc.detach().floor().long()
        fx, fy = xc - x0, yc - y0
        x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
        img = self._tensor
        top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
        bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
        value = top * (1 - fy) + bottom * fy
        return torch.where(inside, value, torch.full_like(value, self.outside_cost))

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear cost at (N, 2) full-resolution pixel coordinates; ``outside_cost`` off-image."""
        uv = np.asarray(uv, dtype=float)
        with torch.no_grad():
            return self.sample_torch(torch.from_numpy(uv)).numpy()


class EvidenceStack:
    """All cameras' cost images on one canvas (C, 1, H, W) for batched, differentiable bilinear
    sampling with ``grid_sample`` (one call for all cameras; far cheaper than per-camera indexing).
    Each image sits at offset (1, 1) in a canvas filled with its ``outside_cost``; cameras without
    evidence (None) read 0 everywhere."""

    def __init__(self, evidence: list[EvidenceImage | None]):
        present = [e for e in evidence if e is not None]
        h = max((e.shape[0] for e in present), default=1) + 2
        w = max((e.shape[1] for e in present), default=1) + 2
        canvas = np.zeros((len(evidence), 1, h, w), dtype=np.float64)
        self.scale = np.ones(len(evidence))
        for c, e in enumerate(evidence):
            if e is None:
                continue
            canvas[c, 0] = e.outside_cost
            canvas[c, 0, 1 : 1 + e.shape[0], 1 : 1 + e.shape[1]] = e.cost
            self.scale[c] = e.scale
        self.shape = (h, w)
        self._flat = torch.from_numpy(canvas.reshape(-1))
        self._base = torch.arange(len(evidence))[:, None] * (h * w)
        self._scale = torch.from_numpy(self.scale)[:, None]

    def sample_torch(self, uv: torch.Tensor) -> torch.Tensor:
        """uv (C, N, 2) full-resolution pixels, camera c in row c -> (C, N) bilinear costs,
        differentiable in uv; points off the canvas read the border (the outside cost)."""
        h, w = self.shape
        x = torch.nan_to_num((uv[..., 0] * self._scale + 1.0), nan=-1.0).clamp(0, w - 1)
        y = torch.nan_to_num((uv[..., 1] * self._scale + 1.0), nan=-1.0).clamp(0, h - 1)
        x0 = x.detach().floor().clamp(max=w - 2)
        y0 = y.detach().floor().clamp(max=h - 2)
        fx, fy = x - x0, y - y0
        idx = self._base + y0.long() * w + x0.long()
        flat = self._flat
        top = flat[idx] * (1 - fx) + flat[idx + 1] * fx
        bottom = flat[idx + w] * (1 - fx) + flat[idx + w + 1] * fx
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
) -> EvidenceImage:
    """Cost image of one camera view.

    ``image``: grey (H, W) or BGR (H, W, 3) uint8/float; ``mask``: (H, W) bool tape mask or None
    (whole image counts as tape). Inside the mask the cost is ``1 - normalised brightness`` in
    [0, 1] (1st/99.5th brightness percentiles inside the mask, after the blur, map to 1/0); outside it is
    ``1 + outside_slope * distance_px``. ``blur_sigma_px`` (full-resolution px) defaults to 0.6 of
    the dot radius estimated from the mask width."""
    if image.ndim == 3:
        grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2GRAY)
    else:
        grey = np.asarray(image)
    grey = grey.astype(np.float32)
    h, w = grey.shape
    tape = np.ones((h, w), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if tape.shape != (h, w):
        raise ValueError(f"mask shape {tape.shape} differs from image shape {(h, w)}")
    if blur_sigma_px is None:
        blur_sigma_px = 0.6 * estimate_dot_radius_px(tape, dot_to_width) if mask is not None else 1.5
    if downscale != 1.0:
        size = (max(1, int(round(w * downscale))), max(1, int(round(h * downscale))))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        tape = cv2.resize(tape.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    sigma = blur_sigma_px * downscale
    if sigma > 0.3 and tape.any():
        # off-tape pixels take the tape's dark level first, so bright skin beside the tape does not
        # bleed into the blurred tape border and pose as a dot
        dark = np.float32(np.percentile(grey[tape], 1))
        grey = cv2.GaussianBlur(np.where(tape, grey, dark), (0, 0), sigma)
    elif sigma > 0.3:
        grey = cv2.GaussianBlur(grey, (0, 0), sigma)
    if tape.any():
        lo, hi = np.percentile(grey[tape], [1, 99.5])
    else:
        lo, hi = float(grey.min()), float(grey.max())
    cost = 1.0 - np.clip((grey - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    if not tape.all():
        outside = cv2.distanceTransform((~tape).astype(np.uint8), cv2.DIST_L2, 5) / downscale
        cost = np.where(tape, cost, 1.0 + outside_slope * outside)
    outside_cost = float(cost.max()) if cost.size else 1.0
    return EvidenceImage(cost=cost.astype(np.float32), scale=float(downscale), outside_cost=outside_cost)
