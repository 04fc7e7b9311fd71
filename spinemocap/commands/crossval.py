"""``spinemocap crossval TRACKED VICON.c3d --capture CAPTURE --out DIR``: cross-validate the tape
against a Vicon recording (clock offset, transform, marker and angle agreement; merged C3D; HTML
page with plots; summary.json)."""

from __future__ import annotations

import argparse
import base64
import io
import json
from pathlib import Path

import numpy as np


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "crossval", help="cross-validate tracked tape dots against Vicon markers (agreement, merged C3D, report)",
        description="Bring the tracked dots and a Vicon C3D into one frame and clock (from Vicon markers on the "
                    "tape's centre line, VT_Rnn, or the wand calibration's rig with --rig-vicon), resample, and "
                    "compare markers and segment angles: RMSE, bias, Bland-Altman limits, ICC(2,1), CMC. Writes "
                    "summary.json, merged.c3d (tracked dots + VICON_* markers in the rig frame), angles.csv and "
                    "report.html into --out.")
    p.add_argument("tracked", type=Path, help="tracked dots (C3D, TRC or CSV marker table)")
    p.add_argument("vicon", type=Path, help="Vicon C3D")
    p.add_argument("--capture", type=Path, required=True, help="the capture folder (tape spec, rig)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--rig-vicon", type=Path, help="the capture's rig expressed in the Vicon frame (from "
                   "'spinemocap calibrate wand'): the transform is taken from it, only the clock offset is estimated")
    p.add_argument("--marker-diameter", type=float, default=14.0, help="Vicon marker diameter in mm (default 14)")
    p.add_argument("--max-offset", type=float, default=1.0, help="largest clock offset searched, s (default 1)")
    p.set_defaults(func=run_crossval)


def _dense(table) -> tuple[np.ndarray, np.ndarray, list[str]]:
    point_types = table.meta.get("point_types") or {}
    labels = [label for label in table.labels if label not in point_types]
    arrays = table.select(labels=labels).to_arrays()
    time = arrays["frames"] / table.fps
    return time, arrays["positions"], list(arrays["labels"])


def rig_transform(capture_rig, vicon_rig_path: Path) -> tuple[np.ndarray, np.ndarray]:
    from spinemocap.camera import Rig
    from spinemocap.crossval.register import transform_between_rigs
    from spinemocap.fileio import InputError

    vicon_rig = Rig.from_toml(vicon_rig_path)
    common = [n for n in capture_rig.names if n in vicon_rig.names]
    if not common:
        raise InputError(vicon_rig_path, f"no camera of the capture's rig ({capture_rig.names}) in this rig")
    cams = [capture_rig[n] for n in common]
    vcams = [vicon_rig[n] for n in common]
    return transform_between_rigs([c.R for c in cams], [c.t for c in cams], [c.R for c in vcams], [c.t for c in vcams])


def run_crossval(args: argparse.Namespace) -> int:
    import exporters
    from spinemocap.capture import Capture
    from spinemocap.crossval.compare import cross_validate
    from spinemocap.fileio import atomic_write
    from spinemocap.markers import MarkerTable

    capture = Capture.open(args.capture)
    tracked = exporters.read(args.tracked)
    vicon = exporters.read(args.vicon)
    t_time, t_pos, t_labels = _dense(tracked)
    v_time, v_pos, v_labels = _dense(vicon)
    transform = rig_transform(capture.rig, args.rig_vicon) if args.rig_vicon else None
    result = cross_validate(t_time, t_pos, t_labels, capture.tape, v_time, v_pos, v_labels, args.marker_diameter,
                            transform, args.max_offset)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    summary = dict(result.summary, tracked=str(args.tracked), vicon=str(args.vicon), capture=str(args.capture))
    flagged = [n for n, a in summary["angles"].items() if not (a["icc"] > 0.75)]
    summary["angles_flagged"] = flagged
    with atomic_write(out / "summary.json") as handle:
        json.dump(summary, handle, indent=2)
    frames = tracked.frames
    reference = MarkerTable.from_arrays(result.vicon_labels, result.vicon_rig, tracked.fps, first_frame=int(frames[0]))
    exporters.write(tracked, out / "merged.c3d", reference=reference, reference_prefix="VICON_")
    with atomic_write(out / "angles.csv") as handle:
        names = list(result.angles)
        handle.write("time_s," + ",".join(f"{n}_tape,{n}_vicon" for n in names) + "\n")
        for i, t in enumerate(t_time):
            values = [f"{result.angles[n][k][i]:.4f}" for n in names for k in (0, 1)]
            handle.write(f"{t:.5f}," + ",".join(values) + "\n")
    write_report(out / "report.html", summary, t_time, result.angles)
    a = result.alignment
    print(f"clock offset (t_vicon - t_rgb) {1000 * a.offset_s:+.2f} ms; alignment residual {a.residual_mm:.2f} mm "
          f"over {a.n_frames} frames ({a.estimated} estimated)")
    for name, stats in summary["angles"].items():
        print(f"  {name:28s} RMSE {stats['rmse_deg']:5.2f} deg  bias {stats['bias_deg']:+5.2f}  LoA "
              f"[{stats['loa_low_deg']:+.2f}, {stats['loa_high_deg']:+.2f}]  ICC {stats['icc']:.3f}  CMC {stats['cmc']:.3f}")
    if flagged:
        print(f"WARNING: poor agreement (ICC <= 0.75) for {', '.join(flagged)}")
    print(f"wrote {out}/summary.json, merged.c3d, angles.csv, report.html")
    return 0


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

    from spinemocap.fileio import atomic_write

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
    if angles:
        names = list(angles)
        fig, axes = plt.subplots(len(names), 2, figsize=(11, 2.4 * len(names)), constrained_layout=True)
        axes = np.atleast_2d(axes)
        for row, name in enumerate(names):
            tape, vicon = angles[name]
            axes[row, 0].plot(time_s, tape, label="tape")
            axes[row, 0].plot(time_s, vicon, "--", label="Vicon")
            axes[row, 0].set_ylabel(f"{name} (deg)", fontsize=8)
            axes[row, 0].legend(fontsize=7)
            mean, diff = (tape + vicon) / 2, tape - vicon
            s = summary["angles"][name]
            axes[row, 1].scatter(mean, diff, s=6)
            for level, style in ((s["bias_deg"], "-"), (s["loa_low_deg"], "--"), (s["loa_high_deg"], "--")):
                axes[row, 1].axhline(level, color="k", ls=style, lw=0.8)
            axes[row, 1].set_xlabel("mean of tape and Vicon (deg)", fontsize=8)
            axes[row, 1].set_ylabel("tape - Vicon (deg)", fontsize=8)
        axes[-1, 0].set_xlabel("time (s)")
        parts.append("<h2>Waveforms and Bland-Altman plots</h2>" + _figure_html(fig))
        plt.close(fig)
    parts.append("</body></html>")
    with atomic_write(path) as handle:
        handle.write("\n".join(parts))
