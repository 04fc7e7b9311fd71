"""``spinemocap bench sync``: the clock-offset estimates (:mod:`spinemocap.app.sync`) against the
truth on studio captures whose cameras are not synchronised.

Each scenario renders a small studio capture (tiny layout, 480x360, lossless video with a clap on
the audio tracks) whose cameras record on their own clocks: whole and fractional frame offsets up
to 2 s, mixed rates (50/60/100 frames/s) and dropped frames. Both estimators run on it (``motion``
from the detected dots, ``audio`` from the clap), and as the peer the motion estimate without each
matched pair's own epipolar bias; the numbers are each camera's error against the
true offset (relative to camera 1), the dropped frames found against those rendered, and the share
of capture frames paired to the same media frames by the estimated offsets as by the true ones.
Goal: |error| <= 1 ms for 100 fps cameras (other than the reference).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..app.sync import SyncEstimate, detect_camera_dots, estimate_audio, estimate_motion
from ..capture import Capture
from ..fileio import read_toml
from ..synth import SynthConfig, write_capture
from ..timebase import CameraClock, pair_cameras
from .records import JsonRecord

GOAL_MS = 1.0  # |offset error| on 100 frames/s cameras
# name -> the studio settings that differ from the tiny preset's
SCENARIOS: dict[str, dict] = {
    # whole (+1.93 s = 193 frames) and fractional (-0.4567 s = 45.67 frames) offsets, 100 frames/s
    "offsets_100fps": {"cameras": 3, "fps": 100.0, "frames": 100, "camera_offsets_s": (0.0, 1.93, -0.4567)},
    # mixed rates (the reference camera at 60, the others at 100 and 50), fractional offsets, two dropped frames
    "mixed_50_60_100fps": {"cameras": 3, "fps": 100.0, "frames": 150, "camera_offsets_s": (0.0, -0.7123, 0.3456),
                           "camera_fps": (60.0, 100.0, 50.0), "drop_frames": 2},
}


@dataclass(frozen=True)
class OffsetErrors(JsonRecord):
    """One estimate of a capture's offsets against the truth (per camera, in the capture's camera
    order): the estimated offsets, their errors and standard errors (ms), the largest error on the
    100 fps cameras other than the reference (None: no such camera) and on all (ms), which cameras
    it found, and the share of capture frames paired to the same media frames as the truth pairs them."""

    offset_ms: list[float]
    error_ms: list[float]
    stderr_ms: list[float]
    max_abs_error_100fps_ms: float | None
    max_abs_error_ms: float
    found: list[bool]
    pairs_as_truth: float



@dataclass(frozen=True)
class CaptureSync:
    """One studio capture's estimates against its truth (:func:`measure_capture`): the cameras,
    their frame rates and true offsets (ms, relative to the first), seconds of the audio estimate,
    of the dot detection and of the motion estimate, each method's errors (``motion``,
    ``motion_no_bias_term``, ``audio`` where the videos carry it), the dropped frames rendered and
    found ((camera, media slot) pairs) and the seconds the capture took to render (None: reused)."""

    cameras: list[str]
    camera_fps: list[float]
    true_offset_ms: list[float]
    audio_s: float
    detect_s: float
    motion_s: float
    methods: dict[str, OffsetErrors]
    dropped_rendered: list[tuple[int, int]]
    dropped_found: list[tuple[int, int]]
    render_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: each method's errors under its name, between the times and the dropped frames."""
        return {"cameras": self.cameras, "camera_fps": self.camera_fps, "true_offset_ms": self.true_offset_ms,
                "audio_s": self.audio_s, "detect_s": self.detect_s, "motion_s": self.motion_s,
                **{method: errors.to_dict() for method, errors in self.methods.items()},
                "dropped_rendered": self.dropped_rendered, "dropped_found": self.dropped_found,
                "render_s": self.render_s}


@dataclass(frozen=True)
class SyncNumbers:
    """``bench sync``'s numbers (:func:`run_sync_benchmark`): the goal (ms), the detector, the
    studio's realism and each scenario's capture."""

    goal_ms: float
    detector: str
    realism: str
    scenarios: dict[str, CaptureSync]

    def to_dict(self) -> dict[str, Any]:
        return {"goal_ms": self.goal_ms, "detector": self.detector, "realism": self.realism,
                "scenarios": {name: capture.to_dict() for name, capture in self.scenarios.items()}}


def run_sync_benchmark(out_dir: Path, scenarios: list[str], detector: str = "classical", realism: str = "lab",
                       progress: bool = True) -> SyncNumbers:
    """Render and estimate every scenario under ``out_dir/<scenario>`` (a capture an earlier run
    rendered from the same settings is reused: ``render_s`` None); returns the numbers (see the
    module docstring; offsets in ms, times in s)."""
    results = {}
    for name in scenarios:
        config = SynthConfig.preset("tiny", size=(480, 360), realism=realism, video=True, clap=True, seed=0,
                                    name=name, **SCENARIOS[name])
        root, render_s = out_dir / name, None
        if not _rendered(root, config):
            t0 = time.perf_counter()
            write_capture(config, root, progress=progress)
            render_s = time.perf_counter() - t0
        results[name] = replace(measure_capture(root, detector, progress), render_s=render_s)
    return SyncNumbers(GOAL_MS, detector, realism, results)


def _rendered(root: Path, config: SynthConfig) -> bool:
    """Does ``root`` hold a finished capture of exactly ``config`` (rendered by an earlier run)?"""
    if not (root / "capture.toml").is_file() or not (root / "synth.toml").is_file():
        return False
    return read_toml(root / "synth.toml").get("synth") == config.to_dict()


def measure_capture(root: Path, detector: str = "classical", progress: bool = True) -> CaptureSync:
    """One studio capture's estimates against its truth (see :class:`CaptureSync`)."""
    capture = Capture.open(root)
    truth = capture.groundtruth()
    offsets = truth["clock_offsets_s"] - truth["clock_offsets_s"][0]
    t0 = time.perf_counter()
    audio = estimate_audio(capture)
    audio_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    dots = detect_camera_dots(capture, detector, seconds=10.0, progress=progress)
    detect_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    motion = estimate_motion(capture.rig, dots, 2.0)
    motion_s = time.perf_counter() - t0
    # the peer: the same search without each matched pair's own epipolar bias (an inexact calibration)
    peer = estimate_motion(capture.rig, dots, 2.0, per_track_bias=False)
    peer = SyncEstimate(peer.camera_names, peer.offsets_s, peer.stderr_s, "motion_no_bias_term", peer.pairs)
    clocks = capture.clocks
    times = capture.media_times()
    methods: dict[str, OffsetErrors] = {}
    for estimate in (motion, peer, audio):
        if estimate is None:
            continue
        error = 1000 * (estimate.offsets_s - offsets)
        fast = np.asarray(truth["camera_fps"]) >= 100
        fast[0] = False  # the reference camera: 0 by definition
        methods[estimate.method] = OffsetErrors(
            offset_ms=(1000 * estimate.offsets_s).tolist(), error_ms=error.tolist(),
            stderr_ms=(1000 * estimate.stderr_s).tolist(),
            max_abs_error_100fps_ms=float(np.nanmax(np.abs(error[fast]))) if fast.any() else None,
            max_abs_error_ms=float(np.nanmax(np.abs(error))), found=estimate.found.tolist(),
            pairs_as_truth=_same_pairing(capture, times, clocks, estimate.offsets_s, offsets))
    rendered = sorted((int(c), int(k)) for c, k in truth["dropped_slots"])
    found = sorted((c, d.after_slot + 1 + m) for c, t in enumerate(times) for d in t.dropped for m in range(d.missing))
    return CaptureSync(cameras=capture.camera_names, camera_fps=truth["camera_fps"].tolist(),
                       true_offset_ms=(1000 * offsets).tolist(), audio_s=audio_s, detect_s=detect_s, motion_s=motion_s,
                       methods=methods, dropped_rendered=rendered, dropped_found=found)


def _same_pairing(capture: Capture, times, clocks: list[CameraClock], estimated_s: np.ndarray,
                  true_s: np.ndarray) -> float:
    """Share of (camera, capture frame) pairs that read the same media frame with the estimated
    offsets as with the true ones (NaN estimates count as offset 0)."""
    def slots(values: np.ndarray) -> np.ndarray:
        with_offsets = [CameraClock(float(np.nan_to_num(v)), clock.fps, clock.media) for v, clock in zip(values, clocks)]
        return pair_cameras(capture.camera_names, times, with_offsets, capture.fps, capture.n_frames).slots

    return float(np.mean(slots(estimated_s) == slots(true_s)))


def format_table(numbers: SyncNumbers) -> str:
    """The per-camera errors as a text table, with the goal's verdict per scenario."""
    lines = [f"clock offsets against the truth (goal |error| <= {numbers.goal_ms:g} ms on 100 fps cameras; "
             f"detector {numbers.detector}, realism {numbers.realism})"]
    for name, r in numbers.scenarios.items():
        lines.append(f"{name}:")
        lines.append(f"  {'camera':<8} {'fps':>5} {'true ms':>10} {'motion err':>11} {'+-':>7} {'peer err':>9} "
                     f"{'audio err':>10}")
        nan = [float("nan")] * len(r.cameras)
        m, q, a = (r.methods.get(k) for k in ("motion", "motion_no_bias_term", "audio"))
        for c, cam in enumerate(r.cameras):
            lines.append(f"  {cam:<8} {r.camera_fps[c]:5g} {r.true_offset_ms[c]:10.3f} {(m.error_ms if m else nan)[c]:11.3f} "
                         f"{(m.stderr_ms if m else nan)[c]:7.3f} {(q.error_ms if q else nan)[c]:9.3f} "
                         f"{(a.error_ms if a else nan)[c]:10.4f}")
        for method in ("motion", "motion_no_bias_term", "audio"):
            if method in r.methods:
                errors = r.methods[method]
                worst = errors.max_abs_error_100fps_ms
                verdict = "met" if worst is not None and worst <= numbers.goal_ms else "NOT met"
                lines.append(f"  {method}: worst |error| on 100 fps cameras {worst:.3f} ms (goal {verdict}), on all "
                             f"{errors.max_abs_error_ms:.3f} ms; frames paired as the truth pairs them "
                             f"{100 * errors.pairs_as_truth:.1f} %")
        lines.append(f"  dropped frames rendered {r.dropped_rendered}, found {r.dropped_found}")
    return "\n".join(lines)


def save(numbers: SyncNumbers, path: Path, plot_path: Path | None = None) -> None:
    """Write the numbers as JSON and, with ``plot_path``, a bar plot of the errors per camera."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(numbers.to_dict(), indent=2))
    if plot_path is None:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = numbers.scenarios
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5 * len(scenarios), 3.6), squeeze=False)
    for ax, (name, r) in zip(axes[0], scenarios.items()):
        x = np.arange(len(r.cameras))
        for shift, method in ((-0.27, "motion"), (0.0, "motion_no_bias_term"), (0.27, "audio")):
            if method in r.methods:
                ax.bar(x + shift, r.methods[method].error_ms, width=0.27, label=method,
                       yerr=r.methods[method].stderr_ms if method == "motion" else None)
        ax.set_yscale("symlog", linthresh=0.1)
        ax.axhspan(-numbers.goal_ms, numbers.goal_ms, color="0.9", zorder=0, label="goal (100 fps)")
        ax.set_xticks(x, [f"{c}\n{f:g} fps" for c, f in zip(r.cameras, r.camera_fps)])
        ax.set_ylabel("offset error (ms)")
        ax.set_title(name)
        ax.legend(fontsize=8)
    fig.tight_layout()
    plot_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_path, dpi=110)
    plt.close(fig)
