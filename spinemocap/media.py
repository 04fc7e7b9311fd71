"""Frame sources and decoders: a capture's images or videos read (and written) as BGR uint8
arrays, one per camera.

A :class:`FrameSource` yields, for a frame index, one BGR ``uint8`` image per camera in rig order.
:class:`ImageFolderSource` reads one image file per camera and frame, :class:`VideoSource` one
video per camera (:class:`VideoDecoder`, PyAV); :class:`VideoWriter` writes the lossless videos the
decoder reads back. The synthetic studio provides an in-process source with the same interface.
"""

from __future__ import annotations

import logging
import os
import sys
from fractions import Fraction
from pathlib import Path
from typing import Protocol, Sequence, runtime_checkable

import cv2
import numpy as np

from .fileio import InputError, atomic_path
from .timebase import (
    CameraClock,
    DroppedFrames,
    FramePairing,
    image_times,
    pair_cameras,
    partial_recordings,
    video_times,
)

log = logging.getLogger(__name__)

VIDEO_CODEC = "utvideo"
# The lossless codecs VideoWriter writes, and the pixel format each stores BGR images in: UT Video
# (planar RGB, Huffman-coded: 0.57x the raw size on the lab-realism studio capture, ~28 CPU ms to
# decode a 2448x1600 image) or uncompressed BGR (``rawvideo``: 1.77x UT Video's size; a frame is
# the bytes read, nothing to decode)
VIDEO_CODECS = {"utvideo": "gbrp", "rawvideo": "bgr24"}
# Videos for people to watch (not lossless): H.264 in 8-bit 4:2:0, which every browser plays; an MP4
# gets its index first (``+faststart``) so that playing starts at once. ``ultrafast``: on the
# labelled videos of the studio capture (6 cameras at 1224x800 and their grid) 0.6x the encoding
# CPU time of ``superfast`` and 0.65x its size, the dots and labels as sharp.
VIEWING_CODECS = {"libx264": "yuv420p"}
# File suffixes (lower case) read as still images (OpenCV) and as videos (PyAV)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mkv", ".mp4", ".avi", ".mov", ".webm", ".m4v", ".mts", ".ts")
VIEWING_OPTIONS = {"libx264": {"crf": "20", "preset": "ultrafast"}}
# A VideoDecoder's BGR arrays kept for reuse once the caller drops them (a new 11.75 MB array makes
# the kernel zero its pages again on every frame): the most frames of one camera held at once
# that still reuse (the tracker's reader holds about 4: prefetched, being detected, being solved)
REUSED_BUFFERS = 6


@runtime_checkable
class FrameSource(Protocol):
    """Multi-camera frames on the capture's clock. ``read(i)`` returns one BGR uint8 image per
    camera, None for a camera that has no frame at capture frame ``i`` (see
    :mod:`spinemocap.timebase`)."""

    camera_names: list[str]
    n_frames: int

    def read(self, frame: int) -> list[np.ndarray | None]: ...


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as BGR uint8, raising :class:`InputError` naming the file if it is missing
    or cannot be decoded."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(path, "image file is corrupt or in an unsupported format")
    return image


def check_image_size(image: np.ndarray, size: tuple[int, int] | None, camera: str,
                     source: str | os.PathLike) -> np.ndarray:
    """``image`` unchanged when it is ``size`` = (width, height) px (the rig's), else
    :class:`InputError` naming ``source``: a calibration of another sensor or crop is wrong data."""
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        raise InputError(source, f"image is {image.shape[1]}x{image.shape[0]} px but the rig says camera "
                                 f"{camera!r} is {size[0]}x{size[1]} px")
    return image


class _StoredFrames:
    """The state an image-folder and a video source share: the capture folder ``root``, the
    cameras in rig order, ``n_frames``, the rig's (width, height) per camera (``sizes``; None: not
    checked), each camera's :class:`~spinemocap.timebase.CameraClock` (``clocks``; default: the
    capture's timing), whether the clocks leave the capture's timing (:attr:`timed`), the frame
    pairing (set by a timed source) and :attr:`unreadable`."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int,
                 sizes: Sequence[tuple[int, int]] | None, clocks: Sequence[CameraClock] | None,
                 fps: float | None):
        self.root = Path(root)
        self.camera_names = list(camera_names)
        self.n_frames = int(n_frames)
        self.sizes: list[tuple[int, int] | None] = list(sizes) if sizes is not None else [None] * len(self.camera_names)
        self.clocks = list(clocks) if clocks is not None else [CameraClock()] * len(self.camera_names)
        self.timed = not all_default(self.clocks, fps)
        self.pairing: FramePairing | None = None
        #: camera name -> {capture frame: why its image could not be read} (missing file, damaged data)
        self.unreadable: dict[str, dict[int, str]] = {cam: {} for cam in self.camera_names}


class ImageFolderSource(_StoredFrames, FrameSource):
    """Frames stored as one image file per camera and frame. ``sizes``: the rig's (width,
    height) per camera; every image read is checked against it.

    ``clocks`` (rig order, :class:`~spinemocap.timebase.CameraClock`) with ``fps`` (the capture's
    rate): each camera's images are frames of its own clock (image ``k`` at ``k / clock.fps`` s,
    from ``clock.media``, a folder of images in name order, when given) and capture frame ``i`` reads
    the image nearest in time (:attr:`pairing`); a camera with none there gives None. Without clocks,
    or with clocks that all leave the timing at its defaults, frame ``i`` is every camera's image
    ``i``; a camera may hold fewer than ``n_frames`` images (a missing or unreadable image gives
    None for that camera and frame, recorded in :attr:`unreadable`), not more."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str,
                 sizes: Sequence[tuple[int, int]] | None = None, clocks: Sequence[CameraClock] | None = None,
                 fps: float | None = None):
        super().__init__(root, camera_names, n_frames, sizes, clocks, fps)
        self.pattern = pattern
        self._files: list[list[Path] | None] = [None] * len(self.camera_names)
        timed = self.timed
        times = []
        for k, (cam, clock) in enumerate(zip(self.camera_names, self.clocks)):
            if clock.media is not None:
                folder = self.root / clock.media
                if not folder.is_dir():
                    raise InputError(folder, f"image folder for camera {cam!r} is missing (capture.toml [camera.{cam}] media)")
                self._files[k] = files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
                count = len(files)
            else:
                folder = (self.root / pattern.format(camera=cam, frame=0)).parent
                if not folder.is_dir():
                    raise InputError(folder, f"image folder for camera {cam!r} is missing")
                count = sum(1 for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
            if not timed and count > self.n_frames:
                raise InputError(folder, f"camera {cam!r} has {count} images, capture.toml says n_frames = {self.n_frames}")
            if not timed and count < self.n_frames:
                log.info("%s: camera %r has %d of %d images; the tracker goes on without it where one is missing",
                            folder, cam, count, self.n_frames)
            if timed:
                if count == 0:
                    raise InputError(folder, f"camera {cam!r} has no images")
                rate = clock.fps or fps
                if rate is None:
                    raise InputError(self.root / "capture.toml", f"camera {cam!r} has no frame rate: set fps")
                times.append(image_times(count, rate, cam))
        if timed:
            assert fps is not None
            self.pairing = pair_cameras(self.camera_names, times, self.clocks, fps, self.n_frames)
            check_pairing(self.pairing, self.root)

    def path(self, camera: str, frame: int) -> Path:
        """The image file of camera ``camera``'s own frame ``frame`` (its slot on its clock)."""
        files = self._files[self.camera_names.index(camera)]
        if files is not None:
            return files[frame]
        return self.root / self.pattern.format(camera=camera, frame=frame)

    def read(self, frame: int) -> list[np.ndarray | None]:
        return [self.read_camera(k, frame) for k in range(len(self.camera_names))]

    def read_camera(self, camera: int, frame: int) -> np.ndarray | None:
        """One camera's image of capture frame ``frame`` (``camera``: index in rig order), None
        where the camera has no frame there; cameras may be read from different threads at once."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        slot = frame if self.pairing is None else int(self.pairing.slots[camera, frame])
        if slot < 0:
            return None
        name = self.camera_names[camera]
        path = self.path(name, slot) if self._files[camera] is None or slot < len(self._files[camera] or []) else None
        try:
            if path is None:
                raise InputError(self.root, f"camera {name!r} has no image {slot}")
            image = read_image(path)
        except InputError as exc:   # this camera has no usable image here: the others go on
            self.unreadable[name][frame] = exc.problem
            return None
        return check_image_size(image, self.sizes[camera], name, path)


def check_pairing(pairing: FramePairing, root: Path) -> None:
    """Warn (logged) about each camera whose recording starts after capture frame 0 or ends
    before the last; :class:`InputError` naming ``root``'s ``capture.toml`` when no camera
    recorded the last capture frame (see :func:`~spinemocap.timebase.partial_recordings`)."""
    recorded = pairing.slots >= 0
    starts = [int(np.argmax(row)) if row.any() else pairing.n_frames for row in recorded]
    ends = [int(pairing.n_frames - np.argmax(row[::-1])) if row.any() else 0 for row in recorded]
    for line in partial_recordings(pairing.camera_names, starts, ends, pairing.n_frames, root / "capture.toml"):
        log.warning("%s: %s", root, line)


def all_default(clocks: Sequence[CameraClock], fps: float | None) -> bool:
    """Do ``clocks`` leave every camera on the capture's timing (no offset, the capture's rate or
    none given, the file pattern's media)?"""
    return all(c.offset_s == 0 and c.media is None and (c.fps is None or c.fps == fps) for c in clocks)


def _pyav(path: str | os.PathLike):
    """The PyAV module (a declared dependency; imported when a video is read or written), or an
    :class:`InputError` naming ``path`` when this installation lacks it."""
    try:
        import av
    except ImportError as exc:
        raise InputError(path, f"videos need PyAV (the package 'av'), which this installation lacks ({exc})") from None
    return av


class VideoDecoder:
    """One camera's video decoded through PyAV (FFmpeg), one frame after the other; a jump seeks
    to the key frame before and decodes forward. Planar RGB (``gbrp``, the captures' UT Video)
    is interleaved into BGR directly, without FFmpeg's colour conversion (per 2448x1600
    image, one thread: 29 CPU ms against 42 through ``bgr24``, and OpenCV's reader 30-44 ms);
    other formats go through FFmpeg's ``bgr24`` conversion. FFmpeg's own threads are off: the
    cameras are decoded in parallel. Frame ``k`` is the frame at ``k / fps`` s after the stream's
    start (``fps``: the camera's rate; None: the stream's declared rate): a dropped frame's index is
    missing, not taken by the next frame."""

    def __init__(self, path: str | os.PathLike, fps: float | None = None):
        self.path = Path(path)
        av = _pyav(self.path)
        self._errors: tuple[type[BaseException], ...] = (av.error.FFmpegError, ValueError, StopIteration)
        try:
            self._container = av.open(str(self.path))
            self._stream = self._container.streams.video[0]
        except (*self._errors, IndexError) as exc:
            raise InputError(self.path, f"video cannot be opened (corrupt or unsupported codec: {exc})") from None
        self._stream.thread_type = "NONE"
        rate, time_base = (Fraction(fps).limit_denominator(1001) if fps else
                           self._stream.average_rate or self._stream.guessed_rate), self._stream.time_base
        if not rate or not time_base:
            self.close()
            raise InputError(self.path, "video has no frame rate or time base")
        self._rate, self._time_base = Fraction(rate), Fraction(time_base)  # frames per s, s per tick
        self._start = self._stream.start_time or 0
        self._frames = self._container.decode(self._stream)
        self._next = 0
        self._buffers: list[np.ndarray] = []  # BGR arrays handed out, reused once free (_bgr)

    @property
    def fps(self) -> float:
        """The frame rate frames are indexed by, frames/s."""
        return float(self._rate)

    @property
    def n_frames(self) -> int:
        """Frames in the video (0 when the container does not say and gives no duration)."""
        if self._stream.frames:
            return int(self._stream.frames)
        if self._stream.duration is not None:
            return int(round(float(self._stream.duration * self._time_base * self._rate)))
        if self._container.duration is not None:  # microseconds (Matroska gives only this)
            return int(round(float(Fraction(self._container.duration, 1_000_000) * self._rate)))
        return 0

    def read(self, frame: int) -> np.ndarray:
        """Frame ``frame`` (0-based) as BGR uint8 (H, W, 3)."""
        try:
            back = 0  # frames before ``frame`` the last seek aimed at
            if frame != self._next:
                self._seek(frame)
            while True:
                decoded = next(self._frames)
                index = self._index(decoded)
                if index > frame and self._next == frame - back and back < frame:
                    # a seek that landed past the frame (AVI indexes a video with dropped frames
                    # by packet, not time): aim earlier, twice as far each time, and decode forward
                    back = min(frame, 2 * back or 1)
                    self._seek(frame - back)
                    continue
                if index >= frame:
                    break
        except self._errors as exc:
            why = "the video ends before it" if isinstance(exc, StopIteration) else str(exc)
            raise InputError(self.path, f"cannot decode frame {frame} ({why})") from None
        if index != frame:
            raise InputError(self.path, f"cannot decode frame {frame} (the video skips from it to frame {index})")
        self._next = frame + 1
        return self._bgr(decoded)

    def _bgr(self, decoded) -> np.ndarray:
        """``decoded`` as BGR uint8. Planar RGB is interleaved into one of the arrays this decoder
        handed out before once nothing else holds it (no reference left but the decoder's own: a
        held image, or a view of it, is never overwritten), else into a new one: a new 11.75 MB
        array costs the kernel's zeroing of its pages on every frame. (BGR frames, ``rawvideo``,
        come as a view of the frame FFmpeg read: no copy.)"""
        if decoded.format.name != "gbrp":
            return _bgr(decoded)
        shape = (decoded.height, decoded.width, 3)
        out = None
        for k in range(len(self._buffers)):
            # references: the list's and getrefcount's argument, none outside this decoder
            if sys.getrefcount(self._buffers[k]) == 2 and self._buffers[k].shape == shape:
                out = self._buffers[k]
                break
        if out is None:
            out = np.empty(shape, np.uint8)
            if len(self._buffers) < REUSED_BUFFERS:
                self._buffers.append(out)
        return _bgr(decoded, out)

    def _index(self, decoded) -> int:
        if decoded.pts is None:
            return self._next
        return int(round(float((decoded.pts - self._start) * self._time_base * self._rate)))

    def _seek(self, frame: int) -> None:
        target = self._start + int(round(frame / (self._rate * self._time_base)))
        self._container.seek(target, stream=self._stream, backward=True, any_frame=False)
        self._frames = self._container.decode(self._stream)
        self._next = frame

    def close(self) -> None:
        self._container.close()


def _bgr(decoded, out: np.ndarray | None = None) -> np.ndarray:
    """A decoded PyAV video frame as a BGR uint8 array. Planar RGB is interleaved by OpenCV,
    without FFmpeg's colour conversion, into ``out`` (H, W, 3) when given, else a new array;
    other formats go through PyAV (BGR itself: a view of the frame's memory)."""
    if decoded.format.name != "gbrp":
        return decoded.to_ndarray(format="bgr24")
    height, width = decoded.height, decoded.width
    g, b, r = (np.frombuffer(plane, np.uint8).reshape(height, plane.line_size)[:, :width] for plane in decoded.planes)
    return cv2.merge([b, g, r], out) if out is not None else cv2.merge([b, g, r])


class VideoSource(_StoredFrames, FrameSource):
    """Frames stored as one video per camera (:class:`VideoDecoder` each); sequential reads are
    cheap, jumps seek.

    ``clocks`` and ``fps`` as for :class:`ImageFolderSource`: each video's frames are placed by
    their container timestamps (:func:`~spinemocap.timebase.video_times`; ``clock.media`` names the
    file when given) and capture frame ``i`` reads each camera's frame nearest in time
    (:attr:`pairing`), None where a camera has none. Without clocks, or with default ones, frame
    ``i`` is every video's frame ``i`` (a video may hold fewer than ``n_frames``, not more).
    :attr:`dropped` lists the frames the videos lack (gaps in their timestamps), read only with
    clocks. A frame that cannot be decoded (a damaged packet, a file cut short) gives None for that
    camera and frame, recorded in :attr:`unreadable`; a video that ends early gives None after."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str,
                 sizes: Sequence[tuple[int, int]] | None = None, clocks: Sequence[CameraClock] | None = None,
                 fps: float | None = None):
        super().__init__(root, camera_names, n_frames, sizes, clocks, fps)
        clocks, timed = self.clocks, self.timed
        self.paths = [self.root / (clock.media or pattern.format(camera=cam))
                      for cam, clock in zip(self.camera_names, clocks)]
        self._rates = [clock.fps for clock in clocks]
        self._decoders: list[VideoDecoder | None] = [None] * len(self.paths)
        self._ends_at: list[int | None] = [None] * len(self.paths)  # the first slot a camera's video lacks
        try:
            times = []
            for k, (path, cam) in enumerate(zip(self.paths, self.camera_names)):
                if not path.is_file():
                    raise InputError(path, f"video for camera {cam!r} is missing")
                decoder = self._decoders[k] = VideoDecoder(path, self._rates[k])  # kept open for the reads
                if timed:
                    times.append(video_times(path, self._rates[k] or decoder.fps, cam))
                    continue
                count = decoder.n_frames
                if count and count > self.n_frames:
                    raise InputError(path, f"video has {count} frames, capture.toml says n_frames = {self.n_frames}")
                if count and count < self.n_frames:
                    log.info("%s: the video of camera %r has %d of %d frames; the tracker goes on without it after",
                                path, cam, count, self.n_frames)
                    self._ends_at[k] = count
            if timed:
                assert fps is not None
                self.pairing = pair_cameras(self.camera_names, times, clocks, fps, self.n_frames)
                check_pairing(self.pairing, self.root)
        except BaseException:
            self.close()  # the cameras' videos opened so far
            raise

    @property
    def dropped(self) -> tuple[DroppedFrames, ...]:
        return self.pairing.dropped if self.pairing is not None else ()

    def read_camera(self, camera: int, frame: int) -> np.ndarray | None:
        """One camera's image of capture frame ``frame`` (``camera``: index in rig order), None
        where the camera has no frame there. Each camera has its own decoder, so different cameras
        may be read from different threads at once (one thread per camera)."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return self._read_one(camera, frame)

    def _read_one(self, k: int, frame: int) -> np.ndarray | None:
        slot = frame if self.pairing is None else int(self.pairing.slots[k, frame])
        if slot < 0:
            return None
        name = self.camera_names[k]
        ends_at = self._ends_at[k]
        if ends_at is not None and slot >= ends_at:
            self.unreadable[name][frame] = f"the video ends at frame {ends_at}"
            return None
        decoder = self._decoders[k]
        if decoder is None:
            decoder = self._decoders[k] = VideoDecoder(self.paths[k], self._rates[k])
        try:
            image = decoder.read(slot)
        except InputError as exc:   # a damaged or missing frame: this camera sits this frame out
            self.unreadable[name][frame] = exc.problem
            if "ends before it" in exc.problem:
                self._ends_at[k] = slot if ends_at is None else min(ends_at, slot)
            return None
        return check_image_size(image, self.sizes[k], name, self.paths[k])

    def read(self, frame: int) -> list[np.ndarray | None]:
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return [self._read_one(k, frame) for k in range(len(self.paths))]

    def close(self) -> None:
        for decoder in self._decoders:
            if decoder is not None:
                decoder.close()
        self._decoders = [None] * len(self.paths)


class VideoWriter:
    """One camera's video, written through PyAV to a temporary file that :meth:`close` renames
    into place (:meth:`abort` drops it). ``codec``: one of :data:`VIDEO_CODECS` (lossless, planar
    RGB or BGR, so every BGR pixel comes back exactly; :data:`VIDEO_CODEC` by default) or of
    :data:`VIEWING_CODECS` (for watching: H.264 4:2:0, even sizes; an ``.mp4`` path starts playing
    at once). ``fps`` frames/s, ``size`` (width, height) px; read back by :class:`VideoDecoder`.
    ``audio_rate``: samples/s of a mono 16-bit PCM audio track written beside the video
    (:meth:`write_audio`; None: no audio).

    Raises:
        InputError: an unknown codec, or no PyAV.
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], codec: str = VIDEO_CODEC,
                 audio_rate: int | None = None):
        formats = {**VIDEO_CODECS, **VIEWING_CODECS}
        if codec not in formats:
            raise InputError(path, f"unknown video codec {codec!r} (choose {', '.join(formats)})")
        av = _pyav(path)
        self._place = atomic_path(path)
        tmp = self._place.__enter__()
        self._rate = Fraction(fps).limit_denominator(1001)
        try:
            fast_start = {"movflags": "+faststart"} if tmp.suffix.lower() == ".mp4" else {}
            self._container = av.open(str(tmp), "w", options=fast_start)
            self._stream = self._container.add_stream(codec, rate=self._rate)
            self._stream.width, self._stream.height = int(size[0]), int(size[1])
            self._stream.pix_fmt = formats[codec]
            if codec in VIEWING_OPTIONS:
                self._stream.options = dict(VIEWING_OPTIONS[codec])
            self._audio = None
            if audio_rate is not None:
                self._audio = self._container.add_stream("pcm_s16le", rate=int(audio_rate))
                self._audio.layout = "mono"
        except BaseException as exc:
            self._place.__exit__(type(exc), exc, exc.__traceback__)
            raise
        self._frame_type, self._audio_frame_type = av.VideoFrame, av.AudioFrame
        self._audio_written = 0

    def write(self, image_bgr: np.ndarray, slot: int | None = None) -> None:
        """Append one BGR uint8 image of the video's size; ``slot``: its place on the frame grid
        (timestamp ``slot / fps`` s; None: right after the last frame). Skipping slots leaves a
        gap in the timestamps: dropped frames."""
        frame = self._frame_type.from_ndarray(np.ascontiguousarray(image_bgr), format="bgr24")
        if slot is not None:
            frame.pts, frame.time_base = int(slot), 1 / self._rate
        self._container.mux(self._stream.encode(frame))

    def write_audio(self, samples: np.ndarray) -> None:
        """Append mono 16-bit samples (N,) to the audio track (after the ones written before;
        the first at timestamp 0). Write it in pieces as the video goes (a muxer holds packets
        until every stream has reached their time)."""
        if self._audio is None:
            raise ValueError("this video was opened without an audio track (audio_rate)")
        samples = np.ascontiguousarray(np.asarray(samples, np.int16).reshape(1, -1))
        if not samples.shape[1]:
            return
        frame = self._audio_frame_type.from_ndarray(samples, format="s16", layout="mono")
        frame.sample_rate = self._audio.rate
        frame.pts, frame.time_base = self._audio_written, Fraction(1, self._audio.rate)
        self._audio_written += samples.shape[1]
        self._container.mux(self._audio.encode(frame))

    def close(self) -> None:
        """Finish the file and rename it into place."""
        self._container.mux(self._stream.encode(None))
        if self._audio is not None:
            self._container.mux(self._audio.encode(None))
        self._container.close()
        self._place.__exit__(None, None, None)

    def abort(self) -> None:
        """Drop the unfinished file."""
        self._container.close()
        error = RuntimeError("aborted")
        self._place.__exit__(RuntimeError, error, None)
