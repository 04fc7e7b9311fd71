"""A capture on disk, and frame sources that deliver its synchronized images.

Folder layout::

    CAPTURE/
      capture.toml          # this module's manifest (below)
      rig.toml              # cameras, see spinemocap.camera
      images/<camera>/000000.png ...      (media = "images")
      videos/<camera>.mkv                 (media = "video")
      groundtruth.npz       # synthetic captures only

``capture.toml``::

    [capture]
    name = "trial01"
    fps = 100.0
    n_frames = 548
    cameras = ["cam1", "cam2", "cam3", "cam4"]
    rig = "rig.toml"
    media = "images"                              # or "video"
    image_pattern = "images/{camera}/{frame:06d}.png"
    video_pattern = "videos/{camera}.mkv"
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, Sequence, runtime_checkable

import cv2
import numpy as np

from .camera import Rig
from .fileio import InputError, read_toml, write_toml
from .tape import TapeSpec

MANIFEST = "capture.toml"


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


class ImageFolderSource:
    """Frames stored as one image file per camera and frame."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str):
        self.root = Path(root)
        self.camera_names = list(camera_names)
        self.n_frames = int(n_frames)
        self.pattern = pattern
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
        return read_image(self.path(self.camera_names[camera], frame))


class VideoSource:
    """Frames stored as one video per camera; sequential reads are cheap, jumps seek."""

    def __init__(self, root: Path, camera_names: Sequence[str], n_frames: int, pattern: str):
        self.root = Path(root)
        self.camera_names = list(camera_names)
        self.n_frames = int(n_frames)
        self.paths = [self.root / pattern.format(camera=cam) for cam in self.camera_names]
        self._captures: list[cv2.VideoCapture | None] = [None] * len(self.paths)
        self._next = [0] * len(self.paths)
        for path, cam in zip(self.paths, self.camera_names):
            if not path.is_file():
                raise InputError(path, f"video for camera {cam!r} is missing")
            cap = cv2.VideoCapture(str(path))
            if not cap.isOpened():
                raise InputError(path, "video cannot be opened (corrupt or unsupported codec)")
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            cap.release()
            if count and count != self.n_frames:
                raise InputError(path, f"video has {count} frames, capture.toml says n_frames = {self.n_frames}")

    def read_camera(self, camera: int, frame: int) -> np.ndarray:
        """One camera's image (``camera``: index in rig order). Each camera has its own decoder,
        so different cameras may be read from different threads at once (one thread per camera)."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return self._read_one(camera, frame)

    def _read_one(self, k: int, frame: int) -> np.ndarray:
        cap = self._captures[k]
        if cap is None:
            cap = self._captures[k] = cv2.VideoCapture(str(self.paths[k]))
            self._next[k] = 0
        if self._next[k] != frame:
            cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
        ok, image = cap.read()
        if not ok or image is None:
            raise InputError(self.paths[k], f"cannot decode frame {frame}")
        self._next[k] = frame + 1
        return image

    def read(self, frame: int) -> list[np.ndarray]:
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return [self._read_one(k, frame) for k in range(len(self.paths))]

    def close(self) -> None:
        for cap in self._captures:
            if cap is not None:
                cap.release()
        self._captures = [None] * len(self.paths)


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

    @property
    def camera_names(self) -> list[str]:
        return self.rig.names

    @property
    def up(self) -> np.ndarray:
        """Unit world direction toward the subject's head in the first frame."""
        v = np.asarray(self.subject.get("up", (0.0, 0.0, 1.0)), float)
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
        except (OSError, ValueError) as exc:
            raise InputError(path, f"unreadable ground truth ({exc})") from exc

    def row_levels(self) -> list[str] | None:
        """The vertebral level under each tape row from the ground truth (synthetic captures), else None."""
        if not self.has_groundtruth:
            return None
        gt = self.groundtruth()
        return [str(x) for x in gt["row_levels"]] if "row_levels" in gt else None

    def frame_source(self) -> FrameSource:
        if self.media == "images":
            return ImageFolderSource(self.root, self.camera_names, self.n_frames, self.image_pattern)
        if self.media == "video":
            return VideoSource(self.root, self.camera_names, self.n_frames, self.video_pattern)
        raise InputError(self.root / MANIFEST, f"unknown media {self.media!r} (expected 'images' or 'video')")

    @classmethod
    def open(cls, root: str | os.PathLike) -> "Capture":
        root = Path(root)
        manifest = root / MANIFEST
        if not root.is_dir():
            raise InputError(root, "capture folder not found")
        if not manifest.is_file():
            raise InputError(root, f"not a capture folder (no {MANIFEST})")
        data = read_toml(manifest)
        section = data.get("capture")
        if section is None:
            raise InputError(manifest, "missing [capture] table")
        for key in ("fps", "n_frames", "cameras"):
            if key not in section:
                raise InputError(manifest, f"[capture] lacks {key!r}")
        rig_file = section.get("rig", "rig.toml")
        rig = Rig.from_toml(root / rig_file)
        cameras = [str(c) for c in section["cameras"]]
        absent = [c for c in cameras if c not in rig.names]
        if absent:
            raise InputError(manifest, f"cameras {absent} are not in the rig file {rig_file} (rig has {rig.names})")
        tape = TapeSpec.from_dict(data.get("tape", {}), source=str(manifest))
        if float(section["fps"]) <= 0 or int(section["n_frames"]) < 1:
            raise InputError(manifest, "fps must be positive and n_frames >= 1")
        return cls(
            root=root,
            name=str(section.get("name", root.name)),
            fps=float(section["fps"]),
            n_frames=int(section["n_frames"]),
            rig=rig.subset(cameras),
            tape=tape,
            subject=dict(data.get("subject", {})),
            media=str(section.get("media", "images")),
            image_pattern=str(section.get("image_pattern", cls.image_pattern)),
            video_pattern=str(section.get("video_pattern", cls.video_pattern)),
            rig_file=rig_file,
        )

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
                },
                "tape": self.tape.to_dict(),
                "subject": self.subject,
            },
        )
