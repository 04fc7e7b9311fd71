"""The world frame after ``--refine-rig``, over many calibrations (``spinemocap bench gauge``).

``--refine-rig`` fixes the cameras' relative geometry from the tracked dots, but no residual
says where the world is: a similarity common to all cameras moves every dot and changes no
reprojection. The refinement picks it with weak priors toward the given cameras (see
:mod:`spinemocap.track.rig_refine`), so what is left of the error is the given rig's own frame
error, which differs from one calibration to the next. One seeded case (``bench realism``'s
``calibration 2.0 px``) says little about it; this benchmark measures it over several scenes
and several seeded calibrations per error level.

Per scene (``artificial`` preset, light occlusion, shipped detector): render and detect once,
track once in sequence mode with the scene's own 2 px rig (what ``bench realism`` does), then
for every level and every seeded rig written by the studio's perturbation
(:func:`spinemocap.synth.lab_errors.perturb_rig`; the scene's own written rig is the first at
the level it was rendered with) keep the tracker's blob-to-dot assignment and score:

- ``given``: the dots triangulated with the given rig (the tracker without ``--refine-rig``);
- ``refined``: after ``--refine-rig`` (the shipped gauge: weak priors toward the given cameras);
- ``refined_shape``: the same after removing the best similarity onto the truth (the error the
  refinement's geometry leaves; the rest is the world frame);
- ``frame_uncertainty``: what ``rig_refine.json`` reports as the frame error left;
- peers: ``residual_priors``, ``--refine-rig`` with prior widths sized from each given
  camera's own residual (:data:`RESIDUAL_PRIORS`,
  :func:`~spinemocap.track.rig_refine.residual_priors`) instead of the fixed 20 mm / 0.5 deg, and
  two other gauges for the same refined geometry: ``cloud_gauge`` (the refined dots moved by the
  similarity that best fits them onto the given rig's own triangulation of the same dot-frames,
  :func:`~spinemocap.bench.frame_error.cloud_gauge`) and ``closest_cameras`` (the refined cameras
  moved by the similarity closest to the given cameras,
  :func:`~spinemocap.track.rig_refine.closest_gauge`).

With ``reference`` (``--reference``) every scene also has the studio's L-frame beside the subject
(:mod:`spinemocap.synth.reference`, rendered in the images) and every calibration is refined a
second time with its markers as control points (:func:`spinemocap.app.reference.observe_reference`
found with that given rig, ``refine_rig(..., control=...)``): ``reference`` is that error, beside
``refined`` (the same capture and rig without the reference) in the same run; ``reference_shape``,
``reference_fit_px`` / ``reference_fit_mm`` (the markers' fit) and ``given_frame_offset_mm`` come
with it.

Errors are mean mm over the tracked dot-frames against the ground truth (as ``bench realism``).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..app.reference import REFERENCE_FRAMES, observe_reference
from ..app.run import TrackingWarning, TrackResult, apply_refined_rig, make_detector, run_tracking
from ..camera import Rig
from ..fileio import atomic_path
from ..markers import OBSERVED, MarkerTable
from ..reference import ReferenceObject
from ..synth import SynthConfig, build_scene
from ..synth.lab_errors import perturb_rig
from ..tape import TapeSpec
from ..track.config import TrackerConfig
from ..track.rig_check import CalibrationWarning
from ..track.rig_refine import ReferenceFitError, RigRefineConfig, closest_gauge, refine_rig
from .frame_error import cloud_gauge, mean_error_mm, shape_error_mm, truth_of
from .realism import _render

TRACKED_WITH_PX = 2.0  # the calibration error of the rig the scene is tracked with
GAUGES = ("given", "refined", "residual_priors", "cloud_gauge", "closest_cameras")
REFERENCE_KEYS = ("reference", "reference_shape", "reference_fit_px", "reference_fit_mm", "given_frame_offset_mm")
RESIDUAL_PRIORS = RigRefineConfig(centre_prior_mm=None, rotation_prior_deg=None)  # widths from each camera's residual


@dataclass
class TrackedScene:
    """One rendered and tracked scene: what the refinement needs, and the truth."""

    seed: int
    fps: float
    true_rig: Rig
    written_rig: Rig
    calibration_points: np.ndarray  # (N, 3) mm: the true dots the studio's calibration error is measured on
    result: TrackResult
    tape: TapeSpec
    truth: np.ndarray  # (F, D, 3) mm, in the table's label order
    reference: ReferenceObject | None = None
    reference_images: list | None = None  # grey images (per camera) of a few frames, to find its markers in


def track_scene(seed: int, frames: int, fps: float, detector: str = "net", progress: bool = False,
                reference: bool = False, size: tuple[int, int] | None = None) -> TrackedScene:
    """Render the ``artificial`` preset (light occlusion, ideal realism but a
    :data:`TRACKED_WITH_PX` rig; ``reference``: with the studio's L-frame; ``size`` another image
    size, the same framing) and track it in sequence mode with the written rig."""
    synth = SynthConfig.preset("artificial", occlusion="light", seed=seed, frames=frames, fps=fps,
                               realism="ideal", calibration_error_px=TRACKED_WITH_PX, reference=reference,
                               **({"size": size} if size else {}))
    scene = build_scene(synth)
    views = _render(scene, make_detector(detector), synth.frames, progress)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TrackingWarning)
        warnings.simplefilter("ignore", CalibrationWarning)
        result = run_tracking(iter(views), scene.calibrated_rig, scene.tape, scene.fps, up=scene.subject()["up"],
                              mode="sequence", config=TrackerConfig(), progress=False, n_frames=len(views))
    picks = np.unique(np.linspace(0, len(views) - 1, min(REFERENCE_FRAMES, len(views))).round().astype(int))
    images = [[view.image for view in views[k][1]] for k in picks] if reference else None
    scene.close()
    return TrackedScene(seed, scene.fps, scene.rig, scene.calibrated_rig, scene._calibration_points(), result,
                        scene.tape, truth_of(result.table, scene.groundtruth), scene.reference, images)


def calibrations(scene: TrackedScene, level_px: float, count: int) -> list[Rig]:
    """``count`` seeded rigs off by ``level_px`` (the studio's perturbation of the true rig);
    at :data:`TRACKED_WITH_PX` the scene's own written rig comes first."""
    rigs = [scene.written_rig] if level_px == TRACKED_WITH_PX else []
    k = 0
    while len(rigs) < count:
        rng = np.random.default_rng([scene.seed, 1000 + k])
        rigs.append(perturb_rig(scene.true_rig, scene.calibration_points, level_px, rng)[0])
        k += 1
    return rigs


@dataclass(frozen=True)
class ReferenceGauge:
    """``--refine-rig`` with the scene's reference object as control points
    (:func:`score_with_reference`): mean error and shape error (mm), the markers' fit (px, mm) and
    observations, how far the given rig's frame lies from the reference's (mm) and the refined
    rig's reprojection RMS (px)."""

    reference: float
    reference_shape: float
    reference_fit_px: float
    reference_fit_mm: float
    reference_observations: int
    given_frame_offset_mm: float
    reference_rig_rms_after_px: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ReferenceNotUsed:
    """A reference whose markers could not be used: the reason, recorded, not hidden."""

    reference_error: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CalibrationGauges:
    """Every gauge's mean error (mm) for one given rig (:func:`score_calibration`): the given rig,
    ``--refine-rig``, the refinement with residual-sized priors, the cloud and closest-cameras
    gauges, the refined shape (world frame taken out), the reported frame uncertainty (mm) of the
    refinement and of the residual-sized one, the rig's reprojection RMS before and after (px),
    and the refinement with the reference where the scene has one."""

    given: float
    refined: float
    residual_priors: float
    cloud_gauge: float
    closest_cameras: float
    refined_shape: float
    frame_uncertainty: float
    residual_priors_frame_uncertainty: float
    rig_rms_before_px: float
    rig_rms_after_px: float
    with_reference: ReferenceGauge | ReferenceNotUsed | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the gauges, then the reference's numbers (or its error) where it was tried."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "with_reference"}
        return {**out, **(self.with_reference.to_dict() if self.with_reference is not None else {})}


@dataclass(frozen=True)
class GaugeRow:
    """One seeded calibration: the scene's seed, the calibration error level (px), the rig's
    number at that level, and its gauges."""

    seed: int
    level_px: float
    rig: int
    gauges: CalibrationGauges

    def to_dict(self) -> dict[str, Any]:
        return {"seed": self.seed, "level_px": self.level_px, "rig": self.rig, **self.gauges.to_dict()}

    def value(self, key: str) -> float | None:
        """The number named ``key`` in the JSON (a gauge, ``refined_shape``, ``frame_uncertainty``
        or a key of :data:`REFERENCE_KEYS`); None where it was not measured."""
        reference = self.gauges.with_reference
        if key in REFERENCE_KEYS:
            return getattr(reference, key) if isinstance(reference, ReferenceGauge) else None
        return float(getattr(self.gauges, key))

    @property
    def reference_error(self) -> str | None:
        """Why the reference could not be used (None: used, or none in the scene)."""
        reference = self.gauges.with_reference
        return reference.reference_error if isinstance(reference, ReferenceNotUsed) else None


def score_calibration(scene: TrackedScene, given: Rig, config: RigRefineConfig | None = None) -> CalibrationGauges:
    """Every gauge's mean error (mm) for one given rig (see module)."""
    config = config or RigRefineConfig()
    result = scene.result
    refinement = refine_rig(given, result.pixels(), result.table.positions(), scene.fps, config)

    def table_with(rig: Rig) -> MarkerTable:
        return apply_refined_rig(result, dataclasses.replace(refinement, rig=rig), scene.tape)

    given_table, refined_table = table_with(given), table_with(refinement.rig)
    observed = result.table.to_arrays().status == OBSERVED
    fit = cloud_gauge(refined_table.positions()[observed], given_table.positions()[observed])
    closest = closest_gauge(refinement.rig, given, np.array(list(refinement.centre_prior_mm.values())),
                            np.array(list(refinement.rotation_prior_deg.values())))
    sized = refine_rig(given, result.pixels(), result.table.positions(), scene.fps, RESIDUAL_PRIORS)
    return CalibrationGauges(
        given=mean_error_mm(given_table, scene.truth), refined=mean_error_mm(refined_table, scene.truth),
        residual_priors=mean_error_mm(table_with(sized.rig), scene.truth),
        cloud_gauge=mean_error_mm(table_with(refinement.rig.transformed(*fit)), scene.truth),
        closest_cameras=mean_error_mm(table_with(refinement.rig.transformed(*closest)), scene.truth),
        refined_shape=shape_error_mm(refined_table, scene.truth),
        frame_uncertainty=refinement.frame_uncertainty_mm,
        residual_priors_frame_uncertainty=sized.frame_uncertainty_mm,
        rig_rms_before_px=refinement.before_px["all"], rig_rms_after_px=refinement.after_px["all"],
        with_reference=(score_with_reference(scene, given, config, table_with) if scene.reference is not None
                        else None))


def score_with_reference(scene: TrackedScene, given: Rig, config: RigRefineConfig,
                         table_with: Callable[[Rig], MarkerTable]) -> ReferenceGauge | ReferenceNotUsed:
    """``--refine-rig`` with the scene's reference object as control points, found with the
    ``given`` rig (see module); a reference that cannot be used is recorded, not hidden."""
    assert scene.reference is not None and scene.reference_images is not None
    result = scene.result
    control = observe_reference(given, scene.reference, scene.reference_images)
    try:
        refinement = refine_rig(given, result.pixels(), result.table.positions(), scene.fps, config, control)
    except ReferenceFitError as exc:
        return ReferenceNotUsed(str(exc))
    table = table_with(refinement.rig)
    frame = refinement.reference
    assert frame is not None  # refined with control points
    return ReferenceGauge(reference=mean_error_mm(table, scene.truth), reference_shape=shape_error_mm(table, scene.truth),
                          reference_fit_px=frame.fit_rms_px, reference_fit_mm=frame.fit_rms_mm,
                          reference_observations=frame.observations, given_frame_offset_mm=frame.given_frame_offset_mm,
                          reference_rig_rms_after_px=refinement.after_px["all"])


@dataclass(frozen=True)
class GaugeNumbers:
    """``bench gauge``'s numbers (:func:`run_gauge_benchmark`): the scene seeds, calibration error
    levels (px), rigs per level, frames and frame rate, detector, the error of the rig the scenes
    are tracked with (px), whether the reference was rendered, the machine, the wall seconds,
    every row and the per-level summary (:func:`summarize`)."""

    seeds: list[int]
    levels_px: list[float]
    rigs_per_level: int
    frames: int
    fps: float
    detector: str
    tracked_with_px: float
    reference: bool
    machine: str
    wall_s: float
    rows: list[GaugeRow]

    @property
    def summary(self) -> dict[str, dict[str, Any]]:
        return summarize(self.rows)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``--json`` writes."""
        return {"seeds": self.seeds, "levels_px": self.levels_px, "rigs_per_level": self.rigs_per_level,
                "frames": self.frames, "fps": self.fps, "detector": self.detector,
                "tracked_with_px": self.tracked_with_px, "reference": self.reference, "machine": self.machine,
                "wall_s": self.wall_s, "rows": [row.to_dict() for row in self.rows], "summary": self.summary}


def run_gauge_benchmark(seeds: Sequence[int], levels: Sequence[float], rigs: int, frames: int = 30, fps: float = 25.0,
                        detector: str = "net", progress: bool = True, say: Callable[[str], None] = print,
                        after_scene: Callable[[GaugeNumbers], None] | None = None,
                        reference: bool = False) -> GaugeNumbers:
    """Every scene of ``seeds`` x every level of ``levels`` (px) x ``rigs`` seeded calibrations
    (see :class:`GaugeNumbers`). ``after_scene(numbers so far)`` is called after each scene (the
    command saves them). ``reference``: scenes with the studio's L-frame, each calibration also
    refined with it (see module)."""
    import platform

    from tqdm import tqdm

    start = time.perf_counter()
    rows: list[GaugeRow] = []

    def numbers() -> GaugeNumbers:
        return GaugeNumbers(seeds=list(seeds), levels_px=list(levels), rigs_per_level=rigs, frames=frames, fps=fps,
                            detector=detector, tracked_with_px=TRACKED_WITH_PX, reference=reference,
                            machine=f"{platform.machine()} {platform.processor() or ''}".strip(),
                            wall_s=time.perf_counter() - start, rows=list(rows))

    for seed in seeds:
        say(f"[scene {seed}] render + track {frames} frames at {fps:g} fps with its {TRACKED_WITH_PX:g} px rig")
        scene = track_scene(seed, frames, fps, detector, progress, reference=reference)
        jobs = [(level, k, rig) for level in levels for k, rig in enumerate(calibrations(scene, level, rigs))]
        for level, k, rig in tqdm(jobs, desc=f"scene {seed}: refine", unit="rig", disable=not progress, leave=False):
            row = GaugeRow(seed, level, k, score_calibration(scene, rig))
            rows.append(row)
            shown = {key: row.value(key) for key in (*GAUGES, "reference")}
            say(f"  {level:g} px, rig {k}: " + ", ".join(f"{key} {value:.2f}" for key, value in shown.items()
                                                         if value is not None) + " mm"
                + (f"; reference not used: {row.reference_error}" if row.reference_error is not None else ""))
        if after_scene is not None:
            after_scene(numbers())
    return numbers()


def summarize(rows: list[GaugeRow]) -> dict[str, dict[str, Any]]:
    """Per level ("2" for 2.0 px): mean, median, worst and count of each gauge, the shape error,
    the reported frame uncertainty and the reference's numbers, the rigs (``n``), and how often the
    refined dots beat the given rig's and the residual-sized priors', stay within 1 mm, and (where
    a reference was tried) how often it did and was not used."""
    out = {}
    for level in sorted({r.level_px for r in rows}):
        sel = [r for r in rows if r.level_px == level]
        stats: dict[str, Any] = {}
        for key in (*GAUGES, "refined_shape", "frame_uncertainty", *REFERENCE_KEYS):
            v = np.array([value for r in sel if (value := r.value(key)) is not None], float)
            if len(v):
                stats[key] = {"mean": float(np.mean(v)), "median": float(np.median(v)), "max": float(np.max(v)),
                              "n": len(v)}
        stats["n"] = len(sel)
        stats["refined_better_than_given"] = int(sum(r.gauges.refined < r.gauges.given for r in sel))
        stats["refined_better_than_residual_priors"] = int(sum(r.gauges.refined < r.gauges.residual_priors for r in sel))
        stats["refined_at_most_1mm"] = int(sum(r.gauges.refined <= 1.0 for r in sel))
        if any(r.gauges.with_reference is not None for r in sel):
            stats["reference_at_most_1mm"] = int(sum(value <= 1.0 for r in sel if (value := r.value("reference")) is not None))
            stats["reference_not_used"] = int(sum(r.reference_error is not None for r in sel))
        out[f"{level:g}"] = stats
    return out


def format_table(summary: dict[str, dict[str, Any]]) -> str:
    """A Markdown table of :func:`summarize`'s ``summary``: per level, mean (median, worst) mm of each gauge."""
    lines = ["| calibration error | rigs | given rig (no refinement) | `--refine-rig` | frame removed (shape) | "
             "reported frame uncertainty | peer: residual-sized priors | peer: cloud gauge | peer: closest cameras | "
             "refined <= 1.0 mm |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for level, s in summary.items():
        cells = [f"{s[k]['mean']:.2f} ({s[k]['median']:.2f}, {s[k]['max']:.2f})"
                 for k in ("given", "refined", "refined_shape", "frame_uncertainty", "residual_priors", "cloud_gauge",
                           "closest_cameras")]
        lines.append(f"| {level} px | {s['n']} | " + " | ".join(cells) + f" | {s['refined_at_most_1mm']} of {s['n']} |")
    if any("reference" in s for s in summary.values()):
        lines += ["", "| calibration error | rigs | `--refine-rig` without the reference | with the reference (L-frame) | "
                      "with it, frame removed (shape) | markers' fit px | markers' fit mm | given rig's frame at the "
                      "reference, mm | with reference <= 1.0 mm | reference not used |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for level, s in summary.items():
            if "reference" not in s:
                continue
            cells = [f"{s[k]['mean']:.2f} ({s[k]['median']:.2f}, {s[k]['max']:.2f})" for k in ("refined", *REFERENCE_KEYS)]
            lines.append(f"| {level} px | {s['n']} | " + " | ".join(cells)
                         + f" | {s['reference_at_most_1mm']} of {s['n']} | {s['reference_not_used']} |")
    return "\n".join(lines)


def plot(numbers: dict, path: Path) -> None:
    """Each calibration's mean error per gauge against its level (dots), means joined by lines;
    ``numbers``: the JSON object (:meth:`GaugeNumbers.to_dict`, as saved)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = numbers["rows"]
    fig, ax = plt.subplots(figsize=(8, 5))
    series: tuple[tuple[str, str, str], ...] = (("given", "given rig", "tab:red"), ("refined", "--refine-rig", "tab:blue"),
              ("residual_priors", "peer: residual-sized priors", "tab:cyan"),
              ("cloud_gauge", "peer: cloud gauge", "tab:orange"), ("closest_cameras", "peer: closest cameras", "tab:purple"),
              ("refined_shape", "refined, frame removed", "tab:green"),
              ("frame_uncertainty", "reported frame uncertainty", "tab:gray"),
              ("reference", "--refine-rig with the reference (L-frame)", "tab:brown"))
    levels = sorted({r["level_px"] for r in rows})
    series = tuple(item for item in series if any(item[0] in r for r in rows))
    for k, (key, label, colour) in enumerate(series):
        offset = (k - len(series) / 2) * 0.04
        have = [r for r in rows if key in r]
        ax.scatter([r["level_px"] + offset for r in have], [r[key] for r in have], s=10, color=colour, alpha=0.5)
        ax.plot(np.array(levels) + offset, [np.mean([r[key] for r in have if r["level_px"] == lv] or [np.nan])
                                            for lv in levels], "-o", color=colour, label=label)
    ax.axhline(1.0, color="k", ls=":", lw=1, label="goal 1.0 mm at 2 px (refined)")
    ax.set_xlabel("calibration error of the given rig (px RMS)")
    ax.set_ylabel("mean dot error (mm)")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title(f"bench gauge: scenes {numbers['seeds']}, {numbers['rigs_per_level']} rigs per level, "
                 f"{numbers['frames']} frames at {numbers['fps']:g} fps", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
