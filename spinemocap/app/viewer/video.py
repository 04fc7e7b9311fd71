"""Labelled camera videos: every tracked dot reprojected through the rig onto each camera's own
frames, labelled, coloured by its :class:`~.tracked.DotClass`, the tape's rows joined as lines,
the frame number, time and the frame's flag written on it; one H.264 MP4 per camera (yuv420p,
``+faststart``: plays in a browser) and one grid of all cameras.

Pixel convention: a pixel's centre is at integer coordinates (as :meth:`Camera.project` and
OpenCV); with a scale ``s`` a point at ``p`` px lands at ``(p + 0.5) * s - 0.5``. Dots are filled
discs drawn with sub-pixel centres (OpenCV ``shift``), so a decoded frame shows each disc centred
on its reprojection.
"""

from __future__ import annotations

import math
import os
import re
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from tqdm import tqdm

from ...camera import Camera
from ...capture import Capture
from ...fileio import InputError, check_writable
from ...frames import parse_frames
from ...media import VideoWriter
from ..streaming import prefetched_frames
from .layout import GRID_NAME
from .scene3d import playback_rate
from .tracked import CLASS_COLOURS_BGR, CLASS_WORDS, DotClass, TrackedDots, read_tracked

#: Longest image side of the per-camera videos when no scale is given: at most this (px), the
#: camera's size divided by a whole number (see :func:`auto_scale`).
AUTO_LONG_SIDE = 1280
#: Widest grid of all cameras (px): tiles shrink to fit.
GRID_MAX_WIDTH = 1920
ROW_LINE_BGR = (235, 235, 235)
TEXT_BGR = (255, 255, 255)
FLAG_TEXT_BGR = (255, 0, 255)
SUBPIXEL_BITS = 4  # OpenCV drawing shift: centres to 1/16 px
RING_PX = 1.5  # width of a dot's black ring
LABEL_GAP_PX = 4  # a label this far beyond the dot's disc


@dataclass(frozen=True)
class OverlayStyle:
    """Sizes of the drawing on an image ``size`` = (width, height) px."""

    dot_radius_px: int
    font_scale: float
    line_px: int

    @classmethod
    def for_size(cls, size: tuple[int, int]) -> "OverlayStyle":
        short = min(size)
        return cls(dot_radius_px=max(3, round(short / 180)), font_scale=max(0.33, short / 1400),
                   line_px=max(1, round(short / 600)))


@dataclass
class VideoResult:
    """What :func:`write_videos` wrote: ``cameras`` name -> MP4, ``grid`` the grid MP4 (None
    when not asked for), ``frames`` the capture frames drawn, ``seconds`` the wall time and
    ``size`` each camera video's (width, height) px."""

    cameras: dict[str, Path]
    grid: Path | None
    frames: list[int]
    seconds: float
    sizes: dict[str, tuple[int, int]] = field(default_factory=dict)

    @property
    def frames_per_s(self) -> float:
        """Capture frames (all cameras and the grid) written per second of wall time."""
        return len(self.frames) / self.seconds if self.seconds > 0 else float("nan")


# ---------------------------------------------------------------------- geometry
def reproject(camera: Camera, positions_mm: np.ndarray) -> np.ndarray:
    """(D, 3) world points (mm, NaN where missing) -> (D, 2) distorted pixels of ``camera``
    (:meth:`Camera.project`); NaN for missing points and points behind the camera."""
    pixels = np.full((len(positions_mm), 2), np.nan)
    finite = np.isfinite(positions_mm).all(axis=1)
    if finite.any():
        pixels[finite] = camera.project(positions_mm[finite])
    return pixels


def scale_pixels(pixels: np.ndarray, scale_xy: tuple[float, float]) -> np.ndarray:
    """Pixels of the camera image -> pixels of the image resized by ``scale_xy`` (centres at
    integers in both)."""
    return (np.asarray(pixels, float) + 0.5) * np.asarray(scale_xy, float) - 0.5


def even_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """``size`` (width, height) scaled and rounded to even numbers (yuv420p needs them), >= 2."""
    width, height = (max(2, 2 * round(v * scale / 2)) for v in size)
    return width, height


def auto_scale(sizes: Sequence[tuple[int, int]]) -> float:
    """The scale 1/n (n a whole number) that brings the largest camera's longest side to at most
    :data:`AUTO_LONG_SIDE` px: shrinking by a whole factor averages whole blocks of pixels
    (OpenCV's fast path, 1/15 of the time of a fractional shrink at 2448x1600)."""
    return 1.0 / math.ceil(max(max(s) for s in sizes) / AUTO_LONG_SIDE)


def resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` resized to ``size`` (width, height) px: by averaging pixel areas when shrinking
    by 2 or more (every pixel counts: no dot can fall between samples), bilinear otherwise."""
    shrink = min(image.shape[1] / size[0], image.shape[0] / size[1])
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrink >= 2 else cv2.INTER_LINEAR)


# ---------------------------------------------------------------------- drawing
def draw_dots(image: np.ndarray, pixels: np.ndarray, classes: np.ndarray, labels: Sequence[str],
              rows: np.ndarray, segments: np.ndarray, style: OverlayStyle) -> None:
    """Draw in place on the BGR ``image``: the rows' segments (``segments`` (S, 2) dot pairs) as
    lines, then every dot with finite ``pixels`` (D, 2) as a filled disc in its class colour
    (radius ``style.dot_radius_px``) in a black ring (:data:`RING_PX` wide), its label beside it
    (``rows`` (D,) each dot's row: labels go outward from the row)."""
    shift = 1 << SUBPIXEL_BITS
    fixed = np.round(np.nan_to_num(pixels, nan=-1e6) * shift).astype(np.int64)
    visible = np.isfinite(pixels).all(axis=1) & (classes != DotClass.MISSING)
    visible &= (np.abs(fixed) < 2**30).all(axis=1)  # far outside: OpenCV takes 32-bit ints
    for a, b in segments:
        if visible[a] and visible[b]:
            cv2.line(image, tuple(int(v) for v in fixed[a]), tuple(int(v) for v in fixed[b]), ROW_LINE_BGR,
                     style.line_px, cv2.LINE_AA, SUBPIXEL_BITS)
    for d in np.flatnonzero(visible):
        centre = (int(fixed[d, 0]), int(fixed[d, 1]))
        # a black ring (luminance contrast on skin, kept sharp by yuv420p) around the class colour
        cv2.circle(image, centre, round((style.dot_radius_px + RING_PX) * shift), (0, 0, 0), -1, cv2.LINE_AA,
                   SUBPIXEL_BITS)
        cv2.circle(image, centre, style.dot_radius_px * shift, CLASS_COLOURS_BGR[DotClass(int(classes[d]))], -1,
                   cv2.LINE_AA, SUBPIXEL_BITS)
    for d in np.flatnonzero(visible):
        put_label(image, labels[int(d)], pixels[d], label_side(pixels, visible, rows, int(d)), style)


def label_side(pixels: np.ndarray, visible: np.ndarray, rows: np.ndarray, d: int) -> np.ndarray:
    """Unit image direction in which dot ``d``'s label goes: away from the centre of its row's
    visible dots (an end dot's label beside the row), straight up for a row's middle dot."""
    mates = visible & (rows == rows[d])
    away = pixels[d] - pixels[mates].mean(axis=0)
    length = float(np.hypot(*away))
    return away / length if length > 1.0 else np.array([0.0, -1.0])


def put_label(image: np.ndarray, text: str, pixel: np.ndarray, side: np.ndarray, style: OverlayStyle) -> None:
    """``text`` beside the disc at ``pixel``, on ``side`` (a unit image direction), clear of it."""
    scale = style.font_scale * 0.8
    (width, height), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, round(scale * 2)))
    gap = style.dot_radius_px + LABEL_GAP_PX
    if abs(side[0]) >= abs(side[1]):  # left or right of the dot, vertically centred
        x = pixel[0] + gap if side[0] > 0 else pixel[0] - gap - width
        y = pixel[1] + height / 2
    else:  # above or below, horizontally centred
        x = pixel[0] - width / 2
        y = pixel[1] - gap if side[1] < 0 else pixel[1] + gap + height
    put_text(image, text, (int(round(x)), int(round(y))), scale, TEXT_BGR)


def put_text(image: np.ndarray, text: str, origin: tuple[int, int], font_scale: float,
             colour: tuple[int, int, int]) -> None:
    """``text`` at ``origin`` (its baseline's left end), outlined in black to read on any image."""
    thickness = max(1, round(font_scale * 2))
    x, y = origin
    for dx, dy in ((-1, -1), (1, -1), (-1, 1), (1, 1)):  # the outline: the same strokes shifted (a thicker
        # stroke also widens the glyphs' advance in some OpenCV builds, and would not line up)
        cv2.putText(image, text, (x + dx, y + dy), cv2.FONT_HERSHEY_SIMPLEX, font_scale, (0, 0, 0), thickness,
                    cv2.LINE_AA)
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale, colour, thickness, cv2.LINE_AA)


def frame_header(camera: str, frame: int, time_s: float, classes: np.ndarray, flagged: bool) -> list[tuple[str, bool]]:
    """The lines written at the top of a frame: (text, is a warning)."""
    counts = {c: int((classes == c).sum()) for c in DotClass}
    lines = [(f"{camera}   frame {frame}   t = {time_s:.3f} s", False),
             (f"observed {counts[DotClass.OBSERVED]}  inferred {counts[DotClass.INFERRED]}  "
              f"flagged {counts[DotClass.FLAGGED]}  missing {counts[DotClass.MISSING]}", False)]
    if flagged:
        lines.append(("FLAGGED: labels not vouched for (see confidence in markers.csv)", True))
    return lines


def draw_header(image: np.ndarray, lines: list[tuple[str, bool]], style: OverlayStyle) -> None:
    """The header lines on a dark band at the top left, and the colour legend at the bottom left."""
    (_, height), _ = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, style.font_scale, 1)
    step = int(height * 1.9)
    width = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, style.font_scale, 1)[0][0] for t, _ in lines)
    band = image[: step * len(lines) + step // 2, : width + 2 * step]
    band //= 3  # darkened in place
    for k, (text, warning) in enumerate(lines):
        put_text(image, text, (step // 2, step * (k + 1)), style.font_scale, FLAG_TEXT_BGR if warning else TEXT_BGR)
    y = image.shape[0] - step // 2
    x = step // 2
    for cls in (DotClass.OBSERVED, DotClass.INFERRED, DotClass.FLAGGED):
        cv2.rectangle(image, (x, y - height), (x + height, y), CLASS_COLOURS_BGR[cls], -1)
        put_text(image, CLASS_WORDS[cls], (x + height + 4, y), style.font_scale * 0.8, TEXT_BGR)
        x += height + 12 + cv2.getTextSize(CLASS_WORDS[cls], cv2.FONT_HERSHEY_SIMPLEX, style.font_scale * 0.8, 1)[0][0]


def annotate(image: np.ndarray, camera: Camera, tracked: TrackedDots, k: int, size: tuple[int, int]) -> np.ndarray:
    """Camera ``camera``'s BGR ``image`` resized to ``size`` with frame index ``k`` of
    ``tracked`` drawn on it (a new array)."""
    w, h = camera.size
    out = image if (w, h) == tuple(size) else resize_image(image, size)
    out = np.ascontiguousarray(out).copy() if out is image else out
    style = OverlayStyle.for_size(size)
    pixels = scale_pixels(reproject(camera, tracked.positions[k]), (size[0] / w, size[1] / h))
    draw_dots(out, pixels, tracked.classes[k], tracked.labels, tracked.row, tracked.row_segments(), style)
    header = frame_header(camera.name, int(tracked.frames[k]), float(tracked.times[k]), tracked.classes[k],
                          bool(tracked.frame_flagged[k]))
    draw_header(out, header, style)
    return out


def grid_layout(n_cameras: int, tile: tuple[int, int]) -> tuple[int, int, tuple[int, int]]:
    """(columns, rows, tile size) of the grid of ``n_cameras`` tiles of ``tile`` px, shrunk by a
    whole factor (as :func:`auto_scale`) to at most :data:`GRID_MAX_WIDTH` and made even."""
    columns = int(np.ceil(np.sqrt(n_cameras)))
    rows = int(np.ceil(n_cameras / columns))
    return columns, rows, even_size(tile, 1.0 / math.ceil(columns * tile[0] / GRID_MAX_WIDTH))


def tile_grid(images: Sequence[np.ndarray], columns: int, rows: int, tile: tuple[int, int]) -> np.ndarray:
    """The images resized to ``tile`` side by side, ``columns`` x ``rows``, black where empty."""
    grid = np.zeros((rows * tile[1], columns * tile[0], 3), np.uint8)
    for k, image in enumerate(images):
        r, c = divmod(k, columns)
        resized = image if image.shape[1::-1] == tuple(tile) else resize_image(image, tile)
        grid[r * tile[1]:(r + 1) * tile[1], c * tile[0]:(c + 1) * tile[0]] = resized
    return grid


# ---------------------------------------------------------------------- writing
def video_name(camera: str, taken: set[str]) -> str:
    """A file name for camera ``camera``'s video: characters outside ``[A-Za-z0-9._-]`` become
    ``_``; a name already ``taken`` (or the grid's) gets a number."""
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", camera).strip(".") or "camera"
    name, k = f"{stem}.mp4", 2
    while name in taken or name == GRID_NAME:
        name, k = f"{stem}_{k}.mp4", k + 1
    return name


def selected_frames(tracked: TrackedDots, frames: str | None, n_frames: int, source: str = "frames") -> list[int]:
    """Capture frames to draw: the tracked frames inside the selection ``frames`` (the syntax of
    :func:`spinemocap.frames.parse_frames`, e.g. ``100:400:2``; ``None``: every tracked frame).
    Raises :class:`InputError` naming ``source`` for a selection not of the syntax, naming the
    results when it keeps no tracked frame."""
    wanted: set[int] | range = range(n_frames)
    if frames:
        wanted = set(parse_frames(frames, n_frames, source))
    chosen = [int(f) for f in tracked.frames if f in wanted]
    if not chosen:
        raise InputError(tracked.source, f"no tracked frame in {frames or 'the capture'} (the results hold "
                                         f"frames {int(tracked.frames[0])}..{int(tracked.frames[-1])})")
    return chosen


def write_videos(capture_dir: str | os.PathLike, results: str | os.PathLike, out_dir: str | os.PathLike,
                 frames: str | None = None, scale: float | None = None, grid: bool = True,
                 progress: bool = True) -> VideoResult:
    """Per camera ``out_dir/<camera>.mp4`` and (``grid``) ``out_dir/all_cameras.mp4``: the
    capture's frames with ``results`` (a results folder or marker file) drawn on them.

    ``frames``: a selection of capture frames (:func:`spinemocap.frames.parse_frames`: ``A:B``, B
    exclusive; ``A:B:S`` every S-th frame, the video then plays at the capture's rate / S, so time
    runs as recorded); ``scale``: the images'
    resize factor (default :func:`auto_scale`: the longest side at most :data:`AUTO_LONG_SIDE`
    px). Frames are read only through :meth:`Capture.frame_source`. Videos are written atomically: an error leaves the
    folder's earlier videos as they were."""
    capture = Capture.open(capture_dir)
    tracked = read_tracked(results, capture.tape)
    chosen = selected_frames(tracked, frames, capture.n_frames)
    out = check_writable(out_dir, "video output folder")
    cameras = list(capture.rig)
    if scale is not None and not (np.isfinite(scale) and 0 < scale <= 4):
        raise InputError("scale", f"scale {scale} must be a number in (0, 4]")
    factor = auto_scale([c.size for c in cameras]) if scale is None else float(scale)
    sizes = {c.name: even_size(c.size, factor) for c in cameras}
    fps = playback_rate(np.asarray(chosen) / capture.fps, capture.fps)  # recorded time for A:B:S
    names: dict[str, str] = {}
    for camera in cameras:
        names[camera.name] = video_name(camera.name, set(names.values()))
    columns, rows, tile = grid_layout(len(cameras), sizes[cameras[0].name])
    started = time.perf_counter()
    writers = {c.name: VideoWriter(out / names[c.name], fps, sizes[c.name], codec="libx264") for c in cameras}
    grid_writer = VideoWriter(out / GRID_NAME, fps, (columns * tile[0], rows * tile[1]), codec="libx264") if grid else None
    source = capture.frame_source()
    workers = max(1, min(len(cameras), os.cpu_count() or 1))
    pool = ThreadPoolExecutor(workers, thread_name_prefix="draw")  # OpenCV and x264 work outside the GIL

    def draw_and_write(k: int, image: np.ndarray, camera: Camera) -> np.ndarray:
        drawn = annotate(image, camera, tracked, k, sizes[camera.name])
        writers[camera.name].write(drawn)
        return drawn

    try:
        frames_in = prefetched_frames(source, chosen, workers=workers, prefetch=2)  # cameras decoded in threads, ahead
        for frame, images, _ in tqdm(frames_in, total=len(chosen), desc="labelled videos", unit="frame",
                                     disable=not progress):
            k = tracked.index_of(frame)
            drawn = list(pool.map(draw_and_write, [k] * len(cameras), images, cameras))
            if grid_writer is not None:
                grid_writer.write(tile_grid(drawn, columns, rows, tile))
    except BaseException:
        for writer in [*writers.values(), *([grid_writer] if grid_writer else [])]:
            writer.abort()
        raise
    finally:
        pool.shutdown(wait=True)
        close = getattr(source, "close", None)
        if close is not None:
            close()
    for writer in [*writers.values(), *([grid_writer] if grid_writer else [])]:
        writer.close()
    return VideoResult(cameras={c: out / n for c, n in names.items()}, grid=out / GRID_NAME if grid else None,
                       frames=chosen, seconds=time.perf_counter() - started, sizes=sizes)
