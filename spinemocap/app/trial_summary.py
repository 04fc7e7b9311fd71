"""One trial's result in a batch: what ``summary.json`` holds (:class:`TrialSummary`, with the
angle analysis of a successful trial in :class:`TrialAnalysis`) and what a batch run returns
for it (:class:`TrialOutcome`: the summary and whether it was up to date and skipped).

``to_dict`` gives the JSON object written to ``summary.json`` and ``batch.json`` (keys in a
fixed order, optional keys only when present); ``from_dict`` reads one back.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping, cast

from ..fileio import InputError

#: A trial's state: analysed, refused or failed (``reason`` says why), or stopped by an interrupt.
TrialStatus = Literal["ok", "failed", "interrupted"]
#: Where the markers came from (same vocabulary as ``app.batch.MarkerSource``).
SummarySource = Literal["tracked", "groundtruth"]
#: What decided the pelvis frame: a pelvis C3D or the tape itself.
PelvisSource = Literal["c3d", "tape"]

#: A step's state: done, or failed with its reason (the trial keeps its angles either way).
StepStatus = Literal["ok", "failed"]

JsonObject = dict[str, Any]


@dataclass(frozen=True)
class OpenSimStep:
    """``spinemocap opensim`` on a trial's markers (``opensim`` in ``summary.json``): marker RMS
    mean and worst frame (mm), IK time per frame (ms), flagged frame count, the driven joints and
    the output folder; ``reason`` when it failed."""

    status: StepStatus
    reason: str = ""
    marker_rms_mm: float = math.nan
    marker_rms_mm_max: float = math.nan
    ms_per_frame: float = math.nan
    flagged_frames: int = 0
    driven_joints: tuple[str, ...] = ()
    out_dir: str = ""

    def to_dict(self) -> JsonObject:
        if self.status != "ok":
            return {"status": self.status, "reason": self.reason}
        return {"status": self.status, "marker_rms_mm": self.marker_rms_mm, "marker_rms_mm_max": self.marker_rms_mm_max,
                "ms_per_frame": self.ms_per_frame, "flagged_frames": self.flagged_frames,
                "driven_joints": list(self.driven_joints), "out_dir": self.out_dir}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OpenSimStep:
        if data["status"] != "ok":
            return cls("failed", str(data["reason"]))
        return cls("ok", marker_rms_mm=_number(data["marker_rms_mm"]), marker_rms_mm_max=_number(data["marker_rms_mm_max"]),
                   ms_per_frame=_number(data["ms_per_frame"]), flagged_frames=int(data["flagged_frames"]),
                   driven_joints=tuple(data["driven_joints"]), out_dir=str(data["out_dir"]))


@dataclass(frozen=True)
class ViewStep:
    """``spinemocap view`` on a trial (``view`` in ``summary.json``): frames drawn and seconds
    taken; ``reason`` when it failed."""

    status: StepStatus
    reason: str = ""
    frames: int = 0
    seconds: float = 0.0

    def to_dict(self) -> JsonObject:
        if self.status != "ok":
            return {"status": self.status, "reason": self.reason}
        return {"status": self.status, "frames": self.frames, "seconds": self.seconds}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ViewStep:
        if data["status"] != "ok":
            return cls("failed", str(data["reason"]))
        return cls("ok", frames=int(data["frames"]), seconds=data["seconds"])


def _number(value: float | None) -> float:
    """A JSON number; null (written for NaN) back to NaN."""
    return math.nan if value is None else value


@dataclass(frozen=True)
class TrialAnalysis:
    """The angle analysis of a successful trial (the ``ok`` part of ``summary.json``).

    ``fps`` frames per second, ``duration_s`` seconds, ``completeness_pct`` percent of dots
    observed; ``levels`` vertebral level -> tape row (1-based, fractional); ``levels_from`` the
    level map's file or origin; ``lumbar_levels`` (lower, upper) level of the lumbar angle;
    ``notes`` angle group -> reason -> frame count of NaN angles; ``stats`` summary statistic
    name -> value in degrees (``*_valid``: fraction of frames with a value; NaN where none,
    written as null)."""

    n_frames: int
    fps: float
    duration_s: float
    completeness_pct: float
    levels: dict[str, float]
    levels_from: str
    lumbar_levels: tuple[str, str]
    pelvis_from: PelvisSource
    notes: dict[str, dict[str, int]]
    stats: dict[str, float]

    def to_dict(self) -> JsonObject:
        return {"n_frames": self.n_frames, "fps": self.fps, "duration_s": self.duration_s,
                "completeness_pct": self.completeness_pct, "levels": self.levels, "levels_from": self.levels_from,
                "lumbar_levels": list(self.lumbar_levels), "pelvis_from": self.pelvis_from,
                "notes": self.notes, "stats": self.stats}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrialAnalysis:
        lower, upper = data["lumbar_levels"]
        return cls(n_frames=int(data["n_frames"]), fps=data["fps"], duration_s=data["duration_s"],
                   completeness_pct=data["completeness_pct"], levels=dict(data["levels"]),
                   levels_from=str(data["levels_from"]), lumbar_levels=(str(lower), str(upper)),
                   pelvis_from=cast(PelvisSource, data["pelvis_from"]), notes=dict(data["notes"]),
                   stats={name: _number(value) for name, value in data["stats"].items()})


@dataclass(frozen=True)
class TrialSummary:
    """A trial's ``summary.json``: identity, status and reason, the analysis of an ``ok`` trial,
    the optional OpenSim and viewer steps' sub-summaries, warnings raised while analysing, and
    ``elapsed_s`` (seconds; None for a trial that never ran to the end, e.g. interrupted).

    ``out_dir`` is the trial's output folder (where the summary lives); it is not written."""

    key: str
    subject: str
    condition: str
    trial: str
    capture: str
    source: SummarySource
    status: TrialStatus
    reason: str
    out_dir: str
    analysis: TrialAnalysis | None = None
    opensim: OpenSimStep | None = None
    view: ViewStep | None = None
    warnings: tuple[str, ...] = ()
    elapsed_s: float | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def stats(self) -> dict[str, float]:
        """The analysis' statistics; empty for a trial without an analysis."""
        return self.analysis.stats if self.analysis is not None else {}

    @property
    def notes(self) -> dict[str, dict[str, int]]:
        """The analysis' NaN-angle reasons by angle group; empty without an analysis."""
        return self.analysis.notes if self.analysis is not None else {}

    def to_dict(self) -> JsonObject:
        """The JSON object of ``summary.json`` (keys in the order the batch has always written)."""
        data: JsonObject = {"key": self.key, "subject": self.subject, "condition": self.condition,
                            "trial": self.trial, "capture": self.capture, "source": self.source}
        if self.opensim is not None:
            data["opensim"] = self.opensim.to_dict()
        if self.view is not None:
            data["view"] = self.view.to_dict()
        data.update(status=self.status, reason=self.reason)
        if self.analysis is not None:
            data.update(self.analysis.to_dict())
        if self.warnings:
            data["warnings"] = list(self.warnings)
        if self.elapsed_s is not None:
            data["elapsed_s"] = self.elapsed_s
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], out_dir: str | os.PathLike[str]) -> TrialSummary:
        """The summary in ``data`` (a parsed ``summary.json`` of the trial in ``out_dir``).

        Raises:
            InputError: a key is missing or holds the wrong kind of value."""
        try:
            return cls(key=str(data["key"]), subject=str(data["subject"]), condition=str(data["condition"]),
                       trial=str(data["trial"]), capture=str(data["capture"]),
                       source=cast(SummarySource, data["source"]), status=cast(TrialStatus, data["status"]),
                       reason=str(data["reason"]), out_dir=os.fspath(out_dir),
                       analysis=TrialAnalysis.from_dict(data) if data["status"] == "ok" else None,
                       opensim=OpenSimStep.from_dict(data["opensim"]) if "opensim" in data else None,
                   view=ViewStep.from_dict(data["view"]) if "view" in data else None,
                       warnings=tuple(data.get("warnings", ())), elapsed_s=data.get("elapsed_s"))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(os.path.join(out_dir, "summary.json"),
                             f"not a trial summary ({type(exc).__name__}: {exc}); run `spinemocap batch --force` "
                             "to write it anew") from exc


@dataclass(frozen=True)
class TrialOutcome:
    """What a batch run returns for one trial: its summary and whether it was skipped (its
    ``summary.json`` was ``ok`` and newer than every input, so nothing was recomputed)."""

    summary: TrialSummary
    skipped: bool = False

    def to_dict(self) -> JsonObject:
        """The trial's entry in ``batch.json``: the summary's keys, then ``skipped``."""
        return {**self.summary.to_dict(), "skipped": self.skipped}


@dataclass(frozen=True)
class BatchResult:
    """Every trial's outcome, in the order of the study's trials."""

    trials: list[TrialOutcome] = field(default_factory=list)

    @property
    def failed(self) -> list[TrialOutcome]:
        """Trials not analysed (failed or interrupted)."""
        return [t for t in self.trials if not t.summary.ok]

    @property
    def processed(self) -> list[TrialOutcome]:
        """Trials run this time (not skipped as up to date)."""
        return [t for t in self.trials if not t.skipped]
