"""Angle validation: do the tape angles follow the spine motion the synthetic studio applied?

For each single-axis motion (``flexion``, ``lateral``, ``rotation``) the studio poses anny's five
spine bones (``spine05`` at S1 ... ``spine01``), each turned by one fifth of the commanded angle
about world-aligned axes at its head (:mod:`spinemocap.synth.body`); its ``angles_deg`` is the
total, measured at ``spine01``. The tape covers only part of the spine, so the angle between two
tape levels should see only the joints between them: expected = (joints between the levels) / 5
x applied. The levels are chosen a priori where the skin moves with one bone: the tape rows
nearest the middle of the lowest and the highest bone segment the tape covers (at rest, by
height). Linear-blend skinning still spreads each joint's turn over the neighbouring skin, so
the measured gain can differ from 1 by some percent -- the benchmark reports it.

Reported per motion and angle: RMSE (deg) and R^2 of the change from the first (neutral) frame
against the expected change; for the other two angles (crosstalk) their RMS and peak in deg.
The analytic bent rod of :mod:`bent_tape` runs beside it as the peer with an exact answer: it
measures the pipeline's own error (spline, frames) without any skin.
"""

from __future__ import annotations

import time

import numpy as np

from ..analysis.angles import AngleSettings, compute_angles
from ..analysis.bent_tape import bent_tape_dots, relative_turn, smooth_bend, write_bent_capture
from ..analysis.frames import cardan_angles
from ..analysis.levels import LevelMap
from ..app.batch import run_batch
from ..markers import MarkerTable
from ..synth import SynthConfig, build_scene
from ..synth.body import SPINE_BONES
from ..tape import TapeSpec

MOTIONS = ("flexion", "lateral", "rotation")
COLUMNS = ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation")
# Placeholder names for the two benchmark levels: only their rows matter here.
LOW, HIGH = "L3", "T12/L1"


def fit_stats(measured: np.ndarray, expected: np.ndarray) -> dict[str, float]:
    """RMSE (deg), R^2 (coefficient of determination against y = x) and the fitted gain."""
    ok = np.isfinite(measured) & np.isfinite(expected)
    m, e = measured[ok], expected[ok]
    residual = m - e
    total = np.sum((e - e.mean()) ** 2)
    return {"rmse_deg": float(np.sqrt(np.mean(residual**2))),
            "r2": float(1 - np.sum(residual**2) / total) if total > 0 else float("nan"),
            "gain": float(np.dot(m, e) / np.dot(e, e)) if np.dot(e, e) > 0 else float("nan"),
            "frames": int(ok.sum())}


def _score(table, expected_change: np.ndarray, axis: int) -> dict:
    """Scores of the change from frame 0 of the lumbar angles against ``expected_change``
    (F, 3): fit statistics on the motion's ``axis``; crosstalk = the other two angles' deviation
    from their expected change (zero for the studio's single-axis motions)."""
    measured = table[list(COLUMNS)].to_numpy(float)
    change = measured - measured[0]
    out = fit_stats(change[:, axis], expected_change[:, axis])
    others = np.delete(change - expected_change, axis, axis=1)
    out["crosstalk_rms_deg"] = float(np.sqrt(np.nanmean(others**2)))
    out["crosstalk_peak_deg"] = float(np.nanmax(np.abs(others)))
    out["expected_peak_deg"] = float(np.max(np.abs(expected_change[:, axis])))
    return out


def mid_bone_rows(row_heights: np.ndarray, joint_heights: np.ndarray) -> tuple[int, int, int]:
    """(lower row, upper row, joints between them), rows 1-based: the rows nearest the middle of
    the lowest and highest bone segments whose middle lies on the tape, at rest heights (mm)."""
    mids = 0.5 * (joint_heights[:-1] + joint_heights[1:])
    on_tape = mids[(mids >= row_heights.min()) & (mids <= row_heights.max())]
    if len(on_tape) < 2:
        raise ValueError("the tape covers fewer than two bone segments' middles: use more rows")
    lo = int(np.argmin(np.abs(row_heights - on_tape[0])))
    hi = int(np.argmin(np.abs(row_heights - on_tape[-1])))
    joints = int(np.sum((joint_heights > row_heights[lo]) & (joint_heights < row_heights[hi])))
    return lo + 1, hi + 1, joints


def studio_motion(motion: str, frames: int, fps: float, rows: int, seed: int = 0) -> dict:
    """Ground-truth dots of a studio motion (no rendering), the applied angles and the levels."""

    config = SynthConfig.preset("artificial", motion=motion, frames=frames, fps=fps, rows=rows, seed=seed)
    scene = build_scene(config)
    dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])  # the studio's truth, skin strain included
    graph = scene.tape.graph
    row_z = np.array([dots[0][graph.row == r, 2].mean() for r in range(rows)])
    lo, hi, joints = mid_bone_rows(row_z, scene.body.spine_chain()[:, 2])
    return {"dots": dots, "labels": scene.labels, "tape": scene.tape, "applied": scene.angles_deg,
            "rows": (lo, hi), "share": joints / len(SPINE_BONES), "fps": fps,
            "up": scene.subject()["up"], "facing": scene.subject()["facing"]}


def bench_studio(frames: int = 60, fps: float = 20.0, rows: int = 13, seed: int = 0,
                 progress: bool = True) -> dict:
    """The three studio motions on ground-truth markers; see the module docstring."""
    from tqdm import tqdm

    results = {}
    for axis, motion in enumerate(tqdm(MOTIONS, desc="studio motions", disable=not progress)):
        data = studio_motion(motion, frames, fps, rows, seed)
        lo, hi = data["rows"]
        levels = LevelMap({LOW: lo, HIGH: hi}, rows)
        markers = MarkerTable.from_arrays(data["labels"], data["dots"], fps=fps)
        start = time.perf_counter()
        table = compute_angles(markers, data["tape"], levels, up=data["up"], facing=data["facing"],
                               settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
        elapsed = time.perf_counter() - start
        applied = data["applied"] - data["applied"][0]
        expected = np.zeros_like(applied)
        expected[:, axis] = data["share"] * applied[:, axis]
        results[motion] = {**_score(table, expected, axis), "rows": [lo, hi],
                           "joint_share": data["share"], "applied_peak_deg": float(np.abs(applied[:, axis]).max()),
                           "ms_per_frame": 1000 * elapsed / frames}
    return results


def bench_analytic(frames: int = 60, rows: int = 13) -> dict:
    """The peer with an exact answer: a lordotic rod (-0.1 deg/mm everywhere) bent by up to 50
    deg (sine over time) with a smooth profile along the whole tape, measured between rows 2 and
    9; expected = Cardan angles of the rod's exact turn between those rows."""
    tape = TapeSpec(n_rows=rows)
    levels = LevelMap({LOW: 2, HIGH: 9}, rows)
    v_lo, v_hi = tape.row_pitch_mm, 8 * tape.row_pitch_mm
    amplitude = 50.0 * np.sin(np.linspace(0, 2 * np.pi, frames))
    background = np.array([-0.1, 0.0, 0.0])
    results = {}
    for axis, motion in enumerate(MOTIONS):
        bends = [smooth_bend(0.0, tape.length_mm, np.eye(3)[axis] * a, background) for a in amplitude]
        dots = np.array([bent_tape_dots(tape, bend) for bend in bends])
        exact = cardan_angles(np.eye(3), np.array([relative_turn(b, v_lo, v_hi) for b in bends]))
        # one cycle in 3 s, as the studio's motions: the 10 Hz low-pass must leave it alone
        markers = MarkerTable.from_arrays(tape.labels, dots, fps=frames / 3.0)
        table = compute_angles(markers, tape, levels, settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
        results[motion] = _score(table, exact - exact[0], axis)
    return results


def bench_batch(trials: int = 16, frames: int = 300, workers: int = 2, progress: bool = False) -> dict:
    """Wall time of one batch (analytic-rod captures, ground-truth source) run three ways on the
    same study: in this process, on a local process pool of ``workers``, and on a Dask
    ``LocalCluster`` of ``workers`` single-threaded worker processes. Every run starts from an
    empty output folder (``force``), so all three do the same work."""
    import tempfile
    from pathlib import Path

    from distributed import LocalCluster


    tape = TapeSpec(n_rows=13)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "study"
        for k in range(trials):
            folder = root / f"S{k % 4 + 1:02d}" / ("pre" if k % 2 else "post") / f"trial{k:02d}"
            write_bent_capture(folder, tape, 20.0 + k, n_frames=frames, fps=100.0)
            (folder / "levels.toml").write_text('S1 = 1\n"T12/L1" = 7\nT9 = 13\n')
        timings = {}

        def timed(name: str, **kwargs) -> None:
            start = time.perf_counter()
            result = run_batch(root, Path(tmp) / name, source="groundtruth", force=True, progress=progress, **kwargs)
            assert not result.failed, result.failed
            timings[name] = time.perf_counter() - start

        timed("serial", workers=1)
        timed("process_pool", workers=workers)
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            timed("dask_localcluster", scheduler=cluster.scheduler_address)
    return {"trials": trials, "frames": frames, "workers": workers,
            "seconds": {k: round(v, 2) for k, v in timings.items()},
            "trials_per_s": {k: round(trials / v, 2) for k, v in timings.items()},
            "speedup_vs_serial": {k: round(timings["serial"] / v, 2) for k, v in timings.items()}}
