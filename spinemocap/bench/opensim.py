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
"""

from __future__ import annotations

import platform
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

MOTIONS = ("flexion", "lateral", "rotation", "mixed")
AXES = ("flexion", "lateral", "rotation")
GOALS = {"marker_rms_mm": 2.0, "flexion_rmse_deg": 2.0, "lateral_rmse_deg": 3.0, "rotation_rmse_deg": 3.0,
         "ik_frames_per_s": 20.0}


def run_opensim_benchmark(motions: Sequence[str] = MOTIONS, sources: Sequence[str] = ("groundtruth", "tracked"),
                          frames: int = 100, fps: float = 100 / 3, rows: int = 13, tracked_frames: int | None = None,
                          cache: Path | None = None, progress: bool = True, realism: str = "lab") -> dict:
    """Every (motion, source) pair scored (see the module docstring), the headline numbers and
    the goals; ``cache``: folder to keep and reuse the tracked markers; ``realism``: the studio's
    level (``lab``: tension, skin strain, tracking through the lab's inexact rig)."""
    from tqdm import tqdm

    from ..opensim import require_opensim

    require_opensim()
    started = time.time()
    results: dict = {source: {} for source in sources}
    jobs = [(m, s) for m in motions for s in sources]
    for motion, source in tqdm(jobs, desc="motions x sources", disable=not progress):
        n = (tracked_frames or frames) if source == "tracked" else frames
        results[source][motion] = bench_motion(motion, source, n, fps, rows, progress, cache, realism)
    return {
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "date": time.strftime("%Y-%m-%d"),
        "goals": GOALS,
        "realism": realism,
        **headline(results),
        "sources": results,
        "wall_s": round(time.time() - started, 1),
    }


def headline(results: dict) -> dict:
    """The headline keys from the first source present: each RMSE from its own single-axis motion,
    marker RMS the mean over motions; the peer's beside them."""
    source = "groundtruth" if "groundtruth" in results else next(iter(results))
    out: dict = {"headline_source": source}
    runs = results[source]
    for method in ("ik", "geometric"):
        prefix = "" if method == "ik" else "geometric_"
        for axis in AXES:
            run = runs.get({"flexion": "flexion", "lateral": "lateral", "rotation": "rotation"}[axis])
            if run:
                out[f"{prefix}{axis}_rmse_deg"] = run[method][f"{axis}_rmse_deg"]
    out["marker_rms_mm"] = float(np.mean([r["ik"]["marker_rms_mm"] for r in runs.values()]))
    out["ik_ms_per_frame"] = float(np.mean([r["ik"]["ms_per_frame"] for r in runs.values()]))
    return out


def bench_motion(motion: str, source: str, frames: int, fps: float, rows: int, progress: bool,
                 cache: Path | None = None, realism: str = "lab") -> dict:
    """One studio motion from one marker source: IK and geometric angles scored."""
    from ..analysis.angles import AngleSettings, compute_angles
    from ..analysis.levels import LevelMap
    from ..markers import MarkerTable
    from ..opensim import OpenSimSettings, run_opensim
    from .analysis import HIGH, LOW, expected_between_rows, studio_motion

    data = studio_motion(motion, frames, fps, rows, realism=realism)
    tape = data["tape"]
    if source == "tracked":
        markers = tracked_markers(data["scene"], progress, cache and cache / f"markers_{motion}_{frames}_{fps:.4g}_{realism}.csv")
    else:
        markers = MarkerTable.from_arrays(data["labels"], data["dots"], fps=fps)
    applied = data["applied"] - data["applied"][0]
    axes = [AXES.index(motion)] if motion in AXES else [0, 1, 2]
    lo, hi = data["rows"]
    truth = MarkerTable.from_arrays(data["labels"], data["dots"], fps=fps)
    expected = expected_between_rows(data["scene"], truth, lo, hi)
    levels = LevelMap.from_row_levels(data["row_levels"], tape.n_rows)
    with tempfile.TemporaryDirectory() as tmp:
        # the static trial is the neutral first frame: the studio's motions start moving at once
        result = run_opensim(markers, tape, levels, data["up"], data["facing"], Path(tmp) / "opensim",
                             settings=OpenSimSettings(static_frames=1))
        ik = ik_angles(result, lo, hi)
    completeness = markers.completeness()
    t0 = time.perf_counter()
    geometric = compute_angles(markers, tape, LevelMap({LOW: lo, HIGH: hi}, tape.n_rows), up=data["up"],
                               facing=data["facing"], settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
    geometric_ms = 1000 * (time.perf_counter() - t0) / len(geometric)
    peer = geometric[["lumbar_flexion", "lumbar_lateral", "lumbar_rotation"]].to_numpy(float)
    s = result.summary
    bodies = [result.geometry.names[result.geometry.row_body[r - 1]] for r in (lo, hi)]
    return {
        "frames": len(applied), "rows": [lo, hi], "vertebrae": bodies, "joint_share": data["share"],
        "applied_peak_deg": {a: float(np.abs(applied[:, i]).max()) for i, a in enumerate(AXES)},
        "observed_share": completeness["observed"],
        "ik": {**score(ik, expected, axes), "marker_rms_mm": s["marker_rms_mm"],
               "marker_rms_mm_max": s["marker_rms_mm_max"], "ms_per_frame": s["ms_per_frame"],
               "flagged_frames": len(s["flagged_frames"]), "driven_joints": len(s["driven_joints"]),
               "depth_scale": s["depth_scale"]["value"]},
        "geometric": {**score(peer, expected, axes), "ms_per_frame": geometric_ms},
    }


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


def score(measured: np.ndarray, expected_change: np.ndarray, axes: list[int]) -> dict:
    """RMSE, R^2 and gain of the change from frame 0 on the scored ``axes``; crosstalk (RMS, deg)
    on the others (single-axis motions)."""
    from .analysis import fit_stats

    change = measured - measured[0]
    out: dict = {}
    for i in axes:
        stats = fit_stats(change[:, i], expected_change[:, i])
        out.update({f"{AXES[i]}_{k}": v for k, v in (("rmse_deg", stats["rmse_deg"]), ("r2", stats["r2"]),
                                                     ("gain", stats["gain"]))})
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
    lines = [(f"{'source':<13}{'motion':<10}{'method':<11}{'flex RMSE':>10}{'lat RMSE':>9}{'rot RMSE':>9}"
              f"{'R2 (scored)':>12}{'xtalk':>7}{'mkr RMS mm':>11}{'ms/frame':>9}")]
    for source, runs in results.items():
        for motion, run in runs.items():
            for method in ("ik", "geometric"):
                r = run[method]
                r2 = [r[f"{a}_r2"] for a in AXES if f"{a}_r2" in r]
                cells = [f"{r.get(f'{a}_rmse_deg', float('nan')):>9.2f}" for a in AXES]
                lines.append(f"{source:<13}{motion:<10}{method:<11}{cells[0]:>10}{cells[1]:>9}{cells[2]:>9}"
                             f"{min(r2):>12.4f}{r.get('crosstalk_rms_deg', float('nan')):>7.2f}"
                             f"{r.get('marker_rms_mm', float('nan')):>11.2f}{r['ms_per_frame']:>9.1f}")
    return "\n".join(lines)
