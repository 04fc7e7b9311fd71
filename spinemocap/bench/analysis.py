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

import dataclasses
import time
from typing import Any

import numpy as np
import pandas as pd

from ..analysis.angles import AngleSettings, compute_angles, level_frames
from ..analysis.bent_tape import bent_tape_dots, relative_turn, smooth_bend, write_bent_capture
from ..analysis.frames import cardan_angles
from ..analysis.levels import LevelMap
from ..app.batch import run_batch
from ..app.run import TrackingMode
from ..markers import MarkerTable
from ..synth import SynthConfig, build_scene
from ..synth.body import SPINE_BONES, JointDepth
from ..synth.scene import Scene
from ..tape import TapeSpec

MOTIONS = ("flexion", "lateral", "rotation")
COLUMNS = ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation")
# Placeholder names for the two benchmark levels: only their rows matter here.
LOW, HIGH = "L3", "T12/L1"


@dataclasses.dataclass(frozen=True)
class FitStats:
    """Agreement of a measured angle with the expected one (:func:`fit_stats`; NaN frames
    skipped): ``rmse_deg``, ``bias_deg`` (mean of measured - expected), the Bland-Altman 95 %
    limits of agreement ``loa_low_deg`` / ``loa_high_deg`` (bias -/+ 1.96 SD of the differences),
    ``r2`` (coefficient of determination against y = x), ``gain`` (least-squares slope through
    0), ``frames`` scored and ``valid`` (share of frames with a measured value, 0-1)."""

    rmse_deg: float
    bias_deg: float
    loa_low_deg: float
    loa_high_deg: float
    r2: float
    gain: float
    frames: int
    valid: float

    def to_dict(self) -> dict[str, float]:
        """The JSON object: the fields in order."""
        return dataclasses.asdict(self)


def fit_stats(measured: np.ndarray, expected: np.ndarray) -> FitStats:
    """Agreement of ``measured`` (F,) with ``expected`` (F,), both deg (see :class:`FitStats`)."""
    ok = np.isfinite(measured) & np.isfinite(expected)
    m, e = measured[ok], expected[ok]
    if not ok.any():
        nan = float("nan")
        return FitStats(nan, nan, nan, nan, nan, nan, frames=0, valid=0.0)
    residual = m - e
    total = np.sum((e - e.mean()) ** 2)
    bias = float(residual.mean())
    spread = 1.96 * float(residual.std(ddof=1)) if len(residual) > 1 else float("nan")
    return FitStats(rmse_deg=float(np.sqrt(np.mean(residual**2))), bias_deg=bias,
                    loa_low_deg=bias - spread, loa_high_deg=bias + spread,
                    r2=float(1 - np.sum(residual**2) / total) if total > 0 else float("nan"),
                    gain=float(np.dot(m, e) / np.dot(e, e)) if np.dot(e, e) > 0 else float("nan"),
                    frames=int(ok.sum()), valid=float(ok.mean()) if len(ok) else 0.0)


@dataclasses.dataclass(frozen=True)
class AxisAgreement:
    """The lumbar angles' change from frame 0 against the expected change (:func:`_score`): the
    agreement on the motion's own axis (:class:`FitStats`), the other two angles' deviation from
    their expected change (crosstalk RMS and peak, deg) and the expected change's peak (deg)."""

    fit: FitStats
    crosstalk_rms_deg: float
    crosstalk_peak_deg: float
    expected_peak_deg: float

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the agreement's keys, then the crosstalk and the expected peak."""
        return {**self.fit.to_dict(), "crosstalk_rms_deg": self.crosstalk_rms_deg,
                "crosstalk_peak_deg": self.crosstalk_peak_deg, "expected_peak_deg": self.expected_peak_deg}


@dataclasses.dataclass(frozen=True)
class StudioMotionAgreement:
    """One studio motion on ground-truth markers (:func:`bench_studio`): the agreement, the two
    benchmark rows (1-based), the share of the spine's joints between them, the applied motion's
    peak (deg) and the angle computation's ms per frame."""

    agreement: AxisAgreement
    rows: list[int]
    joint_share: float
    applied_peak_deg: float
    ms_per_frame: float

    def to_dict(self) -> dict[str, Any]:
        return {**self.agreement.to_dict(), "rows": self.rows, "joint_share": self.joint_share,
                "applied_peak_deg": self.applied_peak_deg, "ms_per_frame": self.ms_per_frame}


def _score(table, expected_change: np.ndarray, axis: int) -> AxisAgreement:
    """Scores of the change from frame 0 of the lumbar angles against ``expected_change``
    (F, 3): fit statistics on the motion's ``axis``; crosstalk = the other two angles' deviation
    from their expected change (zero for the studio's single-axis motions)."""
    measured = table[list(COLUMNS)].to_numpy(float)
    change = measured - measured[0]
    others = np.delete(change - expected_change, axis, axis=1)
    return AxisAgreement(fit_stats(change[:, axis], expected_change[:, axis]),
                         crosstalk_rms_deg=float(np.sqrt(np.nanmean(others**2))),
                         crosstalk_peak_deg=float(np.nanmax(np.abs(others))),
                         expected_peak_deg=float(np.max(np.abs(expected_change[:, axis]))))


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


@dataclasses.dataclass(frozen=True)
class StudioMotion:
    """A studio motion's ground truth (:func:`studio_motion`): the exact dots ``dots`` (F, D, 3)
    mm (world frame, skin strain included) with their ``labels``, the ``tape``, the applied spine
    angles ``applied`` (F, 3) deg (flexion, lateral, rotation), the benchmark's two tape ``rows``
    (1-based, low then high), the ``share`` of the spine's joints between them, the frame rate
    ``fps``, the subject's ``up`` and ``facing`` directions (world), each row's nearest vertebral
    level ``row_levels`` and the ``scene`` (to render and track it)."""

    dots: np.ndarray
    labels: list[str]
    tape: TapeSpec
    applied: np.ndarray
    rows: tuple[int, int]
    share: float
    fps: float
    up: list[float]
    facing: list[float]
    row_levels: list[str]
    scene: Scene

    @property
    def markers(self) -> MarkerTable:
        """The exact dots as a marker table."""
        return MarkerTable.from_arrays(self.labels, self.dots, fps=self.fps)

    @property
    def levels(self) -> LevelMap:
        """The rows' vertebral levels as a level map."""
        return LevelMap.from_row_levels(self.row_levels, self.tape.n_rows)


def studio_motion(motion: str, frames: int, fps: float, rows: int, seed: int = 0,
                  realism: str | None = None, joint_depth: JointDepth = "anny") -> StudioMotion:
    """Ground-truth dots of a studio ``motion`` of ``frames`` frames at ``fps`` on a ``rows``-row
    tape (no rendering; see :class:`StudioMotion`); ``realism``: the studio's level (None:
    ``SynthConfig``'s default); ``joint_depth``: where the studio's spine bends under the skin
    (:data:`spinemocap.synth.body.JointDepth`)."""

    levels = {} if realism is None else {"realism": realism}
    config = SynthConfig.preset("artificial", motion=motion, frames=frames, fps=fps, rows=rows, seed=seed,
                                joint_depth=joint_depth, **levels)
    scene = build_scene(config)
    dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])  # the studio's truth, skin strain included
    graph = scene.tape.graph
    row_z = np.array([dots[0][graph.row == r, 2].mean() for r in range(rows)])
    lo, hi, joints = mid_bone_rows(row_z, scene.body.spine_chain()[:, 2])
    return StudioMotion(dots=dots, labels=scene.labels, tape=scene.tape, applied=scene.angles_deg, rows=(lo, hi),
                        share=joints / len(SPINE_BONES), fps=fps, up=scene.subject()["up"],
                        facing=scene.subject()["facing"], row_levels=list(scene.tape_on_skin.row_levels), scene=scene)


def bench_studio(frames: int = 60, fps: float = 20.0, rows: int = 13, seed: int = 0,
                 progress: bool = True) -> dict[str, StudioMotionAgreement]:
    """The three studio motions on ground-truth markers; see the module docstring."""
    from tqdm import tqdm

    results: dict[str, StudioMotionAgreement] = {}
    for axis, motion in enumerate(tqdm(MOTIONS, desc="studio motions", disable=not progress)):
        data = studio_motion(motion, frames, fps, rows, seed)
        lo, hi = data.rows
        levels = LevelMap({LOW: lo, HIGH: hi}, rows)
        markers = MarkerTable.from_arrays(data.labels, data.dots, fps=fps)
        start = time.perf_counter()
        table = compute_angles(markers, data.tape, levels, up=data.up, facing=data.facing,
                               settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
        elapsed = time.perf_counter() - start
        applied = data.applied - data.applied[0]
        expected = np.zeros_like(applied)
        expected[:, axis] = data.share * applied[:, axis]
        results[motion] = StudioMotionAgreement(_score(table, expected, axis), rows=[lo, hi],
                                                joint_share=data.share,
                                                applied_peak_deg=float(np.abs(applied[:, axis]).max()),
                                                ms_per_frame=1000 * elapsed / frames)
    return results


def bench_analytic(frames: int = 60, rows: int = 13) -> dict[str, AxisAgreement]:
    """The peer with an exact answer: a lordotic rod (-0.1 deg/mm everywhere) bent by up to 50
    deg (sine over time) with a smooth profile along the whole tape, measured between rows 2 and
    9; expected = Cardan angles of the rod's exact turn between those rows."""
    tape = TapeSpec(n_rows=rows)
    levels = LevelMap({LOW: 2, HIGH: 9}, rows)
    v_lo, v_hi = tape.row_pitch_mm, 8 * tape.row_pitch_mm
    amplitude = 50.0 * np.sin(np.linspace(0, 2 * np.pi, frames))
    background = np.array([-0.1, 0.0, 0.0])
    results: dict[str, AxisAgreement] = {}
    for axis, motion in enumerate(MOTIONS):
        bends = [smooth_bend(0.0, tape.length_mm, np.eye(3)[axis] * a, background) for a in amplitude]
        dots = np.array([bent_tape_dots(tape, bend) for bend in bends])
        exact = cardan_angles(np.eye(3), np.array([relative_turn(b, v_lo, v_hi) for b in bends]))
        # one cycle in 3 s, as the studio's motions: the 10 Hz low-pass must leave it alone
        markers = MarkerTable.from_arrays(tape.labels, dots, fps=frames / 3.0)
        table = compute_angles(markers, tape, levels, settings=AngleSettings(lower=LOW, thoracolumbar=HIGH)).table
        results[motion] = _score(table, exact - exact[0], axis)
    return results


@dataclasses.dataclass(frozen=True)
class BatchBenchResult:
    """One study run by each engine (``serial``, ``process_pool``, ``dask_localcluster``):
    ``seconds`` wall time per engine; ``identical_results`` whether every trial's ``angles.csv`` is
    the same byte for byte on all engines."""

    trials: int
    frames: int
    workers: int
    identical_results: bool
    seconds: dict[str, float]

    @property
    def trials_per_s(self) -> dict[str, float]:
        return {engine: self.trials / s for engine, s in self.seconds.items()}

    @property
    def speedup_vs_serial(self) -> dict[str, float]:
        """Each engine's speed over the serial run's (> 1: faster)."""
        return {engine: self.seconds["serial"] / s for engine, s in self.seconds.items()}

    def to_dict(self) -> dict:
        """The numbers, JSON-ready (rates rounded to 0.01)."""
        return {**dataclasses.asdict(self),
                "trials_per_s": {k: round(v, 2) for k, v in self.trials_per_s.items()},
                "speedup_vs_serial": {k: round(v, 2) for k, v in self.speedup_vs_serial.items()}}


def bench_batch(trials: int = 16, frames: int = 300, workers: int = 2, progress: bool = False) -> BatchBenchResult:
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
        angles: dict[str, dict[str, str]] = {}

        def timed(name: str, **kwargs) -> None:
            start = time.perf_counter()
            out = Path(tmp) / name
            result = run_batch(root, out, source="groundtruth", force=True, progress=progress, **kwargs)
            assert not result.failed, result.failed
            timings[name] = time.perf_counter() - start
            angles[name] = {str(p.relative_to(out)): p.read_text() for p in sorted(out.rglob("angles.csv"))}

        timed("serial", workers=1)
        timed("process_pool", workers=workers)
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            timed("dask_localcluster", scheduler=cluster.scheduler_address)
    first = next(iter(angles.values()))
    return BatchBenchResult(trials, frames, workers,
                            identical_results=len(first) == trials and all(a == first for a in angles.values()),
                            seconds={k: round(v, 2) for k, v in timings.items()})


# ---------------------------------------------------------------------------------- the lab's angle
# Angles as labs report them (lumbar S1 -> T12/L1, thoracic T12/L1 -> the tape's top level), on
# the studio's ground-truth markers (the ceiling) and on tracked markers (rendered, detected with
# the shipped detector and tracked through the calibrated rig of the chosen realism level).
LAB_MOTIONS = ("flexion", "lateral", "rotation", "mixed")
LAB_ANGLES = ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation",
              "thoracic_flexion", "thoracic_lateral", "thoracic_rotation")
#: The motion's own axis (the other two angles are crosstalk); the mixed motion scores all three.
MOTION_AXIS = {"flexion": 0, "lateral": 1, "rotation": 2}
#: Goals for tracked markers: lumbar RMSE (deg) per single-axis motion.
TRACKED_GOALS_DEG = {"flexion": 2.0, "lateral": 3.0, "rotation": 3.0}


def skin_turn_joints(z_mm: np.ndarray | float, joint_heights: np.ndarray) -> np.ndarray:
    """How many of anny's spine joints (fractional) the skin at rest height ``z_mm`` has turned
    with: a point in the middle of bone k (1 = ``spine05``) turns with k joints (the bone's own
    rotation), between two bone middles linearly (linear-blend skinning spreads each joint's turn
    over the skin around it); clamped to 1 below the middle of ``spine05`` and to 5 above the
    middle of ``spine01`` (the neck bones do not move). ``joint_heights`` (6,): rest heights of
    the ``spine05`` ... ``spine01`` heads and the ``neck01`` head (mm)."""
    mids = 0.5 * (joint_heights[:-1] + joint_heights[1:])
    return np.interp(z_mm, mids, np.arange(1, len(mids) + 1, dtype=float))


def expected_change(applied_deg: np.ndarray, joints: dict[str, float], rest: dict[str, np.ndarray],
                    pairs: dict[str, tuple[str, str]]) -> dict[str, np.ndarray]:
    """Expected change from neutral (F, 3) of each angle group in ``pairs`` (group -> (lower
    level, upper level)) for the studio's applied angles (F, 3) deg.

    The studio turns each of its five spine bones by the same rotation D with D^5 = W, the world
    rotation of ``spine01`` (:func:`spinemocap.synth.body.rotation_from_spine_angles` of the applied
    angles); the skin at a level with ``joints[level]`` = n (see :func:`skin_turn_joints`) turns by
    D^n. The segment frame of a level at time t is that turn applied to its rest frame
    (``rest[level]`` (3, 3), measured on the ground truth's neutral first frame), and the expected
    angle is :func:`frames.cardan_angles` of the two levels' frames, minus its neutral value."""
    from scipy.spatial.transform import Rotation

    from ..synth.body import rotation_from_spine_angles

    rotvec = Rotation.from_matrix(np.array([rotation_from_spine_angles(a) for a in applied_deg])).as_rotvec()
    out = {}
    for group, (lo, hi) in pairs.items():
        turn_lo = Rotation.from_rotvec(rotvec * joints[lo] / len(SPINE_BONES)).as_matrix()
        turn_hi = Rotation.from_rotvec(rotvec * joints[hi] / len(SPINE_BONES)).as_matrix()
        absolute = cardan_angles(turn_lo @ rest[lo], turn_hi @ rest[hi])
        out[group] = absolute - cardan_angles(rest[lo], rest[hi])
    return out


def skin_expectation(scene, truth: MarkerTable, levels: LevelMap, settings: AngleSettings,
                     pairs: dict[str, tuple[str, str]]) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Expected change from neutral (F, 3) deg per angle group of ``pairs`` (group -> (lower
    level, upper level) of ``levels``) for ``scene``'s applied motion, and each level's
    :func:`skin_turn_joints` at its rest height: :func:`expected_change` with the levels' segment
    frames on the ground truth's first frame ``truth`` as rest frames."""
    names = list(dict.fromkeys(name for pair in pairs.values() for name in pair))
    rest_frames = level_frames(truth, scene.tape, levels, names, settings)
    rest = {name: rest_frames[name][0][0] for name in names}
    rows = scene.tape.n_rows
    rest_dots = truth.to_arrays().positions[0]
    row_z = np.array([np.nanmean(rest_dots[scene.tape.graph.row == r, 2]) for r in range(rows)])
    chain = scene.body.spine_chain()[:, 2]
    joints = {name: float(skin_turn_joints(np.interp(levels.row_of(name), np.arange(1, rows + 1), row_z), chain))
              for name in names}
    return expected_change(scene.angles_deg, joints, rest, pairs), joints


def expected_between_rows(scene, truth: MarkerTable, lo: int, hi: int) -> np.ndarray:
    """Expected change from the first frame (F, 3) deg of the angle between tape rows ``lo`` and
    ``hi`` (1-based): :func:`skin_expectation`, the model ``bench angles`` scores against."""
    levels = LevelMap({LOW: lo, HIGH: hi}, scene.tape.n_rows)
    expected, _ = skin_expectation(scene, truth, levels, AngleSettings(lower=LOW, thoracolumbar=HIGH),
                                   {"pair": (LOW, HIGH)})
    return expected["pair"] - expected["pair"][0]


def lab_scene(motion: str, frames: int, fps: float, rows: int, realism: str, seed: int = 0):
    """The studio scene of one benchmark motion (the ``artificial`` camera layout, 4 cameras)."""
    config = SynthConfig.preset("artificial", motion=motion, frames=frames, fps=fps, rows=rows, seed=seed,
                                realism=realism)
    return build_scene(config)


def lab_expectation(scene, markers: MarkerTable, settings: AngleSettings) -> tuple[LevelMap, dict[str, np.ndarray], dict]:
    """The level map a lab would palpate (the studio's nearest level per row), the expected
    change from neutral per angle group and the levels used: ``{"lumbar": (F, 3), "thoracic": (F, 3)}``."""
    rows = scene.tape.n_rows
    levels = LevelMap.from_row_levels([str(x) for x in scene.tape_on_skin.row_levels], rows, source="studio row levels")
    upper = settings.upper or list(levels.rows)[-1]
    pairs = {"lumbar": (settings.lower, settings.thoracolumbar), "thoracic": (settings.thoracolumbar, upper)}
    expected, joints = skin_expectation(scene, markers, levels, settings, pairs)
    return levels, expected, {"levels": {g: list(p) for g, p in pairs.items()}, "skin_turn_joints": joints}


#: The previous analysis in the same run: row centres as the plain L-R midpoints. Without ``C``
#: dots :func:`spinemocap.analysis.curve.row_tracks` has no cross-sagitta to correct them with,
#: which is exactly what it computed before the midline correction.
PEER_SOURCE = "tracked_lr_midpoints"


def without_middle_dots(table: MarkerTable) -> MarkerTable:
    """``table`` without the 3-dot rows' ``C`` dots (see :data:`PEER_SOURCE`)."""
    return table.select(labels=[label for label in table.labels if not label.endswith("C")])


def tracked_markers(scene, detector: str = "net", mode: TrackingMode = "sequence", progress: bool = True) -> MarkerTable:
    """Render every frame of ``scene``, detect with ``detector`` and track through the rig the
    lab calibrated (``scene.calibrated_rig``, the one written to ``rig.toml``)."""
    import warnings

    from ..app.run import TrackingWarning, make_detector, run_tracking
    from .track import _rendered_views

    detect = make_detector(detector)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TrackingWarning)
        result = run_tracking(_rendered_views(scene, detect, scene.n_frames), scene.calibrated_rig, scene.tape,
                              scene.fps, up=scene.subject()["up"], mode=mode, progress=progress,
                              n_frames=scene.n_frames)
    return result.table


@dataclasses.dataclass(frozen=True)
class AngleScore:
    """One angle's change from the neutral first frame against the expected change
    (:func:`score_lab_angles`): the agreement (:class:`FitStats`), the expected change's peak
    (deg) and the measured change per frame (deg, rounded to 0.001; None where not measured)."""

    fit: FitStats
    expected_peak_deg: float
    change: list[float | None]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the agreement's keys, then ``expected_peak_deg`` and ``change``."""
        return {**self.fit.to_dict(), "expected_peak_deg": self.expected_peak_deg, "change": self.change}


def score_lab_angles(table: pd.DataFrame, expected: dict[str, np.ndarray]) -> dict[str, AngleScore]:
    """Agreement (:func:`fit_stats`) of each angle's change from the first (neutral) frame with
    the expected change, per angle column of :data:`LAB_ANGLES`."""
    from ..analysis.neutral import neutral_from_angles, relative_to_neutral

    change = relative_to_neutral(table, neutral_from_angles(table, first_s=0.0))
    out: dict[str, AngleScore] = {}
    for column in LAB_ANGLES:
        group, axis = column.split("_")[0], ("flexion", "lateral", "rotation").index(column.split("_")[1])
        values = change[column].to_numpy(float)
        out[column] = AngleScore(fit_stats(values, expected[group][:, axis]),
                                 expected_peak_deg=float(np.nanmax(np.abs(expected[group][:, axis]))),
                                 change=[round(float(v), 3) if np.isfinite(v) else None for v in values])
    return out


@dataclasses.dataclass(frozen=True)
class LabTracking:
    """The tracked markers of one motion against the studio's truth: mean and 95th-percentile
    error (mm), swapped dot-frames, frames with a swap, frames without a solution, and seconds
    of rendering, detection and tracking per frame."""

    mean_error_mm: float
    p95_error_mm: float
    label_swaps: int
    frames_with_swaps: int
    frames_without_solution: int
    s_per_frame: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class LabMotionAngles:
    """One studio motion of ``bench angles`` (:func:`bench_lab_angles`): the levels of each angle
    group and the joints whose skin turn the expectation counts, the applied motion's peak per
    axis (deg), the scores per angle column on ground-truth markers and, when tracked, on the
    tracked markers and on them with the L-R midpoint row centres (the peer), the tracking's
    accuracy, the wall seconds and the expected change per angle group ((F, 3) deg as lists)."""

    levels: dict[str, list[str]]
    skin_turn_joints: dict[str, float]
    applied_peak_deg: list[float]
    groundtruth: dict[str, AngleScore]
    wall_s: float
    expected: dict[str, list[list[float]]]
    tracked: dict[str, AngleScore] | None = None
    lr_midpoints: dict[str, AngleScore] | None = None
    tracking: LabTracking | None = None

    def scores(self, source: str) -> dict[str, AngleScore] | None:
        """The scores per angle column of ``source`` ("groundtruth", "tracked" or
        :data:`PEER_SOURCE`); None when that source did not run."""
        return {"groundtruth": self.groundtruth, "tracked": self.tracked, PEER_SOURCE: self.lr_midpoints}[source]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object (the tracked sources and the tracking only when tracked)."""
        def scored(scores: dict[str, AngleScore]) -> dict[str, Any]:
            return {column: score.to_dict() for column, score in scores.items()}

        out: dict[str, Any] = {"levels": self.levels, "skin_turn_joints": self.skin_turn_joints,
                               "applied_peak_deg": self.applied_peak_deg, "groundtruth": scored(self.groundtruth)}
        if self.tracked is not None:
            out["tracked"] = scored(self.tracked)
        if self.lr_midpoints is not None:
            out[PEER_SOURCE] = scored(self.lr_midpoints)
        if self.tracking is not None:
            out["tracking"] = self.tracking.to_dict()
        return {**out, "wall_s": self.wall_s, "expected": self.expected}


def lab_angles_plot_png(results: dict[str, LabMotionAngles]) -> bytes:
    """PNG: per motion (columns) the lumbar angle on the motion's axis (all three for the mixed
    motion) over time, expected vs ground-truth vs tracked markers (top), and the Bland-Altman
    plot of the tracked markers with bias and 95 % limits of agreement (bottom)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    motions = list(results)
    fig, axes = plt.subplots(2, len(motions), figsize=(3.6 * len(motions), 5.6), squeeze=False)
    colours = {"lumbar_flexion": "tab:blue", "lumbar_lateral": "tab:orange", "lumbar_rotation": "tab:green"}
    for k, motion in enumerate(motions):
        entry, top, bottom = results[motion], axes[0, k], axes[1, k]
        columns = [LAB_ANGLES[MOTION_AXIS[motion]]] if motion in MOTION_AXIS else list(colours)
        for column in columns:
            expected = np.asarray(entry.expected["lumbar"], float)[:, LAB_ANGLES.index(column)]
            top.plot(expected, color=colours[column], lw=2.5, alpha=0.35, label=f"{column} applied")
            top.plot(_floats(entry.groundtruth[column].change), color=colours[column], ls=":", lw=1.2,
                     label="ground-truth markers")
            source = "tracked" if entry.tracked is not None else "groundtruth"
            stats = (entry.tracked or entry.groundtruth)[column]
            measured = _floats(stats.change)
            top.plot(measured, color=colours[column], lw=1.2, marker=".", ms=3, label=f"{source} markers")
            mean, diff = 0.5 * (measured + expected), measured - expected
            bottom.scatter(mean, diff, s=8, color=colours[column])
            for y, style in ((stats.fit.bias_deg, "-"), (stats.fit.loa_low_deg, "--"), (stats.fit.loa_high_deg, "--")):
                bottom.axhline(y, color=colours[column], ls=style, lw=0.8)
        top.set_title(f"{motion}: change from neutral (deg)", fontsize=9)
        top.set_xlabel("frame", fontsize=8)
        bottom.set_title(f"Bland-Altman, {'tracked' if entry.tracked is not None else 'ground-truth'} markers",
                         fontsize=9)
        bottom.set_xlabel("mean of measured and applied (deg)", fontsize=8)
        bottom.axhline(0, color="0.6", lw=0.5)
        for ax in (top, bottom):
            ax.tick_params(labelsize=7)
        if k == 0:
            bottom.set_ylabel("measured - applied (deg)", fontsize=8)
            top.legend(fontsize=6, loc="best")
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    plt.close(fig)
    return buffer.getvalue()


def _floats(values: list) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)


def bench_lab_angles(motions=LAB_MOTIONS, frames: int = 30, fps: float = 10.0, rows: int = 13,
                     realism: str = "lab", detector: str = "net", tracked: bool = True, seed: int = 0,
                     progress: bool = True, say=print) -> dict[str, LabMotionAngles]:
    """Lumbar (S1 -> T12/L1) and thoracic angles against the studio's applied motion, on
    ground-truth markers (the ceiling) and, with ``tracked``, on tracked markers; per motion the
    agreement of every angle (:func:`score_lab_angles`), the tracking accuracy (mean error,
    label swaps) and the time. See :func:`expected_change` for the expected angles."""
    from ..track.evaluate import evaluate_tracking

    settings = AngleSettings(lower="S1", thoracolumbar="T12/L1")
    results: dict[str, LabMotionAngles] = {}
    for motion in motions:
        started = time.perf_counter()
        scene = lab_scene(motion, frames, fps, rows, realism, seed)
        truth = MarkerTable.from_arrays(scene.labels, np.array([scene.frame_dots(f) for f in range(scene.n_frames)]),
                                        fps=fps)
        levels, expected, info = lab_expectation(scene, truth, settings)
        up, facing = scene.subject()["up"], scene.subject()["facing"]
        groundtruth = score_lab_angles(compute_angles(truth, scene.tape, levels, up, facing, settings).table, expected)
        tracked_scores: dict[str, AngleScore] | None = None
        lr_midpoints: dict[str, AngleScore] | None = None
        tracking: LabTracking | None = None
        if tracked:
            say(f"{motion}: rendering, detecting ({detector}) and tracking {frames} frames ...")
            t0 = time.perf_counter()
            table = tracked_markers(scene, detector, progress=progress)
            track_s = time.perf_counter() - t0
            truth_dots = {"dots": truth.to_arrays().positions, "labels": np.array(scene.labels)}
            accuracy = evaluate_tracking(table, truth_dots, scene.tape.graph.min_spacing_mm)
            tracked_scores = score_lab_angles(compute_angles(table, scene.tape, levels, up, facing, settings).table,
                                              expected)
            lr_midpoints = score_lab_angles(
                compute_angles(without_middle_dots(table), scene.tape, levels, up, facing, settings).table, expected)
            tracking = LabTracking(mean_error_mm=accuracy.mean_error_mm, p95_error_mm=accuracy.p95_error_mm,
                                   label_swaps=accuracy.label_swaps, frames_with_swaps=accuracy.frames_with_swaps,
                                   frames_without_solution=accuracy.frames_without_solution,
                                   s_per_frame=track_s / frames)
        results[motion] = LabMotionAngles(
            levels=info["levels"], skin_turn_joints=info["skin_turn_joints"],
            applied_peak_deg=np.abs(scene.angles_deg).max(axis=0).round(2).tolist(), groundtruth=groundtruth,
            wall_s=time.perf_counter() - started, expected={g: v.round(3).tolist() for g, v in expected.items()},
            tracked=tracked_scores, lr_midpoints=lr_midpoints, tracking=tracking)
        scene.close()
    return results


def headline(results: dict[str, LabMotionAngles]) -> dict[str, float]:
    """The headline JSON keys: ``tracked_<motion>_rmse_deg`` and ``groundtruth_<motion>_rmse_deg``
    (lumbar angle on the motion's own axis) for the single-axis motions present, and the peer's
    ``tracked_lr_midpoints_<motion>_rmse_deg``."""
    out = {}
    for motion, axis in MOTION_AXIS.items():
        if motion not in results:
            continue
        column = LAB_ANGLES[axis]
        for source in ("tracked", "groundtruth", PEER_SOURCE):
            scores = results[motion].scores(source)
            if scores is not None:
                out[f"{source}_{motion}_rmse_deg"] = scores[column].fit.rmse_deg
    return out
