"""Cross-validation of a tracked capture against a Vicon C3D (``spinemocap crossval``): reads the
files, runs :func:`spinemocap.crossval.compare.cross_validate`, writes summary.json, merged.c3d
(tracked dots + ``VICON_*`` markers in the rig frame at the camera rate), angles.csv and an HTML
page with plots.

Angles, like with like (:func:`crossval_angles`): both systems get the analysis's definitions
(:mod:`spinemocap.analysis.angles`): lumbar = the segment frame at ``T12/L1`` relative to the one
at ``S1``, thoracic = the most cranial mapped level relative to ``T12/L1`` (the row-to-level map
of the capture), :func:`~spinemocap.analysis.frames.cardan_angles` (flexion, lateral bending,
axial rotation), each **from neutral** (:mod:`spinemocap.analysis.neutral`: minus its value in
the trial's first frame that both systems measure), degrees.

- Tape: :func:`~spinemocap.analysis.angles.compute_angles` on the tracked dots, exactly as
  ``spinemocap angles`` / the batch report them (frame at a level: the midline spline's tangent
  and the rows' L -> R axis there).
- Vicon: the same frames from the markers beside the tape, ``VT_RnnL`` / ``VT_RnnR`` at the
  triad rows (:func:`vicon_level_frames`): per frame the superior axis is the tangent, at the
  level, of the not-a-knot cubic spline (a parabola for three rows, the chord for two) through the
  rows' L/R midpoints, the right axis the rows' L -> R axis interpolated at the level (the end
  row's beyond the outer rows), the tracks gap-filled and low-passed as the analysis does its
  rows. A level more than one row pitch outside the triad rows has no Vicon frame, except
  ``S1`` below them: then the Plug-in Gait pelvis (LASI, RASI, LPSI, RPSI) stands in for it, its
  constant offset to the sacral skin removed by the neutral.
"""

from __future__ import annotations

import base64
import io
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline

import exporters

from ..analysis.angles import ANGLE_GROUPS, AngleSettings, compute_angles, level_roles
from ..analysis.curve import row_tracks
from ..analysis.frames import PELVIS_MARKERS, cardan_angles, frame_from_axes, pelvis_frame_from_markers
from ..analysis.levels import LevelMap
from ..analysis.neutral import neutral_from_angles, relative_to_neutral
from ..camera import Rig
from ..capture import Capture
from ..crossval.agreement import agreement
from ..crossval.compare import CrossValidation, CrossValSummary, cross_validate, set_angles, triad_rows
from ..crossval.register import RigToVicon, transform_between_rigs
from ..fileio import InputError, atomic_write, strict_json
from ..markers import MarkerTable
from ..tape import TapeSpec

# an angle whose ICC(2,1) is at or below this is flagged (poor agreement, Koo & Li 2016: < 0.5
# poor, 0.5-0.75 moderate)
ICC_FLAG = 0.75


COMPARED = ANGLE_GROUPS["lumbar"] + ANGLE_GROUPS["thoracic"]


def tape_angle_table(time_s: np.ndarray, positions: np.ndarray, labels: list[str], spec: TapeSpec,
                     levels: LevelMap, up=(0.0, 0.0, 1.0), facing=(0.0, -1.0, 0.0),
                     settings: AngleSettings | None = None) -> pd.DataFrame:
    """The analysis's angle table (:attr:`SpineAngles.table`, deg) of tape dots (F, D, 3) mm at
    ``time_s`` (a regular clock)."""
    fps = 1.0 / float(np.median(np.diff(time_s))) if len(time_s) > 1 else 1.0
    table = MarkerTable.from_arrays(labels, positions, fps)
    return compute_angles(table, spec, levels, up, facing, settings or AngleSettings()).table


def vicon_level_frames(positions: np.ndarray, labels: list[str], spec: TapeSpec, levels: LevelMap,
                       names: list[str], fps: float, settings: AngleSettings | None = None
                       ) -> dict[str, tuple[np.ndarray, str]]:
    """Segment frames (F, 3, 3) (columns a, s, r, :mod:`spinemocap.analysis.frames`) at the
    levels ``names`` from Vicon markers (F, M, 3) mm at the tape's frames (rig frame), and the
    markers that define each (see the module docstring). All-NaN frames where no Vicon frame
    exists, with the reason as the description."""
    settings = settings or AngleSettings()
    rows = triad_rows(labels, spec)
    beside = np.full((len(positions), 2 * len(rows), 3), np.nan)
    pseudo = []
    for k, r in enumerate(rows):
        for j, side in enumerate("LR"):
            beside[:, 2 * k + j] = positions[:, labels.index(f"VT_R{r + 1:02d}{side}")]
            pseudo.append(f"R{r + 1:02d}{side}")
    tracks = row_tracks(beside, pseudo, spec, fps, settings.max_gap_s, settings.lowpass_hz)
    v, centre, across = tracks.v[rows], tracks.centre[:, rows], tracks.transverse[:, rows]
    used = ", ".join(f"VT_R{r + 1:02d}L/R" for r in rows)
    out: dict[str, tuple[np.ndarray, str]] = {}
    for name in names:
        frames = np.full((len(positions), 3, 3), np.nan)
        try:
            at = levels.v_of(name, spec.row_pitch_mm)
        except KeyError as exc:
            out[name] = (frames, str(exc.args[0]))
            continue
        reach = settings.level_reach_rows * spec.row_pitch_mm + 1e-6
        if len(rows) >= 2 and v[0] - reach <= at <= v[-1] + reach:
            for f in range(len(positions)):
                ok = np.isfinite(centre[f]).all(axis=1) & np.isfinite(across[f]).all(axis=1)
                if ok.sum() >= 2 and v[ok][0] - reach <= at <= v[ok][-1] + reach:
                    tangent = CubicSpline(v[ok], centre[f, ok], bc_type="not-a-knot", axis=0).derivative()(at)
                    right = [np.interp(at, v[ok], across[f, ok, k]) for k in range(3)]
                    frames[f] = frame_from_axes(tangent, np.array(right))
            out[name] = (frames, f"tangent of the spline through the midpoints of {used} at {name}, "
                                 f"L -> R of the same rows interpolated there")
        elif name == settings.lower and set(PELVIS_MARKERS) <= set(labels):
            _, frames = pelvis_frame_from_markers({m: positions[:, labels.index(m)] for m in PELVIS_MARKERS})
            out[name] = (frames, "Plug-in Gait pelvis (LASI, RASI, LPSI, RPSI): no triad within a row of " + name)
        else:
            out[name] = (frames, f"no Vicon triad (VT_RnnL/R) within a row of {name} (triads at {used or 'none'})")
    return out


def vicon_angle_table(time_s: np.ndarray, positions: np.ndarray, labels: list[str], spec: TapeSpec,
                      levels: LevelMap, settings: AngleSettings | None = None
                      ) -> tuple[pd.DataFrame, dict[str, str]]:
    """Lumbar and thoracic angles (deg, the analysis's columns) from Vicon markers (F, M, 3) at
    the tape's times ``time_s``, and the markers defining each level's frame."""
    settings = settings or AngleSettings()
    if settings.upper is None:
        settings = replace(settings, upper=list(levels.rows)[-1])
    fps = 1.0 / float(np.median(np.diff(time_s))) if len(time_s) > 1 else 1.0
    roles = level_roles(settings, levels)
    frames = vicon_level_frames(positions, labels, spec, levels, list(roles.values()), fps, settings)
    table = pd.DataFrame({"time": time_s})
    for group, (lo, hi) in {"lumbar": ("lower", "thoracolumbar"), "thoracic": ("thoracolumbar", "upper")}.items():
        values = cardan_angles(frames[roles[lo]][0], frames[roles[hi]][0])
        for k, column in enumerate(ANGLE_GROUPS[group]):
            table[column] = values[:, k]
    return table, {name: described for name, (_, described) in frames.items()}


def crossval_angles(result: CrossValidation, time_s: np.ndarray, positions: np.ndarray, labels: list[str],
                    spec: TapeSpec, levels: LevelMap, up=(0.0, 0.0, 1.0), facing=(0.0, -1.0, 0.0),
                    settings: AngleSettings | None = None) -> None:
    """Lumbar and thoracic angles, from neutral, of the tape and of the Vicon (and of the
    body-model reference when ``result`` has one), stored and scored in ``result`` (see the
    module docstring)."""
    settings = settings or AngleSettings()
    if settings.upper is None:
        settings = replace(settings, upper=list(levels.rows)[-1])

    tape = tape_angle_table(time_s, positions, labels, spec, levels, up, facing, settings)
    vicon, defined = vicon_angle_table(time_s, result.vicon_rig, result.vicon_labels, spec, levels, settings)
    tables = {"tape": tape, "vicon": vicon}
    if result.reference_rig is not None:
        tables["reference"] = tape_angle_table(time_s, result.reference_rig, list(spec.graph.labels), spec, levels,
                                               up, facing, settings)
    # neutral: the first frame every system has every compared angle in (the Vicon's resampled
    # markers may start after the tape's first frame)
    complete = np.logical_and.reduce([np.isfinite(t[list(COMPARED)].to_numpy(float)).all(axis=1)
                                      for t in tables.values()])
    first = int(np.argmax(complete)) if complete.any() else 0
    tables = {k: relative_to_neutral(t, neutral_from_angles(t.iloc[first:], 0.0)) for k, t in tables.items()}
    angles = {c: (tables["tape"][c].to_numpy(float), tables["vicon"][c].to_numpy(float)) for c in COMPARED}
    reference = None
    if "reference" in tables:
        reference = {c: (tables["tape"][c].to_numpy(float), tables["reference"][c].to_numpy(float)) for c in COMPARED}
    convention = {
        "definition": "spinemocap.analysis angles on both sides: lumbar = frame at "
                      f"{settings.thoracolumbar} relative to {settings.lower}, thoracic = {settings.upper} relative to "
                      f"{settings.thoracolumbar}; Cardan flexion (forward +), lateral bending (right +), axial "
                      "rotation (left +); each minus its value in the neutral frame; tape minus Vicon",
        "neutral_time_s": float(time_s[first]),
        "level_rows": {name: _row_or_none(levels, name) for name in defined},
        "tape_frames": "midline spline tangent and the rows' L -> R axis at each level (spinemocap angles)",
        "vicon_frames": defined,
    }
    set_angles(result, angles, convention, reference)


def _row_or_none(levels: LevelMap, name: str) -> float | None:
    """The tape row (1-based) of a level, None where the map does not place it."""
    try:
        return levels.row_of(name)
    except KeyError:
        return None


def _dense(table) -> tuple[np.ndarray, np.ndarray, list[str]]:
    point_types = table.meta.get("point_types") or {}
    labels = [label for label in table.labels if label not in point_types]
    arrays = table.select(labels=labels).to_arrays()
    time = arrays.time  # the file's clock (C3D: frame / rate from its first frame)
    if not np.isfinite(time).all():
        time = arrays.frames / table.fps
    return time, arrays.positions, list(arrays.labels)


def rig_transform(capture_rig: Rig, vicon_rig_path: str | os.PathLike) -> RigToVicon:
    """Rig -> Vicon similarity (R, t mm, scale) from the capture's rig and the same rig expressed in
    the Vicon frame (``spinemocap calibrate wand``'s output)."""
    vicon_rig = Rig.from_toml(vicon_rig_path)
    common = [n for n in capture_rig.names if n in vicon_rig.names]
    if not common:
        raise InputError(vicon_rig_path, f"no camera of the capture's rig ({capture_rig.names}) in this rig")
    cams = [capture_rig[n] for n in common]
    vcams = [vicon_rig[n] for n in common]
    return transform_between_rigs([c.R for c in cams], [c.t for c in cams], [c.R for c in vcams], [c.t for c in vcams])


def crossval_files(tracked_path: str | os.PathLike, vicon_path: str | os.PathLike, capture_path: str | os.PathLike,
                   out: str | os.PathLike, rig_vicon: str | os.PathLike | None = None,
                   marker_diameter_mm: float = 14.0, max_offset_s: float = 1.0,
                   reference_path: str | os.PathLike | None = None,
                   levels_path: str | os.PathLike | None = None) -> CrossValidation:
    """Run the cross-validation on files and write its outputs into ``out`` (summary.json,
    merged.c3d, angles.csv, report.html); returns the result. ``reference_path``: body-model dots in the Vicon frame
    and clock (``spinemocap bodyfit --tape`` on the Vicon file: tape_dots.c3d), written as
    ``REF_*`` beside the tracked dots in merged.c3d and compared with them. ``levels_path``: the
    row-to-level map (default: the capture's, as the batch finds it)."""
    from .levels import find_level_map

    capture = Capture.open(capture_path)
    tracked = exporters.read(tracked_path)
    vicon = exporters.read(vicon_path)
    t_time, t_pos, t_labels = _dense(tracked)
    v_time, v_pos, v_labels = _dense(vicon)
    transform = rig_transform(capture.rig, rig_vicon) if rig_vicon else None
    reference = _dense(exporters.read(reference_path)) if reference_path else None
    result = cross_validate(t_time, t_pos, t_labels, capture.tape, v_time, v_pos, v_labels, marker_diameter_mm,
                            transform, max_offset_s, reference)
    levels: LevelMap | None
    try:
        levels = LevelMap.from_toml(levels_path, capture.tape.n_rows) if levels_path else find_level_map(capture)[0]
    except InputError as exc:
        if levels_path:
            raise
        levels, result.summary.angles_skipped = None, str(exc)
    if levels is not None and not triad_rows(v_labels, capture.tape):
        levels, result.summary.angles_skipped = None, "the Vicon file has no triads (VT_RnnL/R) beside the tape"
    if levels is not None:
        crossval_angles(result, t_time, t_pos, t_labels, capture.tape, levels, capture.up, capture.facing)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = dict(result.summary.to_dict(), tracked=str(tracked_path), vicon=str(vicon_path),
                   capture=str(capture_path), angles_flagged=result.summary.poorly_agreeing(ICC_FLAG))
    with atomic_write(out / "summary.json") as handle:
        handle.write(strict_json(summary, indent=2))
    beside_labels = [f"VICON_{label}" for label in result.vicon_labels]
    beside = result.vicon_rig
    if result.reference_rig is not None:
        beside_labels += [f"REF_{label}" for label in capture.tape.graph.labels]
        beside = np.concatenate([beside, result.reference_rig], axis=1)
    others = MarkerTable.from_arrays(beside_labels, beside, tracked.fps, first_frame=int(tracked.frames[0]))
    exporters.write(tracked, out / "merged.c3d", reference=others, reference_prefix="")
    with atomic_write(out / "angles.csv") as handle:
        names = list(result.angles)
        handle.write("time_s," + ",".join(f"{n}_tape,{n}_vicon" for n in names) + "\n")
        for i, t in enumerate(t_time):
            values = [f"{result.angles[n][k][i]:.4f}" for n in names for k in (0, 1)]
            handle.write(f"{t:.5f}," + ",".join(values) + "\n")
    angles = dict(result.angles)
    angles.update({f"{name} (tape vs body fit)": pair for name, pair in (result.reference_angles or {}).items()})
    write_crossval_page(out / "report.html", result.summary, str(tracked_path), str(vicon_path), t_time, angles)
    return result


def _figure_html(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    return f'<img src="data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}">'


def write_crossval_page(path: Path, summary: CrossValSummary, tracked: str, vicon: str, time_s: np.ndarray,
                        angles: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """HTML page at ``path``: the files compared, alignment, marker table, angle table, and each
    angle's waveforms (name -> (tape (F,), other (F,)) deg at ``time_s`` (F,) s) with its
    Bland-Altman plot."""
    import html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = ["<html><head><meta charset='utf-8'><title>spinemocap cross-validation</title></head><body>",
             "<h1>Tape vs Vicon cross-validation</h1>",
             f"<p>Tracked: {html.escape(tracked)}<br>Vicon: {html.escape(vicon)}</p>",
             "<h2>Frame and clock</h2><pre>" + html.escape(json.dumps(summary.alignment.to_dict(), indent=1)) + "</pre>",
             ("<h2>Markers on or beside the tape</h2><table border=1><tr><th>marker</th><th>RMSE (mm)</th>"
              "<th>nearest dot (mm)</th></tr>")]
    for label, entry in summary.markers.items():
        rmse = f"{entry.rmse_mm:.2f}" if entry.rmse_mm is not None else ""
        parts.append(f"<tr><td>{html.escape(label)}</td><td>{rmse}</td><td>{entry.nearest_dot_mm_mean:.1f}</td></tr>")
    parts.append("</table><h2>Angles (tape - Vicon)</h2><table border=1><tr><th>angle</th><th>RMSE</th><th>bias</th>"
                 "<th>LoA</th><th>ICC(2,1)</th><th>CMC</th><th>n</th></tr>")
    for name, s in summary.angles.items():
        parts.append(f"<tr><td>{name}</td><td>{s.rmse:.2f}</td><td>{s.bias:+.2f}</td>"
                     f"<td>[{s.loa_low:+.2f}, {s.loa_high:+.2f}]</td><td>{s.icc:.3f}</td>"
                     f"<td>{s.cmc:.3f}</td><td>{s.n}</td></tr>")
    convention = summary.angle_convention or {}
    if convention:
        parts.append(f"</table><p>{html.escape(convention['definition'])}</p><ul>" + "".join(
            f"<li>Vicon frame at {html.escape(level)}: {html.escape(text)}</li>"
            for level, text in convention["vicon_frames"].items()) + "</ul>")
    else:
        parts.append(f"</table><p>No angles: {html.escape(summary.angles_skipped or '')}</p>")
    if summary.reference is not None:
        r = summary.reference
        parts.append("<h2>Body-model tape (REF_*) vs tracked dots</h2>"
                     f"<p>dot distance mean {r.dot_distance_mean_mm:.2f} mm, median {r.dot_distance_median_mm:.2f} "
                     f"mm, p95 {r.dot_distance_p95_mm:.2f} mm over {r.n} dot-frames</p><table border=1>"
                     "<tr><th>angle (tape - body fit)</th><th>RMSE</th><th>bias</th><th>ICC(2,1)</th><th>CMC</th></tr>")
        for name, a in r.angles.items():
            parts.append(f"<tr><td>{name}</td><td>{a.rmse:.2f}</td><td>{a.bias:+.2f}</td>"
                         f"<td>{a.icc:.3f}</td><td>{a.cmc:.3f}</td></tr>")
        parts.append("</table>")
    if angles:
        names = list(angles)
        fig, axes = plt.subplots(len(names), 2, figsize=(11, 2.4 * len(names)), constrained_layout=True)
        axes = np.atleast_2d(axes)
        for row, name in enumerate(names):
            tape, other = angles[name]
            axes[row, 0].plot(time_s, tape, label="tape")
            axes[row, 0].plot(time_s, other, "--", label="body fit" if "body fit" in name else "Vicon")
            axes[row, 0].set_ylabel(f"{name} (deg)", fontsize=8)
            axes[row, 0].legend(fontsize=7)
            mean, diff = (tape + other) / 2, tape - other
            s = agreement(tape, other, "deg")
            axes[row, 1].scatter(mean, diff, s=6)
            for level, style in ((s.bias, "-"), (s.loa_low, "--"), (s.loa_high, "--")):
                axes[row, 1].axhline(level, color="k", ls=style, lw=0.8)
            axes[row, 1].set_xlabel("mean of tape and Vicon (deg)", fontsize=8)
            axes[row, 1].set_ylabel("difference (deg)", fontsize=8)
        axes[-1, 0].set_xlabel("time (s)")
        parts.append("<h2>Waveforms and Bland-Altman plots</h2>" + _figure_html(fig))
        plt.close(fig)
    parts.append("</body></html>")
    with atomic_write(path) as handle:
        handle.write("\n".join(parts))
