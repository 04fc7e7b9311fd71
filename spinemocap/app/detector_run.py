"""``spinemocap detector run``: the detector on image files, videos and capture folders; each
image's dots written as CSV and drawn over the image."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..capture import MANIFEST, Capture
from ..detect import Detector
from ..detect.overlay import draw_detections
from ..fileio import InputError, atomic_path, atomic_write
from ..frames import parse_frames
from ..media import VIDEO_SUFFIXES, VideoDecoder, read_image
from ..views import ViewDots


@dataclass(frozen=True)
class DetectedImage:
    """One image's detection: ``name`` (``<file stem>``, ``<video stem>_f<frame>`` or
    ``<capture>_<camera>_f<frame>``) and its ``dots``."""

    name: str
    dots: ViewDots

    @property
    def tape_px(self) -> int:
        """Pixels of the tape mask."""
        return int(np.count_nonzero(self.dots.tape_mask))

    @property
    def tape_share(self) -> float:
        """The tape mask's share of the image, percent."""
        return 100.0 * self.tape_px / self.dots.tape_mask.size


def input_images(path: Path, frames: str) -> Iterator[tuple[str, np.ndarray]]:
    """(name, BGR image) of each image an input gives: an image file, the ``frames`` (a
    :func:`spinemocap.frames.parse_frames` selection) of a video, or those frames of every camera
    of a capture folder (a camera that dropped a frame gives no image there). InputError for a
    folder that is not a capture."""
    if path.is_dir():
        if not (path / MANIFEST).is_file():
            raise InputError(path, f"a folder given to 'detector run' must be a capture (with {MANIFEST})")
        capture = Capture.open(path)
        source = capture.frame_source()
        try:
            for frame in parse_frames(frames, capture.n_frames):
                for camera, image in zip(capture.camera_names, source.read(frame)):
                    if image is not None:  # None: the camera dropped that frame
                        yield f"{capture.name}_{camera}_f{frame:06d}", image
        finally:
            close = getattr(source, "close", None)
            if close:
                close()
    elif path.suffix.lower() in VIDEO_SUFFIXES:
        decoder = VideoDecoder(path)
        try:
            for frame in parse_frames(frames, decoder.n_frames or 1):
                yield f"{path.stem}_f{frame:06d}", decoder.read(frame)
        finally:
            decoder.close()
    else:
        yield path.stem, read_image(path)


def write_detection(out: Path, name: str, image: np.ndarray, dots: ViewDots) -> None:
    """``out/<name>_dots.csv`` (u_px, v_px, confidence per dot) and ``out/<name>_overlay.png`` (the
    mask's outline and the dots over ``image``); InputError when the overlay cannot be written."""
    with atomic_write(out / f"{name}_dots.csv") as handle:
        handle.write("u_px,v_px,confidence\n")
        for (u, v), c in zip(dots.uv, dots.confidence):
            handle.write(f"{u:.3f},{v:.3f},{c:.3f}\n")
    overlay = draw_detections(image, dots.tape_mask, dots.uv, dots.confidence, name)
    with atomic_path(out / f"{name}_overlay.png") as tmp:
        if not cv2.imwrite(str(tmp), overlay):
            raise InputError(out, "the overlay could not be written (is the folder writable?)")


def detect_inputs(detector: Detector, inputs: Iterable[Path], frames: str = "0:1", dot_px: float | None = None,
                  out: Path | None = None) -> Iterator[DetectedImage]:
    """Each image of ``inputs`` (see :func:`input_images`) detected by ``detector`` (``dot_px``: the
    expected dot diameter, None: from the mask's width), in input order; with ``out`` (created when
    absent) each one's files written there (:func:`write_detection`) before it is yielded."""
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    for path in inputs:
        for name, image in input_images(path, frames):
            dots = detector.detect(image, expected_dot_px=dot_px)
            if out is not None:
                write_detection(out, name, image, dots)
            yield DetectedImage(name, dots)
