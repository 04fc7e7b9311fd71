"""A capture on disk: its manifest, rig and tape, and the frame source that delivers its images
(the sources themselves are in :mod:`spinemocap.media`).

Folder layout::

    CAPTURE/
      capture.toml          # this module's manifest (below)
      rig.toml              # cameras, see spinemocap.camera
      images/<camera>/000000.png ...      (media = "images")
      videos/<camera>.avi                 (media = "video"; lossless UT Video or uncompressed BGR, see VideoWriter;
                                           older captures: FFV1 .mkv, named in capture.toml)
      groundtruth.npz       # synthetic captures only

``capture.toml`` (every key, its unit, default and meaning: ``docs/CAPTURE.md``)::

    [capture]
    name = "trial01"
    fps = 100.0                 # the capture's clock: frame i at start_s + i / fps s
    n_frames = 548              # optional: the span every camera recorded
    cameras = ["cam1", "cam2", "cam3", "cam4"]
    rig = "rig.toml"
    reference = "reference.toml"                  # optional: a reference object of known geometry
    media = "images"                              # or "video"
    image_pattern = "images/{camera}/{frame:06d}.png"
    video_pattern = "videos/{camera}.avi"
    [camera.cam2]               # optional, per camera: its own media, clock offset and rate
    media = "videos/cam2.mp4"
    offset_s = 0.0123
    [tape]                                        # spinemocap.tape.TapeSpec fields
    n_rows = 13
    [subject]
    id = "S01"
    up = [0.0, 0.0, 1.0]        # world direction toward the head in the first frame
    facing = [0.0, -1.0, 0.0]   # world direction the subject's front faces in the first frame

Unknown tables and keys are refused, naming the valid ones.

A :class:`~spinemocap.media.FrameSource` yields, for a frame index, one BGR ``uint8`` image per
camera in rig order. The synthetic studio provides an in-process source with the same interface, so
a benchmark can render and track without writing images to disk.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from .camera import Rig
from .fileio import InputError, read_toml, reading, write_toml
from .media import (  # noqa: F401  (moved to media; re-exported for existing importers)
    REUSED_BUFFERS,
    VIDEO_CODEC,
    VIDEO_CODECS,
    FrameSource,
    ImageFolderSource,
    VideoDecoder,
    VideoSource,
    VideoWriter,
    _bgr,
    _pyav,
    all_default,
    check_image_size,
    read_image,
)
from .reference import ReferenceObject
from .tape import TapeSpec
from .timebase import CameraClock, MediaTimes, common_frames, image_times, partial_recordings, shared_span, video_times

log = logging.getLogger(__name__)

MANIFEST = "capture.toml"
MEDIA = ("images", "video")
# New captures' videos: lossless UT Video in planar RGB (decodes ~7x cheaper than FFV1, whose
# .mkv files of older captures stay readable: the manifest names each capture's own pattern).
VIDEO_PATTERN = "videos/{camera}.avi"
MAX_FPS = 1e5


def to_grey(image: np.ndarray) -> np.ndarray:
    """BGR or grey uint8 image -> grey uint8 (H, W)."""
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    raise ValueError(f"expected a BGR or grey image, got shape {image.shape}")


# The tables a capture.toml may hold, and the keys of each (anything else is refused, naming these)
CAPTURE_KEYS = ("name", "fps", "n_frames", "cameras", "rig", "reference", "media", "image_pattern",
                "video_pattern", "start_s", "external_media", "force_fps", "detector_weights")
CAMERA_KEYS = ("media", "offset_s", "fps")
SUBJECT_KEYS = ("id", "up", "facing", "age", "sex", "height_m", "mass_kg", "phenotype", "skin_tone",
                "tape_start", "notes")
TABLES = ("capture", "tape", "subject", "camera", "levels")
# Two rates are the same rate within this fraction (a camera's 29.97 frames/s against 30)
RATE_TOLERANCE = 0.01
# Calibration files other systems write, which a capture names only once converted to a rig TOML
FOREIGN_CALIBRATIONS = {".qca.txt": "Qualisys", ".xcp": "Vicon"}


@dataclass
class Capture:
    """A capture folder opened for reading: manifest, rig, tape, the cameras' clocks and a frame
    source. ``docs/CAPTURE.md`` describes every key of ``capture.toml``.

    ``n_frames``: capture frames (frame ``i`` at ``start_s + i / fps`` s on the capture's clock);
    a camera whose recording starts later or ends earlier reads None for the frames it lacks (the
    other cameras are tracked there);
    ``camera_clocks``: the ``[camera.<name>]`` tables as given (cameras without one are on the
    capture's timing); ``start_s``: where capture frame 0 lies on the cameras' clocks, s;
    ``external_media``: paths may lead outside the folder; ``force_fps``: ``fps`` is used even
    where the videos say another rate; ``detector_weights``: the tape network's weights to detect
    this capture with (:attr:`detector_weights_path`; None: the shipped ones);
    ``spans_recordings``: ``n_frames`` is not written but found
    on opening (the span every camera recorded, which follows the offsets)."""

    root: Path
    name: str
    fps: float
    n_frames: int
    rig: Rig
    tape: TapeSpec
    subject: dict = field(default_factory=dict)
    media: str = "images"
    image_pattern: str = "images/{camera}/{frame:06d}.png"
    video_pattern: str = VIDEO_PATTERN
    rig_file: str = "rig.toml"
    reference_file: str | None = None
    detector_weights: str | None = None
    camera_clocks: dict[str, CameraClock] = field(default_factory=dict)
    start_s: float = 0.0
    external_media: bool = False
    force_fps: bool = False
    spans_recordings: bool = False

    @property
    def camera_names(self) -> list[str]:
        return self.rig.names

    @property
    def clocks(self) -> list[CameraClock]:
        """Each camera's clock in rig order (:class:`~spinemocap.timebase.CameraClock`) against
        the clock on which capture frame ``i`` is at ``i / fps`` s: the ``[camera.<name>]``
        ``offset_s`` plus ``start_s``, the camera's own ``fps`` (None: the capture's) and ``media``."""
        return [replace(self.camera_clocks.get(name, CameraClock()),
                        offset_s=self.camera_clocks.get(name, CameraClock()).offset_s + self.start_s)
                for name in self.camera_names]

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
                             "only synthetic captures have it; use the tracked markers instead")
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

    @property
    def detector_weights_path(self) -> Path | None:
        """The network weights ``[capture] detector_weights`` names (relative to the capture folder
        or absolute), or None (the shipped weights); :class:`InputError` naming ``capture.toml``
        when the file is missing."""
        if not self.detector_weights:
            return None
        path = self.root / self.detector_weights
        if not path.is_file():
            raise InputError(self.root / MANIFEST, f"detector_weights = {self.detector_weights!r}: no such file; "
                                                   "name the weights.pt that 'spinemocap detector adapt' wrote, "
                                                   "or remove the key to use the shipped weights")
        return path

    def media_path(self, camera: str) -> Path:
        """Camera ``camera``'s video file or image folder: its ``[camera.<name>] media``, else the
        capture's pattern (an image folder: the folder of its first image)."""
        clock = self.camera_clocks.get(camera)
        if clock is not None and clock.media is not None:
            return self.root / clock.media
        if self.media == "video":
            return self.root / self.video_pattern.format(camera=camera)
        return (self.root / self.image_pattern.format(camera=camera, frame=0)).parent

    def frame_source(self) -> FrameSource:
        """The capture's frames; every image is checked against its camera's size in the rig.
        Cameras are paired by time (:attr:`clocks`) where a camera's timing or media differs from
        the capture's, or the capture covers a part of the recordings; else frame ``i`` is every
        camera's frame ``i``."""
        sizes = [cam.size for cam in self.rig]
        clocks = self._source_clocks()
        if self.media == "images":
            return ImageFolderSource(self.root, self.camera_names, self.n_frames, self.image_pattern, sizes, clocks,
                                     self.fps)
        if self.media == "video":
            return VideoSource(self.root, self.camera_names, self.n_frames, self.video_pattern, sizes, clocks, self.fps)
        raise InputError(self.root / MANIFEST, f"unknown media {self.media!r} (expected 'images' or 'video')")

    def _source_clocks(self) -> list[CameraClock] | None:
        """:attr:`clocks` for the frame source: None where every camera's frame ``i`` is capture
        frame ``i`` (default timing: a camera holding fewer frames reads None for the ones it
        lacks, see :meth:`check_recordings`); else clocks that name every camera's media, so that
        the source pairs the frames by time."""
        clocks = self.clocks
        if all_default(clocks, self.fps):
            return None
        return [replace(clock, media=clock.media or str(self.media_path(name).relative_to(self.root)))
                for name, clock in zip(self.camera_names, clocks)]

    def recorded_frames(self) -> tuple[list[int], list[int]]:
        """Default timing (frame ``i`` of a camera is capture frame ``i``): per camera (rig order)
        its first recorded frame and the frame after its last. Numbered images: their lowest and
        highest numbers; a video: 0 and its count (``n_frames`` where its header does not say);
        other images: 0 and their count."""
        counts = self.media_counts()
        starts, ends = [], []
        for name in self.camera_names:
            numbers = self._image_numbers(name) if self.media == "images" else []
            if numbers:
                starts.append(min(numbers))
                ends.append(max(numbers) + 1)
            else:
                starts.append(0)
                ends.append(counts[name] or (self.n_frames if self.media == "video" else 0))
        return starts, ends

    def _image_numbers(self, name: str) -> list[int]:
        """The frame numbers of camera ``name``'s images that follow the image pattern (empty where
        the pattern has no ``{frame}`` or the folder is missing)."""
        if "{frame" not in self.image_pattern:
            return []
        sentinel = 987654321
        expected = Path(self.image_pattern.format(camera=name, frame=sentinel))
        before, _, after = expected.name.partition(str(sentinel))
        folder = self.root / expected.parent
        if not folder.is_dir():
            return []
        numbered = re.compile(re.escape(before) + r"(\d+)" + re.escape(after) + "$")
        out = []
        for entry in os.scandir(folder):
            match = numbered.match(entry.name)
            if match and self.image_pattern.format(camera=name, frame=int(match.group(1))) == str(
                    expected.parent / entry.name):
                out.append(int(match.group(1)))
        return out

    def check_recordings(self) -> list[str]:
        """Cameras whose recordings do not cover every capture frame, one line each (warned by
        :meth:`open`): the others carry those frames. :class:`InputError` naming ``capture.toml``
        when ``n_frames`` exceeds every camera's recording. Default timing only (paired
        cameras are checked by their frame source); missing media are left to the frame source."""
        if not all_default(self.clocks, self.fps):
            return []
        starts, ends = self.recorded_frames()
        recorded = [k for k, end in enumerate(ends) if end > 0]
        if not recorded:
            return []
        return partial_recordings([self.camera_names[k] for k in recorded], [starts[k] for k in recorded],
                                  [ends[k] for k in recorded], self.n_frames, self.root / MANIFEST)

    def media_counts(self) -> dict[str, int]:
        """Frames each camera's media holds (images in its folder; a video's count from its header,
        0 where the header does not say), by camera name; missing media count 0."""
        out = {}
        for name in self.camera_names:
            path = self.media_path(name)
            if self.media == "images":
                out[name] = (sum(1 for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
                             if path.is_dir() else 0)
            elif path.is_file():
                decoder = VideoDecoder(path, self.camera_clocks.get(name, CameraClock()).fps)
                try:
                    out[name] = decoder.n_frames
                finally:
                    decoder.close()
            else:
                out[name] = 0
        return out

    def media_times(self) -> list[MediaTimes]:
        """Each camera's recorded frames on its own clock (rig order): a video's container
        timestamps, an image folder's ``index / fps``. :class:`InputError` naming a missing file."""
        out = []
        counts = self.media_counts() if self.media == "images" else {}
        for name, clock in zip(self.camera_names, self.clocks):
            path = self.media_path(name)
            rate = clock.fps or self.fps
            if self.media == "video":
                if not path.is_file():
                    raise InputError(path, f"video for camera {name!r} is missing")
                out.append(video_times(path, clock.fps, name))
            else:
                if not counts[name]:
                    raise InputError(path, f"image folder for camera {name!r} is missing or empty")
                out.append(image_times(counts[name], rate, name))
        return out

    def check_rates(self) -> None:
        """Every video's own rate (its header's) against the rate the capture gives its camera
        (``[camera.<name>] fps``, else ``[capture] fps``): :class:`InputError` naming
        ``capture.toml`` on a mismatch unless ``force_fps``. Missing videos are left to the frame
        source."""
        if self.media != "video" or self.force_fps:
            return
        for name in self.camera_names:
            path = self.media_path(name)
            if not path.is_file():
                continue
            decoder = VideoDecoder(path)
            try:
                own = decoder.fps
            finally:
                decoder.close()
            given = self.camera_clocks.get(name, CameraClock()).fps
            said = given or self.fps
            if abs(own - said) > RATE_TOLERANCE * own:
                where = f"[camera.{name}] fps = {said:g}" if given else f"fps = {said:g}"
                raise InputError(self.root / MANIFEST,
                                 f"{where} but camera {name!r}'s video {path.name} runs at {own:g} frames/s: "
                                 f"the markers would be timed wrong. Set {where.split(' =')[0]} = {own:g}, or give "
                                 f"[camera.{name}] fps = {own:g} to pair its frames by time with a capture at "
                                 f"{self.fps:g} frames/s, or force_fps = true in [capture] to use {said:g} anyway")

    @classmethod
    def open(cls, root: str | os.PathLike) -> "Capture":
        """Open a capture folder; :class:`InputError` naming the file for anything missing,
        mistyped, unknown or impossible in ``capture.toml`` or the rig (see
        :func:`capture_settings`), a path leading outside the folder (unless ``external_media``),
        a video whose rate is not the capture's (:meth:`check_rates`), or an ``n_frames`` beyond
        every camera's recording (:meth:`check_recordings`; a camera that starts late or ends early
        is a logged warning). Without ``n_frames`` the capture spans the frames at least two
        cameras recorded (on the capture's clock; :func:`~spinemocap.timebase.common_frames`)."""
        root = Path(root)
        manifest = root / MANIFEST
        if not root.is_dir():
            raise InputError(root, "capture folder not found")
        if not manifest.is_file():
            raise InputError(root, f"not a capture folder (no {MANIFEST})")
        data = read_toml(manifest)
        with reading(manifest, MANIFEST):
            settings = capture_settings(data, manifest)
        rig = _open_rig(root, manifest, settings["rig_file"], settings["external_media"])
        absent = [c for c in settings["cameras"] if c not in rig.names]
        if absent:
            raise InputError(manifest, f"cameras {absent} are not in the rig file {settings['rig_file']} "
                                       f"(rig has {rig.names})")
        unknown = sorted(set(settings["camera_clocks"]) - set(settings["cameras"]))
        if unknown:
            raise InputError(manifest, f"[camera.{unknown[0]}]: no such camera in cameras = {settings['cameras']}")
        tape = data.get("tape", {})
        if not isinstance(tape, dict):
            raise InputError(manifest, "[tape] must be a table")
        n_frames = settings.pop("n_frames")
        capture = cls(root=root, rig=rig.subset(settings.pop("cameras")), n_frames=n_frames or 1,
                      tape=TapeSpec.from_dict(tape, source=str(manifest)), **settings)
        capture._check_paths()
        capture.check_rates()
        if n_frames is None:
            capture.spans_recordings = True
            if capture.media == "images" and all_default(capture.clocks, capture.fps):  # numbered: by their numbers
                capture.n_frames = shared_span(capture.recorded_frames()[1])
            else:
                capture.n_frames = common_frames(capture.media_times(), capture.clocks, capture.fps)
        for line in capture.check_recordings():
            log.warning("%s: %s", capture.root, line)
        return capture

    def _check_paths(self) -> None:
        """Every path the manifest names stays inside the folder unless ``external_media``."""
        if self.external_media:
            return
        named = {f"rig = {self.rig_file!r}": self.root / self.rig_file}
        if self.reference_file:
            named[f"reference = {self.reference_file!r}"] = self.root / self.reference_file
        for name in self.camera_names:
            clock = self.camera_clocks.get(name)
            key = f"[camera.{name}] media" if clock is not None and clock.media else f"{self.media} pattern"
            named[f"{key} ({self.media_path(name)})"] = self.media_path(name)
        for what, path in named.items():
            if not _inside(path, self.root):
                raise InputError(self.root / MANIFEST,
                                 f"{what} leads outside the capture folder; set external_media = true in [capture] "
                                 "if this capture is meant to use files kept elsewhere")

    def save(self) -> None:
        """Write ``capture.toml`` and the rig file into :attr:`root` (atomically)."""
        self.root.mkdir(parents=True, exist_ok=True)
        self.rig.to_toml(self.root / self.rig_file)
        write_toml(self.root / MANIFEST, self.manifest())

    def manifest(self) -> dict:
        """The contents of ``capture.toml`` (keys left out where they hold their default)."""
        options = {"start_s": self.start_s, "external_media": self.external_media, "force_fps": self.force_fps}
        cameras = {name: _clock_table(self.camera_clocks[name]) for name in self.camera_names
                   if name in self.camera_clocks and _clock_table(self.camera_clocks[name])}
        return {
            "capture": {
                "name": self.name, "fps": self.fps, **({} if self.spans_recordings else {"n_frames": self.n_frames}),
                "cameras": self.camera_names, "rig": self.rig_file, "media": self.media,
                "image_pattern": self.image_pattern, "video_pattern": self.video_pattern,
                **({"reference": self.reference_file} if self.reference_file else {}),
                **({"detector_weights": self.detector_weights} if self.detector_weights else {}),
                **{k: v for k, v in options.items() if v},
            },
            **({"camera": cameras} if cameras else {}),
            "tape": self.tape.to_dict(),
            "subject": self.subject,
        }


def set_camera_offsets(root: str | os.PathLike, offsets: dict[str, float]) -> Path:
    """Write ``offset_s`` (s, the camera's clock minus the capture's, not counting ``start_s``)
    into the ``[camera.<name>]`` tables of the capture folder ``root``'s ``capture.toml``, keeping
    everything else; returns the manifest's path. :class:`InputError` naming the manifest for a
    camera the capture lacks or an offset that is not a finite number."""
    manifest = Path(root) / MANIFEST
    data = read_toml(manifest)
    with reading(manifest, MANIFEST):
        cameras = capture_settings(data, manifest)["cameras"]
    tables = data.setdefault("camera", {})
    for name, offset in offsets.items():
        if name not in cameras:
            raise InputError(manifest, f"no camera {name!r} in this capture (it has {cameras})")
        if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not np.isfinite(offset):
            raise InputError(manifest, f"offset of camera {name!r} must be a finite number of seconds, got {offset!r}")
        tables.setdefault(name, {})["offset_s"] = float(offset)
    write_toml(manifest, data)
    return manifest


def set_detector_weights(root: str | os.PathLike, weights: str | os.PathLike) -> Path:
    """Name ``weights`` (a network weights file) as ``[capture] detector_weights`` in the capture
    folder ``root``'s ``capture.toml``, keeping everything else: relative to the folder when it lies
    inside it, else absolute. Returns the manifest's path; :class:`InputError` naming the manifest
    when it is not a valid one."""
    manifest = Path(root) / MANIFEST
    data = read_toml(manifest)
    with reading(manifest, MANIFEST):
        capture_settings(data, manifest)
    path = Path(weights).resolve()
    folder = Path(root).resolve()
    data["capture"]["detector_weights"] = str(path.relative_to(folder)) if _inside(path, folder) else str(path)
    write_toml(manifest, data)
    return manifest


def _clock_table(clock: CameraClock) -> dict:
    """A ``[camera.<name>]`` table: the values that differ from the defaults."""
    table = {"media": clock.media, "offset_s": clock.offset_s or None, "fps": clock.fps}
    return {k: v for k, v in table.items() if v is not None}


def _inside(path: Path, root: Path) -> bool:
    """Does ``path``, as written (``..`` and absolute paths taken at their word; a symbolic link
    placed inside the folder is the folder's own), lie inside ``root``?"""
    return os.path.commonpath([os.path.abspath(path), os.path.abspath(root)]) == os.path.abspath(root)


def _open_rig(root: Path, manifest: Path, rig_file: str, external: bool) -> Rig:
    """The rig named by ``rig``: a rig TOML (see :mod:`spinemocap.camera`); another system's
    calibration is refused with the command that converts it."""
    path = root / rig_file
    kind = next((name for suffix, name in FOREIGN_CALIBRATIONS.items() if rig_file.lower().endswith(suffix)), None)
    if kind is not None:
        raise InputError(manifest, f"rig = {rig_file!r} is a {kind} calibration, and a capture's rig is a rig TOML: "
                                   f"convert it with `spinemocap calibrate convert {path} {root / 'rig.toml'}` and set "
                                   "rig = \"rig.toml\" (or build the capture with `spinemocap capture init`, which "
                                   "converts it)")
    if not path.is_file():
        raise InputError(manifest, f"rig = {rig_file!r}: no such file in {root}")
    return Rig.from_toml(path)


# ---------------------------------------------------------------------------------- validation
def _typed(section: dict, key: str, kinds: tuple[type, ...], default=None, table: str = "capture"):
    value = section.get(key, default)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = {int: "number", float: "number", str: "string", list: "list", bool: "true or false"}
        wanted = " or ".join(dict.fromkeys(names.get(k, k.__name__) for k in kinds))
        raise InputError(None, f"[{table}] {key} must be a {wanted}, got {value!r}")
    return value


def unknown_keys(table: dict, valid: Sequence[str], name: str) -> list[str]:
    """One problem per key of ``table`` not in ``valid``, naming the valid ones."""
    return [f"unknown key {key!r} in [{name}] (valid keys: {', '.join(valid)})" for key in table if key not in valid]


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
    """``[subject]``: only its known keys; ``up`` and ``facing`` finite, non-zero and not
    parallel (the angles' neutral frame needs both); ``id`` a string."""
    out = []
    if not isinstance(subject, dict):
        return ["[subject] must be a table"]
    out += unknown_keys(subject, SUBJECT_KEYS, "subject")
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


def camera_clocks(tables, problems: list[str]) -> dict[str, CameraClock]:
    """The ``[camera.<name>]`` tables as clocks by camera name; their problems appended to
    ``problems`` (unknown keys, a media that is not a path, an offset or rate that is not a finite
    number, a rate that is not positive)."""
    if not isinstance(tables, dict) or not all(isinstance(t, dict) for t in tables.values()):
        problems.append("[camera] must hold one table per camera: [camera.<name>] with media, offset_s, fps")
        return {}
    out = {}
    for name, table in tables.items():
        here = f"camera.{name}"
        problems += unknown_keys(table, CAMERA_KEYS, here)
        try:
            media = _typed(table, "media", (str,), "", here) or None
            offset = float(_typed(table, "offset_s", (int, float), 0.0, here))
            rate = table.get("fps")
            rate = None if rate is None else float(_typed(table, "fps", (int, float), None, here))
        except InputError as exc:
            problems.append(exc.problem)
            continue
        if not np.isfinite(offset):
            problems.append(f"[{here}] offset_s = {offset} must be a finite number of seconds")
        if rate is not None and not (np.isfinite(rate) and 0 < rate <= MAX_FPS):
            problems.append(f"[{here}] fps = {rate} must be finite, positive and at most {MAX_FPS:g}")
        out[str(name)] = CameraClock(offset_s=offset, fps=rate, media=media)
    return out


def capture_settings(data: dict, manifest: Path) -> dict:
    """The checked values of a ``capture.toml`` as :class:`Capture` fields (plus ``cameras``;
    ``n_frames`` None where the manifest leaves it to the media): known tables and keys only,
    types, a whole positive frame count, a finite positive frame rate, unique camera names, known
    media, usable file patterns, camera clocks, sane subject directions. :class:`InputError`
    naming ``manifest`` otherwise, listing every problem found and the valid keys."""
    section = data.get("capture")
    if not isinstance(section, dict):
        raise InputError(manifest, "missing [capture] table")
    problems = [f"unknown table [{key}] (valid tables: {', '.join(TABLES)})" for key in data if key not in TABLES]
    problems += unknown_keys(section, CAPTURE_KEYS, "capture")
    for key in ("fps", "cameras"):
        if key not in section:
            problems.append(f"[capture] lacks {key!r}")
    if problems:
        raise InputError(manifest, "; ".join(problems))
    try:
        fps = float(_typed(section, "fps", (int, float)))
        n_frames = _typed(section, "n_frames", (int, float), 1)
        cameras = _typed(section, "cameras", (list,))
        rig_file = _typed(section, "rig", (str,), "rig.toml")
        media = _typed(section, "media", (str,), "images")
        name = _typed(section, "name", (str, int), manifest.parent.name)
        reference = _typed(section, "reference", (str,), "") or None
        detector_weights = _typed(section, "detector_weights", (str,), "") or None
        start_s = float(_typed(section, "start_s", (int, float), 0.0))
        flags = {key: _typed(section, key, (bool,), False) for key in ("external_media", "force_fps")}
        patterns = {key: _typed(section, key, (str,), getattr(Capture, key))
                    for key in ("image_pattern", "video_pattern")}
    except InputError as exc:
        raise InputError(manifest, exc.problem) from None
    if not (np.isfinite(fps) and 0 < fps <= MAX_FPS):
        problems.append(f"fps = {fps} must be finite, positive and at most {MAX_FPS:g}")
    if not (float(n_frames).is_integer() and n_frames >= 1):
        problems.append(f"n_frames = {n_frames!r} must be a whole number >= 1 (or left out: the span every camera recorded)")
    if not np.isfinite(start_s):
        problems.append(f"start_s = {start_s} must be a finite number of seconds")
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
    clocks = camera_clocks(data.get("camera", {}), problems)
    problems += subject_problems(data.get("subject", {}))
    if problems:
        raise InputError(manifest, "; ".join(problems))
    return {"name": str(name), "fps": fps, "n_frames": int(n_frames) if "n_frames" in section else None,
            "cameras": list(cameras), "subject": dict(data.get("subject", {})), "media": media,
            "rig_file": rig_file, "reference_file": reference, "detector_weights": detector_weights,
            "camera_clocks": clocks, "start_s": start_s,
            **flags, **patterns}
