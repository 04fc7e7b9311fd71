"""``spinemocap bench opensim``: OpenSim inverse kinematics of the tape markers against the spine
motion the synthetic studio applied, with the geometric angles of :mod:`spinemocap.analysis` as
the peer in the same run.

Per studio motion (``flexion``, ``lateral``, ``rotation``, ``mixed``) and marker source
(``groundtruth``: exact dot centres; ``tracked``: rendered and tracked with the shipped detector),
``spinemocap opensim``'s pipeline runs on the markers; the IK angle is the Cardan angle (this
project's sequence and signs) of the vertebra under the upper benchmark row relative to the one
under the lower row, from the solved model's body orientations. As in ``bench angles``, the
rows are the ones nearest the middle of the lowest and highest anny bone segments on the tape,
and the expected change from the neutral first frame is ``bench angles``' skin model
(:func:`spinemocap.bench.analysis.expected_between_rows`: the skin at a row turns with the
fractional number of anny's spine joints at its rest height; Cardan angles of the two rows'
turned rest frames), so that both
benchmarks score against one model.
For ``mixed`` all three angles are scored.
The peer measures the same two rows with :func:`spinemocap.analysis.angles.compute_angles`.

Methods per run (same markers, same rows): ``ik`` (the pipeline: row tilt normalised, each
row's slip held at the one the tape's lengthening shows, each frame solved from the previous
solution and from the static pose, inferred dots down-weighted), ``ik_slip_goal`` and
``ik_slip_from_markers`` (:func:`spinemocap.opensim.pipeline.slip_solved_as` ``goal`` / ``off``:
the slips solved with a goal at the tape's slip, or from the markers with a prior toward 0, each
at its own accuracy), ``ik_one_start`` (the pipeline's skin model, each frame solved from the
previous solution only, inferred dots weighed as observed ones), ``ik_rigid`` (every marker fixed
to its vertebra, tilt as measured, one start, inferred as observed: the pipeline without the skin
model) and ``geometric``; ``methods`` picks the IK ones that run. Marker RMS is over the
observed (measured) dots; ``marker_rms_all_mm`` includes the inferred ones. The IK runs place the joint centres at
the studio body's own depth under the tape (:func:`body_model_depth_scale`: anny's spine joints,
the depth a lab would take from imaging), named in their ``summary.json``. Subjects: one studio
seed each (``seeds``).
"""

from __future__ import annotations

import platform
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..opensim.pipeline import slip_solved_as
from ..opensim.skin_model import SlipFromTape
from ..opensim.tools import OBSERVED_SD_MM
from ..synth.body import JointDepth

if TYPE_CHECKING:  # bench.analysis loads the batch and the tracker: imported where it runs
    from ..analysis.levels import LevelMap
    from .analysis import StudioMotion

MOTIONS = ("flexion", "lateral", "rotation", "mixed")
AXES = ("flexion", "lateral", "rotation")
GOALS = {"marker_rms_mm": 2.0, "flexion_rmse_deg": 2.0, "lateral_rmse_deg": 2.0, "rotation_rmse_deg": 3.0}


def _slip_method(from_tape: SlipFromTape) -> dict[str, Any]:
    return {name: getattr(slip_solved_as(from_tape), name) for name in ("slip", "accuracy", "fresh_start_margin")}


# the peers: the slips solved with a goal at the tape's slip or from the markers alone (each at its own
# accuracy); the skin model with each frame solved only from the previous solution and inferred dots
# weighed as observed ones; every marker fixed to its vertebra (one start, inferred as observed)
ONE_START: dict[str, Any] = {"restart_from_static": False, "inferred_sd_mm": OBSERVED_SD_MM}
RIGID: dict[str, Any] = {"slip": None, "normalise_tilt": False, **ONE_START}
IK_METHODS: dict[str, dict[str, Any]] = {"ik": {}, "ik_slip_goal": _slip_method("goal"),
                                         "ik_slip_from_markers": _slip_method("off"), "ik_one_start": ONE_START,
                                         "ik_rigid": RIGID}
METHODS = (*IK_METHODS, "geometric")
BODY_MODEL_DEPTH = "the studio body's spine joints under the tape rows, static trial"


def run_opensim_benchmark(motions: Sequence[str] = MOTIONS, sources: Sequence[str] = ("groundtruth", "tracked"),
                          frames: int = 100, fps: float = 100 / 3, rows: int = 13, tracked_frames: int | None = None,
                          cache: Path | None = None, progress: bool = True, realism: str = "lab",
                          seeds: Sequence[int] = (0,), accuracy: float | None = None,
                          methods: Sequence[str] = tuple(IK_METHODS),
                          joint_depth: JointDepth = "anny") -> OpenSimBenchReport:
    """Every (seed, motion, source) scored (see the module docstring; runs keyed
    ``<motion>/seed<seed>``), the headline numbers and the goals; ``cache``: folder to keep and
    reuse the tracked markers; ``realism``: the studio's level (``lab``: tension, skin strain,
    tracking through the lab's inexact rig); ``accuracy``: the IK solver accuracy of every IK
    method (:attr:`spinemocap.opensim.OpenSimSettings.accuracy`; None = each method's own);
    ``methods``: the IK methods to run (keys of :data:`IK_METHODS`; the geometric peer always runs);
    ``joint_depth``: where the studio's spine bends under the skin
    (:data:`spinemocap.synth.body.JointDepth`)."""
    from ..fileio import InputError

    unknown = sorted(set(methods) - set(IK_METHODS))
    if unknown:
        raise InputError("methods", f"unknown IK methods {unknown}: choose from {' '.join(IK_METHODS)}")
    from tqdm import tqdm

    from ..opensim import require_opensim

    require_opensim()
    started = time.time()
    results: dict = {source: {} for source in sources}
    jobs = [(seed, m, s) for seed in seeds for m in motions for s in sources]
    for seed, motion, source in tqdm(jobs, desc="subjects x motions x sources", disable=not progress):
        n = (tracked_frames or frames) if source == "tracked" else frames
        results[source][f"{motion}/seed{seed}"] = bench_motion(motion, source, n, fps, rows, progress, cache,
                                                               realism, seed, accuracy, methods, joint_depth)
    return OpenSimBenchReport(
        machine=f"{platform.machine()} {platform.processor() or ''}".strip(), date=time.strftime("%Y-%m-%d"),
        realism=realism, ik_accuracy=accuracy, methods=[*methods, "geometric"], headline=headline(results),
        sources=results, wall_s=round(time.time() - started, 1), joint_depth=joint_depth)


@dataclass(frozen=True)
class MethodHeadline:
    """One method on one marker source, worst over subjects (:func:`headline`): per angle
    (``flexion``, ``lateral``, ``rotation``) the worst RMSE (deg) over its own single-axis motion
    and ``mixed``, the same over the frames without a flagged marker where they were scored, the
    worst marker RMS (mm; None for the geometric angles, which fit no markers) and the goals met
    (per angle, and ``marker_rms``)."""

    rmse_deg_worst: dict[str, float]
    rmse_deg_vouched_worst: dict[str, float]
    marker_rms_mm_worst: float | None
    goals_met: dict[str, bool]

    def numbers(self) -> dict[str, float]:
        """The numbers as the JSON names them (``<angle>_rmse_deg_worst``,
        ``<angle>_rmse_deg_vouched_worst``, ``marker_rms_mm_worst``), angle by angle."""
        out: dict[str, float] = {}
        for axis in AXES:
            if axis in self.rmse_deg_worst:
                out[f"{axis}_rmse_deg_worst"] = self.rmse_deg_worst[axis]
            if axis in self.rmse_deg_vouched_worst:
                out[f"{axis}_rmse_deg_vouched_worst"] = self.rmse_deg_vouched_worst[axis]
        if self.marker_rms_mm_worst is not None:
            out["marker_rms_mm_worst"] = self.marker_rms_mm_worst
        return out

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: :meth:`numbers`, then ``goals_met``."""
        return {**self.numbers(), "goals_met": dict(self.goals_met)}


@dataclass(frozen=True)
class OpenSimBenchReport:
    """``bench opensim``'s numbers (:func:`run_opensim_benchmark`): the machine, date, realism
    level, IK solver accuracy (None: each method's own) and methods run; the headline per marker
    source and method; every run's scores (source -> ``<motion>/seed<seed>`` -> method -> the
    numbers :func:`bench_motion` gives), the wall seconds and the studio's joint depth."""

    machine: str
    date: str
    realism: str
    ik_accuracy: float | None
    methods: list[str]
    headline: dict[str, dict[str, MethodHeadline]]
    sources: dict[str, dict[str, dict[str, Any]]]
    wall_s: float
    joint_depth: str = "anny"

    def to_dict(self) -> dict[str, Any]:
        """The JSON object (the goals after the date)."""
        return {"machine": self.machine, "date": self.date, "goals": GOALS, "realism": self.realism,
                "ik_accuracy": self.ik_accuracy, "methods": self.methods,
                "headline": {source: {method: row.to_dict() for method, row in table.items()}
                             for source, table in self.headline.items()},
                "sources": self.sources, "wall_s": self.wall_s, "joint_depth": self.joint_depth}


def headline(results: dict) -> dict[str, dict[str, MethodHeadline]]:
    """Per source and method (those that ran on every run): the worst RMSE over subjects of each
    angle on its own single-axis motion and on ``mixed``, the worst marker RMS, and whether each
    goal is met."""
    out: dict[str, dict[str, MethodHeadline]] = {}
    for source, runs in results.items():
        table: dict[str, MethodHeadline] = {}
        for method in [m for m in METHODS if all(m in r for r in runs.values())]:
            worst: dict[str, float] = {}
            vouched_worst: dict[str, float] = {}
            for axis in AXES:
                values = [r[method][f"{axis}_rmse_deg"] for key, r in runs.items()
                          if key.split("/")[0] in (axis, "mixed") and f"{axis}_rmse_deg" in r[method]]
                if values:
                    worst[axis] = float(np.max(values))
                vouched = [r[method][f"{axis}_rmse_deg_vouched"] for key, r in runs.items()
                           if key.split("/")[0] in (axis, "mixed") and f"{axis}_rmse_deg_vouched" in r[method]]
                if vouched:  # the same over the frames none of whose markers is flagged
                    vouched_worst[axis] = float(np.nanmax(vouched))
            marker = (float(np.max([r[method]["marker_rms_mm"] for r in runs.values()]))
                      if method != "geometric" else None)
            goals = {axis: value <= GOALS[f"{axis}_rmse_deg"] for axis, value in worst.items()}
            if marker is not None:
                goals["marker_rms"] = marker <= GOALS["marker_rms_mm"]
            table[method] = MethodHeadline(worst, vouched_worst, marker, goals)
        out[source] = table
    return out


def bench_motion(motion: str, source: str, frames: int, fps: float, rows: int, progress: bool,
                 cache: Path | None = None, realism: str = "lab", seed: int = 0,
                 accuracy: float | None = None, methods: Sequence[str] = tuple(IK_METHODS),
                 joint_depth: JointDepth = "anny") -> dict:
    """One studio motion of one subject (``seed``) from one marker source: the IK ``methods``
    (:data:`IK_METHODS`; solver ``accuracy``) and the geometric angles scored."""
    from ..analysis.angles import AngleSettings, compute_angles
    from ..analysis.levels import LevelMap
    from ..markers import MarkerTable
    from ..opensim import OpenSimSettings, run_opensim
    from .analysis import HIGH, LOW, expected_between_rows, studio_motion

    data = studio_motion(motion, frames, fps, rows, seed=seed, realism=realism, joint_depth=joint_depth)
    tape = data.tape
    if source == "tracked":
        depth = "" if joint_depth == "anny" else f"_{joint_depth}"
        markers = tracked_markers(data.scene, progress,
                                  cache and cache / f"markers_{motion}_{frames}_{fps:.4g}_{realism}{depth}_seed{seed}.csv")
    else:
        markers = MarkerTable.from_arrays(data.labels, data.dots, fps=fps)
    applied = data.applied - data.applied[0]
    axes = [AXES.index(motion)] if motion in AXES else [0, 1, 2]
    lo, hi = data.rows
    truth = MarkerTable.from_arrays(data.labels, data.dots, fps=fps)
    expected = expected_between_rows(data.scene, truth, lo, hi)
    levels = LevelMap.from_row_levels(data.row_levels, tape.n_rows)
    depth_scale = body_model_depth_scale(data, levels)
    ik: dict = {}
    vouched: np.ndarray | None = None  # (F,) frames without a flagged marker (from the IK runs' summary)
    for method in methods:
        overrides = IK_METHODS[method]
        with tempfile.TemporaryDirectory() as tmp:
            # the static trial is the neutral first frame: the studio's motions start moving at once
            settings = replace(OpenSimSettings(static_frames=1, depth_scale=depth_scale,
                                               depth_source=BODY_MODEL_DEPTH), **overrides)
            if accuracy is not None:
                settings = replace(settings, accuracy=accuracy)
            result = run_opensim(markers, tape, levels, data.up, data.facing, Path(tmp) / "opensim",
                                 settings=settings)
            s = result.summary
            slip = s.skin_model.slip
            vouched = np.ones(len(applied), bool)
            vouched[s.flagged_frames] = False  # positions of the frames with a flagged marker
            ik[method] = {**score(ik_angles(result, lo, hi), expected, axes, vouched),
                          "marker_rms_mm": s.marker_rms_observed_mm, "marker_rms_all_mm": s.marker_rms_mm,
                          "marker_rms_mm_max": s.marker_rms_mm_max, "ms_per_frame": s.ms_per_frame,
                          "flagged_frames": len(s.flagged_frames), "driven_joints": len(s.driven_joints),
                          "slip_at_peak_mm": slip.at_peak_mm if slip is not None else None}
    completeness = markers.completeness()
    t0 = time.perf_counter()
    geometric = compute_angles(markers, tape, LevelMap({LOW: lo, HIGH: hi}, tape.n_rows), up=data.up,
                               facing=data.facing, settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
    geometric_ms = 1000 * (time.perf_counter() - t0) / len(geometric)
    peer = geometric[["lumbar_flexion", "lumbar_lateral", "lumbar_rotation"]].to_numpy(float)
    bodies = [result.geometry.names[result.geometry.row_body[r - 1]] for r in (lo, hi)]
    return {
        "seed": seed, "frames": len(applied), "rows": [lo, hi], "vertebrae": bodies, "joint_share": data.share,
        "applied_peak_deg": {a: float(np.abs(applied[:, i]).max()) for i, a in enumerate(AXES)},
        "observed_share": completeness["observed"], "depth_scale": depth_scale,
        **ik,
        "geometric": {**score(peer, expected, axes, vouched), "ms_per_frame": geometric_ms},
    }


def body_model_depth_scale(data: StudioMotion, levels: LevelMap) -> float:
    """Depth of the studio body's spine joints under the tape as a factor on the published
    depths the model would use: the median over the static (first-frame) rows of the distance
    from the row's L-R midpoint to anny's spine-joint polyline, over the published depth of the
    vertebra under the row scaled to the tape (:func:`spinemocap.opensim.geometry.spine_geometry`)."""
    from ..opensim.geometry import opensim_axes, row_frames, spine_geometry, to_opensim

    axes = opensim_axes(data.up, data.facing)
    rows = row_frames(to_opensim(data.dots[0], axes), data.tape)
    geometry = spine_geometry(rows, levels, 1.0)
    chain = to_opensim(data.scene.body.spine_chain(), axes)
    ratios = []
    for r in np.flatnonzero(rows.seen):
        ratios.append(_distance_to_polyline(rows.centre[r], chain) / geometry.depth[geometry.row_body[r]])
    return float(np.median(ratios))


def _distance_to_polyline(point: np.ndarray, vertices: np.ndarray) -> float:
    a, b = vertices[:-1], vertices[1:]
    t = np.clip(np.einsum("ij,ij->i", point - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * (b - a) - point, axis=1)))


def ik_angles(result, lo: int, hi: int) -> np.ndarray:
    """(F, 3) Cardan angles (deg, project signs) of the vertebra under row ``hi`` relative to the
    one under row ``lo`` (rows 1-based) in the solved IK motion."""
    from ..analysis.frames import cardan_angles
    from ..opensim.model import body_name
    from ..opensim.tools import body_rotations

    g = result.geometry
    names = [body_name(g.names[g.row_body[r - 1]]) for r in (lo, hi)]
    _, R = body_rotations(result.out_dir / "model.osim", result.out_dir / "ik.mot", names)
    return cardan_angles(R[:, 0], R[:, 1])


def score(measured: np.ndarray, expected_change: np.ndarray, axes: list[int],
          vouched: np.ndarray | None = None) -> dict:
    """RMSE, R^2 and gain of the change from frame 0 on the scored ``axes``; crosstalk (RMS, deg)
    on the others (single-axis motions). ``vouched`` (F,) bool: the frames no marker of which is
    flagged; the scored axes' RMSE over them is added as ``<axis>_rmse_deg_vouched`` (NaN when
    there are none) with their number, ``vouched_frames``."""
    from .analysis import fit_stats

    change = measured - measured[0]
    out: dict = {}
    for i in axes:
        stats = fit_stats(change[:, i], expected_change[:, i])
        out.update({f"{AXES[i]}_{k}": v for k, v in (("rmse_deg", stats.rmse_deg), ("r2", stats.r2),
                                                     ("gain", stats.gain))})
        if vouched is not None:
            error = change[vouched, i] - expected_change[vouched, i]
            out[f"{AXES[i]}_rmse_deg_vouched"] = float(np.sqrt(np.nanmean(error**2))) if vouched.any() else float("nan")
    if vouched is not None:
        out["vouched_frames"] = int(vouched.sum())
    others = [i for i in range(3) if i not in axes]
    if others:
        out["crosstalk_rms_deg"] = float(np.sqrt(np.nanmean((change[:, others] - expected_change[:, others]) ** 2)))
    return out


def tracked_markers(scene, progress: bool, cache: Path | None = None):
    """Render the scene and track it with the shipped detector (sequence mode); with ``cache``,
    read the markers from there when present, else write them there."""
    import exporters

    from .analysis import tracked_markers as track_scene

    if cache is not None and cache.is_file():
        return exporters.read(cache)

    table = track_scene(scene, progress=progress)  # shipped detector, through the rig the lab calibrated
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        exporters.write(table, cache)
    return table


def format_table(results: dict) -> str:
    lines = [(f"{'source':<13}{'motion/subject':<16}{'method':<19}{'flex RMSE':>10}{'lat RMSE':>9}{'rot RMSE':>9}"
              f"{'R2 (scored)':>12}{'xtalk':>7}{'mkr RMS mm':>11}{'ms/frame':>9}")]
    for source, runs in results.items():
        for key, run in runs.items():
            for method in [m for m in METHODS if m in run]:
                r = run[method]
                r2 = [r[f"{a}_r2"] for a in AXES if f"{a}_r2" in r]
                cells = [f"{r.get(f'{a}_rmse_deg', float('nan')):>9.2f}" for a in AXES]
                lines.append(f"{source:<13}{key:<16}{method:<19}{cells[0]:>10}{cells[1]:>9}{cells[2]:>9}"
                             f"{min(r2):>12.4f}{r.get('crosstalk_rms_deg', float('nan')):>7.2f}"
                             f"{r.get('marker_rms_mm', float('nan')):>11.2f}{r['ms_per_frame']:>9.1f}")
    return "\n".join(lines)


def headline_plot_png(report: OpenSimBenchReport) -> bytes:
    """Bars of the headline (:func:`headline`): per marker source, the worst RMSE over subjects of
    each angle (deg) and the worst marker RMS (mm) per method, the goals as dashes; the median time
    a frame per method in the legend."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    quantities = [*(f"{a}_rmse_deg_worst" for a in AXES), "marker_rms_mm_worst"]
    goals = [GOALS[f"{a}_rmse_deg"] for a in AXES] + [GOALS["marker_rms_mm"]]
    sources = list(report.headline)
    fig, axes = plt.subplots(1, len(sources), figsize=(6 * len(sources), 4.2), squeeze=False)
    for ax, source in zip(axes[0], sources):
        table = report.headline[source]
        methods = list(table)
        width = 0.8 / len(methods)
        for m, method in enumerate(methods):
            times = [run[method]["ms_per_frame"] for run in report.sources[source].values() if method in run]
            heights = [table[method].numbers().get(q, np.nan) for q in quantities]
            ax.bar(np.arange(len(quantities)) + (m - (len(methods) - 1) / 2) * width, heights, width,
                   label=f"{method} ({np.median(times):.0f} ms/frame)")
        for q, goal in enumerate(goals):
            ax.hlines(goal, q - 0.45, q + 0.45, colors="k", linestyles="dashed", lw=1)
        ax.set_xticks(range(len(quantities)),
                      ["flexion RMSE\n(deg)", "lateral RMSE\n(deg)", "rotation RMSE\n(deg)", "marker RMS\n(mm)"])
        ax.set_title(f"{source}: worst over subjects and motions (goals dashed)", fontsize=10)
        ax.legend(fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()
