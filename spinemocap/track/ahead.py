"""A frame's candidate stage computed ahead of the tracker, off its thread, with the same result.

The candidate stage (:mod:`.candidates`, the rig residuals of :mod:`.rig_check` and the stretch
reading of :mod:`.stretch`) depends on the earlier frames only through the candidate gate
``th1_px``, which the rig monitor sets from the frames before. :func:`frame_candidates` builds a
frame's cloud with the gate known when it is asked (a few frames old) and records the range of
gates that build the same cloud (:func:`~.candidates.candidates_and_gate_range`);
:meth:`FrameCandidates.serves` tells whether the tracker's gate for that frame falls in it, and
only then does :meth:`~.pipeline.FrameTracker.candidates` take the cloud, so the tracked output is
bit for bit the one of building it in place. The residuals and stretch reading are those of the
same cloud; the tracker completes them with its own state (the running residual history, the last
frame's stretch).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..camera import Rig
from ..tape import TapeSpec
from ..views import ViewDots
from .candidates import candidates_and_gate_range
from .config import TrackerConfig
from .rig_check import frame_residuals
from .stretch import StretchReading, read_stretch
from .types import CandidateCloud


@dataclass(frozen=True)
class FrameCandidates:
    """One frame's candidate stage built ahead (:func:`frame_candidates`).

    ``cloud``: the candidate cloud built with gate ``gate_px`` (px); ``gate_range``: (lo, hi] px,
    the gates that build the same cloud; ``residuals``: per camera the frame's robust RMS (px) and
    its number of observations, None where too few (:func:`~.rig_check.frame_residuals`);
    ``stretch``: the stretch reading of the cloud's points (:meth:`~.pipeline.FrameTracker.measure_stretch`'s
    choice of points)."""

    cloud: CandidateCloud
    gate_px: float
    gate_range: tuple[float, float]
    residuals: list[tuple[float, int] | None]
    stretch: StretchReading

    def serves(self, gate_px: float) -> bool:
        """True when a cloud built with ``gate_px`` is this one (bit for bit)."""
        lo, hi = self.gate_range
        return bool(lo < gate_px <= hi)


def stretch_points(cloud: CandidateCloud, min_points: int) -> np.ndarray:
    """(N, 3) mm: the points the stretch is measured on: those seen by >= 3 cameras when there
    are at least ``min_points`` of them (ghosts rarely reach three views), else all."""
    strong = cloud.points[cloud.n_views >= 3] if len(cloud) else np.zeros((0, 3))
    return strong if len(strong) >= min_points else cloud.points


def frame_candidates(rig: Rig, views: Sequence[ViewDots], tape: TapeSpec, config: TrackerConfig,
                     gate_px: float) -> FrameCandidates:
    """The candidate stage of one frame with candidate gate ``gate_px`` (px): what
    :meth:`~.pipeline.FrameTracker.candidates` and ``measure_stretch`` compute from ``views``
    (only their ``uv`` is read) given that gate. Raises ValueError when ``views`` and ``rig``
    differ in length."""
    candidate_config = dataclasses.replace(config.candidates, th1_px=gate_px)
    cloud, gate_range = candidates_and_gate_range(rig, views, candidate_config)
    residuals = frame_residuals(rig, views, cloud, config.rig.min_views)
    reading = read_stretch(stretch_points(cloud, config.stretch.min_points), tape, config.stretch)
    return FrameCandidates(cloud, gate_px, gate_range, residuals, reading)
