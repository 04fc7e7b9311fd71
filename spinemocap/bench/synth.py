"""``spinemocap bench render``: render speed at the studio resolution and the occlusion table.

Two measurements:
1. render time per camera-frame of the ``studio`` preset (2448x1600, image + tape mask pass),
   the ground-truth time per frame and the CPU time of three stages that are not rendering:
   the visibility tests (:func:`spinemocap.synth.visibility.dot_visibility`), the scene's meshes
   of every camera clock (body, tape, balls, band) and one atomic PNG-sized write into a folder
   already holding thousands of files;
2. the share of dot-frames seen by 4/3/2/1/0 cameras on the ``artificial`` preset for the
   occlusion levels none/light/heavy, next to the paper's Table 2 (0, 5000, 10000 balls).
   Visibility is purely geometric, so this needs no rendering.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..fileio import InputError, atomic_write
from ..synth.scene import SynthConfig, build_scene
from .records import JsonRecord

# Paper Table 2: dot-frames of the 548-frame, 32-dot Artificial sequence seen by 4/3/2/1/0 cameras.
PAPER_TABLE2 = {
    "none": np.array([17536, 0, 0, 0, 0]),
    "light": np.array([11197, 5328, 825, 83, 103]),
    "heavy": np.array([6846, 6812, 2764, 607, 507]),
}
PAPER_BALLS = {"none": 0, "light": 5000, "heavy": 10000}


def views_histogram(visible: np.ndarray) -> np.ndarray:
    """(F, C, D) visibility -> counts of dot-frames seen by C, C-1, ..., 0 cameras."""
    n_views = visible.sum(axis=1).ravel()
    C = visible.shape[1]
    return np.array([(n_views == k).sum() for k in range(C, -1, -1)])


def visibility_table(frames: int = 548, seed: int = 0, progress: bool = True) -> dict[str, np.ndarray]:
    """Histograms of views per dot-frame on the artificial preset for each occlusion level."""
    table = {}
    for level in PAPER_TABLE2:
        scene = build_scene(SynthConfig.preset("artificial", frames=frames, occlusion=level, seed=seed))
        table[level] = views_histogram(scene.groundtruth["visible"])
    return table


def _read_png(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(path, "not a readable PNG image")
    return image


@dataclass(frozen=True)
class RenderTiming(JsonRecord):
    """One preset's render timing (:func:`time_render_paths`). Seconds are per frame (all cameras,
    images and masks written); ``*_rounds`` every round's wall-clock seconds per frame, the
    un-suffixed numbers the fastest round; ``*_cpu_s_per_frame`` CPU seconds of the process (all
    threads); ``speedup``: reference / current wall-clock seconds; ``image_*_abs_diff``: grey
    levels between the two renderers' images; ``clocks``: distinct camera clocks whose meshes were
    posed; ``load_average``: the 1-minute load before and after each round (None where the OS does
    not say)."""

    preset: str
    realism: str
    occlusion: str
    balls: int
    cameras: int
    size: list[int]
    frames: int
    rounds: int
    setup_s: float
    reference_s_per_frame: float
    fast_s_per_frame: float
    speedup: float
    reference_s_per_frame_rounds: list[float]
    fast_s_per_frame_rounds: list[float]
    reference_cpu_s_per_frame: float
    fast_cpu_s_per_frame: float
    image_max_abs_diff: int
    image_mean_abs_diff: float
    masks_identical: bool
    groundtruth_s_per_frame: float
    groundtruth_cpu_s_per_frame: float
    visibility_cpu_s_per_frame: float
    meshes_cpu_s_per_frame: float
    clocks: int
    load_average: list[float | None]


@dataclass(frozen=True)
class AtomicWrites(JsonRecord):
    """CPU milliseconds per atomic write of ``bytes`` bytes into one folder of ``files`` files: the
    mean over the first 100 writes and over the last 100 (:func:`time_atomic_writes`)."""

    files: int
    bytes: int
    first_100_cpu_ms: float
    last_100_cpu_ms: float


@dataclass(frozen=True)
class VisibilityRow(JsonRecord):
    """One occlusion level of the visibility table: dot-frames seen by 4/3/2/1/0 cameras
    (``counts``), their shares and the paper's (%), and the largest share difference (points)."""

    level: str
    counts: list[int]
    share_percent: list[float]
    paper_share_percent: list[float]
    max_abs_diff_points: float


@dataclass(frozen=True)
class RenderBenchmark(JsonRecord):
    """``spinemocap bench render``'s numbers (``render_benchmark.json``): the machine, each preset's
    timing, the atomic writes and the visibility table (empty when ``visibility_frames`` is 0)."""

    machine: str
    cpus: int | None
    timing: list[RenderTiming]
    atomic_writes: AtomicWrites
    visibility_frames: int
    visibility: list[VisibilityRow]


def time_render_paths(preset: str, frames: int = 3, realism: str = "lab", rounds: int = 2,
                      workdir: Path | None = None, occlusion: str = "none") -> RenderTiming:
    """Seconds per frame to render ``frames`` frames of a preset and write them as a capture does
    (images and tape masks as PNG), for the reference renderer (the reference path:
    one thread, files written one after the other) and the current one, in the same process on
    the same scene. The two alternate ``rounds`` times (reference first) so both see the same
    machine load; the fastest round of each counts, in wall-clock and in CPU seconds of the
    process (all threads: VTK's rasteriser and the workers; what survives a shared machine's
    load best). Also: the pixel differences between the two
    captures' files (max and mean absolute grey-level difference, masks identical or not) and
    the ground-truth time per frame (ray-cast visibility, no rendering)."""
    import tempfile

    from ..capture import Capture
    from ..synth.writer import render_frames

    scene = build_scene(SynthConfig.preset(preset, frames=frames + 1, realism=realism, occlusion=occlusion))
    with tempfile.TemporaryDirectory(prefix="bench-render-", dir=workdir) as tmp:
        roots = {"reference": Path(tmp) / "reference", "fast": Path(tmp) / "fast"}
        captures = {k: Capture(root=r, name=k, fps=scene.fps, n_frames=scene.n_frames, rig=scene.rig, tape=scene.tape)
                    for k, r in roots.items()}
        t0 = time.perf_counter()
        for kind in roots:  # warm-up: plotters, lens maps, mask windows, worker threads
            render_frames(scene, roots[kind], captures[kind], [0], reference=kind == "reference")
        setup = time.perf_counter() - t0
        timed = range(1, frames + 1)
        seconds: dict[str, list[float]] = {"reference": [], "fast": []}
        cpu_seconds: dict[str, list[float]] = {"reference": [], "fast": []}
        loads = [_load_average()]
        for _ in range(rounds):
            for kind in ("reference", "fast"):
                t0, c0 = time.perf_counter(), time.process_time()
                render_frames(scene, roots[kind], captures[kind], timed, reference=kind == "reference")
                seconds[kind].append((time.perf_counter() - t0) / frames)
                cpu_seconds[kind].append((time.process_time() - c0) / frames)
                loads.append(_load_average())
        diffs, masks_equal = [], True
        for path in sorted(roots["fast"].rglob("*.png")):  # every file both paths wrote
            written = _read_png(path).astype(np.int16)
            other = _read_png(roots["reference"] / path.relative_to(roots["fast"]))
            diff = np.abs(written - other.astype(np.int16))
            if "masks" in path.parts:
                masks_equal &= not diff.any()
            else:
                diffs.append((int(diff.max()), float(diff.mean())))
    t0, c0 = time.perf_counter(), time.process_time()
    with _visibility_cpu_time() as visibility_cpu:
        for frame in timed:
            scene.frame_groundtruth(frame)
    gt_per_frame, gt_cpu_per_frame = (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames
    c0 = time.process_time()
    for frame in timed:
        for offset in np.unique(scene.sync_offsets_s):
            scene.meshes(frame, offset_s=float(offset))
    meshes_cpu_per_frame = (time.process_time() - c0) / frames
    scene.close()
    reference_s, fast_s = min(seconds["reference"]), min(seconds["fast"])
    return RenderTiming(
        preset=preset, realism=realism, occlusion=occlusion, balls=scene.config.n_balls, cameras=len(scene.rig),
        size=list(scene.rig[0].size), frames=frames, rounds=rounds, setup_s=setup,
        reference_s_per_frame=reference_s, fast_s_per_frame=fast_s, speedup=reference_s / fast_s,
        reference_s_per_frame_rounds=seconds["reference"], fast_s_per_frame_rounds=seconds["fast"],
        reference_cpu_s_per_frame=min(cpu_seconds["reference"]), fast_cpu_s_per_frame=min(cpu_seconds["fast"]),
        image_max_abs_diff=max(d for d, _ in diffs), image_mean_abs_diff=float(np.mean([m for _, m in diffs])),
        masks_identical=bool(masks_equal), groundtruth_s_per_frame=gt_per_frame,
        groundtruth_cpu_s_per_frame=gt_cpu_per_frame, visibility_cpu_s_per_frame=visibility_cpu[0] / frames,
        meshes_cpu_s_per_frame=meshes_cpu_per_frame, clocks=int(len(np.unique(scene.sync_offsets_s))),
        load_average=loads)


@contextlib.contextmanager
def _visibility_cpu_time() -> Iterator[list[float]]:
    """CPU seconds spent on the studio's visibility while the block runs (``[seconds]``, filled
    in as it goes): building the ray caster of each posed mesh and ``dot_visibility`` (the scene
    module's two names are wrapped for the block)."""
    from ..synth import scene as scene_module

    spent = [0.0]
    originals = {name: getattr(scene_module, name) for name in ("MeshRayCaster", "dot_visibility")}

    def timing(inner):
        def timed(*args, **kwargs):
            c0 = time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[0] += time.process_time() - c0
        return timed

    for name, inner in originals.items():
        setattr(scene_module, name, timing(inner))
    try:
        yield spent
    finally:
        for name, inner in originals.items():
            setattr(scene_module, name, inner)


def time_atomic_writes(folder: Path, files: int = 3000, size: int = 200_000) -> AtomicWrites:
    """CPU milliseconds per :func:`spinemocap.fileio.atomic_write` of ``size`` bytes (a PNG's
    order) into one folder: the first 100 writes and the last 100 of ``files`` (does writing slow
    down as the folder fills?)."""
    folder.mkdir(parents=True, exist_ok=True)
    payload = os.urandom(size)
    cpu_ms = []
    for i in range(files):
        c0 = time.process_time()
        with atomic_write(folder / f"{i:06d}.png", "wb") as handle:
            handle.write(payload)
        cpu_ms.append((time.process_time() - c0) * 1000)
    return AtomicWrites(files=files, bytes=size, first_100_cpu_ms=float(np.mean(cpu_ms[:100])),
                        last_100_cpu_ms=float(np.mean(cpu_ms[-100:])))


def _load_average() -> float | None:
    """The machine's 1-minute load average (None where the OS does not say)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def plot_table(table: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4), sharey=True)
    x = np.arange(5)
    for ax, level in zip(axes, table):
        ours = table[level] / table[level].sum() * 100
        paper = PAPER_TABLE2[level] / PAPER_TABLE2[level].sum() * 100
        ax.bar(x - 0.2, paper, 0.4, label="paper Table 2")
        ax.bar(x + 0.2, ours, 0.4, label="synthetic studio")
        ax.set_xticks(x, ["4", "3", "2", "1", "0"])
        ax.set_xlabel("cameras seeing the dot")
        ax.set_title(f"{level} ({PAPER_BALLS[level]} balls)")
    axes[0].set_ylabel("% of dot-frames")
    axes[0].legend()
    fig.tight_layout()
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)


def run_render_benchmark(frames: int, visibility_frames: int, out: Path, presets=("artificial", "studio"),
                         realism: str = "lab", rounds: int = 2, occlusion: str = "none") -> RenderBenchmark:
    """``spinemocap bench render``: render speed per preset against the reference renderer, and the
    visibility table (skipped with ``visibility_frames`` 0)."""
    out.mkdir(parents=True, exist_ok=True)
    timings = []
    for preset in presets:
        print(f"timing {preset} renders at the {realism} level, occlusion {occlusion} ({frames} frames, images + "
              f"masks written as PNG; "
              f"the reference renderer and this one alternating, {rounds} rounds) ...")
        timing = time_render_paths(preset, frames, realism, rounds, workdir=out, occlusion=occlusion)
        timings.append(timing)
        print(f"  {timing.cameras} cameras {timing.size[0]}x{timing.size[1]}: reference renderer "
              f"{timing.reference_s_per_frame:.2f} s/frame ({timing.reference_cpu_s_per_frame:.2f} CPU s), "
              f"this one {timing.fast_s_per_frame:.2f} s/frame ({timing.fast_cpu_s_per_frame:.2f} CPU s): "
              f"{timing.speedup:.2f}x; images differ by max {timing.image_max_abs_diff} / mean "
              f"{timing.image_mean_abs_diff:.1e} grey levels, masks "
              f"{'identical' if timing.masks_identical else 'DIFFER'}; ground truth "
              f"{timing.groundtruth_s_per_frame * 1000:.0f} ms/frame "
              f"({timing.groundtruth_cpu_s_per_frame * 1000:.0f} CPU ms, visibility "
              f"{timing.visibility_cpu_s_per_frame * 1000:.0f}); meshes of {timing.clocks} clocks "
              f"{timing.meshes_cpu_s_per_frame * 1000:.0f} CPU ms/frame; load {timing.load_average}")
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bench-writes-", dir=out) as tmp:
        writes = time_atomic_writes(Path(tmp))
    print(f"atomic writes into one folder of {writes.files} files: {writes.first_100_cpu_ms:.2f} CPU ms per "
          f"write (first 100), {writes.last_100_cpu_ms:.2f} (last 100)")
    rows: list[VisibilityRow] = []
    if visibility_frames > 0:
        print(f"visibility table on the artificial preset ({visibility_frames} frames) ...")
        table = visibility_table(visibility_frames)
        rows = _print_visibility_table(table)
        plot_table(table, out / "visibility_table.png")
    result = RenderBenchmark(machine=f"{platform.machine()} {platform.processor()}".strip(), cpus=os.cpu_count(),
                             timing=timings, atomic_writes=writes, visibility_frames=visibility_frames, visibility=rows)
    with atomic_write(out / "render_benchmark.json", "w") as handle:
        json.dump(result.to_dict(), handle, indent=2)
    print(f"wrote {out / 'render_benchmark.json'}" + (f" and {out / 'visibility_table.png'}" if rows else ""))
    return result


def _print_visibility_table(table: dict[str, np.ndarray]) -> list[VisibilityRow]:
    rows = []
    print(f"  {'level':<6} {'balls':>6} | " + " ".join(f"{k} cams".rjust(15) for k in (4, 3, 2, 1, 0)))
    for level, counts in table.items():
        share = counts / counts.sum() * 100
        paper = PAPER_TABLE2[level] / PAPER_TABLE2[level].sum() * 100
        cells = " ".join(f"{s:5.1f}% ({p:4.1f}%)".rjust(15) for s, p in zip(share, paper))
        print(f"  {level:<6} {PAPER_BALLS[level]:>6} | {cells}")
        rows.append(VisibilityRow(level=level, counts=counts.tolist(), share_percent=share.round(2).tolist(),
                                  paper_share_percent=paper.round(2).tolist(),
                                  max_abs_diff_points=float(np.abs(share - paper).max())))
    print("  (paper's Table 2 shares in brackets)")
    return rows


# ---------------------------------------------------------------------- realism envelope
ENVELOPE_MOTIONS = ("flexion", "mixed", "lateral", "rotation", "forehand")


@dataclass(frozen=True)
class EnvelopeRow(JsonRecord):
    """What the tape goes through at one realism ``level`` and ``motion`` (:func:`realism_envelope`):
    the peak spine angles (deg, per axis), stretch against the roll's spec (1 = spec) between
    consecutive rows, over the whole tape and across it (min and max over frames), the
    modified-Schober growth of the lowest 150 mm (mm), the lab's calibration error (px RMS) and
    sync error (ms RMS), and the whole-tape stretch per frame."""

    level: str
    motion: str
    rows: int
    peak_angles_deg: list[float]
    row_stretch_min: float
    row_stretch_max: float
    tape_stretch_min: float
    tape_stretch_max: float
    width_stretch_min: float
    width_stretch_max: float
    schober_growth_mm: float
    calibration_rms_px: float
    sync_rms_ms: float
    tape_stretch_series: list[float]


@dataclass(frozen=True)
class StudioEnvelope(JsonRecord):
    """``spinemocap bench studio``'s numbers (``studio_envelope.json``): the machine, the frames
    and frame rate of each motion, the wall-clock seconds and one row per level and motion."""

    machine: str
    frames: int
    fps: float
    wall_s: float
    rows: list[EnvelopeRow]


def realism_envelope(levels=("ideal", "skin", "lab"), motions=ENVELOPE_MOTIONS, frames: int = 60,
                     fps: float = 20.0, seed: int = 0, progress: bool = True) -> list[EnvelopeRow]:
    """What the tape on the ``artificial`` preset goes through at each realism level and motion:
    the stretch against the roll's spec between consecutive rows (``row_stretch``), over the
    whole tape and across it, the modified-Schober growth of the lowest 150 mm, and the lab's
    calibration and sync errors. Ground truth only (no rendering). ``ideal`` (no skin strain, exact set-up) is
    the peer the others are compared with."""
    from tqdm import tqdm

    rows = []
    for level, motion in tqdm([(lv, m) for lv in levels for m in motions], desc="studio envelope",
                              disable=not progress):
        scene = build_scene(SynthConfig.preset("artificial", frames=frames, fps=fps, motion=motion, realism=level,
                                               seed=seed))
        layout = scene.layout_truth(np.stack([scene.frame_dots(f) for f in range(scene.n_frames)]))
        spacing, pitch = layout["row_spacing_mm"], scene.tape.row_pitch_mm
        whole = spacing.sum(axis=1) / (spacing.shape[1] * pitch)
        lumbar = spacing[:, :6].sum(axis=1)  # the six lowest gaps from S1: 150 mm of spec
        rows.append(EnvelopeRow(
            level=level, motion=motion, rows=scene.tape.n_rows,
            peak_angles_deg=np.abs(scene.angles_deg).max(axis=0).round(1).tolist(),
            row_stretch_min=float(layout["row_stretch"].min()), row_stretch_max=float(layout["row_stretch"].max()),
            tape_stretch_min=float(whole.min()), tape_stretch_max=float(whole.max()),
            width_stretch_min=float(layout["width_stretch"].min()),
            width_stretch_max=float(layout["width_stretch"].max()),
            schober_growth_mm=float(lumbar.max() - lumbar[0]),
            calibration_rms_px=float(scene.calibration_rms_px.mean()),
            sync_rms_ms=float(np.sqrt(np.mean(scene.sync_offsets_s**2)) * 1000),
            tape_stretch_series=whole.round(4).tolist(),
        ))
        scene.close()
    return rows


def plot_envelope(rows: list[EnvelopeRow], fps: float, path: Path) -> None:
    """Whole-tape stretch against the spec over time, one panel per motion, one line per level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    motions = list(dict.fromkeys(r.motion for r in rows))
    fig, axes = plt.subplots(1, len(motions), figsize=(3.2 * len(motions), 3.2), sharey=True)
    for ax, motion in zip(np.atleast_1d(axes), motions):
        for r in (r for r in rows if r.motion == motion):
            series = np.asarray(r.tape_stretch_series)
            ax.plot(np.arange(len(series)) / fps, 100 * (series - 1), label=r.level)
        ax.set_title(motion)
        ax.set_xlabel("time (s)")
        ax.axhline(0, color="grey", lw=0.5)
    np.atleast_1d(axes)[0].set_ylabel("tape length vs spec (%)")
    np.atleast_1d(axes)[0].legend()
    fig.tight_layout()
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)


def run_studio_benchmark(frames: int, fps: float, out: Path, progress: bool = True) -> StudioEnvelope:
    """``spinemocap bench studio``: the realism envelope table, JSON and plot."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = realism_envelope(frames=frames, fps=fps, progress=progress)
    print(f"{'level':<6} {'motion':<9} {'row stretch':>14} {'tape stretch':>14} {'width':>13} "
          f"{'Schober mm':>10} {'calib px':>8} {'sync ms':>7}")
    for r in rows:
        print(f"{r.level:<6} {r.motion:<9} {r.row_stretch_min:6.3f}..{r.row_stretch_max:5.3f} "
              f"{r.tape_stretch_min:6.3f}..{r.tape_stretch_max:5.3f} {r.width_stretch_min:5.3f}.."
              f"{r.width_stretch_max:5.3f} {r.schober_growth_mm:10.1f} {r.calibration_rms_px:8.2f} "
              f"{r.sync_rms_ms:7.2f}")
    plot_envelope(rows, fps, out / "studio_envelope.png")
    result = StudioEnvelope(machine=f"{platform.machine()} {platform.processor()}".strip(), frames=frames, fps=fps,
                            wall_s=time.perf_counter() - t0, rows=rows)
    with atomic_write(out / "studio_envelope.json", "w") as handle:
        json.dump(result.to_dict(), handle, indent=2)
    print(f"wrote {out / 'studio_envelope.json'} and {out / 'studio_envelope.png'}")
    return result
