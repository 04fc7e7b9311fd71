"""Per-camera clocks: when each camera's media frames were taken, on the capture's clock.

Timestamp convention (seconds throughout):

- The capture's clock: capture frame ``i`` is at time ``t = i / fps_capture``.
- A camera's media timestamp ``tau``: a video frame's container time (``pts * time_base``, minus the
  stream's start time), or ``index / fps`` for an image folder.
- A camera's clock runs ``offset_s`` ahead of the capture's: the media frame with timestamp ``tau``
  shows capture time ``t = tau - offset_s`` (a camera that started recording late has a negative
  offset: its first frame shows a later capture time).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .fileio import InputError


@dataclass(frozen=True)
class CameraClock:
    """One camera's clock relative to the capture's.

    ``offset_s``: this camera's clock minus the capture clock, s (sub-frame values allowed): its media
    frame with timestamp ``tau`` s shows capture time ``tau - offset_s``. ``fps``: the camera's own
    frame rate, frames/s (None: the capture's; a video's container timestamps take precedence).
    ``media``: the camera's video file or image folder, relative to the capture folder (None: the
    capture's file pattern)."""

    offset_s: float = 0.0
    fps: float | None = None
    media: str | None = None


# A gap between consecutive media timestamps longer than this many frame intervals is a drop.
DROP_GAP_FRAMES = 1.5


@dataclass(frozen=True)
class DroppedFrames:
    """Frames a camera failed to record: a gap in its media timestamps.

    ``camera``: the camera's name; ``after_slot``: the camera's last frame slot before the gap (slot
    = round(timestamp * fps), the frame's place on the camera's own frame grid); ``at_s``: that
    frame's media timestamp, s; ``missing``: how many frames the gap lacks."""

    camera: str
    after_slot: int
    at_s: float
    missing: int

    def __str__(self) -> str:
        return (f"camera {self.camera!r} dropped {self.missing} frame{'s' if self.missing != 1 else ''} "
                f"after its frame {self.after_slot} (t = {self.at_s:.4f} s on its clock)")


@dataclass(frozen=True)
class MediaTimes:
    """One camera's recorded frames on its own clock: ``timestamps_s`` (N,) increasing media
    timestamps, s, of the frames the media holds (the first at 0); ``fps`` the camera's frame rate,
    frames/s; ``slots`` (N,) int each frame's place on the camera's frame grid (round(timestamp *
    fps): a video decoder's frame index, an image's file index); ``dropped``: the gaps."""

    timestamps_s: np.ndarray
    fps: float
    slots: np.ndarray
    dropped: tuple[DroppedFrames, ...]

    @property
    def duration_s(self) -> float:
        """Time the recording covers, s (the last frame's timestamp plus one frame interval)."""
        return float(self.timestamps_s[-1]) + 1.0 / self.fps if len(self.timestamps_s) else 0.0


def media_times(timestamps_s: Sequence[float] | np.ndarray, fps: float, camera: str = "") -> MediaTimes:
    """:class:`MediaTimes` of a camera's recorded frames: ``timestamps_s`` (N,) their media
    timestamps (any origin: shifted so the first is 0; sorted), ``fps`` the camera's nominal rate.
    Each frame is placed on the camera's frame grid (``slots``); a gap of more than
    :data:`DROP_GAP_FRAMES` intervals is reported as dropped frames (later frames keep their own
    timestamps: nothing is shifted). ValueError for no frames, a non-positive rate or two frames on
    one slot."""
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"camera {camera!r}: frame rate {fps} must be finite and positive")
    stamps = np.sort(np.asarray(timestamps_s, float).reshape(-1))
    if not len(stamps):
        raise ValueError(f"camera {camera!r} has no frames")
    stamps = stamps - stamps[0]
    slots = np.round(stamps * fps).astype(np.int64)
    if len(slots) > 1 and (np.diff(slots) < 1).any():
        k = int(np.flatnonzero(np.diff(slots) < 1)[0])
        raise ValueError(f"camera {camera!r}: frames at {stamps[k]:.5f} s and {stamps[k + 1]:.5f} s are closer than "
                         f"one frame interval at {fps:g} frames/s (wrong frame rate?)")
    gaps = np.flatnonzero(np.diff(stamps) > DROP_GAP_FRAMES / fps)
    dropped = tuple(DroppedFrames(camera, int(slots[k]), float(stamps[k]), int(slots[k + 1] - slots[k] - 1))
                    for k in gaps)
    return MediaTimes(stamps, float(fps), slots, dropped)


def image_times(n_images: int, fps: float, camera: str = "") -> MediaTimes:
    """An image folder's frames: image ``k`` at ``k / fps`` s (a folder cannot show a drop)."""
    return media_times(np.arange(int(n_images)) / fps, fps, camera)


def video_times(path: str | os.PathLike, fps: float | None = None, camera: str = "") -> MediaTimes:
    """A video's frames from its container timestamps (PyAV: each video packet's ``pts *
    time_base``, read without decoding). ``fps``: the camera's rate (None: the stream's declared
    rate). :class:`InputError` naming ``path`` for a video that cannot be read or has no
    timestamps."""
    try:
        import av
    except ImportError as exc:
        raise InputError(path, f"videos need PyAV (the package 'av'), which this installation lacks ({exc})") from None
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            rate = fps or stream.guessed_rate or stream.average_rate
            time_base = stream.time_base
            pts = [packet.pts for packet in container.demux(stream) if packet.pts is not None and packet.size]
    except (av.error.FFmpegError, IndexError, ValueError) as exc:
        raise InputError(path, f"video cannot be read ({exc})") from None
    if not pts:
        raise InputError(path, "video has no frames with timestamps")
    if not rate or not time_base:
        raise InputError(path, "video has no frame rate or time base; give the camera's fps in capture.toml")
    try:
        return media_times(np.array(pts, float) * float(time_base), float(rate), camera)
    except ValueError as exc:
        raise InputError(path, str(exc)) from None


def pair_frames(times: MediaTimes, offset_s: float, capture_fps: float, n_frames: int) -> np.ndarray:
    """(n_frames,) int: for capture frame ``i`` (capture time ``i / capture_fps`` s), the slot of the
    camera's recorded frame nearest in time on its clock (``i / capture_fps + offset_s``), or -1
    where the nearest is more than half of the camera's frame interval away (before its recording
    starts, after it ends, or in a drop)."""
    wanted = np.arange(int(n_frames)) / float(capture_fps) + float(offset_s)
    stamps = times.timestamps_s
    right = np.clip(np.searchsorted(stamps, wanted), 0, len(stamps) - 1)
    left = np.clip(right - 1, 0, len(stamps) - 1)
    nearest = np.where(np.abs(stamps[left] - wanted) <= np.abs(stamps[right] - wanted), left, right)
    # a hair of tolerance: a frame exactly half an interval away (rates 2:1) still pairs
    close = np.abs(stamps[nearest] - wanted) <= 0.5 / times.fps + 1e-9
    return np.where(close, times.slots[nearest], -1)


@dataclass(frozen=True)
class FramePairing:
    """Which recorded frame each camera shows for each capture frame.

    ``camera_names`` (C,); ``slots`` (C, F) int: camera ``c``'s frame slot for capture frame ``i``
    (-1: the camera has no frame there); ``dropped``: every camera's dropped frames."""

    camera_names: tuple[str, ...]
    slots: np.ndarray
    dropped: tuple[DroppedFrames, ...] = ()

    @property
    def n_frames(self) -> int:
        return int(self.slots.shape[1])

    def missing(self) -> dict[str, list[int]]:
        """Capture frames (0-based) each camera has no frame for, by camera name (cameras with
        a frame everywhere left out)."""
        return {name: np.flatnonzero(row < 0).tolist() for name, row in zip(self.camera_names, self.slots)
                if (row < 0).any()}

    def is_identity(self) -> bool:
        """Does every camera show its own frame ``i`` for capture frame ``i`` (a synchronised capture)?"""
        return bool((self.slots == np.arange(self.n_frames)).all())


def pair_cameras(camera_names: Sequence[str], times: Sequence[MediaTimes], clocks: Sequence[CameraClock],
                 capture_fps: float, n_frames: int | None = None) -> FramePairing:
    """The :class:`FramePairing` of cameras whose recorded frames are ``times`` and whose clocks are
    ``clocks`` (rig order). ``n_frames`` None: the capture frames from 0 up to the end of the
    cameras' common span (the earliest end of a recording on the capture's clock)."""
    if n_frames is None:
        n_frames = common_frames(times, clocks, capture_fps)
    slots = np.stack([pair_frames(t, clock.offset_s, capture_fps, n_frames) for t, clock in zip(times, clocks)])
    return FramePairing(tuple(camera_names), slots, tuple(d for t in times for d in t.dropped))


#: cameras a capture frame needs to be worth tracking (a dot is triangulated from two views)
MIN_CAMERAS = 2


def recording_ends(times: Sequence[MediaTimes], clocks: Sequence[CameraClock], capture_fps: float) -> list[int]:
    """Per camera, the capture frame after the last one its recording shows (its last frame at
    ``timestamp - offset_s`` on the capture's clock)."""
    return [int(np.floor((float(t.timestamps_s[-1]) - clock.offset_s) * capture_fps + 1e-6)) + 1
            for t, clock in zip(times, clocks)]


def common_frames(times: Sequence[MediaTimes], clocks: Sequence[CameraClock], capture_fps: float) -> int:
    """Capture frames from 0 to the end of the recordings that :data:`MIN_CAMERAS` cameras
    share (all cameras where fewer), at least 1: a camera whose recording ends earlier is left out
    of the frames after its end, the others are tracked there."""
    return shared_span(recording_ends(times, clocks, capture_fps))


def partial_recordings(camera_names: Sequence[str], starts: Sequence[int], ends: Sequence[int], n_frames: int,
                       where: str | os.PathLike) -> list[str]:
    """The cameras whose recordings do not cover capture frames ``0..n_frames-1`` (each camera's
    ``starts``/``ends``: its first recorded capture frame and the one after its last), one line
    each, saying that the other cameras carry those frames; :class:`InputError` naming ``where``
    when no camera recorded the last frame (``n_frames`` beyond every recording)."""
    if max(ends) < n_frames:
        longest = int(np.argmax(ends))
        raise InputError(where, f"n_frames = {n_frames} but no camera recorded that many frames (the longest, "
                                f"{camera_names[longest]!r}, ends at frame {ends[longest]}): set n_frames = "
                                f"{ends[longest]} or fewer, or leave n_frames out (the span the cameras recorded)")
    lines = []
    for name, start, end in zip(camera_names, starts, ends):
        lacking = ([f"frames 0-{start - 1} (its recording starts late)"] if start > 0 else []) + (
            [f"frames {end}-{n_frames - 1} (its recording ends early)"] if end < n_frames else [])
        if lacking:
            lines.append(f"camera {name!r} has no images for capture {' and '.join(lacking)}: the other cameras are "
                         "tracked there, and the marker files record the camera as missing in those frames")
    return lines


def shared_span(ends: Sequence[int]) -> int:
    """Capture frames from 0 to where fewer than :data:`MIN_CAMERAS` cameras still record
    (``ends``: each camera's end, :func:`recording_ends`), at least 1."""
    ordered = sorted(int(e) for e in ends)
    return max(1, ordered[-min(MIN_CAMERAS, len(ordered))])
