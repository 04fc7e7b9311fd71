"""Finding the tape and its dots in camera images.

    from spinemocap.detect import Detector
    det = Detector("net")                      # or Detector("classical")
    dots = det.detect(image_bgr, camera=0)     # ViewDots: uv (N, 2) px, confidence, mask, grey image

Modules in pipeline order: segnet (compact U-Net) / classical (darkness + morphology) -> tape
mask -> instances (separate stripes) -> blobs (dots with sub-pixel centres) -> detector (the
API above). dataset + train make and train on data (``spinemocap detector train|finetune``);
drawn makes 2D test images with exact answers.
"""

from .blobs import BlobParams, find_dots
from .detector import Detector, shipped_weights_path

__all__ = ["Detector", "BlobParams", "find_dots", "shipped_weights_path"]
