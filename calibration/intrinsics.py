"""Single-camera intrinsics from board views: detect, reject bad views, cv2.calibrateCamera,
drop outlier views, re-calibrate; report RMS, per-view residuals and image coverage.

Pixels follow OpenCV (pixel (0, 0) is the centre of the top-left pixel); distortion is
k1 k2 p1 p2 k3 as in :class:`spinemocap.camera.Camera`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Hashable, Iterable, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from spinemocap.camera import Camera
from spinemocap.fileio import InputError
from spinemocap.media import IMAGE_SUFFIXES, VIDEO_SUFFIXES

from .boards import BoardDetection, BoardSpec, detect_board, view_problem

MIN_VIEWS = 4
ViewKey = Hashable  # a view: an image name, or a frame key of a recording


@dataclass
class ViewResult:
    name: ViewKey
    n_corners: int
    rms_px: float


@dataclass
class IntrinsicsResult:
    """Calibrated camera (pose = identity), RMS reprojection error (px), per-view residuals,
    rejected views with reasons, and the fraction of a 10x10 image grid covered by corners."""

    camera: Camera
    rms_px: float
    views: list[ViewResult]
    rejected: list[tuple[ViewKey, str]]
    coverage: float
    detections: dict[ViewKey, BoardDetection] = field(default_factory=dict, repr=False)

    def summary(self) -> str:
        c = self.camera
        lines = [
            f"camera {c.name}: {c.size[0]}x{c.size[1]} px, fx={c.K[0, 0]:.2f} fy={c.K[1, 1]:.2f} "
            f"cx={c.K[0, 2]:.2f} cy={c.K[1, 2]:.2f} px, dist={np.array2string(c.dist, precision=5)}",
            f"RMS {self.rms_px:.3f} px over {len(self.views)} views; image coverage {100 * self.coverage:.0f} %",
        ]
        lines += [f"  view {v.name}: {v.n_corners} corners, RMS {v.rms_px:.3f} px" for v in self.views]
        lines += [f"  rejected {name}: {why}" for name, why in self.rejected]
        return "\n".join(lines)


# ---------------------------------------------------------------------- image input
def iter_images(source: str | os.PathLike | Sequence[str | os.PathLike], max_video_frames: int = 60
                ) -> Iterable[tuple[str, np.ndarray]]:
    """Yield (name, BGR image) from a folder of images, a list of image files, or a video
    (``max_video_frames`` frames sampled evenly)."""
    paths = [Path(source)] if isinstance(source, (str, os.PathLike)) else [Path(p) for p in source]
    files: list[Path] = []
    for path in paths:
        if path.is_dir():
            files += sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES + VIDEO_SUFFIXES)
        elif path.is_file():
            files.append(path)
        else:
            raise InputError(path, "no such image, video or folder")
    if not files:
        raise InputError(paths[0], "contains no images or videos (.png/.jpg/... or .mp4/.mkv/...)")
    for path in files:
        if path.suffix.lower() in VIDEO_SUFFIXES:
            yield from _video_frames(path, max_video_frames)
        else:
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(path, "cannot be read as an image")
            yield path.name, image


def _video_frames(path: Path, max_frames: int) -> Iterable[tuple[str, np.ndarray]]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(path, "cannot be opened as a video")
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or max_frames
    wanted = set(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int).tolist())
    index = 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if index in wanted:
                yield f"{path.name}#{index}", frame
            index += 1
    finally:
        cap.release()


# ---------------------------------------------------------------------- detection
def detect_views(images: Iterable[tuple[str, np.ndarray]], board: BoardSpec, source: str = "images",
                 progress: bool = True) -> tuple[dict[ViewKey, BoardDetection], list[tuple[ViewKey, str]], tuple[int, int]]:
    """Detect the board in every image; return usable detections, rejected (name, reason) and
    the common image size (width, height). Mixed image sizes are an :class:`InputError`."""
    usable: dict[ViewKey, BoardDetection] = {}
    rejected: list[tuple[ViewKey, str]] = []
    size: tuple[int, int] | None = None
    for name, image in tqdm(list(images), desc=f"detect {board.kind}", disable=not progress, leave=False):
        this = (image.shape[1], image.shape[0])
        if size is None:
            size = this
        elif this != size:
            raise InputError(source, f"image {name} is {this[0]}x{this[1]} px but earlier images are "
                             f"{size[0]}x{size[1]}; calibrate each camera/resolution separately")
        detection = detect_board(image, board)
        problem = view_problem(detection, board, this)
        if problem or detection is None:
            rejected.append((name, problem or "board not found"))
        else:
            usable[name] = detection
    if size is None:
        raise InputError(source, "no images")
    return usable, rejected, size


# ---------------------------------------------------------------------- calibration
def calibrate_intrinsics(images: Iterable[tuple[str, np.ndarray]], board: BoardSpec, name: str = "cam",
                         source: str = "images", fix_k3: bool = True, progress: bool = True) -> IntrinsicsResult:
    """Calibrate one camera from board images (see module doc)."""
    detections, rejected, size = detect_views(images, board, source, progress)
    return calibrate_from_detections(detections, rejected, size, board, name, source, fix_k3)


def calibrate_from_detections(detections: dict[ViewKey, BoardDetection], rejected: list[tuple[ViewKey, str]],
                              size: tuple[int, int], board: BoardSpec, name: str = "cam",
                              source: str = "images", fix_k3: bool = True,
                              outlier_factor: float = 3.0) -> IntrinsicsResult:
    rejected = list(rejected)
    detections = dict(detections)
    _require_views(detections, rejected, source)
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    while True:
        rms, K, dist, per_view = _calibrate(detections, board, size, flags)
        worst = max(per_view, key=lambda view: per_view[view])
        limit = max(outlier_factor * float(np.median(list(per_view.values()))), 1.0)
        if per_view[worst] <= limit or len(detections) <= MIN_VIEWS:
            break
        rejected.append((worst, f"outlier view (RMS {per_view[worst]:.2f} px > {limit:.2f})"))
        del detections[worst]
    camera = Camera(name, K, dist.ravel()[:5], np.eye(3), np.zeros(3), size)
    views = [ViewResult(n, len(detections[n]), per_view[n]) for n in detections]
    return IntrinsicsResult(camera, rms, views, rejected, image_coverage(detections.values(), size), detections)


def _require_views(detections: dict, rejected: list[tuple[ViewKey, str]], source: str) -> None:
    if len(detections) >= MIN_VIEWS:
        return
    reasons = "; ".join(f"{n}: {why}" for n, why in rejected[:8])
    raise InputError(source, f"only {len(detections)} usable board views (need at least {MIN_VIEWS}). "
                     f"Capture again: the whole board sharp and in focus, tilted in several directions, "
                     f"covering the image corners. Rejected: {reasons or 'none'}")


def _calibrate(detections: dict[ViewKey, BoardDetection], board: BoardSpec, size: tuple[int, int], flags: int):
    obj_all = board.object_points()
    names = list(detections)
    obj = [obj_all[detections[n].ids].astype(np.float32) for n in names]
    img = [detections[n].pixels.astype(np.float32).reshape(-1, 1, 2) for n in names]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None, flags=flags, criteria=crit)
    per_view: dict[ViewKey, float] = {}
    for n, o, i, r, t in zip(names, obj, img, rvecs, tvecs):
        proj = cv2.projectPoints(o, r, t, K, dist)[0].reshape(-1, 2)
        per_view[n] = float(np.sqrt(np.mean(np.sum((proj - i.reshape(-1, 2)) ** 2, axis=1))))
    return float(rms), K, np.asarray(dist, float).ravel(), per_view


def image_coverage(detections: Iterable[BoardDetection], size: tuple[int, int], grid: int = 10) -> float:
    """Fraction of a grid x grid partition of the image that contains at least one corner."""
    hit = np.zeros((grid, grid), bool)
    for det in detections:
        gx = np.clip((det.pixels[:, 0] / size[0] * grid).astype(int), 0, grid - 1)
        gy = np.clip((det.pixels[:, 1] / size[1] * grid).astype(int), 0, grid - 1)
        hit[gy, gx] = True
    return float(hit.mean())
