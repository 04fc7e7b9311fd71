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
from pathlib import Path
from typing import Callable

import numpy as np

from ..analysis.levels import LevelMap
from ..app.crossval import crossval_angles
from ..bodymodel.anny_body import AnnyModel
from ..bodymodel.fit import FitOptions, MarkerFitter
from ..bodymodel.markersets import place_markers
from ..bodymodel.tape import lay_tape
from ..bodymodel.virtual_vicon import ViconSetup, VirtualVicon
from ..crossval.compare import cross_validate
from ..fileio import atomic_write
from ..synth import SynthConfig, build_scene
from ..synth.scene import Scene
from .track import run_track_benchmark

PAPER_STUDIO_MM = {"bodyfit": 24.75, "tracker": 4.12}


def _stats(errors: np.ndarray, prefix: str) -> dict[str, float]:
    e = errors[np.isfinite(errors)]
    return {f"{prefix}_dot_error_mean_mm": float(e.mean()), f"{prefix}_dot_error_median_mm": float(np.median(e)),
            f"{prefix}_dot_error_p95_mm": float(np.percentile(e, 95)), f"{prefix}_dot_frames": int(len(e))}


def bodyfit_dots(scene, vicon, key_frames: int, progress: bool, pose_jacobian: str = "kernel"
                 ) -> tuple[np.ndarray, dict]:
    """(F, D, 3) dots of the body fitted to the virtual Vicon recording ``vicon`` of ``scene``,
    at the scene's frames (studio frame), and the fit's numbers; ``pose_jacobian`` as in
    :class:`~spinemocap.bodymodel.fit.FitOptions` ("autodiff": the earlier per-frame path)."""
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
    numbers = {"vicon_frames": len(vicon.time_s), "vicon_markers_fitted": kept,
               "marker_rms_mm": float(np.sqrt(np.nanmean(fit.residual_mm ** 2))), "fit_s": fit_s,
               "fit_ms_per_vicon_frame": 1000 * fit.timings_s["pose_stage"] / len(vicon.time_s),
               "shape_stage_s": fit.timings_s["shape_stage"], "misplacement_mm": setup.misplacement_mm,
               "pose_jacobian": pose_jacobian}
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


def crossval_numbers(seed: int, frames: int = 60, fps: float = 30.0, noise_mm: float = 0.3, rows: int = 9) -> dict:
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
    return {"frames": frames, "fps": fps, "rows": rows, "dot_noise_mm": noise_mm,
            "clock_offset_true_ms": 1000 * s.clock_offset_s, "clock_offset_error_ms": 1000 * (a.offset_s - s.clock_offset_s),
            "transform_error_max_mm": float(np.linalg.norm(a.to_vicon(points) - (points @ s.R.T + s.t), axis=1).max()),
            "angles": {name: stats.to_dict() for name, stats in result.summary.angles.items()},
            "angle_convention": result.summary.angle_convention}


def run_bodyfit_benchmark(preset: str = "artificial", frames: int = 10, misplacement_mm: float = 10.0,
                          key_frames: int = 3, seed: int = 0, progress: bool = True,
                          say: Callable[[str], None] = print, peer: bool = True, crossval_rows: int = 9) -> dict:
    """All numbers of the benchmark (see the module docstring); ``peer``: also fit with the
    earlier per-frame path (autograd through the whole skeleton) on the same markers."""
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
    dots, fit_numbers = bodyfit_dots(scene, vicon, key_frames, progress)
    body_err = np.linalg.norm(dots - gt["dots"], axis=2)
    peer_numbers: dict = {}
    if peer:
        say("the same fit with the earlier per-frame path (autograd through all bones) ...")
        peer_dots, peer_numbers = bodyfit_dots(scene, vicon, key_frames, progress, "autodiff")
        peer_numbers.update(_stats(np.linalg.norm(peer_dots - gt["dots"], axis=2), "bodyfit"))
    say("cross-validating against the virtual Vicon ...")
    body_stats, tracker_stats = _stats(body_err, "bodyfit"), _stats(tracker_err, "tracker")
    return {"preset": preset, "frames": frames, "seed": seed, "paper_studio_mm": PAPER_STUDIO_MM,
            **body_stats, **tracker_stats,
            "bodyfit_over_tracker": body_stats["bodyfit_dot_error_mean_mm"] / tracker_stats["tracker_dot_error_mean_mm"],
            "bodyfit": fit_numbers, "bodyfit_peer_autodiff": peer_numbers, "crossval": crossval_numbers(seed, rows=crossval_rows)}


def format_report(n: dict) -> str:
    lines = [f"bench bodyfit ({n['preset']}, {n['frames']} frames): dot error vs the exact dots, mm",
             f"{'':22s}{'paper':>8s}{'mean':>8s}{'median':>8s}{'p95':>8s}"]
    for key, name in (("bodyfit", "body fit (MoSh-like)"), ("tracker", "tracker")):
        lines.append(f"{name:22s}{PAPER_STUDIO_MM[key]:8.2f}{n[f'{key}_dot_error_mean_mm']:8.2f}"
                     f"{n[f'{key}_dot_error_median_mm']:8.2f}{n[f'{key}_dot_error_p95_mm']:8.2f}")
    f = n["bodyfit"]
    lines.append(f"body fit: {len(f['vicon_markers_fitted'])} markers misplaced by {f['misplacement_mm']:.0f} mm, "
                 f"marker RMS {f['marker_rms_mm']:.2f} mm, shape stage {f['shape_stage_s']:.1f} s, "
                 f"{f['fit_ms_per_vicon_frame']:.0f} ms per Vicon frame")
    p = n.get("bodyfit_peer_autodiff")
    if p:
        lines.append(f"  peer (autograd Jacobian): dot error {p['bodyfit_dot_error_mean_mm']:.2f} mm mean, marker RMS "
                     f"{p['marker_rms_mm']:.2f} mm, shape stage {p['shape_stage_s']:.1f} s, "
                     f"{p['fit_ms_per_vicon_frame']:.0f} ms per Vicon frame "
                     f"({p['fit_ms_per_vicon_frame'] / f['fit_ms_per_vicon_frame']:.1f}x ours)")
    c = n["crossval"]
    lines.append(f"crossval ({c['rows']}-row tape, angles from neutral, analysis definitions on both sides): "
                 f"clock offset error {c['clock_offset_error_ms']:+.3f} ms, transform error "
                 f"{c['transform_error_max_mm']:.3f} mm (max over the tape)")
    for name, s in c["angles"].items():
        lines.append(f"  {name:26s} RMSE {s['rmse_deg']:.2f} deg, bias {s['bias_deg']:+.2f}, ICC {s['icc']:.3f}, "
                     f"CMC {s['cmc']:.3f}")
    return "\n".join(lines)


def save(numbers: dict, path: Path) -> None:
    with atomic_write(path) as handle:
        json.dump(numbers, handle, indent=2)
