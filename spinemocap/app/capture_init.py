"""A capture folder from a lab's own recordings (``spinemocap capture init``).

Input: one video file or image folder per camera and a calibration in any format
:mod:`calibration.formats` reads (rig TOML, Pose2Sim/Anipose TOML, Qualisys ``.qca.txt``, Vicon
``.xcp``). Output: ``OUT/capture.toml`` and ``OUT/rig.toml`` (the calibration converted, with any
size fix applied) referencing the media where they are (``external_media = true``) or copies
under ``OUT/videos`` / ``OUT/images`` (``copy=True``).

- Cameras are matched to the rig by file name (:func:`match_cameras`): a file whose name is the
  camera's, or holds it as a separate word (``trial3_cam2.mp4``, ``Miqus_1_28513.avi``);
  ``mapping`` names the rest.
- Frame counts, rates and sizes come from the files (:func:`probe_media`: a video's container
  timestamps, an image folder's files and ``fps``).
- A video whose size differs from its calibration by an encoder crop (up to
  :data:`MAX_CROP_PX` rows or columns) or a whole-number scale is refused with the explanation
  (:func:`size_mismatch`) unless ``fix_size`` names the fix (:func:`fixed_camera`).
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from ..camera import Camera, Rig
from ..capture import MANIFEST, RATE_TOLERANCE, Capture
from ..fileio import InputError
from ..media import IMAGE_SUFFIXES, VideoDecoder, read_image
from ..tape import TapeSpec
from ..timebase import CameraClock, common_frames, image_times, video_times

MediaKind = Literal["video", "images"]
SizeFix = Literal["crop", "crop-centre", "scale"]
SIZE_FIXES: tuple[SizeFix, ...] = ("crop", "crop-centre", "scale")
# Encoders code whole blocks of 16 (H.264) or 8 pixels and crop the rest: a calibration and its
# camera's video may differ by up to this many rows or columns
MAX_CROP_PX = 16


@dataclass(frozen=True)
class MediaProbe:
    """What one camera's recording holds: ``path`` (video file or image folder), ``kind``,
    ``n_frames``, ``fps`` (frames/s: the median interval of a video's container timestamps, or the
    rate given for an image folder), ``size`` (width, height) px of its decoded frames,
    ``duration_s`` (last timestamp plus one interval) and ``dropped`` (frames missing from a
    video's timestamps)."""

    path: Path
    kind: MediaKind
    n_frames: int
    fps: float
    size: tuple[int, int]
    duration_s: float
    dropped: int = 0


@dataclass(frozen=True)
class SizeMismatch:
    """A camera whose recording is not the size its calibration says, and how they relate:
    ``kind`` "crop" (up to :data:`MAX_CROP_PX` rows/columns more or fewer) or "scale" (a
    whole-number ratio, ``scale`` = video / calibration); None: unrelated sizes."""

    camera: str
    video: tuple[int, int]
    calibration: tuple[int, int]
    kind: Literal["crop", "scale"] | None
    scale: float = 1.0

    def explain(self) -> str:
        """One sentence for a person: what differs, the likely cause, the fix (the parameter
        ``fix_size``, written `fix_size=...` for the command line to show as its flag)."""
        (w, h), (cw, ch) = self.video, self.calibration
        said = f"camera {self.camera!r}: its recording is {w}x{h} px but the calibration says {cw}x{ch} px"
        if self.kind == "crop":
            return (f"{said}: {abs(cw - w)} columns and {abs(ch - h)} rows apart, as a video encoder crops a frame to "
                    "its coding blocks (1088 -> 1080 rows). `fix_size=crop` keeps the principal point (the rows or "
                    "columns cut at the bottom/right, as H.264/H.265 encoders do), `fix_size=crop-centre` moves it "
                    "by half the difference (a centred crop)")
        if self.kind == "scale":
            return (f"{said}: the same image scaled by {self.scale:g}. `fix_size=scale` scales the focal lengths "
                    "and the principal point by it")
        return (f"{said}, neither an encoder crop (up to {MAX_CROP_PX} px) nor a whole-number scale: this calibration "
                "is of another sensor mode or camera; calibrate the camera at the size it recorded")


@dataclass
class InitResult:
    """What :func:`init_capture` wrote: the capture folder, the capture as opened back, each
    camera's media probe, the cameras of the rig left without a recording, and the fixes made to
    the calibration (one sentence each)."""

    root: Path
    capture: Capture
    probes: dict[str, MediaProbe]
    unused_cameras: list[str] = field(default_factory=list)
    fixes: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------ media
def probe_media(path: str | Path, fps: float | None = None) -> MediaProbe:
    """A video file's or image folder's frames, rate and size (see :class:`MediaProbe`).
    ``fps``: the rate of an image folder (required there); for a video, None measures it from the
    container timestamps. :class:`InputError` naming ``path`` when it cannot be read."""
    path = Path(path)
    if path.is_dir():
        files = image_files(path)
        if not files:
            raise InputError(path, f"image folder holds no images ({', '.join(IMAGE_SUFFIXES)})")
        if fps is None:
            raise InputError(path, "an image folder carries no frame rate: give it with `fps`")
        image = read_image(files[0])
        times = image_times(len(files), fps)
        return MediaProbe(path, "images", len(files), float(fps), (image.shape[1], image.shape[0]), times.duration_s)
    if not path.is_file():
        raise InputError(path, "no such video file or image folder")
    declared = video_times(path, fps)
    stamps = declared.timestamps_s
    measured = float(1.0 / np.median(np.diff(stamps))) if len(stamps) > 1 else declared.fps
    if abs(measured - declared.fps) <= RATE_TOLERANCE * 0.1 * measured:
        measured = declared.fps  # the header's exact rate (30000/1001), which the timestamps confirm
    rate = fps or measured
    times = video_times(path, rate) if abs(rate - declared.fps) > 1e-6 * rate else declared
    decoder = VideoDecoder(path, rate)
    try:
        image = decoder.read(int(times.slots[0]))
    finally:
        decoder.close()
    return MediaProbe(path, "video", len(stamps), float(rate), (image.shape[1], image.shape[0]), times.duration_s,
                      sum(d.missing for d in times.dropped))


def image_files(folder: Path) -> list[Path]:
    """The images of a folder in name order (hidden files left out)."""
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES)


# ------------------------------------------------------------------------------ camera names
def _holds_name(stem: str, camera: str) -> bool:
    """Does a file stem name ``camera``: equal to it, or holding it as a word of its own (not a
    part of a longer name or number)? Case and separators ignored for the whole name."""
    if _plain(stem) == _plain(camera):
        return True
    return re.search(rf"(?<![A-Za-z0-9]){re.escape(camera)}(?![A-Za-z0-9])", stem, re.IGNORECASE) is not None


def _plain(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


def _stem(path: Path) -> str:
    return path.name.split(".")[0] if path.is_file() else path.name


def match_cameras(rig_names: Sequence[str], media: Sequence[Path], mapping: dict[str, str] | None = None,
                  named: dict[str, Path] | None = None) -> dict[str, Path]:
    """Each recording's camera, in rig order: ``named`` (camera -> path, given by the user) and
    ``mapping`` (camera -> file name or path among ``media``) first, the rest of ``media`` by
    file name (:func:`_holds_name`). :class:`InputError` listing both sides when a recording
    matches no camera or several, a camera is named twice, or a name is not in the rig."""
    mapping, named = dict(mapping or {}), dict(named or {})
    chosen: dict[str, Path] = {}
    unknown = [name for name in [*named, *mapping] if name not in rig_names]
    left = list(media)
    for camera, given in mapping.items():
        hits = [p for p in left if given in (p.name, str(p)) or Path(given).resolve() == p.resolve()]
        if len(hits) != 1:
            raise InputError("mapping", f"{camera}={given}: {'no' if not hits else 'more than one'} recording of "
                                      f"{_listing(media)} is {given!r}")
        chosen[camera] = hits[0]
        left.remove(hits[0])
    chosen.update(named)
    problems = [f"{name!r} is not a camera of the calibration" for name in unknown]
    for path in left:
        cameras = [c for c in rig_names if _holds_name(_stem(path), c) and c not in chosen]
        if len(cameras) == 1:
            chosen[cameras[0]] = path
        else:
            problems.append(f"{path.name} names {'no camera' if not cameras else 'cameras ' + ', '.join(cameras)}")
    taken: dict[Path, list[str]] = {}
    for camera, path in chosen.items():
        taken.setdefault(path, []).append(camera)
    problems += [f"{path.name} is given to cameras {', '.join(cams)}" for path, cams in taken.items() if len(cams) > 1]
    if problems:
        raise InputError("camera names", "; ".join(problems) + f". The calibration's cameras: {', '.join(rig_names)}; "
                         f"the recordings: {_listing(media or list(named.values()))}. Name each recording's camera with "
                         "`mapping` (CAMERA=FILE), or give `named` recordings (CAMERA=PATH)")
    return {name: chosen[name] for name in rig_names if name in chosen}


def _listing(paths: Sequence[Path]) -> str:
    return ", ".join(p.name for p in paths) or "none"


# ------------------------------------------------------------------------------ sizes
def size_mismatch(camera: Camera, size: tuple[int, int]) -> SizeMismatch | None:
    """How a recording of ``size`` (width, height) px relates to ``camera``'s calibration: None
    when equal, else a :class:`SizeMismatch` (crop, whole-number scale or unrelated)."""
    w, h = size
    cw, ch = camera.size
    if (w, h) == (cw, ch):
        return None
    if abs(w - cw) <= MAX_CROP_PX and abs(h - ch) <= MAX_CROP_PX:
        return SizeMismatch(camera.name, (w, h), (cw, ch), "crop")
    for big, small, up in (((w, h), (cw, ch), True), ((cw, ch), (w, h), False)):
        ratio = big[0] // small[0] if small[0] else 0
        if ratio >= 2 and big[0] == ratio * small[0] and big[1] == ratio * small[1]:
            return SizeMismatch(camera.name, (w, h), (cw, ch), "scale", float(ratio) if up else 1.0 / ratio)
    return SizeMismatch(camera.name, (w, h), (cw, ch), None)


def fixed_camera(camera: Camera, mismatch: SizeMismatch, fix: SizeFix) -> Camera:
    """``camera`` calibrated for its recording's size: ``crop`` keeps the principal point (rows
    and columns cut or added at the bottom/right), ``crop-centre`` shifts it by half the size
    difference, ``scale`` multiplies the focal lengths, skew and principal point by the scale
    (pixel centres at integer coordinates: c' = (c + 0.5) s - 0.5). InputError when ``fix`` does
    not fit the mismatch."""
    if mismatch.kind is None or (mismatch.kind == "scale") != (fix == "scale"):
        raise InputError("fix_size", f"`fix_size={fix}` does not fit: {mismatch.explain()}")
    K = camera.K.copy()
    if fix == "crop-centre":
        K[0, 2] -= (mismatch.calibration[0] - mismatch.video[0]) / 2.0
        K[1, 2] -= (mismatch.calibration[1] - mismatch.video[1]) / 2.0
    elif fix == "scale":
        s = mismatch.scale
        K[0, 0], K[0, 1], K[1, 1] = K[0, 0] * s, K[0, 1] * s, K[1, 1] * s
        K[0, 2], K[1, 2] = (K[0, 2] + 0.5) * s - 0.5, (K[1, 2] + 0.5) * s - 0.5
    return replace(camera, K=K, size=mismatch.video)


# ------------------------------------------------------------------------------ times
def parse_time(text: str, fps: float, what: str) -> float:
    """``"2.5s"`` (seconds) or ``"250"`` (a whole number of capture frames at ``fps``) -> seconds."""
    value = text.strip().lower()
    try:
        if value.endswith("s"):
            return float(value[:-1])
        frames = float(value)
    except ValueError:
        raise InputError(what, f"{text!r} is neither seconds (2.5s) nor a frame number (250)") from None
    if not frames.is_integer():
        raise InputError(what, f"{text!r}: frames are whole numbers; write seconds with an s (2.5s)")
    return frames / fps


# ------------------------------------------------------------------------------ the folder
def init_capture(out: str | Path, calibration: str | Path, *, media: Sequence[str | Path] = (),
                 named: dict[str, str | Path] | None = None, mapping: dict[str, str] | None = None,
                 fps: float | None = None, start: str | None = None, end: str | None = None,
                 offsets: dict[str, float] | None = None, fix_size: SizeFix | None = None, copy: bool = False,
                 tape: TapeSpec | None = None, subject: str | None = None, force: bool = False) -> InitResult:
    """Write the capture folder ``out`` (see the module docstring) and open it back.

    ``media``: recordings matched to cameras by name; ``named``: camera -> recording; ``mapping``:
    camera -> one of ``media`` by file name. ``fps``: the capture's rate (default: the slowest
    camera's; required for image folders). ``start``/``end``: the part of the recordings to use,
    seconds (``"2.5s"``) or capture frames (``"250"``) on the capture's clock (default: from 0 to
    the end of the shortest recording, left out of ``capture.toml`` so that it follows offsets
    estimated later). ``offsets``: camera -> clock offset, s (see
    ``docs/CAPTURE.md``). ``fix_size``: the fix for recordings whose size differs from the
    calibration. ``copy``: copy the media into the folder. ``force``: replace an existing
    ``capture.toml``. :class:`InputError` naming the problem and its fix otherwise; nothing is
    written before every check has passed."""
    from calibration.formats import read_rig

    root = Path(out)
    if (root / MANIFEST).exists() and not force:
        raise InputError(root / MANIFEST, "a capture is already here; choose a new folder or pass `force=True` to replace it")
    rig = read_rig(calibration)
    paths = [Path(p) for p in media]
    given = {name: Path(p) for name, p in (named or {}).items()}
    by_camera = match_cameras(rig.names, paths, mapping, given)
    probes = {name: probe_media(path, fps if Path(path).is_dir() else None) for name, path in by_camera.items()}
    kinds = {p.kind for p in probes.values()}
    if len(kinds) > 1:
        raise InputError("media", "give every camera a video or every camera an image folder, not both")
    for name in offsets or {}:
        if name not in probes:
            raise InputError("offsets", f"{name}: no camera of that name has a recording ({', '.join(probes)})")
    cameras, fixes = _fit_sizes(rig, probes, fix_size, calibration)
    rate = float(fps) if fps else min(p.fps for p in probes.values())
    start_s = parse_time(start, rate, "start") if start else 0.0
    clocks = {name: CameraClock(offset_s=float((offsets or {}).get(name, 0.0)),
                                fps=None if abs(p.fps - rate) <= 1e-6 * rate else p.fps,
                                media=str(p.path.resolve()))
              for name, p in probes.items()}
    for name, probe in probes.items():  # capture time of each recording's end, from --start
        if probe.duration_s - clocks[name].offset_s - start_s <= 0:
            raise InputError("start", f"{start} lies after the end of camera {name!r}'s recording "
                                        f"({probe.duration_s:.3f} s on its clock)")
    span = common_frames([_times(p) for p in probes.values()],
                         [replace(c, offset_s=c.offset_s + start_s) for c in clocks.values()], rate)
    n_frames = span
    if end is not None:
        n_frames = int(round((parse_time(end, rate, "end") - start_s) * rate))
        if not 1 <= n_frames <= span:
            raise InputError("end", f"{end} leaves {n_frames} frames after `start`; the recordings hold {span} "
                                      f"frames at {rate:g} frames/s from there")
    root.mkdir(parents=True, exist_ok=True)
    if copy:
        clocks = {name: replace(clock, media=_copy_media(probes[name], root, name)) for name, clock in clocks.items()}
    capture = Capture(root=root, name=root.name, fps=rate, n_frames=n_frames, rig=Rig(cameras), tape=tape or TapeSpec(),
                      subject={"id": subject or root.name}, media=kinds.pop(), camera_clocks=clocks, start_s=start_s,
                      external_media=not copy, spans_recordings=end is None)
    capture.save()
    return InitResult(root, Capture.open(root), probes, [n for n in rig.names if n not in probes], fixes)


def _times(probe: MediaProbe):
    if probe.kind == "images":
        return image_times(probe.n_frames, probe.fps)
    return video_times(probe.path, probe.fps)


def _fit_sizes(rig: Rig, probes: dict[str, MediaProbe], fix: SizeFix | None,
               calibration: str | Path) -> tuple[list[Camera], list[str]]:
    """The cameras with recordings (rig order), each calibrated for its recording's size
    (:func:`fixed_camera` with ``fix``), and one sentence per fix made. :class:`InputError`
    naming ``calibration`` and explaining every mismatch when ``fix`` is None or cannot fix one."""
    cameras, fixes, problems = [], [], []
    for name, probe in probes.items():
        camera = rig[name]
        mismatch = size_mismatch(camera, probe.size)
        if mismatch is None:
            cameras.append(camera)
        elif fix is None or mismatch.kind is None or (mismatch.kind == "scale") != (fix == "scale"):
            problems.append(mismatch.explain())
        else:
            cameras.append(fixed_camera(camera, mismatch, fix))
            fixes.append(f"camera {name!r}: calibration {mismatch.calibration[0]}x{mismatch.calibration[1]} -> "
                         f"{mismatch.video[0]}x{mismatch.video[1]} px (`fix_size={fix}`)")
    if problems:
        raise InputError(calibration, "; ".join(problems))
    return cameras, fixes


def _copy_media(probe: MediaProbe, root: Path, camera: str) -> str:
    """Copy a camera's recording into the capture folder; its path there, relative."""
    if probe.kind == "video":
        target = root / "videos" / f"{camera}{''.join(probe.path.suffixes[-1:])}"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(probe.path, target)
    else:
        target = root / "images" / camera
        target.mkdir(parents=True, exist_ok=True)
        for path in image_files(probe.path):
            shutil.copy2(path, target / path.name)
    return str(target.relative_to(root))
