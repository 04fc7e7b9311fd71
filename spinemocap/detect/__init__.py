"""Finding the tape and its dots in camera images.

    from spinemocap.detect import Detector
    det = Detector("net")                      # or Detector("classical")
    dots = det.detect(image_bgr, camera=0)     # ViewDots: uv (N, 2) px, confidence, mask, grey image

Modules in pipeline order: segnet (compact U-Net) / classical (darkness + morphology) -> tape
mask -> instances (separate stripes) -> blobs (dots with sub-pixel centres) -> detector (the
API above). dataset + train make and train on data (``spinemocap detector train|finetune``);
drawn makes 2D test images with exact answers.
"""

from typing import TYPE_CHECKING

from .blobs import BlobParams, find_dots

if TYPE_CHECKING:  # the lazily loaded names, visible to type checkers
    from .detector import Detector, shipped_weights_path

# The detector loads torch: imported on first use so that ``spinemocap.detect.find_dots`` (and the
# CLI) start fast.
_LAZY = {"Detector": "detector", "shipped_weights_path": "detector"}


def __getattr__(name: str):
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Detector", "BlobParams", "find_dots", "shipped_weights_path"]
