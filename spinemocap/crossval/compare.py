"""Cross-validation of tracked tape dots against a Vicon recording (both as dense arrays).

Steps: the shared markers (Vicon markers on the tape's centre line, :mod:`.tape_markers`) give
the clock offset and transform (:mod:`.register`, or the transform from the wand calibration);
every Vicon marker is then resampled at the tape's frame times and brought into the rig frame;
markers are compared with the tape points they sit on (and the nearest dot). Angle waveforms of
both systems are computed by the application layer (``spinemocap.app.crossval``: the analysis's
angle definitions on both sides) and scored here by :func:`set_angles`. Units: mm, s, degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fileio import InputError
from ..tape import TapeSpec
from .agreement import agreement
from .register import Alignment, RigToVicon, estimate_alignment
from .tape_markers import TAPE_MARKER, tape_marker_points


@dataclass
class CrossValidation:
    """Result: the alignment, Vicon markers resampled into the rig frame at the tape's times
    (``vicon_labels``, ``vicon_rig`` (F, M, 3)), the angles of both systems (``angles``: name ->
    (tape (F,), vicon (F,))) and the summary dictionary."""

    alignment: Alignment
    vicon_labels: list[str]
    vicon_rig: np.ndarray
    angles: dict[str, tuple[np.ndarray, np.ndarray]]
    summary: dict
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
    markers = {}
    dots = tape_positions[:, [tape_labels.index(label) for label in spec.graph.labels]]
    for k, label in enumerate(vicon_labels):
        d_dot = np.linalg.norm(vicon_rig[:, k, None] - dots, axis=2)
        nearest = np.nanmin(np.where(np.isfinite(d_dot), d_dot, np.inf), axis=1)
        nearest[~np.isfinite(nearest)] = np.nan
        if not np.any(nearest < 80.0):
            continue  # not on or beside the tape
        entry = {"nearest_dot_mm_mean": float(np.nanmean(nearest))}
        if label in shared:
            diff = vicon_rig[:, k] - expected[:, shared.index(label)]
            ok = np.isfinite(diff).all(axis=1)
            entry.update(rmse_mm=float(np.sqrt(np.mean(np.sum(diff[ok] ** 2, axis=1)))),
                         bias_mm=diff[ok].mean(axis=0).tolist(), n=int(ok.sum()))
        markers[label] = entry
    summary = {
        "alignment": alignment.to_dict(),
        "clock_offset_s": alignment.offset_s,
        "transform": {"rotation": alignment.R.tolist(), "translation_mm": alignment.t.tolist(),
                      "scale": alignment.scale},
        "shared_markers": shared,
        "marker_height_mm": height,
        "markers": markers,
        "angles": {},
    }
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
    result.summary["angles"] = {name: agreement(a, b, "deg") for name, (a, b) in angles.items()}
    result.summary["angle_convention"] = convention
    if reference_angles is not None and "reference" in result.summary:
        result.reference_angles = dict(reference_angles)
        result.summary["reference"]["angles"] = {name: agreement(t, r, "deg")
                                                 for name, (t, r) in reference_angles.items()}


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
    stats: dict[str, object] = {"dot_distance_mean_mm": float(d.mean()) if len(d) else float("nan"),
             "dot_distance_median_mm": float(np.median(d)) if len(d) else float("nan"),
             "dot_distance_p95_mm": float(np.percentile(d, 95)) if len(d) else float("nan"), "n": int(len(d))}
    stats["angles"] = {}
    result.summary["reference"] = stats
    result.reference_rig = ref_rig
