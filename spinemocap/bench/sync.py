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
from pathlib import Path

import numpy as np

from ..app.sync import SyncEstimate, detect_camera_dots, estimate_audio, estimate_motion
from ..capture import Capture
from ..fileio import read_toml
from ..synth import SynthConfig, write_capture
from ..timebase import CameraClock, pair_cameras

GOAL_MS = 1.0  # |offset error| on 100 frames/s cameras
# name -> the studio settings that differ from the tiny preset's
SCENARIOS: dict[str, dict] = {
    # whole (+1.93 s = 193 frames) and fractional (-0.4567 s = 45.67 frames) offsets, 100 frames/s
    "offsets_100fps": {"cameras": 3, "fps": 100.0, "frames": 100, "camera_offsets_s": (0.0, 1.93, -0.4567)},
    # mixed rates (the reference camera at 60, the others at 100 and 50), fractional offsets, two dropped frames
    "mixed_50_60_100fps": {"cameras": 3, "fps": 100.0, "frames": 150, "camera_offsets_s": (0.0, -0.7123, 0.3456),
                           "camera_fps": (60.0, 100.0, 50.0), "drop_frames": 2},
}


def run_sync_benchmark(out_dir: Path, scenarios: list[str], detector: str = "classical", realism: str = "lab",
                       progress: bool = True) -> dict:
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
        results[name] = measure_capture(root, detector, progress)
        results[name]["render_s"] = render_s
    return {"goal_ms": GOAL_MS, "detector": detector, "realism": realism, "scenarios": results}


def _rendered(root: Path, config: SynthConfig) -> bool:
    """Does ``root`` hold a finished capture of exactly ``config`` (rendered by an earlier run)?"""
    if not (root / "capture.toml").is_file() or not (root / "synth.toml").is_file():
        return False
    return read_toml(root / "synth.toml").get("synth") == config.to_dict()


def measure_capture(root: Path, detector: str = "classical", progress: bool = True) -> dict:
    """One studio capture's estimates against its truth: per camera the true and estimated offsets
    (ms), errors and standard errors per method, the dropped frames rendered and found, and the share
    of capture frames paired as the truth pairs them."""
    capture = Capture.open(root)
    truth = capture.groundtruth()
    offsets = truth["clock_offsets_s"] - truth["clock_offsets_s"][0]
    out: dict = {"cameras": capture.camera_names, "camera_fps": truth["camera_fps"].tolist(),
                 "true_offset_ms": (1000 * offsets).tolist()}
    t0 = time.perf_counter()
    audio = estimate_audio(capture)
    out["audio_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dots = detect_camera_dots(capture, detector, seconds=10.0, progress=progress)
    out["detect_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    motion = estimate_motion(capture.rig, dots, 2.0)
    out["motion_s"] = time.perf_counter() - t0
    # the peer: the same search without each matched pair's own epipolar bias (an inexact calibration)
    peer = estimate_motion(capture.rig, dots, 2.0, per_track_bias=False)
    peer = SyncEstimate(peer.camera_names, peer.offsets_s, peer.stderr_s, "motion_no_bias_term", peer.pairs)
    clocks = capture.clocks
    times = capture.media_times()
    for estimate in (motion, peer, audio):
        if estimate is None:
            continue
        error = 1000 * (estimate.offsets_s - offsets)
        fast = np.asarray(truth["camera_fps"]) >= 100
        fast[0] = False  # the reference camera: 0 by definition
        out[estimate.method] = {
            "offset_ms": (1000 * estimate.offsets_s).tolist(), "error_ms": error.tolist(),
            "stderr_ms": (1000 * estimate.stderr_s).tolist(),
            "max_abs_error_100fps_ms": float(np.nanmax(np.abs(error[fast]))) if fast.any() else None,
            "max_abs_error_ms": float(np.nanmax(np.abs(error))),
            "found": estimate.found.tolist(),
            "pairs_as_truth": _same_pairing(capture, times, clocks, estimate.offsets_s, offsets),
        }
    rendered = sorted((int(c), int(k)) for c, k in truth["dropped_slots"])
    found = sorted((c, d.after_slot + 1 + m) for c, t in enumerate(times) for d in t.dropped for m in range(d.missing))
    out["dropped_rendered"], out["dropped_found"] = rendered, found
    return out


def _same_pairing(capture: Capture, times, clocks: list[CameraClock], estimated_s: np.ndarray,
                  true_s: np.ndarray) -> float:
    """Share of (camera, capture frame) pairs that read the same media frame with the estimated
    offsets as with the true ones (NaN estimates count as offset 0)."""
    def slots(values: np.ndarray) -> np.ndarray:
        with_offsets = [CameraClock(float(np.nan_to_num(v)), clock.fps, clock.media) for v, clock in zip(values, clocks)]
        return pair_cameras(capture.camera_names, times, with_offsets, capture.fps, capture.n_frames).slots

    return float(np.mean(slots(estimated_s) == slots(true_s)))


def format_table(numbers: dict) -> str:
    """The per-camera errors as a text table, with the goal's verdict per scenario."""
    lines = [f"clock offsets against the truth (goal |error| <= {numbers['goal_ms']:g} ms on 100 fps cameras; "
             f"detector {numbers['detector']}, realism {numbers['realism']})"]
    for name, r in numbers["scenarios"].items():
        lines.append(f"{name}:")
        lines.append(f"  {'camera':<8} {'fps':>5} {'true ms':>10} {'motion err':>11} {'+-':>7} {'peer err':>9} "
                     f"{'audio err':>10}")
        nan = {"error_ms": [float("nan")] * len(r["cameras"]), "stderr_ms": [float("nan")] * len(r["cameras"])}
        m, q, a = (r.get(k, nan) for k in ("motion", "motion_no_bias_term", "audio"))
        for c, cam in enumerate(r["cameras"]):
            lines.append(f"  {cam:<8} {r['camera_fps'][c]:5g} {r['true_offset_ms'][c]:10.3f} {m['error_ms'][c]:11.3f} "
                         f"{m['stderr_ms'][c]:7.3f} {q['error_ms'][c]:9.3f} {a['error_ms'][c]:10.4f}")
        for method in ("motion", "motion_no_bias_term", "audio"):
            if method in r:
                worst = r[method]["max_abs_error_100fps_ms"]
                verdict = "met" if worst is not None and worst <= numbers["goal_ms"] else "NOT met"
                lines.append(f"  {method}: worst |error| on 100 fps cameras {worst:.3f} ms (goal {verdict}), on all "
                             f"{r[method]['max_abs_error_ms']:.3f} ms; frames paired as the truth pairs them "
                             f"{100 * r[method]['pairs_as_truth']:.1f} %")
        lines.append(f"  dropped frames rendered {r['dropped_rendered']}, found {r['dropped_found']}")
    return "\n".join(lines)


def save(numbers: dict, path: Path, plot_path: Path | None = None) -> None:
    """Write the numbers as JSON and, with ``plot_path``, a bar plot of the errors per camera."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(numbers, indent=2))
    if plot_path is None:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = numbers["scenarios"]
    fig, axes = plt.subplots(1, len(scenarios), figsize=(5 * len(scenarios), 3.6), squeeze=False)
    for ax, (name, r) in zip(axes[0], scenarios.items()):
        x = np.arange(len(r["cameras"]))
        for shift, method in ((-0.27, "motion"), (0.0, "motion_no_bias_term"), (0.27, "audio")):
            if method in r:
                ax.bar(x + shift, r[method]["error_ms"], width=0.27, label=method,
                       yerr=r[method]["stderr_ms"] if method == "motion" else None)
        ax.set_yscale("symlog", linthresh=0.1)
        ax.axhspan(-numbers["goal_ms"], numbers["goal_ms"], color="0.9", zorder=0, label="goal (100 fps)")
        ax.set_xticks(x, [f"{c}\n{f:g} fps" for c, f in zip(r["cameras"], r["camera_fps"])])
        ax.set_ylabel("offset error (ms)")
        ax.set_title(name)
        ax.legend(fontsize=8)
    fig.tight_layout()
    plot_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_path, dpi=110)
    plt.close(fig)
