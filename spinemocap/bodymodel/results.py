"""Writing a body fit: the body sequence (``body.npz``), ``summary.json``, per-marker/per-frame
residuals (``residuals.csv``) and a plot (``residuals.png``). All writes are atomic."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..fileio import atomic_path, atomic_write, strict_json
from .fit import BodyFit
from .markersets import is_trunk

# A fitted marker this far from its measurement (RMS over the trial) is flagged: the body
# could not explain it (wrong label, marker moved, or a rule that does not fit this body).
MARKER_FLAG_MM = 20.0
#: What ``summary.json`` says of every body fit.
FIT_NOTE = ("a body fit to sparse markers is a baseline, not a truth: free per-marker offsets let a small "
            "marker residual coexist with a misplaced back surface")


@dataclass(frozen=True)
class BodyFitSummary:
    """A body fit's numbers (``summary.json``; lengths mm): the marker file (``source``), the
    body model, frames fitted (count, first, fps), the markers used, the RMS marker residual over
    all markers and over the trunk markers (None without any), per marker and per frame,
    each marker's fitted offset from its vertex, the shape parameters, the frames kept at the
    previous pose (too few markers), the markers beyond :data:`MARKER_FLAG_MM`, the fit's time per
    stage (s) and :data:`FIT_NOTE`. With the tape laid on the fitted body: its dots' C3D file
    (``tape_dots``) and the nearest vertebral level of each tape row (``tape_row_levels``)."""

    source: str
    model: str
    n_frames: int
    first_frame: int
    fps: float
    markers: list[str]
    marker_rms_mm: float
    trunk_markers: list[str]
    trunk_marker_rms_mm: float | None
    per_marker_rms_mm: dict[str, float]
    per_frame_rms_mm: list[float]
    offset_mm: dict[str, float]
    shape: list[float]
    frames_without_fit: list[int]
    markers_flagged: list[str]
    timings_s: dict[str, float]
    note: str = FIT_NOTE
    tape_dots: str | None = None
    tape_row_levels: list[str] | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields in order, the tape's two only when it was laid."""
        out: dict[str, Any] = {
            "source": self.source, "model": self.model, "n_frames": self.n_frames, "first_frame": self.first_frame,
            "fps": self.fps, "markers": list(self.markers), "marker_rms_mm": self.marker_rms_mm,
            "trunk_markers": list(self.trunk_markers), "trunk_marker_rms_mm": self.trunk_marker_rms_mm,
            "per_marker_rms_mm": dict(self.per_marker_rms_mm), "per_frame_rms_mm": list(self.per_frame_rms_mm),
            "offset_mm": dict(self.offset_mm), "shape": list(self.shape),
            "frames_without_fit": list(self.frames_without_fit), "markers_flagged": list(self.markers_flagged),
            "timings_s": dict(self.timings_s), "note": self.note}
        if self.tape_dots is not None:
            out["tape_dots"] = self.tape_dots
        if self.tape_row_levels is not None:
            out["tape_row_levels"] = self.tape_row_levels
        return out

    def write(self, folder: str | os.PathLike) -> None:
        """``folder/summary.json`` (strict JSON, atomically)."""
        with atomic_write(Path(folder) / "summary.json") as handle:
            handle.write(strict_json(self.to_dict(), indent=2))


def _rms(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else float("nan")


def fit_summary(fit: BodyFit, frames: np.ndarray, fps: float, source: str) -> BodyFitSummary:
    """The numbers of ``summary.json`` (:class:`BodyFitSummary`) of ``fit`` over ``frames`` (F,)
    at ``fps``, fitted to the marker file ``source``."""
    residual = fit.residual_mm
    trunk = np.array([is_trunk(label) for label in fit.labels])
    per_marker = {label: _rms(residual[:, k]) for k, label in enumerate(fit.labels)}
    flagged_markers = [label for label, value in per_marker.items() if value > MARKER_FLAG_MM]
    return BodyFitSummary(
        source=source,
        model=fit.model_name,
        n_frames=len(frames),
        first_frame=int(frames[0]) if len(frames) else 0,
        fps=float(fps),
        markers=list(fit.labels),
        marker_rms_mm=_rms(residual),
        trunk_markers=[label for label, t in zip(fit.labels, trunk) if t],
        trunk_marker_rms_mm=_rms(residual[:, trunk]) if trunk.any() else None,
        per_marker_rms_mm=per_marker,
        per_frame_rms_mm=[_rms(row) for row in residual],
        offset_mm={label: float(np.linalg.norm(o)) for label, o in zip(fit.labels, fit.offsets)},
        shape=[float(v) for v in fit.shape],
        frames_without_fit=[int(frames[i]) for i in np.flatnonzero(fit.flagged)],
        markers_flagged=flagged_markers,
        timings_s=fit.timings_s,
    )


def write_fit(out: str | os.PathLike, fit: BodyFit, frames: np.ndarray, fps: float, source: str,
              pose_joints: tuple[str, ...], vertices: np.ndarray | None = None) -> BodyFitSummary:
    """Write everything of a fit into folder ``out``; returns the summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    arrays = {"model": np.array(fit.model_name), "labels": np.array(fit.labels), "frames": np.asarray(frames),
              "time": np.asarray(frames) / fps, "fps": np.array(fps), "shape": fit.shape, "poses": fit.poses,
              "pose_joints": np.array(pose_joints), "marker_vertices": fit.vertices,
              "marker_offsets_mm": fit.offsets, "residual_mm": fit.residual_mm, "flagged": fit.flagged}
    if vertices is not None:
        arrays["vertices_mm"] = vertices
    with atomic_path(out / "body.npz") as tmp:
        np.savez_compressed(tmp, allow_pickle=False, **arrays)
    summary = fit_summary(fit, np.asarray(frames), fps, source)
    summary.write(out)
    with atomic_write(out / "residuals.csv") as handle:
        handle.write("frame,label,residual_mm\n")
        for i, frame in enumerate(frames):
            for k, label in enumerate(fit.labels):
                value = fit.residual_mm[i, k]
                handle.write(f"{int(frame)},{label},{'' if not np.isfinite(value) else f'{value:.3f}'}\n")
    plot_fit(out / "residuals.png", fit, np.asarray(frames), summary)
    return summary


def plot_fit(path: Path, fit: BodyFit, frames: np.ndarray, summary: BodyFitSummary) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 7), constrained_layout=True)
    ax1.plot(frames, summary.per_frame_rms_mm, lw=1)
    flagged = frames[fit.flagged]
    if len(flagged):
        ax1.plot(flagged, np.zeros(len(flagged)), "rx", label="no fit (too few markers)")
        ax1.legend()
    ax1.set_xlabel("frame")
    ax1.set_ylabel("marker RMS (mm)")
    ax1.set_title(f"{fit.model_name} fit: marker RMS {summary.marker_rms_mm:.2f} mm"
                  + (f", trunk {summary.trunk_marker_rms_mm:.2f} mm" if summary.trunk_marker_rms_mm else ""))
    values = [summary.per_marker_rms_mm[label] for label in fit.labels]
    colours = ["tab:red" if label in summary.markers_flagged else
               "tab:orange" if label in summary.trunk_markers else "tab:blue" for label in fit.labels]
    ax2.bar(range(len(values)), values, color=colours)
    ax2.set_xticks(range(len(values)), fit.labels, rotation=90, fontsize=7)
    ax2.set_ylabel("RMS over the trial (mm)")
    ax2.set_title(f"per marker (orange: trunk, red: flagged > {MARKER_FLAG_MM:.0f} mm)")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
