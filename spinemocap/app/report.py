"""Study report from a batch output folder: one self-contained HTML page plus CSV/XLSX tables.

Reads every ``summary.json`` and ``angles.csv`` under the batch folder (see :mod:`batch`) and
writes into it (atomically):

- ``report.html``: the problems first (failed trials with their reason, NaN angles with theirs),
  the per-trial table (peak flexion/extension, ranges of motion, data completeness), group
  summaries by subject and by condition, and per trial the lumbar flexion, lateral bending and
  axial rotation over time. Plots are matplotlib PNGs embedded as base64: the page needs no
  other file and no network.
- ``summary.csv`` (one row per trial), ``summary_by_subject.csv``, ``summary_by_condition.csv``
  and ``summary.xlsx`` (the same tables as sheets, plus ``problems``): the numbers on the page.

Angles in degrees, positive flexion = forward bending, lateral positive to the subject's right,
rotation positive to the subject's left (see :mod:`angles`).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ..capture import Capture  # noqa: E402
from ..fileio import atomic_path, atomic_write  # noqa: E402
from .batch import ANGLES, load_results  # noqa: E402

#: Per-trial numbers: (column name in the tables, angle statistic key in summary.json).
TRIAL_COLUMNS = {
    "peak_flexion_deg": "lumbar_flexion_max",
    "peak_extension_deg": "lumbar_flexion_min",
    "flexion_rom_deg": "lumbar_flexion_rom",
    "lateral_right_peak_deg": "lumbar_lateral_max",
    "lateral_left_peak_deg": "lumbar_lateral_min",
    "lateral_rom_deg": "lumbar_lateral_rom",
    "rotation_left_peak_deg": "lumbar_rotation_max",
    "rotation_right_peak_deg": "lumbar_rotation_min",
    "rotation_rom_deg": "lumbar_rotation_rom",
    "thoracic_flexion_rom_deg": "thoracic_flexion_rom",
    "lordosis_max_deg": "lordosis_max",
    "kyphosis_max_deg": "kyphosis_max",
    "lumbar_valid_pct": "lumbar_flexion_valid",
}
GROUP_COLUMNS = ["peak_flexion_deg", "peak_extension_deg", "flexion_rom_deg", "lateral_rom_deg",
                 "rotation_rom_deg", "completeness_pct"]
PLOTTED = (("lumbar_flexion", "lumbar flexion (+ forward)"),
           ("lumbar_lateral", "lateral bending (+ right)"),
           ("lumbar_rotation", "axial rotation (+ left)"))


def trial_table(results: list[dict]) -> pd.DataFrame:
    """One row per trial: identity, status, reason, frames, completeness and the angle numbers."""
    rows = []
    for r in results:
        row = {"subject": r.get("subject", ""), "condition": r.get("condition", ""),
               "trial": r.get("trial", ""), "key": r["key"], "status": r["status"],
               "reason": r.get("reason", ""), "n_frames": r.get("n_frames", np.nan),
               "duration_s": r.get("duration_s", np.nan),
               "completeness_pct": r.get("completeness_pct", np.nan)}
        stats = r.get("stats", {})
        for column, key in TRIAL_COLUMNS.items():
            value = stats.get(key, np.nan)
            row[column] = 100.0 * value if column.endswith("_pct") and value == value else value
        rows.append(row)
    return pd.DataFrame(rows)


def group_table(trials: pd.DataFrame, by: str) -> pd.DataFrame:
    """Mean and SD over the successful trials of each ``by`` group, with trial counts."""
    ok = trials[trials["status"] == "ok"]
    if ok.empty:
        return pd.DataFrame(columns=[by, "n_trials"])
    grouped = ok.groupby(by, sort=True)[GROUP_COLUMNS]
    table = grouped.mean().add_suffix("_mean").join(grouped.std(ddof=1).add_suffix("_sd"))
    table = table[[f"{c}_{s}" for c in GROUP_COLUMNS for s in ("mean", "sd")]]
    table.insert(0, "n_trials", ok.groupby(by).size())
    failed = trials[trials["status"] != "ok"].groupby(by).size()
    table.insert(1, "n_failed", failed.reindex(table.index, fill_value=0))
    return table.reset_index()


def problem_table(results: list[dict]) -> pd.DataFrame:
    """Failed trials and NaN-angle reasons, one row per (trial, what, reason)."""
    rows = [{"key": r["key"], "what": "trial failed", "frames": np.nan, "reason": r.get("reason", "")}
            for r in results if r["status"] != "ok"]
    for r in results:
        if r["status"] != "ok":
            continue
        for group, reasons in r.get("notes", {}).items():
            for reason, count in reasons.items():
                rows.append({"key": r["key"], "what": f"{group} angles NaN", "frames": count, "reason": reason})
    return pd.DataFrame(rows, columns=["key", "what", "frames", "reason"])


def tracking_quality_table(results: list[dict]) -> pd.DataFrame:
    """Trials whose tracked markers.csv holds flagged frames (see
    :func:`spinemocap.track.quality.flagged_from_confidence`): key, flagged frame count, the
    first frames, and the median tape stretch (ratio to the roll's spec)."""
    from ..markers import MarkerTable
    from ..track.quality import flagged_from_confidence
    from .batch import MARKERS

    rows = []
    for r in results:
        path = Path(r.get("out_dir", "")) / MARKERS
        if r["status"] != "ok" or r.get("source", "tracked") != "tracked" or not path.is_file():
            continue
        df = pd.read_csv(path, dtype={"label": str})
        if "confidence" not in df.columns:
            continue
        arrays = MarkerTable(df, {"source": str(path)}).to_arrays()
        flagged = arrays["frames"][flagged_from_confidence(arrays["status"], arrays["confidence"])]
        if len(flagged):
            shown = ", ".join(str(int(f)) for f in flagged[:15]) + (" ..." if len(flagged) > 15 else "")
            rows.append({"key": r["key"], "flagged_frames": len(flagged), "of_frames": len(arrays["frames"]),
                         "frames": shown, "median_stretch": float(np.nanmedian(arrays["stretch"]))
                         if np.isfinite(arrays["stretch"]).any() else np.nan})
    return pd.DataFrame(rows, columns=["key", "flagged_frames", "of_frames", "frames", "median_stretch"])


# ---------------------------------------------------------------------------------- plots
def _png(fig) -> str:
    """The figure as base64 PNG text (for data: URLs); closes it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def angles_plot_png(angles: pd.DataFrame) -> bytes:
    """PNG of lumbar flexion, lateral bending and axial rotation over time (an angles table)."""
    return base64.b64decode(_trial_plot(angles))


def _trial_plot(angles: pd.DataFrame) -> str:
    fig, axes = plt.subplots(1, 3, figsize=(13, 2.4), sharex=True)
    t = angles["time"].to_numpy()
    for ax, (column, label) in zip(axes, PLOTTED):
        values = angles[column].to_numpy(float)
        ax.plot(t, values, lw=1.4, color="tab:blue")
        missing = ~np.isfinite(values)
        if missing.any():
            low, high = ax.get_ylim() if np.isfinite(values).any() else (-1, 1)
            ax.fill_between(t, low, high, where=missing, color="tab:red", alpha=0.15, lw=0,
                            label="no angle (see notes)")
            ax.set_ylim(low, high)
            ax.legend(loc="upper right", fontsize=7)
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("time (s)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("deg", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _group_plot(trials: pd.DataFrame) -> str | None:
    ok = trials[trials["status"] == "ok"]
    if len(ok) < 2:  # nothing to compare
        return None
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.2))
    for ax, column, label in zip(axes, ("flexion_rom_deg", "peak_flexion_deg", "completeness_pct"),
                                 ("lumbar flexion ROM (deg)", "peak lumbar flexion (deg)", "observed dots (%)")):
        pivot = ok.pivot_table(index="subject", columns="condition", values=column, aggfunc="mean")
        spread = ok.pivot_table(index="subject", columns="condition", values=column, aggfunc="std")
        pivot.plot.bar(ax=ax, yerr=spread.reindex_like(pivot), capsize=2, rot=0, legend=ax is axes[0])
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("")
        ax.tick_params(labelsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    if any(label.strip() for label in labels):
        axes[0].legend(handles, labels, title="condition", fontsize=7, title_fontsize=7)
    elif axes[0].get_legend():
        axes[0].get_legend().remove()
    fig.tight_layout()
    return _png(fig)


# ---------------------------------------------------------------------------------- page
_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1400px}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:12px;margin:8px 0}
td,th{border:1px solid #ddd;padding:3px 6px;text-align:right}th{background:#f3f3f3}
td.text,th{text-align:left}.scroll{overflow-x:auto}h3{font-size:14px;margin:14px 0 2px}
.bad{background:#fde8e8}.warn{background:#fff6dd}.ok{color:#2a7a2a}.note{color:#555;font-size:13px}
img{max-width:100%}
"""


def _html_table(df: pd.DataFrame, row_class=None) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = []
    for _, row in df.iterrows():
        cls = f' class="{row_class(row)}"' if row_class else ""
        cells = "".join(f"<td{'' if _numeric(v) else ' class=text'}>{html.escape(_fmt(v))}</td>" for v in row)
        body.append(f"<tr{cls}>{cells}</tr>")
    return f"<div class='scroll'><table><tr>{head}</tr>{''.join(body)}</table></div>"


def _numeric(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _fmt(value) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if not np.isfinite(value) else f"{value:.1f}"
    return str(value)


def write_report(out: str | os.PathLike, title: str | None = None) -> dict[str, Path]:
    """Write the report and summary tables into the batch folder ``out``; returns their paths."""
    out = Path(out)
    results = load_results(out)
    trials = trial_table(results)
    by_subject, by_condition = group_table(trials, "subject"), group_table(trials, "condition")
    problems = problem_table(results)
    paths = _write_tables(out, trials, by_subject, by_condition, problems)

    n_ok = int((trials["status"] == "ok").sum())
    parts = [f"<h1>{html.escape(title or 'Spine angles: ' + out.name)}</h1>",
             f"<p class='note'>{len(trials)} trials, {n_ok} analysed, {len(trials) - n_ok} failed. "
             f"Generated {_dt.datetime.now():%Y-%m-%d %H:%M}. Angles in degrees: lumbar = "
             f"{html.escape(_lumbar_levels(results))} on the tape's midline; flexion positive forward, lateral bending "
             "positive to the subject's right, axial rotation positive to the subject's left. "
             "Peak extension is the smallest flexion angle (negative = extended). "
             "Tables: summary.csv, summary_by_subject.csv, summary_by_condition.csv, summary.xlsx.</p>"]
    parts.append("<h2>Problems</h2>")
    if problems.empty:
        parts.append("<p class='ok'>None: every trial analysed, every angle supported by the data.</p>")
    else:
        parts.append(_html_table(problems, lambda r: "bad" if r["what"] == "trial failed" else "warn"))
    quality = tracking_quality_table(results)
    if not quality.empty:
        parts.append("<h2>Tracking quality</h2><p class='warn'>The tracker could not vouch for the labels "
                     "of these frames (a re-solve wanted other labels, dots were left unlabelled beyond the "
                     "tape's end or the tape's spacing was implausible); their dots carry a low "
                     "<code>confidence</code> in markers.csv. Check them before trusting their angles.</p>")
        parts.append(_html_table(quality, lambda r: "warn"))
    parts.append("<h2>Trials</h2>")
    shown = trials.drop(columns=["key"])
    parts.append(_html_table(shown, lambda r: "bad" if r["status"] != "ok" else ""))
    parts.append("<h2>By subject</h2>" + _html_table(by_subject))
    parts.append("<h2>By condition</h2>" + _html_table(by_condition))
    group_png = _group_plot(trials)
    if group_png:
        parts.append(f"<img alt='group summary' src='data:image/png;base64,{group_png}'>")
    parts.append("<h2>Angles over time</h2>")
    for r in results:
        if r["status"] != "ok":
            parts.append(f"<p class='bad'><b>{html.escape(r['key'])}</b>: failed: {html.escape(r.get('reason', ''))}</p>")
            continue
        angles = pd.read_csv(Path(r["out_dir"]) / ANGLES)
        parts.append(f"<h3>{html.escape(r['key'])} <span class='note'>"
                     f"({r.get('completeness_pct', float('nan')):.0f}% of dots observed)</span></h3>")
        parts.append(f"<img alt='{html.escape(r['key'])}' src='data:image/png;base64,{_trial_plot(angles)}'>")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title or out.name)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")
    with atomic_write(out / "report.html") as handle:
        handle.write(page)
    paths["html"] = out / "report.html"
    return paths


def _lumbar_levels(results: list[dict]) -> str:
    pairs = {tuple(r["lumbar_levels"]) for r in results if r.get("lumbar_levels")}
    return "; ".join(f"{hi} relative to {lo}" for lo, hi in sorted(pairs)) or "T12/L1 relative to S1"


def _write_tables(out: Path, trials: pd.DataFrame, by_subject: pd.DataFrame, by_condition: pd.DataFrame,
                  problems: pd.DataFrame) -> dict[str, Path]:
    paths = {"csv": out / "summary.csv", "by_subject": out / "summary_by_subject.csv",
             "by_condition": out / "summary_by_condition.csv", "xlsx": out / "summary.xlsx"}
    for key, table in (("csv", trials), ("by_subject", by_subject), ("by_condition", by_condition)):
        with atomic_write(paths[key]) as handle:
            table.to_csv(handle, index=False, float_format="%.3f")
    with atomic_path(paths["xlsx"]) as tmp:
        with pd.ExcelWriter(tmp, engine="openpyxl") as writer:
            trials.to_excel(writer, sheet_name="trials", index=False)
            by_subject.to_excel(writer, sheet_name="by_subject", index=False)
            by_condition.to_excel(writer, sheet_name="by_condition", index=False)
            problems.to_excel(writer, sheet_name="problems", index=False)
    return paths


def report_capture(capture_dir: str | os.PathLike, out: str | os.PathLike,
                   markers_csv: str | os.PathLike | None = None, progress: bool = False) -> dict[str, Path]:
    """Angles and report for a single capture (``spinemocap demo``'s last step).

    Uses ``markers_csv`` (the tracker's output) when given, else the capture's ground truth.
    The lumbar angle runs from the lowest level the level map places on the tape (S1 when the
    tape starts there) to T12/L1."""
    import shutil

    from ..analysis.angles import AngleSettings
    from ..analysis.levels import LevelMap
    from .batch import MARKERS, discover, run_batch, trial_out_dir

    out = Path(out)
    (trial,) = discover(capture_dir)
    source = "groundtruth"
    if markers_csv is not None and Path(markers_csv).is_file():
        target = trial_out_dir(out, trial) / MARKERS
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(markers_csv, target)  # newer than the capture: the batch reuses it
        os.utime(target)
        source = "tracked"
    lower = "S1"
    names = Capture.open(capture_dir).row_levels()
    if names is not None:
        lower = next(iter(LevelMap.from_row_levels(names, len(names)).rows))
    run_batch(capture_dir, out, source=source, workers=1, settings=AngleSettings(lower=lower), progress=progress)
    return write_report(out, title=f"Spine angles: {Path(capture_dir).name}")
