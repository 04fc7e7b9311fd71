"""Study report from a batch output folder: one self-contained HTML page plus CSV/XLSX tables.

Reads every ``summary.json``, ``angles.csv``, ``segments.csv`` and ``shape.json`` under the batch
folder (see :mod:`batch`) and writes into it (atomically):

- ``report.html``: the problems first (failed trials with their reason, NaN angles with theirs,
  a trial without any lumbar angle says so), ROM by subject and condition as box/strip plots, the
  per-trial table (lumbar flexion from neutral, extension from neutral, ROM, the absolute angle
  at neutral; lateral bending and axial rotation likewise; data completeness), group summaries
  (mean +- SD) by subject and by condition, and per trial: the angles from neutral over time, a
  picture of the spine (the tape midline in the sagittal and frontal planes at neutral, peak
  flexion and peak extension) and the segmental (per-level) flexion. Plots are matplotlib PNGs
  embedded as base64: the page needs no other file and no network.
- ``summary.csv`` (one row per trial), ``summary_by_subject.csv``, ``summary_by_condition.csv``
  and ``summary.xlsx`` (the same tables as sheets, plus ``problems``): the numbers on the page.

Neutral (zero): a trial named or conditioned ``static``/``neutral``/``standing`` of the same
subject when the study has one (:mod:`spinemocap.analysis.neutral`), else the first
:data:`~spinemocap.analysis.neutral.NEUTRAL_FIRST_S` s of the trial itself. Angles in degrees,
positive flexion = forward bending, lateral positive to the subject's right, rotation positive
to the subject's left (see :mod:`angles`).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import os
import urllib.parse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ..analysis.neutral import (  # noqa: E402
    NEUTRAL_FIRST_S,
    Neutral,
    is_static_name,
    neutral_from_angles,
    neutral_summary,
)
from ..analysis.norms import Norms, load_norms, subject_profile  # noqa: E402
from ..analysis.shape import segments_of  # noqa: E402
from ..capture import Capture  # noqa: E402
from ..fileio import InputError, atomic_path, atomic_write, check_writable, reading  # noqa: E402
from .batch import ANGLES, SEGMENTS, SHAPE, load_results  # noqa: E402
from .trial_summary import TrialSummary  # noqa: E402
from .viewer.layout import view_outputs  # noqa: E402

#: Per-trial numbers: (column name in the tables, angle statistic key in summary.json).
#: Absolute angles (the lumbar angle of a standing lordotic back is negative).
TRIAL_COLUMNS = {
    "flexion_abs_max_deg": "lumbar_flexion_max",
    "flexion_abs_min_deg": "lumbar_flexion_min",
    "flexion_rom_deg": "lumbar_flexion_rom",
    "lateral_abs_max_deg": "lumbar_lateral_max",
    "lateral_abs_min_deg": "lumbar_lateral_min",
    "lateral_rom_deg": "lumbar_lateral_rom",
    "rotation_abs_max_deg": "lumbar_rotation_max",
    "rotation_abs_min_deg": "lumbar_rotation_min",
    "rotation_rom_deg": "lumbar_rotation_rom",
    "thoracic_flexion_rom_deg": "thoracic_flexion_rom",
    "lordosis_max_deg": "lordosis_max",
    "kyphosis_max_deg": "kyphosis_max",
    "lumbar_valid_pct": "lumbar_flexion_valid",
}
#: Numbers relative to neutral (column name, key of :func:`neutral.neutral_summary`).
NEUTRAL_COLUMNS = {
    "flexion_neutral_abs_deg": "lumbar_flexion_neutral",
    "flexion_from_neutral_deg": "lumbar_flexion_pos_from_neutral",
    "extension_from_neutral_deg": "lumbar_flexion_neg_from_neutral",
    "lateral_right_from_neutral_deg": "lumbar_lateral_pos_from_neutral",
    "lateral_left_from_neutral_deg": "lumbar_lateral_neg_from_neutral",
    "rotation_left_from_neutral_deg": "lumbar_rotation_pos_from_neutral",
    "rotation_right_from_neutral_deg": "lumbar_rotation_neg_from_neutral",
}
GROUP_COLUMNS = ["flexion_from_neutral_deg", "extension_from_neutral_deg", "flexion_rom_deg", "lateral_rom_deg",
                 "rotation_rom_deg", "completeness_pct"]
PLOTTED = (("lumbar_flexion", "lumbar flexion from neutral (+ forward)"),
           ("lumbar_lateral", "lateral bending from neutral (+ right)"),
           ("lumbar_rotation", "axial rotation from neutral (+ left)"))
#: The trial table as the page shows it: (group header, [(column, short header)]).
DISPLAY_TRIALS = (
    ("Trial", [("subject", "subject"), ("condition", "condition"), ("trial", "trial"), ("status", "status"),
               ("n_frames", "frames"), ("completeness_pct", "dots seen %")]),
    ("Lumbar flexion (deg)", [("flexion_from_neutral_deg", "flexion from neutral"),
                              ("extension_from_neutral_deg", "extension from neutral"),
                              ("flexion_rom_deg", "ROM"), ("flexion_neutral_abs_deg", "angle at neutral")]),
    ("Lateral bending (deg)", [("lateral_right_from_neutral_deg", "right"), ("lateral_left_from_neutral_deg", "left"),
                               ("lateral_rom_deg", "ROM")]),
    ("Axial rotation (deg)", [("rotation_left_from_neutral_deg", "left"), ("rotation_right_from_neutral_deg", "right"),
                              ("rotation_rom_deg", "ROM")]),
    ("Other", [("thoracic_flexion_rom_deg", "thoracic flexion ROM"), ("lumbar_valid_pct", "lumbar angle valid %"),
               ("neutral_from", "neutral")]),
)
GROUP_HEADERS = {"flexion_from_neutral_deg": "flexion from neutral", "extension_from_neutral_deg": "extension from neutral",
                 "flexion_rom_deg": "flexion ROM", "lateral_rom_deg": "lateral ROM", "rotation_rom_deg": "rotation ROM",
                 "completeness_pct": "dots seen %"}


def trial_table(results: list[TrialSummary], neutrals: dict[str, tuple[dict, str]] | None = None) -> pd.DataFrame:
    """One row per trial: identity, status, reason, frames, completeness, the absolute angle
    numbers and (with ``neutrals``: trial key -> (:func:`neutral.neutral_summary`, where the
    neutral came from)) the numbers relative to neutral."""
    neutrals = neutrals or {}
    rows = []
    for r in results:
        a = r.analysis
        row: dict[str, object] = {
            "subject": r.subject, "condition": r.condition, "trial": r.trial, "key": r.key, "status": r.status,
            "reason": r.reason, "n_frames": a.n_frames if a else np.nan, "duration_s": a.duration_s if a else np.nan,
            "completeness_pct": a.completeness_pct if a else np.nan}
        for column, key in TRIAL_COLUMNS.items():
            value = r.stats.get(key, np.nan)
            row[column] = 100.0 * value if column.endswith("_pct") and value == value else value
        relative, source = neutrals.get(r.key, ({}, ""))
        for column, key in NEUTRAL_COLUMNS.items():
            row[column] = relative.get(key, np.nan)
        row["neutral_from"] = source
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


def problem_table(results: list[TrialSummary]) -> pd.DataFrame:
    """Failed trials and NaN-angle reasons, one row per (trial, what, reason); a trial whose
    lumbar angle is missing in every frame gets a row saying so first."""
    rows: list[dict[str, object]] = [{"key": r.key, "what": "trial failed", "frames": np.nan, "reason": r.reason}
                                     for r in results if not r.ok]
    for r in results:
        if r.analysis is None:
            continue
        if r.stats.get("lumbar_flexion_valid", 1.0) == 0.0:
            rows.append({"key": r.key, "what": "no lumbar angle in any frame", "frames": r.analysis.n_frames,
                         "reason": _lumbar_reason(r)})
        for group, reasons in r.notes.items():
            for reason, count in reasons.items():
                rows.append({"key": r.key, "what": f"{group} angles NaN", "frames": count, "reason": reason})
    return pd.DataFrame(rows, columns=["key", "what", "frames", "reason"])


def empty_column_problems(trials: pd.DataFrame) -> pd.DataFrame:
    """A problem row for every plotted summary column without a single value (all NaN)."""
    ok = trials[trials["status"] == "ok"]
    columns = [c for c in ("flexion_rom_deg", "flexion_abs_max_deg") if c in ok]
    rows = [{"key": "all trials", "what": f"{column} NaN", "frames": np.nan,
             "reason": "no analysed trial has this value (e.g. the level maps do not reach the lumbar "
                       "levels); its plot is empty"}
            for column in columns if len(ok) and ok[column].isna().all()]
    return pd.DataFrame(rows, columns=["key", "what", "frames", "reason"])


def _lumbar_reason(result: TrialSummary) -> str:
    """The most frequent reason for NaN lumbar angles of a trial (summary.json notes)."""
    reasons = result.notes.get("lumbar", {})
    if not reasons:
        return "no reason recorded (summary.json has no lumbar notes)"
    return max(reasons.items(), key=lambda kv: kv[1])[0]


# ---------------------------------------------------------------------------------- neutral
def read_trial_angles(results: list[TrialSummary]) -> dict[str, pd.DataFrame]:
    """Each analysed trial's angles table (read once per report), by trial key."""
    return {r.key: _read_angles(r) for r in results if r.ok}


def trial_neutrals(results: list[TrialSummary], tables: dict[str, pd.DataFrame]) -> dict[str, tuple[dict, str]]:
    """Per analysed trial key: (:func:`neutral.neutral_summary` of its angles ``tables``, where its
    neutral came from). A subject's static trial (:func:`neutral.is_static_name`) is the neutral of
    all the subject's trials; without one, each trial's first frames are."""
    static: dict[str, tuple[Neutral, str]] = {}
    for r in results:
        key = r.key
        if key in tables and is_static_name(r.trial, r.condition) and r.subject not in static:
            static[r.subject] = (neutral_from_angles(tables[key], first_s=None), f"static trial {key}")
    out = {}
    for r in results:
        key = r.key
        if key not in tables:
            continue
        if r.subject in static:
            neutral, source = static[r.subject]
        else:
            neutral = neutral_from_angles(tables[key], first_s=NEUTRAL_FIRST_S)
            source = _first_frames_words()
        out[key] = (neutral_summary(tables[key], neutral), source)
    return out


def _first_frames_words() -> str:
    return f"first {NEUTRAL_FIRST_S:g} s" if NEUTRAL_FIRST_S > 0 else "first frame"


def _read_angles(result: TrialSummary) -> pd.DataFrame:
    return _read_table(Path(result.out_dir) / ANGLES, "angles table")


def _read_table(path: Path, what: str, **options) -> pd.DataFrame:
    """A CSV the batch wrote; a damaged one is an InputError naming it."""
    with reading(path, what):
        return pd.read_csv(path, **options)


def tracking_quality_table(results: list[TrialSummary]) -> pd.DataFrame:
    """Trials whose tracked markers.csv holds flagged frames (see
    :func:`spinemocap.track.quality.flagged_from_confidence`): key, flagged frame count, the
    first frames, and the median tape stretch (ratio to the roll's spec)."""
    from ..markers import MarkerTable
    from ..track.quality import flagged_from_confidence
    from .batch import MARKERS

    rows = []
    for r in results:
        path = Path(r.out_dir) / MARKERS
        if not r.ok or r.source != "tracked" or not path.is_file():
            continue
        df = pd.read_csv(path, dtype={"label": str})
        if "confidence" not in df.columns:
            continue
        arrays = MarkerTable(df, {"source": str(path)}).to_arrays()
        flagged = arrays.frames[flagged_from_confidence(arrays.status, arrays.confidence)]
        if len(flagged):
            shown = ", ".join(str(int(f)) for f in flagged[:15]) + (" ..." if len(flagged) > 15 else "")
            rows.append({"key": r.key, "flagged_frames": len(flagged), "of_frames": len(arrays.frames),
                         "frames": shown, "median_stretch": float(np.nanmedian(arrays.stretch))
                         if np.isfinite(arrays.stretch).any() else np.nan})
    return pd.DataFrame(rows, columns=["key", "flagged_frames", "of_frames", "frames", "median_stretch"])


# ---------------------------------------------------------------------------------- plots
def _png(fig) -> str:
    """The figure as base64 PNG text (for data: URLs); closes it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def angles_plot_png(angles: pd.DataFrame, neutral: Neutral | None = None) -> bytes:
    """PNG of lumbar flexion, lateral bending and axial rotation from neutral over time (an
    angles table; ``neutral`` None: its first frames)."""
    return base64.b64decode(_trial_plot(angles, neutral))


def _trial_plot(angles: pd.DataFrame, neutral: Neutral | None = None, ik: pd.DataFrame | None = None) -> str:
    """Angles from neutral over time; with ``ik`` (spinemocap opensim's spine_angles.csv) the IK
    region sums beside them (IK's zero is its static posture, by default the first frames too)."""
    neutral = neutral or neutral_from_angles(angles)
    fig, axes = plt.subplots(1, 3, figsize=(12, 2.3), sharex=True)
    t = angles["time"].to_numpy()
    for ax, (column, label) in zip(axes, PLOTTED):
        values = angles[column].to_numpy(float) - neutral.value(column)
        ax.plot(t, values, lw=1.4, color="tab:blue", label="tape (geometric)" if ik is not None else None)
        if ik is not None and column in ik:
            ax.plot(ik["time"], ik[column], lw=1.1, color="tab:orange", ls="--",
                    label="OpenSim IK (driven lumbar joints)")
            ax.legend(loc="upper left", fontsize=7)
        _at_least_degrees(ax, MIN_SPAN_DEG)
        missing = ~np.isfinite(values)
        if missing.any():
            low, high = ax.get_ylim() if np.isfinite(values).any() else (-1, 1)
            ax.fill_between(t, low, high, where=missing, color="tab:red", alpha=0.15, lw=0,
                            label="no angle (see problems)")
            ax.set_ylim(low, high)
            ax.legend(loc="upper right", fontsize=7)
        if not np.isfinite(values).any():
            ax.text(0.5, 0.5, "no angle in any frame\n(reason under Problems)", ha="center", va="center",
                    transform=ax.transAxes, fontsize=9, color="tab:red")
        ax.axhline(0, color="0.6", lw=0.6)
        zero = neutral.value(column)
        ax.set_title(f"{label}\nneutral = {zero:.1f} deg absolute" if np.isfinite(zero) else f"{label}\nno neutral value",
                     fontsize=8)
        ax.set_xlabel("time (s)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("deg", fontsize=8)
    fig.tight_layout()
    return _png(fig)


#: Smallest y range (deg) of an angle plot, so that hundredths of a degree do not look like motion.
MIN_SPAN_DEG = 4.0


def _at_least_degrees(ax, span: float) -> None:
    low, high = ax.get_ylim()
    if high - low < span:
        middle = 0.5 * (low + high)
        ax.set_ylim(middle - span / 2, middle + span / 2)


SHAPE_STYLE = {"neutral": ("0.45", "-"), "peak flexion": ("tab:blue", "-"), "peak extension": ("tab:red", "--")}


def _spine_plot(shape: dict | None, segments: pd.DataFrame | None) -> str:
    """Per trial: the tape midline in the sagittal (anterior-superior) and frontal (right-superior)
    planes at neutral, peak flexion and peak extension, the segmental flexion over time and each
    segment's flexion at the peaks (change from the first frame)."""
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.1), gridspec_kw={"width_ratios": [1, 1, 1.6, 1.6]})
    _draw_midlines(axes[0], axes[1], shape)
    _draw_segments(axes[2], axes[3], segments, (shape or {}).get("frames", {}))
    fig.tight_layout()
    return _png(fig)


def _draw_midlines(sagittal, frontal, shape: dict | None) -> None:
    profiles = (shape or {}).get("midline_mm", {})
    for ax, (x, title) in ((sagittal, ("anterior", "sagittal plane (anterior to the left)")),
                           (frontal, ("right", "frontal plane, seen from behind"))):
        for name, profile in profiles.items():
            colour, style = SHAPE_STYLE.get(name, ("k", ":"))
            ax.plot(profile[x], profile["superior"], color=colour, ls=style, lw=1.6, label=name)
        if not profiles:
            ax.text(0.5, 0.5, "no midline:\ntoo few tape rows seen", ha="center", va="center", transform=ax.transAxes,
                    fontsize=8, color="tab:red")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(title, fontsize=8)
        ax.set_xlabel(f"{x} (mm)", fontsize=7)
        ax.tick_params(labelsize=7)
    sagittal.invert_xaxis()  # the subject faces left, the back to the right: the usual sagittal view
    sagittal.set_ylabel("superior (mm, from the tape's sacral end)", fontsize=7)
    if profiles:
        sagittal.legend(fontsize=6, loc="lower left")


def _draw_segments(over_time, at_peaks, segments: pd.DataFrame | None, frames: dict) -> None:
    names = segments_of(segments) if segments is not None else []
    values = segments[[f"{n}_flexion" for n in names]].to_numpy(float) if segments is not None and names else np.zeros((0, 0))
    if segments is None or not names or not np.isfinite(values).any():
        for ax in (over_time, at_peaks):
            ax.text(0.5, 0.5, "no segmental angles:\nlevels not seen or not mapped", ha="center", va="center",
                    transform=ax.transAxes, fontsize=8, color="tab:red")
            ax.set_xticks([])
            ax.set_yticks([])
        return
    change = values - values[0]
    colours = plt.get_cmap("viridis")(np.linspace(0, 1, len(names)))
    t = segments["time"].to_numpy(float)
    for k, name in enumerate(names):
        over_time.plot(t, change[:, k], color=colours[k], lw=1.0, label=name)
    over_time.set_title("segmental flexion (change from first frame)", fontsize=8)
    over_time.set_xlabel("time (s)", fontsize=7)
    over_time.set_ylabel("deg", fontsize=7)
    over_time.legend(fontsize=5, ncol=2, loc="best")
    x = np.arange(len(names))
    width = 0.4
    for name, offset in (("peak flexion", -0.2), ("peak extension", 0.2)):
        if name in frames and frames[name] < len(change):
            at_peaks.bar(x + offset, np.nan_to_num(change[frames[name]]), width, color=SHAPE_STYLE[name][0], label=name)
    at_peaks.axhline(0, color="0.6", lw=0.6)
    at_peaks.set_xticks(x, names, rotation=60, fontsize=6)
    at_peaks.set_title("segmental flexion at the peaks (sacral -> cranial)", fontsize=8)
    if at_peaks.get_legend_handles_labels()[0]:
        at_peaks.legend(fontsize=6)
    else:
        at_peaks.text(0.5, 0.5, "no peaks: the lumbar angle\nis missing in every frame", ha="center", va="center",
                      transform=at_peaks.transAxes, fontsize=8, color="tab:red")
    for ax in (over_time, at_peaks):
        ax.tick_params(labelsize=7)


def _rom_plot(trials: pd.DataFrame) -> str | None:
    """ROM by subject (x) and condition (colour): box plots with every trial as a point; a panel
    without any value says so (the reasons are in the problems table). None without analysed trials."""
    ok = trials[trials["status"] == "ok"]
    if ok.empty:
        return None
    subjects = sorted(ok["subject"].astype(str).unique())
    conditions = sorted(ok["condition"].astype(str).unique())
    colours = plt.get_cmap("tab10")(np.arange(len(conditions)) % 10)
    width = 0.8 / max(len(conditions), 1)
    rng = np.random.default_rng(0)  # jitter of the strip points only
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.0))
    for ax, (column, label) in zip(axes, (("flexion_rom_deg", "lumbar flexion ROM (deg)"),
                                          ("lateral_rom_deg", "lateral bending ROM (deg)"),
                                          ("rotation_rom_deg", "axial rotation ROM (deg)"))):
        for c, condition in enumerate(conditions):
            for s, subject in enumerate(subjects):
                cell = ok[(ok["subject"].astype(str) == subject) & (ok["condition"].astype(str) == condition)]
                values = cell[column].to_numpy(float)
                values = values[np.isfinite(values)]
                if not values.size:
                    continue
                x = s - 0.4 + width * (c + 0.5)
                ax.boxplot(values, positions=[x], widths=0.8 * width, showfliers=False,
                           medianprops={"color": colours[c]}, boxprops={"color": colours[c]},
                           whiskerprops={"color": colours[c]}, capprops={"color": colours[c]})
                ax.scatter(x + rng.uniform(-0.15, 0.15, values.size) * width, values, s=14, color=colours[c],
                           zorder=3, label=condition if s == 0 else None)
        if not np.isfinite(ok[column].to_numpy(float)).any():
            ax.text(0.5, 0.5, "no value in any trial\n(see Problems)", ha="center", va="center",
                    transform=ax.transAxes, color="tab:red", fontsize=9)
        ax.set_xticks(range(len(subjects)), subjects, fontsize=7)
        ax.set_xlim(-0.6, len(subjects) - 0.4)
        ax.set_title(label, fontsize=9)
        ax.tick_params(labelsize=7)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(title="condition", fontsize=7, title_fontsize=7)
    fig.tight_layout()
    return _png(fig)


# ---------------------------------------------------------------------------------- page
_CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1200px}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:12px;margin:8px 0}
td,th{border:1px solid #ddd;padding:2px 5px;text-align:right}th{background:#f3f3f3;font-weight:600}
th.group{text-align:center;background:#e6ecf3}th.col{max-width:80px;white-space:normal;font-size:11px;vertical-align:bottom}
td.text,th{text-align:left}.scroll{overflow-x:auto}h3{font-size:14px;margin:18px 0 2px}
.bad{background:#fde8e8}.warn{background:#fff6dd}.ok{color:#2a7a2a}.note{color:#555;font-size:13px}
td.na{color:#999}img{max-width:100%}
"""


def _html_table(df: pd.DataFrame, row_class=None, groups: list[tuple[str, int]] | None = None,
                headers: list[str] | None = None) -> str:
    """An HTML table; ``groups`` adds a header row of (label, column span) above the column
    headers (``headers``: shown names, default the column names)."""
    top = "".join(f"<th class='group' colspan={span}>{html.escape(label)}</th>" for label, span in groups) if groups else ""
    names = headers or [str(c) for c in df.columns]
    head = "".join(f"<th class='col'>{html.escape(n)}</th>" for n in names)
    body = []
    for _, row in df.iterrows():
        cls = f' class="{row_class(row)}"' if row_class else ""
        body.append(f"<tr{cls}>{''.join(_cell(v) for v in row)}</tr>")
    head_rows = (f"<tr>{top}</tr>" if top else "") + f"<tr>{head}</tr>"
    return f"<div class='scroll'><table>{head_rows}{''.join(body)}</table></div>"


def _cell(value) -> str:
    if _numeric(value) and not np.isfinite(value):
        return "<td class='na' title='not computed: see Problems'>n/a</td>"
    return f"<td{'' if _numeric(value) else ' class=text'}>{html.escape(_fmt(value))}</td>"


def _numeric(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _fmt(value) -> str:
    if isinstance(value, (float, np.floating)):
        return "" if not np.isfinite(value) else f"{value:.1f}"
    return str(value)


def _trials_html(trials: pd.DataFrame) -> str:
    """The trial table with grouped, short headers (the CSV keeps every column)."""
    columns = [(c, h) for _, cols in DISPLAY_TRIALS for c, h in cols]
    shown = trials[[c for c, _ in columns]]
    return _html_table(shown, lambda r: "bad" if r["status"] != "ok" else "",
                       groups=[(label, len(cols)) for label, cols in DISPLAY_TRIALS], headers=[h for _, h in columns])


def _group_html(table: pd.DataFrame, by: str) -> str:
    """A group table as mean +- SD per number, one column each."""
    if table.empty or "n_failed" not in table:
        return "<p class='note'>No analysed trials.</p>"
    shown = table[[by, "n_trials", "n_failed"]].copy()
    for column in GROUP_COLUMNS:
        shown[GROUP_HEADERS[column]] = [_mean_sd(m, s) for m, s in zip(table[f"{column}_mean"], table[f"{column}_sd"])]
    return _html_table(shown, headers=[by, "trials", "failed"] + [GROUP_HEADERS[c] for c in GROUP_COLUMNS])


def _mean_sd(mean: float, sd: float) -> str:
    if not np.isfinite(mean):
        return "n/a"
    return f"{mean:.1f} ± {sd:.1f}" if np.isfinite(sd) else f"{mean:.1f}"


def _trial_section(result: TrialSummary, neutral: Neutral | None, angles: pd.DataFrame | None,
                   report_dir: Path | None = None) -> list[str]:
    """One trial's heading, its problems in words, links to its labelled videos and 3D viewer
    (relative to ``report_dir``), and its three pictures (``angles``: its angles table, None for
    a failed trial)."""
    key = html.escape(result.key)
    if result.analysis is None:
        return [f"<p class='bad'><b>{key}</b>: failed: {html.escape(result.reason)}</p>"]
    assert angles is not None, "an analysed trial has an angles table"
    folder = Path(result.out_dir)
    parts = [f"<h3>{key} <span class='note'>({result.analysis.completeness_pct:.0f}% of dots observed"
             f"{'; neutral: ' + html.escape(neutral.source) if neutral else ''})</span></h3>"]
    if report_dir is not None:
        parts.append(_view_links(folder, report_dir))
    if result.stats.get("lumbar_flexion_valid", 1.0) == 0.0:
        parts.append(f"<p class='bad'>No lumbar angle in any frame: {html.escape(_lumbar_reason(result))}.</p>")
    ik = None
    opensim = result.opensim
    if opensim is not None and opensim.status == "ok":
        ik = _read_table(Path(opensim.out_dir) / "spine_angles.csv", "OpenSim angles", comment="#")
        parts.append(f"<p class='note'>OpenSim IK: marker RMS {opensim.marker_rms_mm:.2f} mm, "
                     f"{opensim.flagged_frames} flagged frames (files in "
                     f"{html.escape(opensim.out_dir)})</p>")
    elif opensim is not None:
        parts.append(f"<p class='warn'>OpenSim IK failed: {html.escape(opensim.reason)}</p>")
    try:
        parts.append(f"<img alt='angles from neutral: {key}' "
                     f"src='data:image/png;base64,{_trial_plot(angles, neutral, ik)}'>")
    except (KeyError, TypeError, ValueError) as exc:  # the page is written anyway, saying why
        parts.append(f"<p class='bad'>no plot: {html.escape(f'{type(exc).__name__}: {exc}')}</p>")
    shape = None
    if (folder / SHAPE).is_file():
        with reading(folder / SHAPE, "spine shape"):
            shape = json.loads((folder / SHAPE).read_text())
    segments = _read_table(folder / SEGMENTS, "segmental angles") if (folder / SEGMENTS).is_file() else None
    parts.append(f"<img alt='spine shape and segmental angles: {key}' "
                 f"src='data:image/png;base64,{_spine_plot(shape, segments)}'>")
    return parts


# ---------------------------------------------------------------------------------- reference ranges
#: The trial table's excursions from neutral compared with each published movement (per direction).
REFERENCE_COLUMNS = (("flexion", "flexion_from_neutral_deg", "forward"),
                     ("extension", "extension_from_neutral_deg", "backward"),
                     ("lateral_bending", "lateral_right_from_neutral_deg", "right"),
                     ("lateral_bending", "lateral_left_from_neutral_deg", "left"),
                     ("axial_rotation", "rotation_left_from_neutral_deg", "left"),
                     ("axial_rotation", "rotation_right_from_neutral_deg", "right"))
REFERENCE_TABLE = "reference_ranges.csv"
PLACEMENT_WORDS = {"below": "below the published span", "above": "above the published span",
                   "within": "within", "median only": "(one published median)",
                   "no reference": "no published value for this subject", "no value": "not measured"}


def subject_profiles(results: list[TrialSummary]) -> dict[str, tuple[float | None, str | None, str]]:
    """Per subject: (age in years, sex, notes) from ``[subject]`` of its trials' capture.toml
    (``age``, ``sex``); the first trial that gives a value wins, a disagreeing one is noted."""
    out: dict[str, tuple[float | None, str | None, str]] = {}
    for r in results:
        subject = r.subject
        age, sex, notes = out.get(subject, (None, None, ""))
        try:
            profile = subject_profile(Capture.open(r.capture).subject)
        except (InputError, OSError) as exc:
            out[subject] = (age, sex, notes or f"metadata unreadable ({exc})")
            continue
        problems = list(profile.problems)
        if age is not None and profile.age is not None and profile.age != age:
            problems.append(f"{r.key} gives age {profile.age:g}")
        if sex is not None and profile.sex is not None and profile.sex != sex:
            problems.append(f"{r.key} gives sex {profile.sex}")
        notes = "; ".join(n for n in [notes, *problems] if n)
        out[subject] = (age if age is not None else profile.age, sex or profile.sex, notes)
    return out


def reference_table(trials: pd.DataFrame, results: list[TrialSummary], norms: Norms | None = None) -> pd.DataFrame:
    """One row per subject and direction of movement: the subject's largest excursion from neutral
    over its analysed trials (and which trial), its age and sex, the published span that applies
    (:func:`spinemocap.analysis.norms.load_norms`; an age band before the pooled span, one sex
    before both), whom that span describes (``reference_applies_to``: sex, ages, band or
    pooled), the placement (below / within / above the span) and the source's key."""
    norms = norms or load_norms()
    profiles = subject_profiles(results)
    ok = trials[trials["status"] == "ok"]
    rows = []
    for subject, own in ok.groupby(ok["subject"].astype(str), sort=True):
        age, sex, notes = profiles.get(subject, (None, None, ""))
        for movement, column, direction in REFERENCE_COLUMNS:
            values = own[column].to_numpy(float)
            best = int(np.nanargmax(values)) if np.isfinite(values).any() else None
            value = float(values[best]) if best is not None else float("nan")
            applicable = norms.for_subject(movement, age, sex)
            reference = applicable[0] if applicable else None
            placement = reference.place(value) if reference is not None else "no reference"
            rows.append({
                "subject": subject, "age": age if age is not None else np.nan, "sex": sex or "not given",
                "movement": movement.replace("_", " "), "direction": direction, "value_deg": value,
                "trial": own["key"].iloc[best] if best is not None else "",
                "reference_low_deg": reference.low_deg if reference else np.nan,
                "reference_high_deg": reference.high_deg if reference else np.nan,
                "reference_sex": reference.sex if reference else "",
                "reference_applies_to": reference.applies_to() if reference else "",
                "statistic": reference.statistic if reference else "",
                "placement": placement, "source": reference.source.key if reference else "",
                "metadata_notes": notes})
    return pd.DataFrame(rows, columns=["subject", "age", "sex", "movement", "direction", "value_deg", "trial",
                                       "reference_low_deg", "reference_high_deg", "reference_sex",
                                       "reference_applies_to", "statistic", "placement", "source", "metadata_notes"])


def _write_reference_table(out: Path, table: pd.DataFrame) -> Path:
    path = out / REFERENCE_TABLE
    with atomic_write(path) as handle:
        table.to_csv(handle, index=False, float_format="%.2f")
    return path


def _reference_html(table: pd.DataFrame, norms: Norms | None = None) -> str:
    """The reference-range section: the note, the table (values outside the published span
    marked), the sources with their methods and the published findings on age and sex."""
    norms = norms or load_norms()
    parts = ["<h2>Reference ranges</h2><p class='note'>Each subject's largest lumbar excursion from neutral "
             "(over its trials) beside published values for asymptomatic adults. A value outside the published "
             "span is <span class='warn'>marked</span>: it differs from other people measured with another "
             "instrument, which is no diagnosis. The comparison means something only when the trials include "
             "maximal movements in each direction. Age and sex come from <code>[subject] age</code> and "
             "<code>sex</code> in capture.toml; without them only values for all ages and both sexes apply. "
             "<i>Applies to</i> names the span used: the age band of the subject's age and sex where a source "
             "tabulates one, else the source's span over all its ages (pooled). "
             f"Table: {REFERENCE_TABLE}.</p>"]
    if table.empty:
        parts.append("<p class='note'>No analysed trial.</p>")
    else:
        shown = pd.DataFrame({
            "subject": table["subject"], "age": [f"{a:g}" if a == a else "not given" for a in table["age"]],
            "sex": table["sex"], "movement": table["movement"], "direction": table["direction"],
            "value (deg)": table["value_deg"], "trial": table["trial"],
            "published (deg)": [_span_words(lo, hi) for lo, hi in zip(table["reference_low_deg"],
                                                                       table["reference_high_deg"])],
            "what the span is": table["statistic"], "applies to": table["reference_applies_to"],
            "source": table["source"],
            "placement": [PLACEMENT_WORDS[p] for p in table["placement"]]})
        parts.append(_html_table(shown, lambda r: "warn" if r["placement"].startswith(("below", "above")) else ""))
        notes = sorted({f"{s}: {n}" for s, n in zip(table["subject"], table["metadata_notes"]) if n})
        if notes:
            parts.append("<p class='warn'>Subject metadata: " + html.escape("; ".join(notes)) + "</p>")
    parts.append("<h3>Sources</h3><ul class='note'>")
    for source in norms.sources.values():
        parts.append(f"<li><b>{html.escape(source.key)}</b>: {html.escape(source.citation)}<br>Method: "
                     f"{html.escape(source.method)}<br>Against ours: {html.escape(source.differs)}</li>")
    parts.append("</ul><h3>Published effects of age and sex</h3><ul class='note'>")
    for finding in norms.findings:
        parts.append(f"<li>{html.escape(finding.about)}: {html.escape(finding.text)} "
                     f"({html.escape(finding.source.key)})</li>")
    parts.append("</ul>")
    return "".join(parts)


def _span_words(low: float, high: float) -> str:
    if not np.isfinite(low):
        return "n/a"
    return f"{low:g}" if low == high else f"{low:g}-{high:g}"


def _view_links(folder: Path, report_dir: Path) -> str:
    """Links (relative to the report) to a trial's labelled videos and 3D viewer (written by
    ``spinemocap view CAPTURE <trial folder>``), or how to make them."""
    found = view_outputs(folder)
    if not found:
        return ("<p class='note'>No labelled video or 3D viewer yet: <code>spinemocap view CAPTURE "
                f"{html.escape(str(folder))}</code> writes them into its view/ folder.</p>")
    words = {"grid": "labelled video, all cameras", "viewer": "tape in 3D"}
    links = []
    for key, path in found.items():
        href = urllib.parse.quote(Path(os.path.relpath(path, report_dir)).as_posix())
        label = words.get(key) or f"camera {key.split(':', 1)[1]}"
        links.append(f"<a href=\"{html.escape(href, quote=True)}\">{html.escape(label)}</a>")
    return "<p class='note'>See it: " + " · ".join(links) + "</p>"


def write_report(out: str | os.PathLike, title: str | None = None) -> dict[str, Path]:
    """Write the report and summary tables into the batch folder ``out``; returns their paths."""
    out = Path(out)
    check_writable(out, "batch output folder")
    results = load_results(out)
    angle_tables = read_trial_angles(results)
    relative = trial_neutrals(results, angle_tables)
    trials = trial_table(results, relative)
    by_subject, by_condition = group_table(trials, "subject"), group_table(trials, "condition")
    problems = pd.concat([problem_table(results), empty_column_problems(trials)], ignore_index=True)
    paths = _write_tables(out, trials, by_subject, by_condition, problems)

    n_ok = int((trials["status"] == "ok").sum())
    parts = [f"<h1>{html.escape(title or 'Spine angles: ' + out.name)}</h1>",
             f"<p class='note'>{len(trials)} trials, {n_ok} analysed, {len(trials) - n_ok} failed. "
             f"Generated {_dt.datetime.now():%Y-%m-%d %H:%M}. Angles in degrees: lumbar = "
             f"{html.escape(_lumbar_levels(results))} on the tape's midline; flexion positive forward, lateral bending "
             "positive to the subject's right, axial rotation positive to the subject's left. "
             "Motion is reported from neutral (zero = the subject's static trial, or else the trial's "
             f"{_first_frames_words()}): flexion and extension from neutral are the largest bends "
             "forward and backward past it, ROM the whole range; 'angle at neutral' is the absolute angle "
             "(negative = lordotic). Tables: summary.csv, summary_by_subject.csv, summary_by_condition.csv, "
             "summary.xlsx.</p>"]
    parts.append("<h2>Problems</h2>")
    if problems.empty:
        parts.append("<p class='ok'>None: every trial analysed, every angle supported by the data.</p>")
    else:
        parts.append(_html_table(problems, lambda r: "warn" if r["what"].endswith("angles NaN") else "bad"))
    quality = tracking_quality_table(results)
    if not quality.empty:
        parts.append("<h2>Tracking quality</h2><p class='warn'>The tracker could not vouch for the labels "
                     "of these frames (a re-solve wanted other labels, dots were left unlabelled beyond the "
                     "tape's end or the tape's spacing was implausible); their dots carry a low "
                     "<code>confidence</code> in markers.csv. Check them before trusting their angles.</p>")
        parts.append(_html_table(quality, lambda r: "warn"))
    rom_png = _rom_plot(trials)
    if rom_png:
        parts.append("<h2>Range of motion by subject and condition</h2>")
        parts.append(f"<img alt='range of motion by subject and condition' src='data:image/png;base64,{rom_png}'>")
    parts.append("<h2>Trials</h2>" + _trials_html(trials))
    parts.append("<h2>By subject</h2>" + _group_html(by_subject, "subject"))
    parts.append("<h2>By condition</h2>" + _group_html(by_condition, "condition"))
    parts.append("<h2>Per trial</h2><p class='note'>Top: lumbar angles from neutral over time. Bottom: the tape "
                 "midline (S1 end at the origin) at neutral, peak flexion and peak extension, and the flexion of "
                 "each vertebral segment.</p>")
    for r in results:
        neutral = _neutral_of(r, relative)
        parts.extend(_trial_section(r, neutral, angle_tables.get(r.key), out))
    references = reference_table(trials, results)
    paths["reference_ranges"] = _write_reference_table(out, references)
    parts.append(_reference_html(references))
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title or out.name)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")
    with atomic_write(out / "report.html") as handle:
        handle.write(page)
    paths["html"] = out / "report.html"
    return paths


def _neutral_of(result: TrialSummary, relative: dict[str, tuple[dict, str]]) -> Neutral | None:
    """The neutral a trial's numbers were taken from (rebuilt from its summary's ``*_neutral``)."""
    if result.key not in relative:
        return None
    summary, source = relative[result.key]
    return Neutral({k[: -len("_neutral")]: v for k, v in summary.items() if k.endswith("_neutral")}, source)


def _lumbar_levels(results: list[TrialSummary]) -> str:
    pairs = {r.analysis.lumbar_levels for r in results if r.analysis is not None}
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

    import exporters

    from ..analysis.angles import AngleSettings
    from ..analysis.levels import LevelMap
    from .batch import MARKERS, MarkerSource, discover, run_batch, trial_out_dir
    from .results import RESULT_FILES, RESULTS_MANIFEST, results_complete, write_markers

    out = Path(out)
    (trial,) = discover(capture_dir)
    source: MarkerSource = "groundtruth"
    if markers_csv is not None and Path(markers_csv).is_file():
        target = trial_out_dir(out, trial)
        target.mkdir(parents=True, exist_ok=True)
        for name in (*RESULT_FILES, RESULTS_MANIFEST):  # the whole set: the batch reuses only a complete one
            if (Path(markers_csv).parent / name).is_file():
                shutil.copy2(Path(markers_csv).parent / name, target / name)
                os.utime(target / name)  # newer than the capture
        if Path(markers_csv).name != MARKERS or not results_complete(target):
            write_markers(exporters.read(markers_csv), target)
        source = "tracked"
    lower = "S1"
    names = Capture.open(capture_dir).row_levels()
    if names is not None:
        lower = next(iter(LevelMap.from_row_levels(names, len(names)).rows))
    run_batch(capture_dir, out, source=source, workers=1, settings=AngleSettings(lower=lower), progress=progress)
    return write_report(out, title=f"Spine angles: {Path(capture_dir).name}")
