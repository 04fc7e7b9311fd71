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

from dataclasses import dataclass


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
