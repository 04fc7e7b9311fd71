"""Cross-validation of tracked tape dots against a Vicon recording (both as dense arrays).

Steps: the shared markers (Vicon markers on the tape's centre line, :mod:`.tape_markers`) give
the clock offset and transform (:mod:`.register`, or the transform from the wand calibration);
every Vicon marker is then resampled at the tape's frame times and brought into the rig frame;
markers are compared with the tape points they sit on (and the nearest dot). Angle waveforms of
both systems are computed by the application layer (``spinemocap.app.crossval``: the analysis's
angle definitions on both sides) and scored here by :func:`set_angles`. Units: mm, s, degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..fileio import InputError
from ..tape import TapeSpec
from .agreement import Agreement, agreement
from .register import Alignment, RigToVicon, estimate_alignment
from .tape_markers import TAPE_MARKER, tape_marker_points


@dataclass(frozen=True)
class MarkerAgreement:
    """One Vicon marker on or beside the tape: ``nearest_dot_mm_mean``, its mean distance to the
    nearest tracked dot (mm); for a marker on the tape's centre line also ``rmse_mm`` (3D RMS
    distance to the tape point it sits on), ``bias_mm`` (mean (3,) difference, rig frame) and ``n``
    frames compared (all three None for the others)."""

    nearest_dot_mm_mean: float
    rmse_mm: float | None = None
    bias_mm: list[float] | None = None
    n: int | None = None

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"nearest_dot_mm_mean": self.nearest_dot_mm_mean}
        if self.rmse_mm is not None:
            out.update(rmse_mm=self.rmse_mm, bias_mm=self.bias_mm, n=self.n)
        return out


@dataclass
class ReferenceAgreement:
    """Body-model dots against the tracked dots: distance mean / median / 95th percentile (mm) over
    ``n`` dot-frames, and the angles of both (name -> :class:`Agreement`, tape minus body fit)."""

    dot_distance_mean_mm: float
    dot_distance_median_mm: float
    dot_distance_p95_mm: float
    n: int
    angles: dict[str, Agreement] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        return {"dot_distance_mean_mm": self.dot_distance_mean_mm,
                "dot_distance_median_mm": self.dot_distance_median_mm,
                "dot_distance_p95_mm": self.dot_distance_p95_mm, "n": self.n,
                "angles": {name: a.to_dict() for name, a in self.angles.items()}}


@dataclass
class CrossValSummary:
    """What a cross-validation found: the ``alignment``, the centre-line markers it was estimated
    from (``shared_markers``, at ``marker_height_mm`` above the tape), every Vicon marker on or
    beside the tape (``markers``), the angles' agreement (name -> :class:`Agreement`, tape minus
    Vicon) with how both sides were computed (``angle_convention``), the body-model ``reference``
    where one was given, and ``angles_skipped``: why no angle was compared, where none was."""

    alignment: Alignment
    shared_markers: list[str]
    marker_height_mm: float
    markers: dict[str, MarkerAgreement]
    angles: dict[str, Agreement] = field(default_factory=dict)
    angle_convention: dict | None = None
    reference: ReferenceAgreement | None = None
    angles_skipped: str | None = None

    def poorly_agreeing(self, icc_line: float) -> list[str]:
        """The angles whose ICC(2,1) is not above ``icc_line`` (NaN included)."""
        return [name for name, a in self.angles.items() if not a.icc > icc_line]

    def to_dict(self) -> dict[str, object]:
        """The JSON-ready summary (``summary.json``'s keys)."""
        a = self.alignment
        out: dict[str, object] = {
            "alignment": a.to_dict(), "clock_offset_s": a.offset_s,
            "transform": {"rotation": a.R.tolist(), "translation_mm": a.t.tolist(), "scale": a.scale},
            "shared_markers": self.shared_markers, "marker_height_mm": self.marker_height_mm,
            "markers": {label: m.to_dict() for label, m in self.markers.items()},
            "angles": {name: s.to_dict() for name, s in self.angles.items()}}
        if self.reference is not None:
            out["reference"] = self.reference.to_dict()
        if self.angle_convention is not None:
            out["angle_convention"] = self.angle_convention
        if self.angles_skipped is not None:
            out["angles_skipped"] = self.angles_skipped
        return out


@dataclass
class CrossValidation:
    """Result: the alignment, Vicon markers resampled into the rig frame at the tape's times
    (``vicon_labels``, ``vicon_rig`` (F, M, 3)), the angles of both systems (``angles``: name ->
    (tape (F,), vicon (F,))) and the :class:`CrossValSummary`."""

    alignment: Alignment
    vicon_labels: list[str]
    vicon_rig: np.ndarray
    angles: dict[str, tuple[np.ndarray, np.ndarray]]
    summary: CrossValSummary
    reference_rig: np.ndarray | None = None  # (F, D, 3) body-model dots (tape labels), rig frame
    reference_angles: dict[str, tuple[np.ndarray, np.ndarray]] | None = None  # name -> (tape, reference)


def resample(time_s: np.ndarray, points: np.ndarray, query_s: np.ndarray, max_gap_s: float = 0.05) -> np.ndarray:
    """(Q, M, 3) per-marker cubic resampling of (N, M, 3) trajectories at ``query_s``; NaN
    outside a marker's recording and in gaps longer than ``max_gap_s``."""
    from scipy.interpolate import CubicSpline

    out = np.full((len(query_s), points.shape[1], 3), np.nan)
    for m in range(points.shape[1]):
        ok = np.isfinite(points[:, m]).all(axis=1)
        if ok.sum() < 4:
            continue
        t = time_s[ok]
        spline = CubicSpline(t, points[ok, m], axis=0)
        k = np.searchsorted(t, query_s)
        inside = (k > 0) & (k < len(t))
        gap = np.full(len(query_s), np.inf)
        gap[inside] = t[k[inside]] - t[k[inside] - 1]
        valid = inside & (gap <= max_gap_s)
        out[valid, m] = spline(query_s[valid])
    return out


def triad_rows(vicon_labels: list[str], spec: TapeSpec) -> list[int]:
    """0-based 2-dot rows with a complete Vicon triad (VT_Rnn, VT_RnnL, VT_RnnR)."""
    rows = []
    for label in vicon_labels:
        match = TAPE_MARKER.match(label)
        if match and not match.group(2):
            row, name = int(match.group(1)) - 1, label
            if {name + "L", name + "R"} <= set(vicon_labels) and 0 <= row < spec.n_rows:
                rows.append(row)
    return sorted(set(rows))


def cross_validate(tape_time: np.ndarray, tape_positions: np.ndarray, tape_labels: list[str], spec: TapeSpec,
                   vicon_time: np.ndarray, vicon_positions: np.ndarray, vicon_labels: list[str],
                   marker_diameter_mm: float = 14.0, transform: RigToVicon | None = None,
                   max_offset_s: float = 1.0,
                   reference: tuple[np.ndarray, np.ndarray, list[str]] | None = None) -> CrossValidation:
    """Compare tracked dots (F, D, 3) at ``tape_time`` with Vicon markers (N, M, 3) at
    ``vicon_time`` (Vicon clock). See the module docstring. ``reference`` (time (K,), dots
    (K, D, 3), labels) in the Vicon frame and clock, e.g. the tape read off a body fitted to the
    Vicon markers (``spinemocap bodyfit --tape``), is compared with the tracked dots too."""
    missing = [label for label in spec.graph.labels if label not in tape_labels]
    if missing:
        raise InputError("tracked markers", f"tape dots {missing[:6]} are absent (is this the capture's tape?)")
    height = spec.thickness_mm + marker_diameter_mm / 2
    shared, expected = tape_marker_points(tape_positions, tape_labels, spec, vicon_labels, height)
    if not shared:
        raise InputError("vicon", "no Vicon marker on the tape's centre line (labels VT_Rnn at 2-dot rows); "
                                  f"Vicon labels: {vicon_labels[:12]}")
    columns = [vicon_labels.index(s) for s in shared]
    alignment = estimate_alignment(tape_time, expected, vicon_time, vicon_positions[:, columns], max_offset_s,
                                   transform)
    vicon_rig = alignment.to_rig(resample(vicon_time, vicon_positions, tape_time + alignment.offset_s))
    markers: dict[str, MarkerAgreement] = {}
    dots = tape_positions[:, [tape_labels.index(label) for label in spec.graph.labels]]
    for k, label in enumerate(vicon_labels):
        d_dot = np.linalg.norm(vicon_rig[:, k, None] - dots, axis=2)
        nearest = np.nanmin(np.where(np.isfinite(d_dot), d_dot, np.inf), axis=1)
        nearest[~np.isfinite(nearest)] = np.nan
        if not np.any(nearest < 80.0):
            continue  # not on or beside the tape
        if label in shared:
            diff = vicon_rig[:, k] - expected[:, shared.index(label)]
            ok = np.isfinite(diff).all(axis=1)
            markers[label] = MarkerAgreement(float(np.nanmean(nearest)),
                                             float(np.sqrt(np.mean(np.sum(diff[ok] ** 2, axis=1)))),
                                             diff[ok].mean(axis=0).tolist(), int(ok.sum()))
        else:
            markers[label] = MarkerAgreement(float(np.nanmean(nearest)))
    summary = CrossValSummary(alignment, shared, height, markers)
    result = CrossValidation(alignment, list(vicon_labels), vicon_rig, {}, summary)
    if reference is not None:
        _compare_reference(result, reference, tape_time, tape_positions, tape_labels, spec)
    return result


def set_angles(result: CrossValidation, angles: dict[str, tuple[np.ndarray, np.ndarray]], convention: dict,
               reference_angles: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> None:
    """Store angle waveforms (name -> (tape (F,), Vicon (F,)) deg at the tape's frames) and
    their agreement (tape minus Vicon: RMSE, bias, limits of agreement, ICC(2,1), CMC) in
    ``result`` and its summary; ``convention`` says how both sides were computed;
    ``reference_angles``: name -> (tape, body-model reference), scored likewise."""
    result.angles = dict(angles)
    result.summary.angles = {name: agreement(a, b, "deg") for name, (a, b) in angles.items()}
    result.summary.angle_convention = convention
    if reference_angles is not None and result.summary.reference is not None:
        result.reference_angles = dict(reference_angles)
        result.summary.reference.angles = {name: agreement(t, r, "deg") for name, (t, r) in reference_angles.items()}


def _compare_reference(result: CrossValidation, reference: tuple[np.ndarray, np.ndarray, list[str]],
                       tape_time: np.ndarray, tape_positions: np.ndarray, tape_labels: list[str], spec: TapeSpec
                       ) -> None:
    """Body-model dots vs tracked dots: per dot-frame distances (``reference_rig``: the body-model
    dots in the rig frame at the tape's times, tape labels, for the angles)."""
    ref_time, ref_positions, ref_labels = reference
    missing = [label for label in spec.graph.labels if label not in ref_labels]
    if missing:
        raise InputError("reference", f"reference dots lack the tape's labels {missing[:6]}")
    order = [list(ref_labels).index(label) for label in spec.graph.labels]
    a = result.alignment
    ref_rig = a.to_rig(resample(np.asarray(ref_time), np.asarray(ref_positions)[:, order], tape_time + a.offset_s))
    tracked = tape_positions[:, [tape_labels.index(label) for label in spec.graph.labels]]
    d = np.linalg.norm(ref_rig - tracked, axis=2)
    d = d[np.isfinite(d)]
    if len(d):
        stats = ReferenceAgreement(float(d.mean()), float(np.median(d)), float(np.percentile(d, 95)), int(len(d)))
    else:
        stats = ReferenceAgreement(float("nan"), float("nan"), float("nan"), 0)
    result.summary.reference = stats
    result.reference_rig = ref_rig
