"""The tracking benchmark (``spinemocap bench track``): the paper's accuracy experiments (Tables 1 and 2) on the synthetic
studio, rendered in-process and tracked, printed next to the paper's numbers.

Per run: mean / median / 95th-percentile error (mm) with observed and inferred dots apart, the
visibility histogram (dot-frames seen by 4/3/2/1/0 cameras), label swaps, frames without a
solution, the 1-/2-/3-plane keypoint baselines on the same frames (see
:mod:`spinemocap.track.evaluate`) and time per stage per frame. ``--json FILE`` saves every
number; a plot of the per-frame errors (as the paper's Fig. 6) goes beside it as FILE.png.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..app.run import TrackingMode, TrackingWarning, TrackQuality, make_detector, run_tracking
from ..fileio import atomic_path, atomic_write
from ..markers import MarkerTable
from ..synth import SynthConfig, build_scene
from ..track.config import TrackerConfig
from ..track.evaluate import TrackingAccuracy, evaluate_tracking, plane_baseline

# Paper (Hachmann et al.): Table 1 (Artificial, mean mm) and Table 2 (per occlusion level).
PAPER_ERROR_MM = {"none": 5.55, "light": 6.17, "heavy": 7.89}
PAPER_PLANES_MM = {"1-plane": 37.67, "2-plane": 21.89, "3-plane": 10.29}
PAPER_BALLS = {"none": 0, "light": 5000, "heavy": 10000}
PAPER_VISIBILITY = {  # dot-frames of 548 frames x 32 dots seen by 4/3/2/1/0 cameras
    "none": [17536, 0, 0, 0, 0],
    "light": [11197, 5328, 825, 83, 103],
    "heavy": [6846, 6812, 2764, 607, 507],
}
GOAL_MM = {"none": 2.0, "light": 2.5, "heavy": 3.5}


def _rendered_views(scene, detect, n_frames: int):
    for frame in range(n_frames):
        rendered = scene.render(frame)
        t0 = time.perf_counter()
        views = detect(frame, rendered.images, rendered.masks)
        yield frame, views, 1000 * (time.perf_counter() - t0)


@dataclass
class TrackBenchRun:
    """How a ``bench track`` run was made and what the tracker reported beside its accuracy:
    the studio (preset, occlusion and its balls, realism, cameras, tape rows and thickness in
    mm), the tracker (mode, detector, wall-clock seconds, its quality summary, frames per route,
    frames unsolved before gap filling, frames whose LP was relaxed) and the paper's numbers and
    our goal (mm) for the occlusion level."""

    preset: str
    occlusion: str
    balls: int
    mode: TrackingMode
    realism: str
    quality: TrackQuality
    detector: str
    cameras: int
    rows: int | None
    wall_s: float
    tape_thickness_mm: float
    routes: dict[str, int]
    frames_failed_before_gap_fill: int
    lp_relaxed_frames: int
    paper: dict
    goal_mm: float
    weights: str = "shipped"  # the net detector's weights file


@dataclass
class TrackBenchResult:
    """One ``bench track`` run: the accuracy, the run's set-up and tracker report, the tracked
    table and the scene's ground truth (for the plot)."""

    accuracy: TrackingAccuracy
    run: TrackBenchRun
    table: MarkerTable
    groundtruth: dict

    @property
    def numbers(self) -> dict:
        """Every number, JSON-ready: the accuracy's (:meth:`TrackingAccuracy.to_dict`), then the run's."""
        return {**self.accuracy.to_dict(), **dataclasses.asdict(self.run), "quality": self.run.quality.to_dict()}

    def save(self, path: Path) -> Path:
        """Write the numbers to ``path`` (JSON) and the per-frame error plot beside it; returns the plot's path."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path) as fh:
            json.dump(self.numbers, fh, indent=2, default=float)
        plot = path.with_suffix(".png")
        plot_errors(self.table, self.groundtruth, plot, self.run.occlusion)
        return plot


def run_track_benchmark(preset: str = "artificial", occlusion: str = "none", frames: int | None = None,
                        mode: TrackingMode = "sequence", detector: str = "net", config: TrackerConfig | None = None,
                        seed: int = 0, progress: bool = True,
                        say: Callable[[str], None] = print, realism: str = "lab",
                        weights: Path | None = None) -> TrackBenchResult:
    """Render the synthetic sequence in-process, track it and score it against the ground truth.

    ``realism``: the studio's realism level (``lab`` by default: taping tension, Schober skin
    strain, calibration and sync error, sensor noise; ``ideal`` = no skin strain, exact set-up).
    The tracker gets what a lab has: the roll's nominal tape spec and the written rig. ``weights``:
    the ``net`` detector's weights file (None: the shipped ones)."""
    config = config or TrackerConfig()
    synth = SynthConfig.preset(preset, occlusion=occlusion, seed=seed, realism=realism,
                               **({"frames": frames} if frames else {}))
    say(f"building the {preset} scene ({synth.frames} frames, {synth.cameras} cameras, "
        f"{synth.rows}-row tape, occlusion {occlusion}: {synth.n_balls} balls) at the '{realism}' realism level: "
        f"tape tension {100 * float(synth.tape_tension or 0):g} %, skin strain x{float(synth.skin_strain or 0):g}, "
        f"calibration error {float(synth.calibration_error_px or 0):g} px, sync error "
        f"{float(synth.sync_error_ms or 0):g} ms, noise {float(synth.noise or 0):g} ...")
    scene = build_scene(synth)
    rig = getattr(scene, "calibrated_rig", scene.rig)  # the rig a lab would have been given
    detect = make_detector(detector, weights=weights)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TrackingWarning)
        result = run_tracking(_rendered_views(scene, detect, synth.frames), rig, scene.tape, scene.fps,
                              up=scene.subject()["up"], mode=mode, config=config,
                              progress=progress, n_frames=synth.frames)
    wall = time.perf_counter() - start
    gt = scene.groundtruth
    accuracy = evaluate_tracking(result.table, gt, scene.tape.graph.min_spacing_mm, result.stage_ms())
    run = TrackBenchRun(
        preset=preset, occlusion=occlusion, balls=synth.n_balls, mode=mode, realism=realism,
        quality=result.quality(),
        detector=detector, cameras=len(scene.rig), rows=synth.rows, wall_s=wall,
        tape_thickness_mm=scene.tape.thickness_mm,
        routes=result.routes(), frames_failed_before_gap_fill=result.routes().get("failed", 0),
        lp_relaxed_frames=sum(f.lp_status == "relaxed" for f in result.frames),
        paper={"error_mm": PAPER_ERROR_MM[occlusion], "plane_baselines_mm": PAPER_PLANES_MM,
               "visibility_histogram": PAPER_VISIBILITY[occlusion]},
        goal_mm=GOAL_MM[occlusion], weights=str(weights) if weights else "shipped",
    )
    return TrackBenchResult(accuracy, run, result.table, gt)


def _row(name: str, paper, ours, fmt: str = "{:.2f}") -> str:
    def cell(v):
        if v is None or (isinstance(v, float) and not np.isfinite(v)):
            return "-"
        return fmt.format(v) if isinstance(v, float) else str(v)

    return f"  {name:<34}{cell(paper):>12}{cell(ours):>12}"


def format_report(result: TrackBenchResult) -> str:
    """The paper's Tables 1 and 2 beside ours, then diagnostics and stage timing."""
    acc, run = result.accuracy, result.run
    occ = run.occlusion
    planes = acc.plane_baselines_mm or {}
    lines = [f"\nTable 1 (Artificial, mean error mm)   [{acc.frames} frames x {acc.dots} dots, "
             f"mode {run.mode}, detector {run.detector} (weights {run.weights}), "
             f"tape thickness {run.tape_thickness_mm} mm, "
             f"studio realism '{run.realism}']",
             f"  {'':<34}{'paper':>12}{'ours':>12}"]
    for name in ("1-plane", "2-plane", "3-plane"):
        lines.append(_row(f"{name} keypoint baseline", PAPER_PLANES_MM[name], planes.get(name)))
    lines.append(_row("tracker, all dots", PAPER_ERROR_MM[occ] if occ == "none" else None, acc.mean_error_mm))
    lines += [f"\nTable 2 (occlusion '{occ}': paper {PAPER_BALLS[occ]} balls, ours {run.balls} balls)",
              f"  {'':<34}{'paper':>12}{'ours':>12}"]
    hist = acc.visibility_histogram or {}
    paper_hist = PAPER_VISIBILITY[occ]
    ours_hist = list(hist.values())
    total_paper, total_ours = sum(paper_hist), max(sum(ours_hist), 1)
    for k, (key, value) in enumerate(hist.items()):
        paper_share = 100 * paper_hist[k] / total_paper if k < len(paper_hist) else None
        lines.append(_row(f"seen by {key} (% dot-frames)", paper_share, 100 * value / total_ours, "{:.1f}"))
    lines.append(_row("error mean (mm)", PAPER_ERROR_MM[occ], acc.mean_error_mm))
    lines.append(_row("error median (mm)", None, acc.median_error_mm))
    lines.append(_row("error p95 (mm)", None, acc.p95_error_mm))
    lines.append(_row(f"observed dots mean (n={acc.observed.n})", None, acc.observed.mean))
    lines.append(_row("observed dots p95", None, acc.observed.p95))
    lines.append(_row(f"inferred dots mean (n={acc.inferred.n})", None, acc.inferred.mean))
    lines.append(_row("inferred dots p95", None, acc.inferred.p95))
    lines.append(_row("label swaps (dot-frames)", None, acc.label_swaps))
    lines.append(_row("frames without a solution", None, acc.frames_without_solution))
    lines.append(_row("  unsolved before gap filling", None, run.frames_failed_before_gap_fill))
    lines.append(_row("flagged frames (labels not vouched for)", None, len(run.quality.flagged_frames)))
    lines.append(f"  goal: <= {run.goal_mm} mm, zero swaps, every frame solved; routes {run.routes}, "
                 f"LP relaxed in {run.lp_relaxed_frames} frames")
    if acc.stage_ms is not None:
        lines.append("\nTime per stage per frame (ms): " + ", ".join(f"{k} {v:.0f}" for k, v in acc.stage_ms.items())
                     + f"; total {acc.total_ms_per_frame:.0f} ms (rendering excluded)")
    return "\n".join(lines)


def plot_errors(table, gt: dict, path: Path, occlusion: str) -> None:
    """Per-frame mean error of the tracker and of the plane baselines (paper Fig. 6)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    arrays = table.to_arrays()
    frames = arrays.frames
    truth = np.asarray(gt["dots"], float)[frames]
    err = np.linalg.norm(arrays.positions - truth, axis=2)
    fig, ax = plt.subplots(figsize=(9, 4))
    if "keypoints" in gt:
        kp = np.asarray(gt["keypoints"], float)[frames]
        for n in (1, 2, 3):
            ax.plot(frames, np.nanmean(plane_baseline(truth, kp, n), axis=1), label=f"{n}-plane baseline")
    ax.plot(frames, np.nanmean(err, axis=1), "k", lw=2, label="tracker (mean over dots)")
    ax.plot(frames, np.nanmax(err, axis=1), "k:", lw=1, label="tracker (worst dot)")
    ax.set_xlabel("frame")
    ax.set_ylabel("error (mm)")
    ax.set_yscale("log")
    ax.set_title(f"Tracking error per frame, occlusion '{occlusion}'")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
