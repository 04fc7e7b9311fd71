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

A :class:`~spinemocap.media.FrameSource` yields, for a frame index, one BGR ``uint8`` image per
camera in rig order. The synthetic studio provides an in-process source with the same interface, so
a benchmark can render and track without writing images to disk.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

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
    check_image_size,
    read_image,
)
from .reference import ReferenceObject
from .tape import TapeSpec

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
