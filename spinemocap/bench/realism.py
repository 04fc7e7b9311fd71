"""The realism benchmark (``spinemocap bench realism``): the tracker on a studio as hard
as a real back, one factor at a time and all together at the ``lab`` level, beside its peer, the
tracker without its adaptations (the roll's nominal dot spacing, the fixed 2 px candidate gate, no
label continuity check: :meth:`TrackerConfig.nominal_unchecked`), on the very same rendered frames.

Each case renders the ``artificial`` preset (4 cameras, light occlusion unless told) with the
shipped detector, tracks it in sequence mode with both trackers and scores them against the
ground truth: mean / p95 error (mm), the mean error of the dot-frames it vouches for, swapped
dot-frames, flagged frames and the share of dot-frames flagged or missing, frames without a
solution. Calibration cases also score the new tracker after ``--refine-rig`` (the rig
bundle-adjusted on the tracked dots, observed dots re-triangulated). The tracker is handed what a
lab has: ``capture.toml``'s nominal tape spec and the written (perturbed) rig.

``held-out look (lab)`` renders the detection benchmark's held-out appearance family (the
tape colour no training set holds, painted lab rooms, lab camera looks: ``bench detect --sets
held-out``) at the ``lab`` level; its goal: mean error <= 1 mm and no wrong label among the
dot-frames the tracker vouches for (``vouched_swaps``). ``held-out look, woven tape, marked skin,
shorts (lab)`` adds a lab's subject (:data:`LAB_SUBJECT`) to it.

``calibration 2.0 px + reference`` adds the studio's L-frame beside the subject
(:mod:`spinemocap.synth.reference`): its ``--refine-rig`` holds the L-frame's markers (found in
the rendered images with the given rig) as control points, and scores the refinement without
them on the same frames beside it (``new_refined_without_reference``).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np

from ..app.reference import REFERENCE_FRAMES, observe_reference
from ..app.run import TrackingWarning, apply_refined_rig, make_detector, run_tracking
from ..fileio import atomic_path, atomic_write
from ..markers import MISSING
from ..synth import SynthConfig, build_scene
from ..track.config import TrackerConfig
from ..track.evaluate import evaluate_tracking, label_swaps
from ..track.quality import flagged_from_confidence
from ..track.rig_check import CalibrationWarning
from ..track.rig_refine import ReferenceFitError, RigRefineConfig, refine_rig
from .detect import HELD_OUT, TEST_SETS
from .frame_error import shape_error_mm, truth_of
from .records import JsonRecord


@dataclass(frozen=True)
class Case:
    """One benchmark condition: studio overrides (``realism`` level plus fields) and whether the
    ``--refine-rig`` variant is scored too."""

    name: str
    factor: str
    studio: dict = field(default_factory=dict)
    refine: bool = False


WorldFrame = Literal["reference", "given rig"]  # the frame a refined rig is in


def sweep() -> list[Case]:
    """The sweep: tension 0/10/20/30 % with skin strain, 30 % with skin strain off, calibration
    error 0.5/1/2/3 px (with and without --refine-rig), sync error 1/3 ms, full flexion (at the
    ``lab`` level, and with 20 % tension and 1 px calibration error) and the forehand at the
    ``lab`` level, the held-out appearance family at the ``lab`` level (:func:`held_out_look`),
    ``lab`` and its full flexion on a spine bending at the published depth of the vertebral bodies
    (``joint_depth="anatomical"``), and ``lab`` itself (the ``ideal`` case = 0 of every factor)."""
    cases = [Case("ideal", "baseline", {"realism": "ideal"}), Case("lab", "all", {"realism": "lab"})]
    cases += [Case(f"tension {int(100 * t)} % + skin", "tension", {"realism": "skin", "tape_tension": t})
              for t in (0.0, 0.1, 0.2, 0.3)]
    cases.append(Case("tension 30 %, skin strain off", "tension", {"realism": "ideal", "tape_tension": 0.3}))
    cases += [Case(f"calibration {e} px", "calibration", {"realism": "ideal", "calibration_error_px": e}, refine=True)
              for e in (0.5, 1.0, 2.0, 3.0)]
    cases.append(Case("calibration 2.0 px + reference", "calibration",
                      {"realism": "ideal", "calibration_error_px": 2.0, "reference": True}, refine=True))
    cases += [Case(f"sync {s} ms", "sync", {"realism": "ideal", "sync_error_ms": s}) for s in (1.0, 3.0)]
    cases += [Case("flexion (lab)", "motion", {"realism": "lab", "motion": "flexion"}),
              Case("flexion, 20 % tension, 1 px", "motion", {"realism": "lab", "motion": "flexion", "tape_tension": 0.2,
                                                             "calibration_error_px": 1.0}),
              Case("forehand (lab)", "motion", {"realism": "lab", "motion": "forehand"})]
    cases.append(Case(HELD_OUT_CASE, "appearance", {"realism": "lab", **held_out_look()}))
    cases.append(Case(HELD_OUT_CASE_SUBJECT, "appearance", {"realism": "lab", **held_out_look(), **LAB_SUBJECT}))
    cases += [Case("lab, anatomical joint depth", "anatomy", {"realism": "lab", "joint_depth": "anatomical"}),
              Case("flexion, 20 % tension, 1 px, anatomical joint depth", "anatomy",
                   {"realism": "lab", "motion": "flexion", "tape_tension": 0.2, "calibration_error_px": 1.0,
                    "joint_depth": "anatomical"})]
    return cases


HELD_OUT_CASE = "held-out look (lab)"
HELD_OUT_CASE_SUBJECT = "held-out look, woven tape, marked skin, shorts (lab)"
# a lab's subject the studio renders beyond the plain one: woven tape, hair, freckles, moles and a
# sweaty sheen on the skin, shorts below the tape
LAB_SUBJECT = {"tape_finish": "weave", "skin_marks": ("hair", "freckles", "moles", "sweat"), "clothing": ("shorts",)}


def held_out_look() -> dict:
    """The studio settings of ``bench detect``'s held-out appearance family (tape colour, backdrop,
    camera look), the one definition of it."""
    held = TEST_SETS[HELD_OUT]
    return {"tape_colour": held.tape_colour, "backdrop": held.backdrop, "camera_look": held.camera_look}


GOALS: dict[str, Any] = {
    "swaps": "0 swaps up to 30 % tension with skin strain and 2 px calibration error",
    "lab_mean_mm": 1.0, "refined_2px_mean_mm": 1.0,
    "flagged_dot_share": 0.05,  # in every case up to full flexion, 20 % tension and 1 px calibration error
    "held_out_mean_mm": 1.0}  # and no wrong label among the vouched-for dot-frames


def _render(scene, detect, n_frames: int, progress: bool) -> list:
    from tqdm import tqdm

    out = []
    for frame in tqdm(range(n_frames), desc="render + detect", unit="frame", disable=not progress, leave=False):
        rendered = scene.render(frame)
        t0 = time.perf_counter()
        views = detect(frame, rendered.images, rendered.masks)
        out.append((frame, views, 1000 * (time.perf_counter() - t0)))
    return out


def flagged_dot_share(table) -> float:
    """Share of the table's dot-frames the tracker does not vouch for: missing, or with a
    label-doubting confidence (:func:`spinemocap.track.quality.flagged_from_confidence` asked
    dot by dot: a flagged frame's dots and the doubted dots of an unflagged one)."""
    arrays = table.to_arrays()
    status, confidence = arrays.status, arrays.confidence
    doubted = flagged_from_confidence(status.reshape(-1, 1), confidence.reshape(-1, 1))
    return float(np.mean(doubted | (status.reshape(-1) == MISSING))) if status.size else float("nan")


@dataclass(frozen=True)
class TrackerScore(JsonRecord):
    """One tracker's result on a case against the ground truth (:func:`_score`): mean and 95th
    percentile error (mm), swapped dot-frames, flagged frames and the share of dot-frames flagged
    or missing (0-1), the mean error (mm) and swaps of the dot-frames it vouches for, frames per
    quality flag, frames without a solution, the tape's stretch along (min, median, max; None
    without vouched-for frames), the median candidate gate (px) and ms per frame (None: not timed). Results read
    back from files without the vouched-for numbers hold None there."""

    mean_mm: float
    p95_mm: float
    swaps: int
    flagged_frames: int
    flagged_dot_share: float | None
    vouched_mean_mm: float | None
    vouched_swaps: int | None
    flags: dict[str, int]
    unsolved_frames: int
    stretch_along: list[float] | None
    gate_px: float | None
    ms_per_frame: float | None


    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrackerScore:
        """A score read back from a results file (keys it lacks: None)."""
        values: dict[str, Any] = {f.name: data.get(f.name) for f in fields(cls)}
        return cls(**values)


@dataclass(frozen=True)
class RefinedScore:
    """The new tracker after ``--refine-rig`` (:func:`_refined_row`): its score, the rig's
    reprojection RMS before and after (px), the world frame's uncertainty and the error left once
    the world frame is taken out (mm), which frame the refined rig is in ("reference" or "given
    rig") and, in the reference's frame, the reference's fit (px, mm) and how far the given rig's
    frame lies from it (mm)."""

    score: TrackerScore
    rig_rms_before_px: float
    rig_rms_after_px: float
    frame_uncertainty_mm: float
    shape_mm: float
    world_frame: WorldFrame
    reference_fit_px: float | None = None
    reference_fit_mm: float | None = None
    given_frame_offset_mm: float | None = None

    @property
    def mean_mm(self) -> float:
        return self.score.mean_mm

    def to_dict(self) -> dict[str, Any]:
        """The score's keys, then the refinement's; the reference's only in its frame."""
        reference = {"reference_fit_px": self.reference_fit_px, "reference_fit_mm": self.reference_fit_mm,
                     "given_frame_offset_mm": self.given_frame_offset_mm} if self.world_frame == "reference" else {}
        return {**self.score.to_dict(), "rig_rms_before_px": self.rig_rms_before_px,
                "rig_rms_after_px": self.rig_rms_after_px, "frame_uncertainty_mm": self.frame_uncertainty_mm,
                "shape_mm": self.shape_mm, "world_frame": self.world_frame, **reference}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RefinedScore | RefinementFailure:
        """A refinement read back from a results file (one that failed: :class:`RefinementFailure`)."""
        if "error" in data:
            return RefinementFailure(str(data["error"]))
        refinement: dict[str, Any] = {f.name: data.get(f.name) for f in fields(cls)[1:]}
        refinement["world_frame"] = data.get("world_frame", "given rig")  # files older than the reference
        return cls(TrackerScore.from_dict(data), **refinement)


@dataclass(frozen=True)
class RefinementFailure:
    """A ``--refine-rig`` that failed on the case, recorded with its reason, not hidden."""

    error: str

    def to_dict(self) -> dict[str, Any]:
        return {"error": self.error}


@dataclass(frozen=True)
class CaseResult:
    """One case of the sweep (:func:`run_case`): its name, factor and studio settings, the new
    tracker's score and the peer's, and for calibration cases the new tracker after
    ``--refine-rig`` (and, with a reference, the refinement without its control points)."""

    case: str
    factor: str
    studio: dict[str, Any]
    new: TrackerScore
    peer: TrackerScore
    new_refined: RefinedScore | RefinementFailure | None = None
    new_refined_without_reference: RefinedScore | RefinementFailure | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: case, factor, studio, new, the refinements present, peer."""
        out: dict[str, Any] = {"case": self.case, "factor": self.factor, "studio": dict(self.studio),
                               "new": self.new.to_dict()}
        if self.new_refined_without_reference is not None:
            out["new_refined_without_reference"] = self.new_refined_without_reference.to_dict()
        if self.new_refined is not None:
            out["new_refined"] = self.new_refined.to_dict()
        out["peer"] = self.peer.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CaseResult:
        """A case read back from a results file (``bench realism --json``)."""
        def refined(key: str) -> RefinedScore | RefinementFailure | None:
            return RefinedScore.from_dict(data[key]) if key in data else None

        return cls(case=data["case"], factor=data["factor"], studio=dict(data["studio"]),
                   new=TrackerScore.from_dict(data["new"]), peer=TrackerScore.from_dict(data["peer"]),
                   new_refined=refined("new_refined"),
                   new_refined_without_reference=refined("new_refined_without_reference"))


def _score(table, gt: dict, spacing: float, result) -> TrackerScore:
    ev = evaluate_tracking(table, gt, spacing, result.stage_ms())
    quality = result.quality()
    return TrackerScore(mean_mm=ev.mean_error_mm, p95_mm=ev.p95_error_mm, swaps=ev.label_swaps,
                        flagged_frames=len(quality.flagged_frames), flagged_dot_share=flagged_dot_share(table),
                        vouched_mean_mm=vouched_error_mm(table, gt), vouched_swaps=vouched_swaps(table, gt, spacing),
                        flags=quality.flags, unsolved_frames=ev.frames_without_solution,
                        stretch_along=list(quality.stretch_along) if quality.stretch_along is not None else None,
                        gate_px=quality.gate_px, ms_per_frame=ev.total_ms_per_frame)


def _vouched(table, gt: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table's (F, D, 3) positions, their (F, D, 3) true dots and the (F, D) dot-frames the
    tracker vouches for (not flagged, not missing)."""
    arrays = table.to_arrays()
    labels = [str(x) for x in gt["labels"]]
    truth = np.asarray(gt["dots"], float)[arrays.frames][:, [labels.index(str(lab)) for lab in arrays.labels]]
    status = arrays.status
    doubted = flagged_from_confidence(status.reshape(-1, 1), arrays.confidence.reshape(-1, 1)).reshape(status.shape)
    return arrays.positions, truth, ~doubted & (status != MISSING)


def vouched_error_mm(table, gt: dict) -> float:
    """Mean error (mm) of the dot-frames the tracker vouches for (not flagged, not missing)."""
    positions, truth, vouched = _vouched(table, gt)
    error = np.linalg.norm(positions - truth, axis=2)[vouched]
    return float(error.mean()) if error.size else float("nan")


def vouched_swaps(table, gt: dict, spacing_mm: float) -> int:
    """Wrong labels among the dot-frames the tracker vouches for: each nearer another true dot
    than its own (:func:`spinemocap.track.evaluate.label_swaps`, the tape's closest dot spacing
    ``spacing_mm``)."""
    positions, truth, vouched = _vouched(table, gt)
    if not vouched.any():
        return 0
    return int((label_swaps(positions, truth, spacing_mm) & vouched).sum())


def run_case(case: Case, frames: int, fps: float | None, preset: str, occlusion: str, detector: str,
             seed: int, progress: bool, say: Callable[[str], None], weights: Path | None = None) -> CaseResult:
    """Render one case and score the new tracker and the peer on it (``weights``: the ``net``
    detector's weights file; None: the shipped ones)."""
    synth = SynthConfig.preset(preset, occlusion=occlusion, seed=seed, frames=frames,
                               **({"fps": fps} if fps else {}), **case.studio)
    scene = build_scene(synth)
    rig = getattr(scene, "calibrated_rig", scene.rig)  # what the lab was given
    say(f"[{case.name}] {synth.frames} frames at {synth.fps:g} fps, motion {synth.motion}, realism "
        f"{synth.realism}: tension {synth.tape_tension}, calibration {synth.calibration_error_px} px, "
        f"sync {synth.sync_error_ms} ms, skin strain {synth.skin_strain}")
    views = _render(scene, make_detector(detector, weights=weights), synth.frames, progress)
    gt = scene.groundtruth
    spacing = scene.tape.graph.min_spacing_mm
    scores: dict[str, TrackerScore] = {}
    refined: RefinedScore | RefinementFailure | None = None
    without_reference: RefinedScore | RefinementFailure | None = None
    for name, config in (("new", TrackerConfig()), ("peer", TrackerConfig.nominal_unchecked())):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TrackingWarning)
            warnings.simplefilter("ignore", CalibrationWarning)
            result = run_tracking(iter(views), rig, scene.tape, scene.fps, up=scene.subject()["up"],
                                  mode="sequence", config=config, progress=False, n_frames=len(views))
        scores[name] = _score(result.table, gt, spacing, result)
        if name == "new" and case.refine:
            control = None
            if scene.reference is not None:
                picks = np.unique(np.linspace(0, len(views) - 1, min(REFERENCE_FRAMES, len(views))).round().astype(int))
                control = observe_reference(rig, scene.reference, [[v.image for v in views[k][1]] for k in picks])
                without_reference = _refined_row(result, rig, scene, gt, spacing, None)
            refined = _refined_row(result, rig, scene, gt, spacing, control)
    row = CaseResult(case=case.name, factor=case.factor, studio=dict(case.studio), new=scores["new"],
                     peer=scores["peer"], new_refined=refined, new_refined_without_reference=without_reference)
    say("  " + describe(row))
    return row


def _refined_row(result, rig, scene, gt: dict, spacing: float, control) -> RefinedScore | RefinementFailure:
    """The new tracker's result after ``--refine-rig`` (with the reference's ``control`` points
    when given), scored; a refinement that fails is recorded, not hidden."""
    import dataclasses

    try:
        refinement = refine_rig(rig, result.pixels(), result.table.positions(), scene.fps, RigRefineConfig(), control)
    except (ValueError, ReferenceFitError) as exc:
        return RefinementFailure(str(exc))
    refined = dataclasses.replace(result, table=apply_refined_rig(result, refinement, scene.tape))
    frame = refinement.reference
    return RefinedScore(_score(refined.table, gt, spacing, refined), rig_rms_before_px=refinement.before_px["all"],
                        rig_rms_after_px=refinement.after_px["all"],
                        frame_uncertainty_mm=refinement.frame_uncertainty_mm,
                        shape_mm=_shape_error(refined.table, gt),
                        world_frame="reference" if frame is not None else "given rig",
                        reference_fit_px=frame.fit_rms_px if frame is not None else None,
                        reference_fit_mm=frame.fit_rms_mm if frame is not None else None,
                        given_frame_offset_mm=frame.given_frame_offset_mm if frame is not None else None)


def _shape_error(table, gt: dict) -> float:
    """Mean error (mm) left once the world frame is taken out (see :mod:`.frame_error`): the rest
    of a refined rig's error is the given rig's frame, which no residual shows."""
    return shape_error_mm(table, truth_of(table, gt))


def _scored(row: CaseResult) -> list[tuple[str, TrackerScore, RefinedScore | None]]:
    """The row's scores as printed: (key, score, the refinement it came from) for the new tracker,
    its refinements that did not fail and the peer."""
    out: list[tuple[str, TrackerScore, RefinedScore | None]] = [("new", row.new, None)]
    for key, refined in (("new_refined", row.new_refined),
                         ("new_refined_without_reference", row.new_refined_without_reference)):
        if isinstance(refined, RefinedScore):
            out.append((key, refined.score, refined))
    return [*out, ("peer", row.peer, None)]


def describe(row: CaseResult) -> str:
    parts = []
    for key, r, refined in _scored(row):
        parts.append(f"{key}: {r.mean_mm:.2f} mm (p95 {r.p95_mm:.2f}), {r.swaps} swaps, "
                     f"{r.flagged_frames} flagged ({100 * _number(r.flagged_dot_share):.1f} % of "
                     f"dot-frames; vouched-for {_number(r.vouched_mean_mm):.2f} mm), {r.unsolved_frames} unsolved"
                     + (f", {refined.shape_mm:.2f} mm with the world frame taken out (frame uncertainty "
                        f"{refined.frame_uncertainty_mm:.2f} mm)" if refined is not None else ""))
    return "; ".join(parts)


def _number(value: float | None) -> float:
    return float("nan") if value is None else value


@dataclass(frozen=True)
class RealismNumbers:
    """``bench realism``'s numbers (:func:`run_realism_benchmark`): the set-up (preset, occlusion,
    frames per case, frame rate, detector, seed, weights, machine), the wall seconds so far, every
    case run, the goals and their verdicts, and whether every case asked for has run."""

    preset: str
    occlusion: str
    frames: int
    fps: float | None
    detector: str
    seed: int
    weights: str
    machine: str
    wall_s: float
    cases: list[CaseResult]
    complete: bool

    @property
    def verdict(self) -> dict[str, GoalVerdict]:
        return verdict(self.cases)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``--json`` writes."""
        return {"preset": self.preset, "occlusion": self.occlusion, "frames": self.frames, "fps": self.fps,
                "detector": self.detector, "seed": self.seed, "weights": self.weights, "machine": self.machine,
                "wall_s": self.wall_s, "cases": [c.to_dict() for c in self.cases], "goals": GOALS,
                "verdict": {goal: judged.to_dict() for goal, judged in self.verdict.items()},
                "complete": self.complete}


def run_realism_benchmark(cases: list[Case], frames: int = 200, fps: float | None = None, preset: str = "artificial",
                          occlusion: str = "light", detector: str = "net", seed: int = 0, progress: bool = True,
                          say: Callable[[str], None] = print,
                          after_case: Callable[[RealismNumbers], None] | None = None,
                          weights: Path | None = None) -> RealismNumbers:
    """Every case of ``cases`` (see :func:`sweep`). ``weights``: the ``net`` detector's weights
    file (None: the shipped ones). ``after_case(numbers so far)`` is called after each case (the
    command saves them, so that a sweep of hours stopped midway keeps the cases it finished)."""
    import platform

    start = time.perf_counter()
    rows: list[CaseResult] = []

    def numbers() -> RealismNumbers:
        return RealismNumbers(preset=preset, occlusion=occlusion, frames=frames, fps=fps, detector=detector, seed=seed,
                              weights=str(weights) if weights else "shipped",
                              machine=f"{platform.machine()} {platform.processor() or ''}".strip(),
                              wall_s=time.perf_counter() - start, cases=list(rows), complete=len(rows) == len(cases))

    for case in cases:
        rows.append(run_case(case, frames, fps, preset, occlusion, detector, seed, progress, say, weights))
        if after_case is not None:
            after_case(numbers())
    return numbers()


@dataclass(frozen=True)
class GoalVerdict:
    """One goal against the cases run: ``met``, and what it was judged on: a single ``value`` (mm),
    or per case the numbers ``by_case`` (case name -> swapped dot-frames or flagged share; for the
    held-out look its mean error and wrong vouched-for labels), named ``judged_on`` ("swaps",
    "shares" or "held_out") in the JSON."""

    met: bool
    value: float | None = None
    by_case: dict[str, float] | None = None
    judged_on: str = "value"

    def to_dict(self) -> dict:
        """The JSON form: ``{"met": ..., "value": ...}`` or ``{"met": ..., "swaps" | "shares": {...}}``."""
        return {"met": self.met, self.judged_on: self.value if self.by_case is None else self.by_case}

    def numbers(self) -> float | dict[str, float] | None:
        """What the goal was judged on: the value, or the numbers per case."""
        return self.value if self.by_case is None else self.by_case


def verdict(rows: list[CaseResult]) -> dict[str, GoalVerdict]:
    """The goals against the rows present: met / not met with the numbers judged."""
    out: dict[str, GoalVerdict] = {}
    swap_rows = [r for r in rows if (r.factor == "tension" and r.studio.get("tape_tension", 0) <= 0.3)
                 or (r.factor == "calibration" and r.studio.get("calibration_error_px", 0) <= 2.0)
                 or r.factor in ("baseline", "all")]
    if swap_rows:
        swaps: dict[str, float] = {r.case: r.new.swaps for r in swap_rows}
        out["zero_swaps"] = GoalVerdict(all(v == 0 for v in swaps.values()), by_case=swaps, judged_on="swaps")
    flag_rows = [r for r in rows if r.studio.get("tape_tension", 0) <= 0.2 and r.studio.get("calibration_error_px", 0) <= 1.0
                 and r.studio.get("sync_error_ms", 0) <= 1.0 and r.new.flagged_dot_share is not None]
    if flag_rows:
        shares = {r.case: _number(r.new.flagged_dot_share) for r in flag_rows}
        out["flagged_dot_share"] = GoalVerdict(all(v <= GOALS["flagged_dot_share"] for v in shares.values()),
                                               by_case=shares, judged_on="shares")
    held = next((r for r in rows if r.case == HELD_OUT_CASE), None)
    if held:
        value, wrong = held.new.mean_mm, held.new.vouched_swaps
        out["held_out"] = GoalVerdict(value <= GOALS["held_out_mean_mm"] and wrong == 0,
                                      by_case={"mean_mm": value, "vouched_swaps": float("nan") if wrong is None else wrong},
                                      judged_on="held_out")
    lab = next((r for r in rows if r.case == "lab"), None)
    if lab:
        out["lab_mean_mm"] = GoalVerdict(lab.new.mean_mm <= GOALS["lab_mean_mm"], value=lab.new.mean_mm)
    for key, with_reference in (("refined_2px_mean_mm", False), ("refined_2px_reference_mean_mm", True)):
        two = next((r for r in rows if r.factor == "calibration" and r.studio.get("calibration_error_px") == 2.0
                    and bool(r.studio.get("reference")) == with_reference), None)
        if two and isinstance(two.new_refined, RefinedScore):
            value = two.new_refined.mean_mm
            out[key] = GoalVerdict(value <= GOALS["refined_2px_mean_mm"], value=value)
    return out


def format_table(numbers: RealismNumbers) -> str:
    """A Markdown table of every case (new tracker, --refine-rig where scored, peer)."""
    labels = {"new": "new", "new_refined": "new + --refine-rig",
              "new_refined_without_reference": "new + --refine-rig, reference ignored", "peer": "before (peer)"}
    lines = ["| case | tracker | mean mm | p95 mm | vouched-for mean mm | swapped dot-frames | flagged frames "
             "| flagged dot-frames % | unsolved |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in numbers.cases:
        for key, s, _ in _scored(r):
            lines.append(f"| {r.case} | {labels[key]} | {s.mean_mm:.2f} | {s.p95_mm:.2f} | "
                         f"{_number(s.vouched_mean_mm):.2f} | {s.swaps} | {s.flagged_frames} | "
                         f"{100 * _number(s.flagged_dot_share):.1f} | {s.unsolved_frames} |")
    return "\n".join(lines)


def save_json(numbers: dict, json_path: Path) -> None:
    """The numbers as indented JSON, written atomically (the folder made if needed)."""
    json_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(json_path) as fh:
        json.dump(numbers, fh, indent=2, default=float)


def save(numbers: dict, json_path: Path | None, plot_path: Path | None,
         draw: Callable[[dict, Path], None] | None = None) -> None:
    """The numbers as JSON and, with ``plot_path``, their plot (``draw``, default this benchmark's
    :func:`plot`; ``bench gauge`` passes its own)."""
    if json_path:
        save_json(numbers, json_path)
    if plot_path:
        (draw or plot)(numbers, plot_path)


def plot(numbers: dict, path: Path) -> None:
    """Mean error (log) and swapped dot-frames per case, new tracker beside the peer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = numbers["cases"]
    names = [r["case"] for r in rows]
    x = np.arange(len(rows))
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(max(8, 0.8 * len(rows) + 3), 7), sharex=True)
    series = (("new", "new tracker", "tab:blue"), ("new_refined", "new + --refine-rig", "tab:green"),
              ("peer", "previous tracker (peer)", "tab:red"))
    for k, (key, label, colour) in enumerate(series):
        mean = [r.get(key, {}).get("mean_mm", np.nan) for r in rows]
        swaps = [r.get(key, {}).get("swaps", np.nan) for r in rows]
        ax1.bar(x + (k - 1) * 0.27, mean, 0.27, label=label, color=colour)
        ax2.bar(x + (k - 1) * 0.27, np.asarray(swaps, float) + 0.5, 0.27, color=colour)
    ax1.axhline(1.0, color="k", ls=":", lw=1, label="goal 1.0 mm (lab)")
    ax1.set_yscale("log")
    ax1.set_ylabel("mean error (mm)")
    ax1.legend(fontsize=8)
    ax2.set_yscale("log")
    ax2.set_ylabel("swapped dot-frames + 0.5")
    ax2.set_xticks(x, names, rotation=35, ha="right", fontsize=8)
    fig.suptitle(f"bench realism: {numbers['preset']}, {numbers['frames']} frames, occlusion {numbers['occlusion']}, "
                 f"detector {numbers['detector']}", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
