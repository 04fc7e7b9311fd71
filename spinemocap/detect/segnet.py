"""A compact U-Net for tape segmentation, in plain PyTorch (no torchvision).

The network maps a BGR image at working resolution (a few hundred px) to one logit per pixel
(tape vs not tape). It is fully convolutional, so any input size divisible by ``2**depth`` works;
:func:`pad_to_multiple` takes care of that. About 0.3 M parameters: ~1.2 MB of float32 weights.

Inputs: float tensor (B, 3, H, W), BGR scaled to [0, 1] and centred (``x - 0.5``), see
:func:`to_tensor`. Outputs: logits (B, 1, H, W).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


class ConvBlock(nn.Sequential):
    """Two 3x3 convolutions, each with batch norm and ReLU."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__(
            nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
            nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        )


class TapeUNet(nn.Module):
    """U-Net with ``len(channels)`` levels; ``channels`` per level, finest first."""

    def __init__(self, channels: tuple[int, ...] = (16, 24, 40, 64)):
        super().__init__()
        self.channels = tuple(int(c) for c in channels)
        self.down = nn.ModuleList()
        c_prev = 3
        for c in self.channels:
            self.down.append(ConvBlock(c_prev, c))
            c_prev = c
        self.up = nn.ModuleList()
        for c_skip in reversed(self.channels[:-1]):
            self.up.append(ConvBlock(c_prev + c_skip, c_skip))
            c_prev = c_skip
        self.head = nn.Conv2d(c_prev, 1, 1)

    @property
    def stride(self) -> int:
        """Input sides must be multiples of this."""
        return 2 ** (len(self.channels) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            if i:
                x = F.max_pool2d(x, 2)
            x = block(x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.head(x)


def to_tensor(images_bgr: np.ndarray | torch.Tensor) -> torch.Tensor:
    """uint8 (H, W, 3) or (B, H, W, 3) BGR -> float (B, 3, H, W) in [-0.5, 0.5], on the device of
    the input (a uint8 tensor already on the GPU is converted there)."""
    t = images_bgr if isinstance(images_bgr, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(images_bgr))
    if t.ndim == 3:
        t = t[None]
    return t.permute(0, 3, 1, 2).float() / 255.0 - 0.5


def pad_to_multiple(image: np.ndarray, multiple: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Pad (H, W, ...) at the bottom/right by edge replication to multiples of ``multiple``;
    returns the padded array and the original (H, W)."""
    h, w = image.shape[:2]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        pad = [(0, ph), (0, pw)] + [(0, 0)] * (image.ndim - 2)
        image = np.pad(image, pad, mode="edge")
    return image, (h, w)


def save_weights(model: TapeUNet, path, metadata: dict | None = None) -> None:
    """Store the state dict and architecture (atomically) in a ``.pt`` file."""
    from ..fileio import atomic_write

    payload = {"channels": list(model.channels), "state_dict": model.state_dict(), "metadata": metadata or {}}
    with atomic_write(path, "wb") as handle:
        torch.save(payload, handle)


def load_weights(path) -> tuple[TapeUNet, dict]:
    """Load a ``.pt`` file written by :func:`save_weights` (or a training checkpoint); returns
    the model in eval mode and its metadata. Raises InputError naming the file when unreadable."""
    from pathlib import Path

    from ..fileio import InputError

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "weights file not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        model = TapeUNet(tuple(payload["channels"]))
        model.load_state_dict(payload["state_dict"] if "state_dict" in payload else payload["model"])
    except Exception as exc:  # torch raises many types for a damaged or foreign file
        raise InputError(path, f"not a spinemocap segmentation weights file ({exc.__class__.__name__}: {exc})") from exc
    model.eval()
    return model, dict(payload.get("metadata", {}))
