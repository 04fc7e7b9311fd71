"""How well the rig fits this capture: reprojection residuals of the capture's own dots, and the
candidate gate derived from them (beyond the paper).

The paper's candidate gate ``th1`` is a fixed 2 px. A real calibration is off by 0.2-0.5 px in a
good optical studio and 1-3 px in a video set-up; with a fixed 2 px gate a 3 px rig drops true
points, the LP then works on a ghost-rich cloud and labels break without a word. Here the gate
follows the rig: the capture's dots seen by >= ``min_views`` cameras (ghosts of wrong blob
pairings rarely agree in three views) are triangulated with a loose ``probe_gate_px`` and their
reprojection errors (distorted px, per camera) measured; the gate is ``gate_factor`` times the
worst camera's robust RMS plus ``gate_margin_px`` (a calibration error is systematic: a camera's
errors cluster near its RMS rather than spreading to three times it, and a wider gate pairs
neighbouring dots' blobs: 15 mm at 2 m is ~11 px), never below the configured ``th1_px`` and never
above ``max_gate_px``. Cameras whose
RMS exceeds ``warn_px`` are named in a :class:`CalibrationWarning`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..camera import Rig
from ..views import ViewDots
from .candidates import build_candidates
from .config import CandidateConfig, RigCheckConfig
from .types import CandidateCloud

#: The calibration warning's advice (replaced once ``--refine-rig`` has run, see ``TrackResult.quality``).
REFINE_ADVICE = "consider `spinemocap track --refine-rig` or recalibrating."


class CalibrationWarning(UserWarning):
    """The rig reprojects the capture's own dots poorly (cameras named in the message)."""


@dataclass
class RigResiduals:
    """Reprojection residuals (distorted px) of the capture's dots, per camera: ``rms_px`` (C,)
    (NaN where a camera saw no such dot), ``n_obs`` (C,), ``overall_px`` over all cameras."""

    cameras: list[str]
    rms_px: np.ndarray
    n_obs: np.ndarray
    overall_px: float

    def high(self, warn_px: float) -> list[str]:
        """Names of the cameras whose RMS exceeds ``warn_px``."""
        return [name for name, rms in zip(self.cameras, self.rms_px) if np.isfinite(rms) and rms > warn_px]

    def describe(self) -> str:
        return ", ".join(f"{n} {r:.2f} px" if np.isfinite(r) else f"{n} -" for n, r in zip(self.cameras, self.rms_px))


def observation_errors(rig: Rig, views: Sequence[ViewDots], cloud: CandidateCloud,
                       min_views: int) -> list[np.ndarray]:
    """Per camera, the reprojection errors (distorted px) of the cloud's points seen by >=
    ``min_views`` cameras at the blobs they were triangulated from."""
    out = []
    keep = cloud.n_views >= min_views if len(cloud) else np.zeros(0, bool)
    points, ids = cloud.points[keep], cloud.blob_ids[keep]
    for c, (cam, view) in enumerate(zip(rig, views)):
        used = ids[:, c] >= 0 if len(ids) else np.zeros(0, bool)
        if not used.any():
            out.append(np.zeros(0))
            continue
        proj = cam.project(points[used])
        out.append(np.linalg.norm(proj - view.uv[ids[used, c]], axis=1))
    return out


def frame_residuals(rig: Rig, views: Sequence[ViewDots], cloud: CandidateCloud,
                    min_views: int) -> list[tuple[float, int] | None]:
    """Per camera, the :func:`robust_rms` (distorted px) of one frame's :func:`observation_errors`
    and their number, or None where the camera has fewer than three (too few to count)."""
    return [(robust_rms(errors), len(errors)) if len(errors) >= 3 else None
            for errors in observation_errors(rig, views, cloud, min_views)]


def robust_rms(errors: np.ndarray) -> float:
    """RMS of 2D error norms from their median (insensitive to a few wrong pairings): for
    isotropic Gaussian errors median(|e|^2) = 1.386 sigma^2 and RMS(|e|) = sqrt(2) sigma."""
    errors = np.asarray(errors, float)
    if not len(errors):
        return float("nan")
    return float(np.sqrt(np.median(errors**2) * 2.0 / 1.386))


def _median(values: list[float]) -> float:
    """``float(np.median(values))`` of a short list (the middle value, or the mean of the two
    middle values as np.median takes it) without numpy's per-call cost."""
    if any(v != v for v in values):  # NaN: np.median's answer
        return float("nan")
    ordered = sorted(values)
    k = len(ordered) // 2
    return float(ordered[k]) if len(ordered) % 2 else float((ordered[k - 1] + ordered[k]) / 2)


class RigMonitor:
    """Running per-camera residuals over the capture and the candidate gate they imply."""

    def __init__(self, rig: Rig, candidates: CandidateConfig, config: RigCheckConfig | None = None):
        self.rig = rig
        self.base = candidates
        self.config = config or RigCheckConfig()
        self.history: list[list[float]] = [[] for _ in range(len(rig))]
        self.counts = np.zeros(len(rig), np.int64)
        self.warned = False
        self._rms_key: tuple | None = None  # the history the cached per-camera RMS below was taken from
        self._rms = np.zeros(0)

    @property
    def measured(self) -> bool:
        return any(self.history)

    def _running_rms(self) -> np.ndarray:
        """(C,) median of each camera's last ``window`` frame RMS values (NaN: none), remembered
        until the history grows (asked for two to three times a frame)."""
        key = (self.config.window, tuple(len(h) for h in self.history))
        if key != self._rms_key:
            self._rms = np.array([_median(h[-self.config.window:]) if h else np.nan for h in self.history])
            self._rms_key = key
        return self._rms

    def residuals(self) -> RigResiduals:
        rms = self._running_rms().copy()
        finite = rms[np.isfinite(rms)]
        overall = float(np.sqrt(np.mean(finite**2))) if len(finite) else float("nan")
        return RigResiduals(list(self.rig.names), rms, self.counts.copy(), overall)

    def gate_px(self) -> float:
        """th1 for the next frame (px)."""
        if not self.config.adaptive_gate or not self.measured:
            return self.base.th1_px
        rms = self._running_rms()
        worst = float(np.nanmax(rms)) if np.isfinite(rms).any() else 0.0
        gate = self.config.gate_factor * worst + self.config.gate_margin_px
        return float(np.clip(gate, self.base.th1_px, self.config.max_gate_px))

    def candidate_config(self) -> CandidateConfig:
        return dataclasses.replace(self.base, th1_px=self.gate_px())

    def update(self, views: Sequence[ViewDots], cloud: CandidateCloud) -> None:
        """Add one frame's residuals (the cloud built with the current gate)."""
        self.add(frame_residuals(self.rig, views, cloud, self.config.min_views))

    def add(self, residuals: Sequence[tuple[float, int] | None]) -> None:
        """Add one frame's :func:`frame_residuals` (per camera)."""
        for c, measured in enumerate(residuals):
            if measured is not None:
                self.history[c].append(measured[0])
                self.counts[c] += measured[1]

    def probe(self, views: Sequence[ViewDots]) -> None:
        """First measurement: triangulate with the loose probe gate so that a poor rig's true
        dots are not dropped before their residuals are seen."""
        loose = dataclasses.replace(self.base, th1_px=self.config.probe_gate_px)
        self.update(views, build_candidates(self.rig, views, loose))

    def warning(self) -> str | None:
        """The warning text naming the cameras above ``warn_px`` (None when all are fine)."""
        res = self.residuals()
        high = res.high(self.config.warn_px)
        if not high:
            return None
        return (f"calibration: camera(s) {', '.join(high)} reproject the capture's own dots with "
                f"{', '.join(f'{r:.2f}' for n, r in zip(res.cameras, res.rms_px) if n in high)} px RMS "
                f"(> {self.config.warn_px} px); candidate gate widened to {self.gate_px():.1f} px. "
                f"Positions carry about 1-1.5 mm of bias per px; {REFINE_ADVICE}")


@dataclass
class RigReport:
    """What the tracker measured about the rig over a capture (for summaries and JSON)."""

    residuals: RigResiduals
    gate_px: float
    warning: str | None = None
    extra: dict = field(default_factory=dict)
