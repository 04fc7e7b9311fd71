"""``spinemocap bench vicon-wand``: the virtual Vicon's wand wave closes the loop. For each
realism level, a studio trial is built (no body frames rendered), the virtual Vicon records it and
the wand wave (:mod:`spinemocap.app.wand_wave`) is written; the wand co-registration of
``spinemocap calibrate wand`` (:func:`calibration.wand.coregister`, on the written images and C3D,
with the capture's ``rig.toml`` rig) gives the rig -> Vicon transform and clock offset, scored
against the truth (offset error ms, rotation error deg, point error mm over the true dots of the
trial). Then the cross-validation of ``spinemocap crossval`` runs on the trial's exact dots plus
``dot_noise_mm`` noise (a stand-in for tracked dots), once with the wand's transform read back from
the rig file as ``crossval --rig-vicon`` reads it (a similarity: the wand's scale is carried), and
once, the peer, with the transform estimated from the Vicon markers on the tape: offset and
transform errors and angle agreement for both (the analysis's angles from neutral on both sides,
as ``spinemocap crossval`` scores them: :func:`spinemocap.app.crossval.crossval_angles`). Also
counted: the occlusion gaps of the Vicon.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass, fields
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from calibration.wand import WandSpec, coregister, synchronized_frames

from ..analysis.levels import LevelMap
from ..app.c3d_inputs import read_vicon_wand
from ..app.crossval import crossval_angles, rig_transform
from ..app.virtual_vicon import write_scene_vicon
from ..app.wand_wave import VICON_WAND_FILE, WAND_DIR, RegistrationErrors, registration_errors
from ..bodymodel.virtual_vicon import ViconSetup
from ..crossval.compare import cross_validate
from ..fileio import atomic_write
from ..synth import SynthConfig, build_scene

NOT_FILMABLE = "not filmable with this rig"


@dataclass(frozen=True)
class WandRegistration:
    """The wand co-registration scored against the truth: its ``errors``, the wand frames it
    used, the transform's scale and the wand markers' RMS residual (mm)."""

    errors: RegistrationErrors
    n_frames: int
    scale: float
    residual_rms_mm: float

    def to_dict(self) -> dict[str, Any]:
        """The errors' keys, then ``n_frames``, ``scale``, ``residual_rms_mm``."""
        return {**self.errors.to_dict(), "n_frames": self.n_frames, "scale": self.scale,
                "residual_rms_mm": self.residual_rms_mm}


@dataclass(frozen=True)
class CrossValRegistration:
    """One cross-validation's transform scored against the truth: its ``errors``, what of the
    transform and offset was ``estimated`` (:attr:`spinemocap.crossval.register.Alignment.estimated`),
    its scale, and each angle's agreement (name -> ``rmse_deg``, ``bias_deg``, ``icc``, ``cmc``)."""

    errors: RegistrationErrors
    estimated: str
    scale: float
    angles: dict[str, dict[str, float]]

    def to_dict(self) -> dict[str, Any]:
        """The errors' keys, then ``estimated``, ``scale``, ``angles``."""
        return {**self.errors.to_dict(), "estimated": self.estimated, "scale": self.scale, "angles": self.angles}


@dataclass(frozen=True)
class WandLevel:
    """One realism level of the benchmark (:func:`run_level`): the trial, the seconds to record
    the Vicon and write the wand wave, the Vicon's occluded share of marker-frames and the markers
    with gaps; the wand's co-registration (or why there is none: :data:`NOT_FILMABLE`) with its
    seconds, and the two cross-validations (None where the wand was not filmable). A method may
    also hold the reason it failed instead of its numbers."""

    realism: str
    preset: str
    motion: str
    frames: int
    fps: float
    size: list[int]
    cameras: int
    record_and_wand_s: float
    vicon_occluded_share: float
    vicon_markers_with_gaps: list[str]
    wand: WandRegistration | str
    coregister_s: float | None = None
    crossval_rig_vicon: CrossValRegistration | str | None = None
    crossval_markers: CrossValRegistration | str | None = None

    def method(self, name: str) -> WandRegistration | CrossValRegistration | str | None:
        """The result of the method ``name`` (a key of :data:`METHODS`)."""
        result: WandRegistration | CrossValRegistration | str | None = getattr(self, name)
        return result

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the trial and the Vicon, then ``coregister_s`` and the methods that
        ran (the order of the fields, ``coregister_s`` before ``wand``)."""
        row: dict[str, Any] = {}
        for f in fields(self):
            if f.name in ("wand", "coregister_s", "crossval_rig_vicon", "crossval_markers"):
                continue
            row[f.name] = getattr(self, f.name)
        if self.coregister_s is not None:
            row["coregister_s"] = self.coregister_s
        for name in METHODS:
            value = self.method(name)
            if value is not None:
                row[name] = value if isinstance(value, str) else value.to_dict()
        return row


@dataclass(frozen=True)
class ViconWandBenchmark:
    """Every level of ``spinemocap bench vicon-wand`` with the dots' noise (mm) and the wand
    wave's length (s)."""

    levels: list[WandLevel]
    dot_noise_mm: float
    wand_seconds: float

    def to_dict(self) -> dict[str, Any]:
        """The JSON object the benchmark writes."""
        return {"levels": [level.to_dict() for level in self.levels], "dot_noise_mm": self.dot_noise_mm,
                "wand_seconds": self.wand_seconds}


def run_level(preset: str, realism: str, frames: int, fps: float, size: tuple[int, int] | None, wand_seconds: float,
              dot_noise_mm: float, seed: int, progress: bool, motion: str = "mixed") -> WandLevel:
    """One realism level: build, record, co-register, cross-validate (see the module docstring)."""
    config = SynthConfig.preset(preset, frames=frames, fps=fps, realism=realism, seed=seed, motion=motion,
                                **({"size": size} if size else {}))
    scene = build_scene(config)
    try:
        with tempfile.TemporaryDirectory(prefix="bench_vicon_wand.") as tmp:
            setup = ViconSetup(seed=seed)
            t0 = time.perf_counter()
            vicon = write_scene_vicon(scene, tmp, setup, wand_seconds, progress)
            level = partial(WandLevel, realism=realism, preset=preset, motion=motion, frames=frames, fps=fps,
                            size=list(config.size), cameras=len(scene.rig), record_and_wand_s=time.perf_counter() - t0,
                            vicon_occluded_share=float(vicon.occluded.mean()),
                            vicon_markers_with_gaps=[lab for k, lab in enumerate(vicon.labels)
                                                     if vicon.occluded[:, k].any()])
            dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])
            truth = {"vicon_R": setup.R, "vicon_t_mm": setup.t, "vicon_clock_offset_s": setup.clock_offset_s,
                     "dots": dots}
            folder = Path(tmp) / WAND_DIR
            if not folder.exists():
                return level(wand=NOT_FILMABLE)
            frames_iter, _ = synchronized_frames([folder / name for name in scene.rig.names], len(scene.rig))
            t0 = time.perf_counter()
            reg = coregister(scene.calibrated_rig, frames_iter, scene.fps, read_vicon_wand(folder / VICON_WAND_FILE,
                                                                                          WandSpec()), progress=progress)
            coregister_s = time.perf_counter() - t0
            wand = WandRegistration(registration_errors(truth, reg.scale * reg.R, reg.t, reg.offset_s),
                                    n_frames=reg.n_frames, scale=reg.scale,
                                    residual_rms_mm=float(np.sqrt(np.mean(np.square(list(reg.residual_mm.values()))))))
            crossvals: dict[str, CrossValRegistration] = {}
            rng = np.random.default_rng([seed, 5])
            noisy = dots + rng.normal(0.0, dot_noise_mm, dots.shape)
            assert reg.rig_in_vicon is not None
            reg.rig_in_vicon.to_toml(Path(tmp) / "rig_vicon.toml")  # as calibrate wand --out writes it
            from_file = rig_transform(scene.calibrated_rig, Path(tmp) / "rig_vicon.toml")  # as crossval --rig-vicon
            levels = LevelMap.from_row_levels(scene.tape_on_skin.row_levels, scene.tape.n_rows)
            subject = scene.subject()
            for name, transform in (("crossval_rig_vicon", from_file), ("crossval_markers", None)):
                result = cross_validate(scene.times, noisy, scene.labels, scene.tape, vicon.time_s, vicon.positions,
                                        vicon.labels, setup.marker_diameter_mm, transform)
                crossval_angles(result, scene.times, noisy, scene.labels, scene.tape, levels, subject["up"],
                                subject["facing"])
                a = result.alignment
                crossvals[name] = CrossValRegistration(
                    registration_errors(truth, a.scale * a.R, a.t, a.offset_s), estimated=a.estimated, scale=a.scale,
                    angles={k: {m: v.to_dict()[m] for m in ("rmse_deg", "bias_deg", "icc", "cmc")}
                            for k, v in result.summary.angles.items()})
    finally:
        scene.close()
    return level(wand=wand, coregister_s=coregister_s, crossval_rig_vicon=crossvals["crossval_rig_vicon"],
                 crossval_markers=crossvals["crossval_markers"])


def run_benchmark(levels: list[str], preset: str, frames: int, fps: float, size: tuple[int, int] | None,
                  wand_seconds: float, dot_noise_mm: float, seed: int, out: str | Path, progress: bool = True,
                  motion: str = "mixed") -> ViconWandBenchmark:
    """Every level in ``levels``; prints a table and writes the JSON ``out``."""
    rows = [run_level(preset, level, frames, fps, size, wand_seconds, dot_noise_mm, seed, progress, motion)
            for level in levels]
    for row in rows:
        if row.vicon_markers_with_gaps:
            print(f"{row.realism}: Vicon occlusion gaps in {', '.join(row.vicon_markers_with_gaps)}")
    report = ViconWandBenchmark(levels=rows, dot_noise_mm=dot_noise_mm, wand_seconds=wand_seconds)
    with atomic_write(out) as handle:
        json.dump(report.to_dict(), handle, indent=2)
    plot = Path(out).with_suffix(".png")
    plot_errors(rows, plot)
    print(format_table(rows))
    print(f"wrote {out} and {plot}")
    return report


METHODS = {"wand": "calibrate wand", "crossval_rig_vicon": "crossval --rig-vicon", "crossval_markers": "crossval (tape markers)"}


def plot_errors(rows: list[WandLevel], path: Path) -> None:
    """Bars of the offset (ms), rotation (deg) and mean point (mm) errors per level and method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [("offset_error_ms", "|clock offset error| (ms)"), ("rotation_error_deg", "rotation error (deg)"),
            ("point_error_mean_mm", "mean point error (mm)")]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    width = 0.8 / len(METHODS)
    for ax, (key, title) in zip(axes, keys):
        for m, (method, name) in enumerate(METHODS.items()):
            values = [abs(errors[key]) if (errors := _errors(r, method)) is not None else np.nan for r in rows]
            ax.bar(np.arange(len(rows)) + (m - (len(METHODS) - 1) / 2) * width, values, width, label=name)
        ax.set_xticks(np.arange(len(rows)), [r.realism for r in rows])
        ax.set_title(title)
    axes[0].legend(fontsize=8)
    fig.suptitle("virtual Vicon: rig -> Vicon co-registration against the truth")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _errors(row: WandLevel, method: str) -> dict[str, float] | None:
    """The JSON keys of ``method``'s errors on ``row`` (None: the method has no numbers there)."""
    result = row.method(method)
    return None if result is None or isinstance(result, str) else result.errors.to_dict()


def format_table(rows: list[WandLevel]) -> str:
    """Offset / rotation / point errors of the wand and of the two cross-validations per level."""
    lines = ["level  method                    offset err ms  rot err deg  point err mean/max mm  gaps %"]
    for row in rows:
        for method in METHODS:
            r = row.method(method)
            if r is None or isinstance(r, str):
                lines.append(f"{row.realism:6s} {method:25s} {r}")
                continue
            e = r.errors
            lines.append(f"{row.realism:6s} {method:25s} {e.offset_error_ms:+13.3f}  {e.rotation_error_deg:11.4f}  "
                         f"{e.point_error_mean_mm:10.3f} / {e.point_error_max_mm:.3f}  "
                         f"{100 * row.vicon_occluded_share:6.2f}")
            if isinstance(r, CrossValRegistration) and r.angles:
                lines.append("         angles RMSE deg / ICC: " + ", ".join(
                    f"{k} {v['rmse_deg']:.2f} / {v['icc']:.3f}" for k, v in r.angles.items()))
    return "\n".join(lines)
