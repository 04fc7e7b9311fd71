"""Cross-validation of a tracked capture against a Vicon C3D (``spinemocap crossval``): reads the
files, runs :func:`spinemocap.crossval.compare.cross_validate`, writes summary.json, merged.c3d
(tracked dots + ``VICON_*`` markers in the rig frame at the camera rate), angles.csv and an HTML
page with plots."""

from __future__ import annotations

import base64
import io
import json
import os
from pathlib import Path

import numpy as np

import exporters

from ..camera import Rig
from ..capture import Capture
from ..crossval.agreement import agreement
from ..crossval.compare import CrossValidation, cross_validate
from ..crossval.register import RigToVicon, transform_between_rigs
from ..fileio import InputError, atomic_write
from ..markers import MarkerTable

# an angle whose ICC(2,1) is at or below this is flagged (poor agreement, Koo & Li 2016: < 0.5
# poor, 0.5-0.75 moderate)
ICC_FLAG = 0.75


def _dense(table) -> tuple[np.ndarray, np.ndarray, list[str]]:
    point_types = table.meta.get("point_types") or {}
    labels = [label for label in table.labels if label not in point_types]
    arrays = table.select(labels=labels).to_arrays()
    time = arrays["time"]  # the file's clock (C3D: frame / rate from its first frame)
    if not np.isfinite(time).all():
        time = arrays["frames"] / table.fps
    return time, arrays["positions"], list(arrays["labels"])


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
                   reference_path: str | os.PathLike | None = None) -> tuple[CrossValidation, dict]:
    """Run the cross-validation on files and write its outputs into ``out``; returns the result
    and the summary written to summary.json. ``reference_path``: body-model dots in the Vicon frame
    and clock (``spinemocap bodyfit --tape`` on the Vicon file: tape_dots.c3d), written as
    ``REF_*`` beside the tracked dots in merged.c3d and compared with them."""
    capture = Capture.open(capture_path)
    tracked = exporters.read(tracked_path)
    vicon = exporters.read(vicon_path)
    t_time, t_pos, t_labels = _dense(tracked)
    v_time, v_pos, v_labels = _dense(vicon)
    transform = rig_transform(capture.rig, rig_vicon) if rig_vicon else None
    reference = _dense(exporters.read(reference_path)) if reference_path else None
    result = cross_validate(t_time, t_pos, t_labels, capture.tape, v_time, v_pos, v_labels, marker_diameter_mm,
                            transform, max_offset_s, reference)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = dict(result.summary, tracked=str(tracked_path), vicon=str(vicon_path), capture=str(capture_path))
    summary["angles_flagged"] = [n for n, a in summary["angles"].items() if not a["icc"] > ICC_FLAG]
    with atomic_write(out / "summary.json") as handle:
        json.dump(summary, handle, indent=2)
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
    write_report(out / "report.html", summary, t_time, angles)
    return result, summary


def _figure_html(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    return f'<img src="data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}">'


def write_report(path: Path, summary: dict, time_s: np.ndarray, angles: dict) -> None:
    """HTML page: alignment, marker table, angle table, waveforms and Bland-Altman plots."""
    import html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = ["<html><head><meta charset='utf-8'><title>spinemocap cross-validation</title></head><body>",
             "<h1>Tape vs Vicon cross-validation</h1>",
             f"<p>Tracked: {html.escape(summary['tracked'])}<br>Vicon: {html.escape(summary['vicon'])}</p>",
             "<h2>Frame and clock</h2><pre>" + html.escape(json.dumps(summary["alignment"], indent=1)) + "</pre>",
             ("<h2>Markers on or beside the tape</h2><table border=1><tr><th>marker</th><th>RMSE (mm)</th>"
              "<th>nearest dot (mm)</th></tr>")]
    for label, entry in summary["markers"].items():
        rmse = f"{entry['rmse_mm']:.2f}" if "rmse_mm" in entry else ""
        parts.append(f"<tr><td>{html.escape(label)}</td><td>{rmse}</td><td>{entry['nearest_dot_mm_mean']:.1f}</td></tr>")
    parts.append("</table><h2>Angles (tape - Vicon)</h2><table border=1><tr><th>angle</th><th>RMSE</th><th>bias</th>"
                 "<th>LoA</th><th>ICC(2,1)</th><th>CMC</th><th>n</th></tr>")
    for name, s in summary["angles"].items():
        parts.append(f"<tr><td>{name}</td><td>{s['rmse_deg']:.2f}</td><td>{s['bias_deg']:+.2f}</td>"
                     f"<td>[{s['loa_low_deg']:+.2f}, {s['loa_high_deg']:+.2f}]</td><td>{s['icc']:.3f}</td>"
                     f"<td>{s['cmc']:.3f}</td><td>{s['n']}</td></tr>")
    parts.append(f"</table><p>{html.escape(summary['angle_convention'])}</p>")
    if "reference" in summary:
        r = summary["reference"]
        parts.append("<h2>Body-model tape (REF_*) vs tracked dots</h2>"
                     f"<p>dot distance mean {r['dot_distance_mean_mm']:.2f} mm, median {r['dot_distance_median_mm']:.2f} "
                     f"mm, p95 {r['dot_distance_p95_mm']:.2f} mm over {r['n']} dot-frames</p><table border=1>"
                     "<tr><th>angle (tape - body fit)</th><th>RMSE</th><th>bias</th><th>ICC(2,1)</th><th>CMC</th></tr>")
        for name, a in r["angles"].items():
            parts.append(f"<tr><td>{name}</td><td>{a['rmse_deg']:.2f}</td><td>{a['bias_deg']:+.2f}</td>"
                         f"<td>{a['icc']:.3f}</td><td>{a['cmc']:.3f}</td></tr>")
        parts.append("</table>")
    if angles:
        names = list(angles)
        fig, axes = plt.subplots(len(names), 2, figsize=(11, 2.4 * len(names)), constrained_layout=True)
        axes = np.atleast_2d(axes)
        for row, name in enumerate(names):
            tape, vicon = angles[name]
            axes[row, 0].plot(time_s, tape, label="tape")
            axes[row, 0].plot(time_s, vicon, "--", label="body fit" if "body fit" in name else "Vicon")
            axes[row, 0].set_ylabel(f"{name} (deg)", fontsize=8)
            axes[row, 0].legend(fontsize=7)
            mean, diff = (tape + vicon) / 2, tape - vicon
            s = agreement(tape, vicon, "deg")
            axes[row, 1].scatter(mean, diff, s=6)
            for level, style in ((s["bias_deg"], "-"), (s["loa_low_deg"], "--"), (s["loa_high_deg"], "--")):
                axes[row, 1].axhline(level, color="k", ls=style, lw=0.8)
            axes[row, 1].set_xlabel("mean of tape and Vicon (deg)", fontsize=8)
            axes[row, 1].set_ylabel("difference (deg)", fontsize=8)
        axes[-1, 0].set_xlabel("time (s)")
        parts.append("<h2>Waveforms and Bland-Altman plots</h2>" + _figure_html(fig))
        plt.close(fig)
    parts.append("</body></html>")
    with atomic_write(path) as handle:
        handle.write("\n".join(parts))
