"""The body-fit benchmark (``spinemocap bench bodyfit``): the paper's Studio row (Table 1: MoSh
24.75 mm vs the tracker 4.12 mm) on the synthetic studio, plus cross-validation against a virtual
Vicon with a known clock offset and transform.

1. A studio sequence is rendered and tracked (the peer: :func:`spinemocap.bench.track.run_track_benchmark`).
2. A virtual Vicon records the same motion (200 Hz, own frame and clock, 14 mm markers, noise,
   gaps, markers misplaced on the skin by ``misplacement_mm``). The body model (anny) is fitted to
   its sparse skin markers (Plug-in Gait + spine, the tape markers left out), the tape is laid on
   the fitted body at the studio's start level and its dots are read off the fitted body at each
   Vicon frame, brought into the studio frame and clock with the true transform/offset and
   interpolated at the camera frames: the body-model ground truth of the paper.
3. Both are scored against the exact dots: mean / median / 95th percentile (mm).
4. Cross-validation: exact dots (skin strain on, as the Vicon's tape markers; + noise) of a longer
   trial against the virtual Vicon: recovered clock offset and transform errors and angle agreement.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..analysis.levels import LevelMap
from ..app.crossval import crossval_angles
from ..bodymodel.anny_body import AnnyModel
from ..bodymodel.fit import FitOptions, MarkerFitter
from ..bodymodel.markersets import place_markers
from ..bodymodel.tape import lay_tape
from ..bodymodel.virtual_vicon import ViconSetup, VirtualVicon
from ..crossval.agreement import Agreement
from ..crossval.compare import cross_validate
from ..fileio import atomic_write
from ..synth import SynthConfig, build_scene
from ..synth.scene import Scene
from .records import JsonRecord
from .track import run_track_benchmark

PAPER_STUDIO_MM = {"bodyfit": 24.75, "tracker": 4.12}


@dataclass(frozen=True)
class DotErrors:
    """Dot errors against the exact dots (mm): mean, median and 95th percentile over the
    ``dot_frames`` dot-frames with a finite error (:func:`dot_errors`)."""

    mean_mm: float
    median_mm: float
    p95_mm: float
    dot_frames: int

    def keyed(self, prefix: str) -> dict[str, float | int]:
        """The JSON keys of the benchmark: ``<prefix>_dot_error_mean_mm``, ``..._median_mm``,
        ``..._p95_mm``, ``<prefix>_dot_frames``."""
        return {f"{prefix}_dot_error_mean_mm": self.mean_mm, f"{prefix}_dot_error_median_mm": self.median_mm,
                f"{prefix}_dot_error_p95_mm": self.p95_mm, f"{prefix}_dot_frames": self.dot_frames}


def dot_errors(errors: np.ndarray) -> DotErrors:
    """The :class:`DotErrors` of per-dot-frame ``errors`` (any shape, mm; non-finite skipped)."""
    e = errors[np.isfinite(errors)]
    return DotErrors(mean_mm=float(e.mean()), median_mm=float(np.median(e)), p95_mm=float(np.percentile(e, 95)),
                     dot_frames=int(len(e)))


@dataclass(frozen=True)
class BodyFitRun(JsonRecord):
    """One fit of the body model to the virtual Vicon's skin markers (:func:`bodyfit_dots`): the
    Vicon frames, the markers fitted, their RMS residual (mm), the fit's seconds in all, its pose
    stage's milliseconds per Vicon frame, its shape stage's seconds, the markers' misplacement on
    the skin (mm) and the pose Jacobian used."""

    vicon_frames: int
    vicon_markers_fitted: list[str]
    marker_rms_mm: float
    fit_s: float
    fit_ms_per_vicon_frame: float
    shape_stage_s: float
    misplacement_mm: float
    pose_jacobian: str


@dataclass(frozen=True)
class CrossValNumbers(JsonRecord):
    """The cross-validation against the virtual Vicon (:func:`crossval_numbers`): the trial
    (frames, fps, tape rows, dot noise in mm), the true clock offset and the recovered one's error
    (ms), the recovered transform's largest error over the tape's dots (mm), the agreement of each
    spine angle (deg) and how both sides computed the angles (the summary's ``angle_convention``)."""

    frames: int
    fps: float
    rows: int
    dot_noise_mm: float
    clock_offset_true_ms: float
    clock_offset_error_ms: float
    transform_error_max_mm: float
    angles: dict[str, Agreement]
    angle_convention: dict[str, Any] | None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields in order, each angle's agreement as its ``to_dict()``."""
        numbers = {f.name: getattr(self, f.name) for f in fields(self)}
        numbers["angles"] = {name: stats.to_dict() for name, stats in self.angles.items()}
        return numbers


@dataclass(frozen=True)
class BodyFitBenchmark:
    """Every number of ``spinemocap bench bodyfit`` (:func:`run_bodyfit_benchmark`): the scene,
    the body fit's and the tracker's dot errors, the fit, the peer fit (autograd Jacobian, None
    when not run) with its dot errors, and the cross-validation."""

    preset: str
    frames: int
    seed: int
    bodyfit_errors: DotErrors
    tracker_errors: DotErrors
    bodyfit: BodyFitRun
    peer: BodyFitRun | None
    peer_errors: DotErrors | None
    crossval: CrossValNumbers

    @property
    def bodyfit_over_tracker(self) -> float:
        """The body fit's mean dot error over the tracker's."""
        return self.bodyfit_errors.mean_mm / self.tracker_errors.mean_mm

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``--json`` writes: the scene, the paper's Studio row, the errors as
        ``bodyfit_dot_error_mean_mm`` ... ``tracker_dot_frames``, their ratio, the fit, the peer
        (its fit's keys then its errors'; empty when not run) and the cross-validation."""
        peer: dict[str, Any] = {}
        if self.peer is not None and self.peer_errors is not None:
            peer = {**self.peer.to_dict(), **self.peer_errors.keyed("bodyfit")}
        return {"preset": self.preset, "frames": self.frames, "seed": self.seed, "paper_studio_mm": PAPER_STUDIO_MM,
                **self.bodyfit_errors.keyed("bodyfit"), **self.tracker_errors.keyed("tracker"),
                "bodyfit_over_tracker": self.bodyfit_over_tracker, "bodyfit": self.bodyfit.to_dict(),
                "bodyfit_peer_autodiff": peer, "crossval": self.crossval.to_dict()}


def bodyfit_dots(scene, vicon, key_frames: int, progress: bool, pose_jacobian: str = "kernel"
                 ) -> tuple[np.ndarray, BodyFitRun]:
    """(F, D, 3) dots of the body fitted to the virtual Vicon recording ``vicon`` of ``scene``,
    at the scene's frames (studio frame), and the fit's numbers; ``pose_jacobian`` as in
    :class:`~spinemocap.bodymodel.fit.FitOptions` ("autodiff": the per-frame peer path)."""
    setup = vicon.setup
    model = AnnyModel()
    skin = [i for i, label in enumerate(vicon.labels) if not label.startswith("VT_")]
    labels = [vicon.labels[i] for i in skin]
    kept, vertices = place_markers(model.rest(), labels)
    columns = [skin[labels.index(k)] for k in kept]
    t0 = time.perf_counter()
    fit = MarkerFitter(model, vertices, FitOptions(n_key_frames=key_frames, pose_jacobian=pose_jacobian)).fit(
        vicon.positions[:, columns], progress=progress, labels=kept)
    fit_s = time.perf_counter() - t0
    laid = lay_tape(model.rest(fit.shape), scene.tape, scene.config.tape_start)
    dots_vicon = laid.dots.sequence(model.vertices(fit.poses, fit.shape), model.faces)  # (N, D, 3) Vicon frame
    dots_studio = (dots_vicon - setup.t) @ setup.R
    studio_time = vicon.time_s - setup.clock_offset_s
    dots = np.stack([np.stack([np.interp(scene.times, studio_time, dots_studio[:, d, k]) for k in range(3)], axis=1)
                     for d in range(dots_studio.shape[1])], axis=1)
    numbers = BodyFitRun(vicon_frames=len(vicon.time_s), vicon_markers_fitted=kept,
                         marker_rms_mm=float(np.sqrt(np.nanmean(fit.residual_mm ** 2))), fit_s=fit_s,
                         fit_ms_per_vicon_frame=1000 * fit.timings_s["pose_stage"] / len(vicon.time_s),
                         shape_stage_s=fit.timings_s["shape_stage"], misplacement_mm=setup.misplacement_mm,
                         pose_jacobian=pose_jacobian)
    return dots, numbers


def crossval_trial(seed: int, frames: int = 60, fps: float = 30.0, rows: int = 9, occlusion: bool = True
                   ) -> tuple[Scene, np.ndarray, VirtualVicon]:
    """The cross-validation trial: a tiny-preset scene with a ``rows``-row tape from S1, its exact
    dots (F, D, 3) mm (the studio's truth, skin strain on, as the Vicon's tape markers ride the
    strained skin) and its virtual Vicon recording (``occlusion``: gaps where the body hides markers)."""
    from ..app.virtual_vicon import record_scene

    scene = build_scene(SynthConfig.preset("tiny", frames=frames, fps=fps, rows=rows, seed=seed))
    dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])
    return scene, dots, record_scene(scene, occlusion=occlusion)


def crossval_numbers(seed: int, frames: int = 60, fps: float = 30.0, noise_mm: float = 0.3, rows: int = 9
                     ) -> CrossValNumbers:
    """Cross-validation of the exact dots + ``noise_mm`` noise against the virtual Vicon on the
    trial of :func:`crossval_trial`."""
    scene, dots, vicon = crossval_trial(seed, frames, fps, rows)
    dots = dots + np.random.default_rng(seed).normal(0.0, noise_mm, dots.shape)
    result = cross_validate(scene.times, dots, scene.labels, scene.tape, vicon.time_s, vicon.positions, vicon.labels)
    levels = LevelMap.from_row_levels(scene.tape_on_skin.row_levels, scene.tape.n_rows)
    subject = scene.subject()
    crossval_angles(result, scene.times, dots, scene.labels, scene.tape, levels, subject["up"], subject["facing"])
    a, s = result.alignment, vicon.setup
    points = dots.reshape(-1, 3)
    return CrossValNumbers(
        frames=frames, fps=fps, rows=rows, dot_noise_mm=noise_mm, clock_offset_true_ms=1000 * s.clock_offset_s,
        clock_offset_error_ms=1000 * (a.offset_s - s.clock_offset_s),
        transform_error_max_mm=float(np.linalg.norm(a.to_vicon(points) - (points @ s.R.T + s.t), axis=1).max()),
        angles=dict(result.summary.angles), angle_convention=result.summary.angle_convention)


def run_bodyfit_benchmark(preset: str = "artificial", frames: int = 10, misplacement_mm: float = 10.0,
                          key_frames: int = 3, seed: int = 0, progress: bool = True,
                          say: Callable[[str], None] = print, peer: bool = True, crossval_rows: int = 9
                          ) -> BodyFitBenchmark:
    """All numbers of the benchmark (see the module docstring); ``peer``: also fit with the
    per-frame path (autograd through the whole skeleton) on the same markers."""
    import torch

    from ..app.virtual_vicon import record_scene

    torch.set_num_threads(1)
    track = run_track_benchmark(preset, "none", frames, seed=seed, progress=progress, say=say)
    gt = track.groundtruth
    labels = list(gt["labels"])
    tracked = track.table.select(labels=labels).to_arrays()
    tracked_pos = tracked.positions[:, [list(tracked.labels).index(lab) for lab in labels]]
    tracker_err = np.linalg.norm(tracked_pos - gt["dots"][: len(tracked_pos)], axis=2)
    say("fitting the body model to the virtual Vicon markers ...")
    scene = build_scene(SynthConfig.preset(preset, occlusion="none", seed=seed, frames=frames))
    vicon = record_scene(scene, ViconSetup(misplacement_mm=misplacement_mm, seed=seed))
    dots, fit = bodyfit_dots(scene, vicon, key_frames, progress)
    peer_fit, peer_errors = None, None
    if peer:
        say("the same fit with the per-frame peer path (autograd through all bones) ...")
        peer_dots, peer_fit = bodyfit_dots(scene, vicon, key_frames, progress, "autodiff")
        peer_errors = dot_errors(np.linalg.norm(peer_dots - gt["dots"], axis=2))
    say("cross-validating against the virtual Vicon ...")
    return BodyFitBenchmark(preset=preset, frames=frames, seed=seed,
                            bodyfit_errors=dot_errors(np.linalg.norm(dots - gt["dots"], axis=2)),
                            tracker_errors=dot_errors(tracker_err), bodyfit=fit, peer=peer_fit,
                            peer_errors=peer_errors, crossval=crossval_numbers(seed, rows=crossval_rows))


def format_report(n: BodyFitBenchmark) -> str:
    """The benchmark's numbers as the lines ``spinemocap bench bodyfit`` prints."""
    lines = [f"bench bodyfit ({n.preset}, {n.frames} frames): dot error vs the exact dots, mm",
             f"{'':22s}{'paper':>8s}{'mean':>8s}{'median':>8s}{'p95':>8s}"]
    for key, name, errors in (("bodyfit", "body fit (MoSh-like)", n.bodyfit_errors),
                              ("tracker", "tracker", n.tracker_errors)):
        lines.append(f"{name:22s}{PAPER_STUDIO_MM[key]:8.2f}{errors.mean_mm:8.2f}"
                     f"{errors.median_mm:8.2f}{errors.p95_mm:8.2f}")
    f = n.bodyfit
    lines.append(f"body fit: {len(f.vicon_markers_fitted)} markers misplaced by {f.misplacement_mm:.0f} mm, "
                 f"marker RMS {f.marker_rms_mm:.2f} mm, shape stage {f.shape_stage_s:.1f} s, "
                 f"{f.fit_ms_per_vicon_frame:.0f} ms per Vicon frame")
    if n.peer is not None and n.peer_errors is not None:
        p = n.peer
        lines.append(f"  peer (autograd Jacobian): dot error {n.peer_errors.mean_mm:.2f} mm mean, marker RMS "
                     f"{p.marker_rms_mm:.2f} mm, shape stage {p.shape_stage_s:.1f} s, "
                     f"{p.fit_ms_per_vicon_frame:.0f} ms per Vicon frame "
                     f"({p.fit_ms_per_vicon_frame / f.fit_ms_per_vicon_frame:.1f}x ours)")
    c = n.crossval
    lines.append(f"crossval ({c.rows}-row tape, angles from neutral, analysis definitions on both sides): "
                 f"clock offset error {c.clock_offset_error_ms:+.3f} ms, transform error "
                 f"{c.transform_error_max_mm:.3f} mm (max over the tape)")
    for name, s in c.angles.items():
        lines.append(f"  {name:26s} RMSE {s.rmse:.2f} deg, bias {s.bias:+.2f}, ICC {s.icc:.3f}, CMC {s.cmc:.3f}")
    return "\n".join(lines)


def save(numbers: BodyFitBenchmark, path: Path) -> None:
    """Write ``numbers.to_dict()`` to ``path`` as indented JSON."""
    with atomic_write(path) as handle:
        json.dump(numbers.to_dict(), handle, indent=2)
