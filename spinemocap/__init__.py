"""spinemocap: 3D spine motion capture from perforated kinesiology tape.

Pipeline (one sub-package or module per stage, in the order data flows):

    synth/        synthetic studio: bodies, tape, cameras, occluders, renders, ground truth
    detect/       tape segmentation and dot (blob) detection per image
    track/        candidates -> edge cloud -> LP -> MRF1 -> MRF2 -> labels/sequence
    analysis/     spine curve, angles, batch processing and reports

Core types shared with the ``calibration`` and ``exporters`` packages live in small modules
at this level: :mod:`spinemocap.tape`, :mod:`spinemocap.camera`, :mod:`spinemocap.markers`,
:mod:`spinemocap.capture`, :mod:`spinemocap.fileio`.

Conventions: millimetres, world Z up, seconds, pixels; cameras are OpenCV pinhole models with
world->camera pose ``x_c = R x_w + t``.
"""

__version__ = "0.1.0"
