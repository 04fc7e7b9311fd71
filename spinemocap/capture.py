"""A capture on disk, and frame sources that deliver its synchronized images.

Folder layout::

    CAPTURE/
      capture.toml          # this module's manifest (below)
      rig.toml              # cameras, see spinemocap.camera
      images/<camera>/000000.png ...      (media = "images")
      videos/<camera>.avi                 (media = "video"; lossless UT Video or uncompressed BGR, see VideoWriter;
                                           older captures: FFV1 .mkv, named in capture.toml)
      groundtruth.npz       # synthetic captures only

``capture.toml``::

    [capture]
    name = "trial01"
    fps = 100.0
    n_frames = 548
    cameras = ["cam1", "cam2", "cam3", "cam4"]
    rig = "rig.toml"
    reference = "reference.toml"                  # optional: a reference object of known geometry
    media = "images"                              # or "video"
    image_pattern = "images/{camera}/{frame:06d}.png"
    video_pattern = "videos/{camera}.avi"
    [tape]                                        # spinemocap.tape.TapeSpec fields
    n_rows = 13
    [subject]
    id = "S01"
    up = [0.0, 0.0, 1.0]        # world direction toward the head in the first frame
    facing = [0.0, -1.0, 0.0]   # world direction the subject's front faces in the first frame

A :class:`FrameSource` yields, for a frame index, one BGR ``uint8`` image per camera in rig
order. The synthetic studio provides an in-process source with the same interface, so a
benchmark can render and track without writing images to disk.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Protocol, Sequence, runtime_checkable

import cv2
import numpy as np

from .camera import Rig
from .fileio import InputError, atomic_path, read_toml, reading, write_toml
from .reference import ReferenceObject
from .tape import TapeSpec

MANIFEST = "capture.toml"
MEDIA = ("images", "video")
# New captures' videos: lossless UT Video in planar RGB (decodes ~7x cheaper than FFV1, whose
# .mkv files of older captures stay readable: the manifest names each capture's own pattern).
VIDEO_PATTERN = "videos/{camera}.avi"
VIDEO_CODEC = "utvideo"
# The lossless codecs VideoWriter writes, and the pixel format each stores BGR images in: UT Video
# (planar RGB, Huffman-coded: 0.57x the raw size on the lab-realism studio capture, ~28 CPU ms to
# decode a 2448x1600 image) or uncompressed BGR (``rawvideo``: 1.77x UT Video's size; a frame is
# the bytes read, nothing to decode)
VIDEO_CODECS = {"utvideo": "gbrp", "rawvideo": "bgr24"}
MAX_FPS = 1e5
# A VideoDecoder's BGR arrays kept for reuse once the caller drops them (a new 11.75 MB array makes
# the kernel zero its pages again on every frame): the most frames of one camera held at once
# that still reuse (the tracker's reader holds about 4: prefetched, being detected, being solved)
REUSED_BUFFERS = 6


@runtime_checkable
class FrameSource(Protocol):
    """Synchronized multi-camera frames. ``read(i)`` returns one BGR uint8 image per camera."""

    camera_names: list[str]
    n_frames: int

    def read(self, frame: int) -> list[np.ndarray]: ...


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


def to_grey(image: np.ndarray) -> np.ndarray:
    """BGR or grey uint8 image -> grey uint8 (H, W)."""
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    raise ValueError(f"expected a BGR or grey image, got shape {image.shape}")


def check_image_size(image: np.ndarray, size: tuple[int, int] | None, camera: str,
                     source: str | os.PathLike) -> np.ndarray:
    """``image`` unchanged when it is ``size`` = (width, height) px (the rig's), else
    :class:`InputError` naming ``source``: a calibration of another sensor or crop is wrong data."""
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        raise InputError(source, f"image is {image.shape[1]}x{image.shape[0]} px but the rig says camera "
                                 f"{camera!r} is {size[0]}x{size[1]} px")
    return image


class ImageFolderSource:
    """Frames stored as one image file per camera and frame. ``sizes``: the rig's (width,
    height) per camera; every image read is checked against it."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str,
                 sizes: Sequence[tuple[int, int]] | None = None):
        self.root = Path(root)
        self.camera_names = list(camera_names)
        self.n_frames = int(n_frames)
        self.pattern = pattern
        self.sizes = list(sizes) if sizes is not None else [None] * len(self.camera_names)
        for cam in self.camera_names:
            folder = (self.root / pattern.format(camera=cam, frame=0)).parent
            if not folder.is_dir():
                raise InputError(folder, f"image folder for camera {cam!r} is missing")
            count = sum(1 for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
            if count != self.n_frames:
                raise InputError(folder, f"camera {cam!r} has {count} images, capture.toml says n_frames = {self.n_frames}")

    def path(self, camera: str, frame: int) -> Path:
        return self.root / self.pattern.format(camera=camera, frame=frame)

    def read(self, frame: int) -> list[np.ndarray]:
        return [self.read_camera(k, frame) for k in range(len(self.camera_names))]

    def read_camera(self, camera: int, frame: int) -> np.ndarray:
        """One camera's image (``camera``: index in rig order); cameras may be read from
        different threads at once."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        name = self.camera_names[camera]
        path = self.path(name, frame)
        return check_image_size(read_image(path), self.sizes[camera], name, path)


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
    cameras are decoded in parallel."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        av = _pyav(self.path)
        self._errors: tuple[type[BaseException], ...] = (av.error.FFmpegError, ValueError, StopIteration)
        try:
            self._container = av.open(str(self.path))
            self._stream = self._container.streams.video[0]
        except (*self._errors, IndexError) as exc:
            raise InputError(self.path, f"video cannot be opened (corrupt or unsupported codec: {exc})") from None
        self._stream.thread_type = "NONE"
        rate, time_base = self._stream.average_rate or self._stream.guessed_rate, self._stream.time_base
        if not rate or not time_base:
            self.close()
            raise InputError(self.path, "video has no frame rate or time base")
        self._rate, self._time_base = Fraction(rate), Fraction(time_base)  # frames per s, s per tick
        self._start = self._stream.start_time or 0
        self._frames = self._container.decode(self._stream)
        self._next = 0
        self._buffers: list[np.ndarray] = []  # BGR arrays handed out, reused once free (_bgr)

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
            if frame != self._next:
                self._seek(frame)
            while True:
                decoded = next(self._frames)
                index = self._index(decoded)
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


class VideoSource:
    """Frames stored as one video per camera (:class:`VideoDecoder` each); sequential reads are
    cheap, jumps seek."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str,
                 sizes: Sequence[tuple[int, int]] | None = None):
        self.root = Path(root)
        self.camera_names = list(camera_names)
        self.n_frames = int(n_frames)
        self.sizes = list(sizes) if sizes is not None else [None] * len(camera_names)
        self.paths = [self.root / pattern.format(camera=cam) for cam in self.camera_names]
        self._decoders: list[VideoDecoder | None] = [None] * len(self.paths)
        try:
            for k, (path, cam) in enumerate(zip(self.paths, self.camera_names)):
                if not path.is_file():
                    raise InputError(path, f"video for camera {cam!r} is missing")
                decoder = self._decoders[k] = VideoDecoder(path)  # kept open for the reads
                count = decoder.n_frames
                if count and count != self.n_frames:
                    raise InputError(path, f"video has {count} frames, capture.toml says n_frames = {self.n_frames}")
        except BaseException:
            self.close()  # the cameras' videos opened so far
            raise

    def read_camera(self, camera: int, frame: int) -> np.ndarray:
        """One camera's image (``camera``: index in rig order). Each camera has its own decoder,
        so different cameras may be read from different threads at once (one thread per camera)."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return self._read_one(camera, frame)

    def _read_one(self, k: int, frame: int) -> np.ndarray:
        decoder = self._decoders[k]
        if decoder is None:
            decoder = self._decoders[k] = VideoDecoder(self.paths[k])
        image = decoder.read(frame)
        return check_image_size(image, self.sizes[k], self.camera_names[k], self.paths[k])

    def read(self, frame: int) -> list[np.ndarray]:
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return [self._read_one(k, frame) for k in range(len(self.paths))]

    def close(self) -> None:
        for decoder in self._decoders:
            if decoder is not None:
                decoder.close()
        self._decoders = [None] * len(self.paths)


class VideoWriter:
    """One camera's lossless video (``codec``: one of :data:`VIDEO_CODECS`, :data:`VIDEO_CODEC`
    by default; planar RGB or BGR, so every BGR pixel comes back exactly), written through PyAV to
    a temporary file that :meth:`close` renames into place (:meth:`abort` drops it). ``fps``
    frames/s, ``size`` (width, height) px; read back by :class:`VideoDecoder`."""

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], codec: str = VIDEO_CODEC):
        if codec not in VIDEO_CODECS:
            raise InputError(path, f"unknown video codec {codec!r} (choose {', '.join(VIDEO_CODECS)})")
        av = _pyav(path)
        self._place = atomic_path(path)
        tmp = self._place.__enter__()
        try:
            self._container = av.open(str(tmp), "w")
            self._stream = self._container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
            self._stream.width, self._stream.height = int(size[0]), int(size[1])
            self._stream.pix_fmt = VIDEO_CODECS[codec]
        except BaseException as exc:
            self._place.__exit__(type(exc), exc, exc.__traceback__)
            raise
        self._frame_type = av.VideoFrame

    def write(self, image_bgr: np.ndarray) -> None:
        """Append one BGR uint8 image of the video's size."""
        frame = self._frame_type.from_ndarray(np.ascontiguousarray(image_bgr), format="bgr24")
        self._container.mux(self._stream.encode(frame))

    def close(self) -> None:
        """Finish the file and rename it into place."""
        self._container.mux(self._stream.encode(None))
        self._container.close()
        self._place.__exit__(None, None, None)

    def abort(self) -> None:
        """Drop the unfinished file."""
        self._container.close()
        error = RuntimeError("aborted")
        self._place.__exit__(RuntimeError, error, None)


@dataclass
class Capture:
    """A capture folder opened for reading: manifest, rig, tape and a frame source."""

    root: Path
    name: str
    fps: float
    n_frames: int
    rig: Rig
    tape: TapeSpec
    subject: dict = field(default_factory=dict)
    media: str = "images"
    image_pattern: str = "images/{camera}/{frame:06d}.png"
    video_pattern: str = "videos/{camera}.mkv"
    rig_file: str = "rig.toml"
    reference_file: str | None = None

    @property
    def camera_names(self) -> list[str]:
        return self.rig.names

    @property
    def up(self) -> np.ndarray:
        """Unit world direction toward the subject's head in the first frame."""
        v = np.asarray(self.subject.get("up", (0.0, 0.0, 1.0)), float)
        return v / np.linalg.norm(v)

    @property
    def facing(self) -> np.ndarray:
        """Unit world direction the subject's front faces in the first frame."""
        v = np.asarray(self.subject.get("facing", (0.0, -1.0, 0.0)), float)
        return v / np.linalg.norm(v)

    @property
    def groundtruth_path(self) -> Path:
        return self.root / "groundtruth.npz"

    @property
    def has_groundtruth(self) -> bool:
        return self.groundtruth_path.is_file()

    def groundtruth(self) -> dict[str, np.ndarray]:
        """The synthetic studio's exact answers (``groundtruth.npz``; keys as
        :attr:`spinemocap.synth.Scene.groundtruth`: ``labels`` (D,), ``dots`` (F, D, 3) mm,
        ``visible`` (F, C, D), ``keypoints``, ``row_levels``, ...). The one reader of that file."""
        path = self.groundtruth_path
        if not path.is_file():
            raise InputError(path, "no ground truth (groundtruth.npz) in this capture; "
                             "only synthetic captures have it -- use --source tracked")
        try:
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        except Exception as exc:  # zipfile, pickle and numpy raise many types for a damaged file
            raise InputError(path, f"unreadable ground truth ({type(exc).__name__}: {exc})") from exc

    def row_levels(self) -> list[str] | None:
        """The vertebral level under each tape row from the ground truth (synthetic captures), else None."""
        if not self.has_groundtruth:
            return None
        gt = self.groundtruth()
        return [str(x) for x in gt["row_levels"]] if "row_levels" in gt else None

    def reference(self) -> ReferenceObject | None:
        """The reference object named by ``[capture] reference`` (see :mod:`spinemocap.reference`),
        or None when the manifest names none; :class:`InputError` naming the file when it is missing
        or wrong."""
        if self.reference_file is None:
            return None
        path = self.root / self.reference_file
        if not path.is_file():
            raise InputError(self.root / MANIFEST, f"reference = {self.reference_file!r}: no such file in {self.root}")
        return ReferenceObject.from_toml(path)

    def frame_source(self) -> FrameSource:
        """The capture's frames; every image is checked against its camera's size in the rig."""
        sizes = [cam.size for cam in self.rig]
        if self.media == "images":
            return ImageFolderSource(self.root, self.camera_names, self.n_frames, self.image_pattern, sizes)
        if self.media == "video":
            return VideoSource(self.root, self.camera_names, self.n_frames, self.video_pattern, sizes)
        raise InputError(self.root / MANIFEST, f"unknown media {self.media!r} (expected 'images' or 'video')")

    @classmethod
    def open(cls, root: str | os.PathLike) -> "Capture":
        """Open a capture folder; :class:`InputError` naming the file for anything missing,
        mistyped or impossible in ``capture.toml`` or the rig (see :func:`capture_settings`)."""
        root = Path(root)
        manifest = root / MANIFEST
        if not root.is_dir():
            raise InputError(root, "capture folder not found")
        if not manifest.is_file():
            raise InputError(root, f"not a capture folder (no {MANIFEST})")
        data = read_toml(manifest)
        with reading(manifest, MANIFEST):
            settings = capture_settings(data, manifest)
        if not (root / settings["rig_file"]).is_file():
            raise InputError(manifest, f"rig = {settings['rig_file']!r}: no such file in {root}")
        rig = Rig.from_toml(root / settings["rig_file"])
        absent = [c for c in settings["cameras"] if c not in rig.names]
        if absent:
            raise InputError(manifest, f"cameras {absent} are not in the rig file {settings['rig_file']} "
                                       f"(rig has {rig.names})")
        tape = data.get("tape", {})
        if not isinstance(tape, dict):
            raise InputError(manifest, "[tape] must be a table")
        return cls(root=root, rig=rig.subset(settings.pop("cameras")),
                   tape=TapeSpec.from_dict(tape, source=str(manifest)), **settings)

    def save(self) -> None:
        """Write ``capture.toml`` and the rig file into :attr:`root` (atomically)."""
        self.root.mkdir(parents=True, exist_ok=True)
        self.rig.to_toml(self.root / self.rig_file)
        write_toml(
            self.root / MANIFEST,
            {
                "capture": {
                    "name": self.name, "fps": self.fps, "n_frames": self.n_frames,
                    "cameras": self.camera_names, "rig": self.rig_file, "media": self.media,
                    "image_pattern": self.image_pattern, "video_pattern": self.video_pattern,
                    **({"reference": self.reference_file} if self.reference_file else {}),
                },
                "tape": self.tape.to_dict(),
                "subject": self.subject,
            },
        )


# ---------------------------------------------------------------------------------- validation
def _typed(section: dict, key: str, kinds: tuple[type, ...], default=None, table: str = "capture"):
    value = section.get(key, default)
    if not isinstance(value, kinds) or isinstance(value, bool):
        names = {int: "number", float: "number", str: "string", list: "list"}
        wanted = " or ".join(dict.fromkeys(names.get(k, k.__name__) for k in kinds))
        raise InputError(None, f"[{table}] {key} must be a {wanted}, got {value!r}")
    return value


def unit_direction(value, what: str) -> np.ndarray:
    """A non-zero finite 3-vector, normalised; ValueError naming ``what`` otherwise."""
    try:
        v = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{what} must be three numbers, got {value!r}") from None
    norm = float(np.linalg.norm(v)) if np.isfinite(v).all() else float("nan")
    if not (np.isfinite(norm) and norm > 1e-9 * max(float(np.abs(v).max()), 1.0) and norm > 0):
        raise ValueError(f"{what} = {value!r} must be a finite, non-zero direction")
    return v / norm


def subject_problems(subject: dict) -> list[str]:
    """``[subject]``: ``up`` and ``facing`` finite, non-zero and not parallel (the angles'
    neutral frame needs both); ``id`` a string."""
    out = []
    if not isinstance(subject, dict):
        return ["[subject] must be a table"]
    directions = {}
    for key, default in (("up", (0.0, 0.0, 1.0)), ("facing", (0.0, -1.0, 0.0))):
        try:
            directions[key] = unit_direction(subject.get(key, default), f"[subject] {key}")
        except ValueError as exc:
            out.append(str(exc))
    if len(directions) == 2 and abs(float(directions["up"] @ directions["facing"])) > 0.99:
        out.append("[subject] up and facing must not be parallel")
    if not isinstance(subject.get("id", ""), (str, int)):
        out.append(f"[subject] id must be a string, got {subject.get('id')!r}")
    return out


def capture_settings(data: dict, manifest: Path) -> dict:
    """The checked ``[capture]`` and ``[subject]`` values of a ``capture.toml`` as
    :class:`Capture` fields (plus ``cameras``): types, a whole positive frame count, a finite
    positive frame rate, unique camera names, known media, usable file patterns, sane subject
    directions. :class:`InputError` naming ``manifest`` otherwise."""
    section = data.get("capture")
    if not isinstance(section, dict):
        raise InputError(manifest, "missing [capture] table")
    for key in ("fps", "n_frames", "cameras"):
        if key not in section:
            raise InputError(manifest, f"[capture] lacks {key!r}")
    try:
        fps = float(_typed(section, "fps", (int, float)))
        n_frames = _typed(section, "n_frames", (int, float))
        cameras = _typed(section, "cameras", (list,))
        rig_file = _typed(section, "rig", (str,), "rig.toml")
        media = _typed(section, "media", (str,), "images")
        name = _typed(section, "name", (str, int), manifest.parent.name)
        reference = _typed(section, "reference", (str,), "") or None
        patterns = {key: _typed(section, key, (str,), getattr(Capture, key))
                    for key in ("image_pattern", "video_pattern")}
    except InputError as exc:
        raise InputError(manifest, exc.problem) from None
    problems = []
    if not (np.isfinite(fps) and 0 < fps <= MAX_FPS):
        problems.append(f"fps = {fps} must be finite, positive and at most {MAX_FPS:g}")
    if not (float(n_frames).is_integer() and n_frames >= 1):
        problems.append(f"n_frames = {n_frames!r} must be a whole number >= 1")
    if not cameras or not all(isinstance(c, str) and c for c in cameras):
        problems.append(f"cameras must be a non-empty list of camera names, got {cameras!r}")
    elif len(set(cameras)) != len(cameras):
        problems.append(f"cameras lists a name twice: {cameras}")
    if media not in MEDIA:
        problems.append(f"unknown media {media!r} (expected one of {MEDIA})")
    for key, pattern in patterns.items():
        try:
            pattern.format(camera="cam", frame=0)
        except (KeyError, IndexError, ValueError, AttributeError) as exc:
            problems.append(f"{key} {pattern!r} is not a usable file pattern ({type(exc).__name__}: {exc}); "
                            "use the fields {camera} and {frame}")
    problems += subject_problems(data.get("subject", {}))
    if problems:
        raise InputError(manifest, "; ".join(problems))
    return {"name": str(name), "fps": fps, "n_frames": int(n_frames), "cameras": list(cameras),
            "subject": dict(data.get("subject", {})), "media": media, "rig_file": rig_file,
            "reference_file": reference, **patterns}
