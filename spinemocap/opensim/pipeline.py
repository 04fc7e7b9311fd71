"""Tape markers -> spine model -> MarkerPlacer -> inverse kinematics -> spine angles, in one call.

:func:`run_opensim` writes into ``out_dir`` (every file built in a temporary sibling folder and
renamed into place at the end):

- ``model_generic.osim``: the model as built from the static trial (anatomical marker places),
- ``model.osim``: after MarkerPlacer (markers moved onto the static trial),
- ``markers_opensim.trc`` / ``markers_static.trc``: metres, OpenSim axes (X facing, Y up),
- ``setup_scale.xml``, ``setup_ik.xml``, ``static_pose.mot`` (radians), ``ik.mot`` (degrees; skin
  slips in metres), ``ik_marker_errors.sto`` (metres), ``skin_slip_goals.sto`` (the slip
  coordinates' value per frame, metres, held or a goal: the coordinate file of ``setup_ik.xml``),
- ``spine_angles.csv``: per driven joint and summed per region, degrees, this project's signs
  (flexion = forward bending positive = -OpenSim extension; lateral bending toward the right
  positive; axial rotation toward the left positive), zero = the static posture,
- ``summary.json`` (:class:`~spinemocap.opensim.summary.SpineModelSummary`) and ``spine_angles.png``.

Steps: the static trial (first frames, or a separate trial) fixes the tape's rows; the declared
facing is checked against the tape (:func:`geometry.check_facing`); the joint centres sit at the
published skin-to-vertebral-body depths (:mod:`spinemocap.anatomy`) scaled to the subject by the tape, times
``settings.depth_scale`` (a measured depth, e.g. from imaging or a body model, enters there and is
named by ``settings.depth_source``); every row's in-plane tilt is kept at its static angle and the
rows above the pinned ones slip along their vertebrae, each slip held in every frame at the one the
tape's lengthening shows there where its dots are measured (or, see :func:`slip_solved_as`, pulled
toward it, or solved from the markers; :mod:`skin_model`); the model is built
(:mod:`model`), MarkerPlacer moves its markers onto the static trial (slips held at 0) and the
placement is checked against the anatomy (:func:`check_placement`); OpenSim's IK solver runs frame
by frame (:func:`tools.solve_ik`: per-sample marker weights from the label confidence, inferred
dots down-weighted as far less certain (:func:`tools.marker_weights`), each frame solved from the
previous one's solution and from the static pose, the static start's kept unless its objective is
more than ``1 + settings.fresh_start_margin`` times the other's, joints clamped to
their published ranges); a short run of frames whose markers IK cannot fit (a row labelled a
column off) is solved again with a prior toward the posture of the frames around it
(:func:`toward_neighbours`) and flagged so. Missing
samples stay NaN (skipped per frame); frames the result cannot vouch for are flagged in the CSV,
the summary and the plot.

Paths: ``out_dir`` may be relative (to the working directory) or hold spaces, and the inputs may
be read-only: every file is built in an absolute temporary folder beside ``out_dir``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..fileio import InputError, atomic_write, strict_json
from ..markers import MISSING, OBSERVED, MarkerTable
from ..tape import TapeSpec
from .geometry import (
    LevelRows,
    RowFrames,
    SpineGeometry,
    check_facing,
    expected_marker_locations,
    opensim_axes,
    row_frames,
    spine_geometry,
    static_positions,
    to_opensim,
)
from .model import DOF, RANGE_FACTOR, ModelPlan, annotate_slips, body_name, build_model, plan_model
from .skin_model import (
    SlipFromTape,
    SlipPrior,
    geometric_slips,
    normalise_row_tilt,
    prior_text,
    slip_coordinate,
    slip_rows,
)
from .summary import Depth, OpenSimSummary, Placement, SkinModelSummary, SlipSummary, SpineModelSummary
from .tools import (
    IK_ACCURACY,
    INFERRED_SD_MM,
    OBSERVED_SD_MM,
    START_ACCURACY,
    CoordinateGoal,
    IKSolution,
    marker_locations,
    marker_weights,
    mean_weights,
    quiet_opensim,
    read_storage,
    require_opensim,
    run_scale,
    solve_ik,
    write_coordinate_goals,
    write_ik_outputs,
    write_ik_setup,
    write_scale_setup,
    write_trc,
)

# A placed marker may sit this far (median over markers, mm) from its anatomical place before the
# placement is refused: beside the spine (lateral) or in front of / behind it (depth).
PLACEMENT_LATERAL_MM = 15.0
PLACEMENT_DEPTH_MM = 30.0
# Frames flagged in the outputs: marker RMS or worst marker beyond these (mm), too few markers,
# or a joint at its clamped range (within LIMIT_MARGIN_DEG of RANGE_FACTOR x its published range).
FLAG_RMS_MM = 4.0
FLAG_MAX_MM = 10.0
FLAG_MIN_MARKERS = 6
LIMIT_MARGIN_DEG = 0.05
# the longest run of frames whose markers IK cannot fit that is solved again toward the frames around it
SHORT_DOUBTFUL_RUN = 2
SLIP_GOALS = "skin_slip_goals.sto"  # the slip coordinates' goal per frame (m), setup_ik.xml's coordinate file
PUBLISHED_DEPTHS = "published skin-to-vertebral-body depths (spinemocap/anatomy.py) scaled to the tape"
SIGN = {"extension": -1.0, "lateral_bending": 1.0, "axial_rotation": 1.0}  # OpenSim -> project
PROJECT_NAME = {"extension": "flexion", "lateral_bending": "lateral", "axial_rotation": "rotation"}
# IK accuracy and fresh-start margin (OpenSimSettings) per use of the slip the tape shows. The solver
# stops on absolute tests (tools.IK_ACCURACY) on an objective of ~1e-9..1e-7 m^2, so along directions
# the markers hardly see it stops where its path takes it: with the slips held (the solve is the
# spine's rotations only) a world turned about the vertical, or a facing declared 30 deg off, moved
# the studio's angles by up to 0.3 / 0.8 deg at 1e-6 and 0.12 deg at 1e-7 (~4x the time). A goal
# around the slip needs 1e-6 to read a trunk twist, and a margin against choosing along the
# slip-against-flexion valley.
SLIP_SOLVER: dict[SlipFromTape, tuple[float, float]] = {"held": (1e-7, 1.0), "goal": (1e-6, 1.0),
                                                       "off": (IK_ACCURACY, 0.0)}


@dataclass(frozen=True)
class OpenSimSettings:
    """``static_frames``: frames from the start averaged as the static trial (when no static file);
    ``accuracy``: IK solver accuracy (:data:`tools.IK_ACCURACY`; frames where a slipping row has
    no slip estimate are solved to at most :data:`tools.START_ACCURACY`); ``depth_scale``: factor on the
    published skin-to-vertebral-body depths (1 = the published adult values, scaled to the
    subject's column length by the tape), ``depth_source``: where that depth comes from (written
    to ``summary.json``); ``coupling``: see :func:`spinemocap.opensim.model.plan_model`;
    ``prior_weight``: the prior on per-level lateral bending and axial rotation (:func:`_priors`);
    ``normalise_tilt``: keep each row's in-plane tilt at its static angle
    (:func:`skin_model.normalise_row_tilt`); ``slip``: the rows' slip and its prior
    (:class:`skin_model.SlipPrior`), None = every marker fixed to its vertebra;
    ``restart_from_static``: every frame solved from the previous solution and from the static
    pose, the static start's kept unless its objective exceeds ``1 + fresh_start_margin`` times the
    other's (:func:`tools.solve_ik`); ``doubtful_prior_deg``: a frame whose markers IK cannot fit
    in a short run (:func:`short_doubtful_runs`) is solved again with a prior of this SD toward
    the posture of the frames around it (:func:`toward_neighbours`; 0 = off)."""

    static_frames: int = 10
    accuracy: float = SLIP_SOLVER["held"][0]
    depth_scale: float = 1.0
    depth_source: str = PUBLISHED_DEPTHS
    coupling: str = "rows"  # see spinemocap.opensim.model.plan_model
    # IK weight (per rad^2, beside marker errors in m^2 summed by weight) of a prior toward the static posture on every
    # level's lateral bending and axial rotation; 0 = off
    prior_weight: float = 0.0
    normalise_tilt: bool = True
    slip: SlipPrior | None = SlipPrior()
    # every frame also solved from the static pose, kept unless far worse (see tools.solve_ik)
    restart_from_static: bool = True
    # position SD (mm) of an inferred dot against an observed one's 1 mm (tools.marker_weights)
    inferred_sd_mm: float = INFERRED_SD_MM
    # the static start's solution kept unless its objective exceeds (1 + this) x the previous start's
    fresh_start_margin: float = SLIP_SOLVER["held"][1]
    # SD (deg) of the prior toward the neighbouring frames' posture on a frame whose markers IK
    # cannot fit (:func:`doubtful_frames`), solved again with it; 0 = off. A level's posture
    # changes by a few tenths of a degree between frames at 12 frames/s and more
    doubtful_prior_deg: float = 0.5


def slip_solved_as(from_tape: SlipFromTape, settings: OpenSimSettings = OpenSimSettings()) -> OpenSimSettings:
    """``settings`` with the slips using the slip the tape shows as ``from_tape`` says
    (:data:`skin_model.SlipFromTape`), with the IK accuracy and start margin of :data:`SLIP_SOLVER`."""
    accuracy, margin = SLIP_SOLVER[from_tape]
    return replace(settings, slip=replace(settings.slip or SlipPrior(), from_tape=from_tape), accuracy=accuracy,
                   fresh_start_margin=margin)


SummaryT = TypeVar("SummaryT", bound=OpenSimSummary)


@dataclass
class OpenSimResult(Generic[SummaryT]):
    """What a run wrote into ``out_dir``: the angle table, the summary (``summary.json``: a
    :class:`~spinemocap.opensim.summary.SpineModelSummary` from :func:`run_opensim`, a
    :class:`~spinemocap.opensim.summary.LabModelSummary` from a lab's model), the model plan, the
    spine geometry and the files by name."""

    out_dir: Path
    angles: pd.DataFrame
    summary: SummaryT
    plan: ModelPlan | None  # None on a lab's own model
    geometry: SpineGeometry
    files: dict[str, Path] = field(default_factory=dict)


@dataclass
class TapeMarkers:
    """The tape's dots in tape order, OpenSim axes (mm): positions (F, D, 3), status (F, D),
    label confidence (F, D; NaN = unknown)."""

    labels: list[str]
    times: np.ndarray
    positions: np.ndarray
    status: np.ndarray
    fps: float
    confidence: np.ndarray

    def weights(self, inferred_sd_mm: float = INFERRED_SD_MM) -> np.ndarray:
        """(F, D) IK weight of every sample (:func:`tools.marker_weights`)."""
        return marker_weights(self.status, self.confidence, inferred_sd_mm)


def tape_markers(markers: MarkerTable, tape: TapeSpec, axes: np.ndarray, source: str | None = None) -> TapeMarkers:
    """The tape's labels from a marker table (absent labels are missing throughout), rotated into
    OpenSim axes; missing samples are NaN, never zero."""
    arrays = markers.to_arrays()
    present = {str(label): i for i, label in enumerate(arrays.labels)}
    labels = list(tape.labels)
    if not any(label in present for label in labels):
        raise InputError(source, f"no tape labels ({labels[0]}, {labels[1]}, ...) in this marker data")
    F = len(arrays.frames)
    positions = np.full((F, len(labels), 3), np.nan)
    status = np.full((F, len(labels)), MISSING, dtype=object)
    confidence = np.full((F, len(labels)), np.nan)
    for d, label in enumerate(labels):
        if label in present:
            positions[:, d] = arrays.positions[:, present[label]]
            status[:, d] = arrays.status[:, present[label]]
            confidence[:, d] = arrays.confidence[:, present[label]]
    positions[status == MISSING] = np.nan
    status[~np.isfinite(positions).all(axis=2)] = MISSING
    times = arrays.time
    fps = float(markers.fps)
    if not np.isfinite(times).all():
        times = arrays.frames / fps
    return TapeMarkers(labels, np.asarray(times, float), to_opensim(positions, axes), status, fps, confidence)


@dataclass
class StaticTrial:
    """The static trial: median positions (D, 3) mm, its markers for the TRC and time range."""

    positions: np.ndarray
    markers: TapeMarkers
    time_range: tuple[float, float]


def _static(data: TapeMarkers, static: MarkerTable | None, tape: TapeSpec, axes: np.ndarray,
            settings: OpenSimSettings, source: str | None) -> StaticTrial:
    if static is not None:
        st = tape_markers(static, tape, axes, source)
    else:
        n = max(1, min(settings.static_frames, len(data.times)))
        st = TapeMarkers(data.labels, data.times[:n], data.positions[:n], data.status[:n], data.fps,
                         data.confidence[:n])
    return StaticTrial(static_positions(st.positions), st, (float(st.times[0]), float(st.times[-1])))


@dataclass
class _Placed:
    geometry: SpineGeometry
    plan: ModelPlan
    labels: list[str]
    placed: np.ndarray  # tape dot indices in the model
    expected: np.ndarray  # (len(placed), 3) anatomical places, mm
    placement: Placement
    slipping: list[int]  # tape rows (0-based) with a slip coordinate
    marker_rows: np.ndarray  # tape row (0-based) of each placed marker


def _build_and_place(work: Path, rows: RowFrames, levels: LevelRows, tape: TapeSpec, static: StaticTrial,
                     settings: OpenSimSettings, source: str | None) -> _Placed:
    """Build ``model_generic.osim`` in ``work`` and run MarkerPlacer (``setup_scale.xml``) to
    ``model.osim`` (slips locked at 0 while the markers are placed, free after); the placement is
    checked against the anatomy."""
    geometry = spine_geometry(rows, levels, settings.depth_scale, source)
    graph = tape.graph
    placed = np.flatnonzero(np.isfinite(static.positions).all(axis=1))
    bodies = geometry.row_body[graph.row]
    expected = expected_marker_locations(geometry, rows, tape)
    row_bodies = geometry.row_body[np.flatnonzero(rows.seen)]
    plan = plan_model(geometry, bodies[placed], row_bodies, settings.coupling)
    if not plan.driven:
        raise InputError(source, "all tape rows lie over one vertebra: no joint for the tape to drive")
    labels = [static.markers.labels[d] for d in placed]
    prior = settings.slip or SlipPrior()
    slipping = [int(r) for r in slip_rows(rows.seen, prior)] if settings.slip is not None else []
    markers = [(labels[i], int(bodies[d]), expected[d], int(graph.row[d])) for i, d in enumerate(placed)]
    model = build_model(geometry, plan, markers, {r: int(geometry.row_body[r]) for r in slipping}, prior)
    _lock(model, [slip_coordinate(r) for r in slipping], True)
    model.printToXML(str(work / "model_generic.osim"))
    place_markers(work, labels, placed, static)
    if slipping:
        _unlock(work / "model.osim", [slip_coordinate(r) for r in slipping])
        annotate_slips(work / "model.osim", prior, slipping)
    placement = check_placement(work / "model.osim", labels, expected[placed], source)
    return _Placed(geometry, plan, labels, placed, expected[placed], placement, slipping, graph.row[placed])


def _lock(model, coordinates: list[str], locked: bool) -> None:
    for name in coordinates:
        model.updCoordinateSet().get(name).setDefaultLocked(locked)


def _unlock(model_file: Path, coordinates: list[str]) -> None:
    osim = require_opensim()
    model = osim.Model(str(model_file))
    _lock(model, coordinates, False)
    model.printToXML(str(model_file))


def place_markers(work: Path, labels: list[str], placed: np.ndarray, static: StaticTrial) -> None:
    """``markers_static.trc`` and ``setup_scale.xml`` in ``work``; MarkerPlacer moves the markers
    of ``model_generic.osim`` onto the static trial and writes ``model.osim`` (+ ``static_pose.mot``,
    radians)."""
    st = static.markers
    times, positions, time_range = st.times, st.positions[:, placed], static.time_range
    if len(times) == 1:  # MarkerPlacer averages over a time range: a one-frame trial is written twice
        times = np.array([times[0], times[0] + 1.0 / st.fps])
        positions = np.repeat(positions, 2, axis=0)
        time_range = (float(times[0]), float(times[1]))
    write_trc(work / "markers_static.trc", labels, times, positions, st.fps)
    setup = write_scale_setup(work, "model_generic.osim", "markers_static.trc", time_range, labels,
                              np.ones(len(labels)), "model.osim", "static_pose.mot")
    run_scale(setup)


def inverse_kinematics(work: Path, labels: list[str], placed: np.ndarray, data: TapeMarkers, frames: np.ndarray,
                       accuracy: float | np.ndarray, priors: dict[str, float] | None = None,
                       positions: np.ndarray | None = None, restart: bool = True,
                       inferred_sd_mm: float = INFERRED_SD_MM, goals: dict[str, CoordinateGoal] | None = None,
                       fresh_start_margin: float = 0.0, doubtful_prior_deg: float = 0.0) -> tuple[float, np.ndarray]:
    """``markers_opensim.trc`` (the given frames, the ``placed`` dots named ``labels``; the
    markers as given, or ``positions`` (F, D, 3) mm in their place: the skin-corrected ones),
    ``setup_ik.xml`` on ``model.osim`` (one mean weight per marker: a re-run in the GUI), and IK
    solved frame by frame (:func:`tools.solve_ik`) into ``ik.mot`` and ``ik_marker_errors.sto``;
    with ``doubtful_prior_deg`` > 0, short runs of frames whose markers it cannot fit solved again
    toward their neighbours' posture (:func:`short_doubtful_runs`, :func:`toward_neighbours`). Returns IK seconds and (F,) bool: the
    frames solved again. ``accuracy``: the solver's, one or per frame of ``data`` (the setup file
    holds the tightest)."""
    source = data.positions if positions is None else positions
    chosen = source[frames][:, placed]
    accuracy = np.broadcast_to(np.asarray(accuracy, float), data.times.shape)  # per frame of data
    times = data.times[frames]
    write_trc(work / "markers_opensim.trc", labels, times, chosen, data.fps)
    weights = data.weights(inferred_sd_mm)[frames][:, placed]
    chosen_goals = {name: goal.at(frames) for name, goal in (goals or {}).items()}
    if chosen_goals:
        write_coordinate_goals(work / SLIP_GOALS, times, chosen_goals)
    write_ik_setup(work, "model.osim", "markers_opensim.trc", (float(times[0]), float(times[-1])), labels,
                   mean_weights(weights), "ik.mot", float(accuracy[frames].min()), priors, SLIP_GOALS,
                   {name: float(np.max(g.weights)) for name, g in chosen_goals.items()})
    observed = data.status[frames][:, placed] == OBSERVED
    solution = solve_ik(work / "model.osim", labels, times, chosen, weights, priors, accuracy[frames], restart,
                        observed, chosen_goals, fresh_start_margin)
    again = short_doubtful_runs(doubtful_frames(solution)) if doubtful_prior_deg > 0 else np.zeros(len(times), bool)
    if again.any():
        redo = np.flatnonzero(again)
        redo_goals = {name: goal.at(redo) for name, goal in chosen_goals.items()}
        redo_goals.update(toward_neighbours(solution, again, doubtful_prior_deg))
        solution = solution.with_frames(redo, solve_ik(work / "model.osim", labels, times[redo], chosen[redo],
                                                       weights[redo], priors, accuracy[frames][redo], restart,
                                                       observed[redo], redo_goals, fresh_start_margin))
    write_ik_outputs(work, solution)
    return solution.seconds, again


def doubtful_frames(solution: IKSolution) -> np.ndarray:
    """(F,) bool: the frames whose markers IK cannot fit, as :func:`spine_angles` flags them: marker
    RMS above :data:`FLAG_RMS_MM`, a marker above :data:`FLAG_MAX_MM` or fewer than
    :data:`FLAG_MIN_MARKERS` markers."""
    with np.errstate(invalid="ignore"):
        return ((solution.marker_rms_mm > FLAG_RMS_MM) | (solution.marker_max_mm > FLAG_MAX_MM)
                | (solution.markers < FLAG_MIN_MARKERS))


def short_doubtful_runs(doubtful: np.ndarray, longest: int = SHORT_DOUBTFUL_RUN) -> np.ndarray:
    """(F,) bool: the ``doubtful`` frames (F,) bool in runs of at most ``longest`` frames with a
    frame that is not doubtful on either side. A longer run (a deep bend the markers fit badly
    throughout) is no gap between known postures, nor is a run at either end of the trial, and
    either is left as solved."""
    short = np.zeros(len(doubtful), bool)
    edges = np.flatnonzero(np.diff(np.r_[0, doubtful.astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2]):
        short[start:stop] = stop - start <= longest and start > 0 and stop < len(doubtful)
    return short


def toward_neighbours(solution: IKSolution, doubtful: np.ndarray, prior_deg: float) -> dict[str, CoordinateGoal]:
    """IK goals for the ``doubtful`` frames (F,) bool of ``solution`` (at least one frame not
    doubtful), in their order: every rotational coordinate pulled toward its value interpolated in
    time between the nearest frames on either side that are not doubtful (the nearest one's
    beyond the last), as a Gaussian prior of SD ``prior_deg`` against the markers' 1 mm
    (:data:`tools.OBSERVED_SD_MM`). A frame the markers under-determine (a row seen one column
    off, most dots inferred) then keeps the posture of the frames around it where its own markers
    do not say otherwise."""
    frames, sure = np.flatnonzero(doubtful), np.flatnonzero(~doubtful)
    weight = (OBSERVED_SD_MM / 1000.0 / np.radians(prior_deg)) ** 2  # per rad^2, beside marker errors in m^2
    return {name: CoordinateGoal(np.interp(frames, sure, solution.values[sure, c]), np.full(len(frames), weight))
            for c, name in enumerate(solution.coordinates) if solution.rotational[c]}


def _slip_goals(positions: np.ndarray, static: np.ndarray, tape: TapeSpec, placed: _Placed,
                prior: SlipPrior | None) -> dict[str, CoordinateGoal]:
    """Per-frame IK goals (m) of the slipping rows: the slip the tape shows
    (:func:`skin_model.geometric_slips` from the measured dots, relative to the mean of the
    pinned rows), held there (``prior.from_tape`` ``held``) or a goal of weight
    :attr:`SlipPrior.estimate_weight` (``goal``); beyond the rows measured in a frame a goal at the
    slip of the nearest measured row (it grows up the tape, so this is a floor) with the wide
    :attr:`SlipPrior.weight`; 0 with that weight in frames without an estimate, or in every frame
    with ``off``. Empty without slip."""
    if prior is None or not placed.slipping:
        return {}
    F = len(positions)
    geometry = placed.geometry
    pinned = sorted({int(r) for r in placed.marker_rows} - set(placed.slipping))
    slips = np.full((F, tape.n_rows), np.nan)
    if prior.from_tape != "off":
        slips = geometric_slips(positions, static, tape, geometry.depth[geometry.row_body], pinned[0])
        with np.errstate(all="ignore"):
            slips = slips - np.nanmean(slips[:, pinned], axis=1, keepdims=True)
    known = np.isfinite(slips)
    weights = np.where(known, prior.estimate_weight, prior.weight)
    values = np.clip(_hold_nearest(slips), -prior.limit_mm, prior.limit_mm) / 1000.0
    held = known if prior.from_tape == "held" else np.zeros_like(known)
    return {slip_coordinate(r): CoordinateGoal(values[:, r], weights[:, r], held[:, r]) for r in placed.slipping}


def _frame_accuracy(goals: dict[str, CoordinateGoal], settings: OpenSimSettings) -> float | np.ndarray:
    """The IK accuracy of every frame: ``settings.accuracy``, but at most :data:`tools.START_ACCURACY`
    (OpenSim's default) in a frame where a slipping row has no slip estimate: there only guessed
    (inferred) dots place that row, and a tight solve chases the guesses."""
    prior = settings.slip
    if prior is None or prior.from_tape == "off" or not goals:
        return settings.accuracy
    unknown = np.any([g.weights < prior.estimate_weight for g in goals.values()], axis=0)
    return np.where(unknown, max(settings.accuracy, START_ACCURACY), settings.accuracy)


def _hold_nearest(values: np.ndarray) -> np.ndarray:
    """(F, R) with each frame's NaNs beyond its finite values set to the nearest finite one (0 in a
    frame without any)."""
    out = np.zeros_like(values)
    rows = np.arange(values.shape[1])
    for f, row in enumerate(values):
        known = np.isfinite(row)
        if known.any():
            out[f] = np.interp(rows, rows[known], row[known])
    return out


def _priors(plan: ModelPlan, settings: OpenSimSettings) -> dict[str, float]:
    """IK coordinate goals toward the static posture (the slips' goals are :func:`_slip_goals`):
    when ``settings.prior_weight`` > 0, a weak one on every independent per-level lateral bending
    and axial rotation (they choose among the distributions the markers cannot tell apart)."""
    if settings.prior_weight <= 0:
        return {}
    dependent = {d for d, _, _ in plan.couplers}
    return {j.coordinate(dof): settings.prior_weight for j in plan.driven
            for dof in ("lateral_bending", "axial_rotation") if j.coordinate(dof) not in dependent}


def prepare(markers: MarkerTable, tape: TapeSpec, up: npt.ArrayLike, facing: Sequence[float],
            static: MarkerTable | None, settings: OpenSimSettings,
            source: str | None) -> tuple[TapeMarkers, StaticTrial, RowFrames, float]:
    """The tape markers in OpenSim axes, the static trial, its rows and the facing check."""
    quiet_opensim()
    axes = opensim_axes(up, facing, source)
    data = tape_markers(markers, tape, axes, source)
    st = _static(data, static, tape, axes, settings, source)
    rows = row_frames(st.positions, tape, source)
    return data, st, rows, check_facing(rows, axes, source)


def work_folder(out_dir: Path) -> Path:
    """An absolute temporary folder beside ``out_dir`` where a run builds its files (see
    :func:`publish`)."""
    out_dir = Path(out_dir).absolute()
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))


def run_opensim(markers: MarkerTable, tape: TapeSpec, levels: LevelRows, up: npt.ArrayLike,
                facing: Sequence[float], out_dir: str | os.PathLike, static: MarkerTable | None = None,
                settings: OpenSimSettings = OpenSimSettings(),
                source: str | None = None) -> OpenSimResult[SpineModelSummary]:
    """Build, place and solve; see the module docstring. ``source`` names the input in errors."""
    osim = require_opensim()
    data, st, rows, facing_error = prepare(markers, tape, up, facing, static, settings, source)
    out_dir = Path(out_dir).absolute()
    work = work_folder(out_dir)
    try:
        placed = _build_and_place(work, rows, levels, tape, st, settings, source)
        positions, tilt_turn = data.positions, None
        if settings.normalise_tilt:
            positions, tilt_turn = normalise_row_tilt(data.positions, st.positions, tape)
        measured = np.where((data.status == OBSERVED)[..., None], positions, np.nan)  # inferred dots are guesses
        slip_goals = _slip_goals(measured, st.positions, tape, placed, settings.slip)
        ik_seconds, toward_others = inverse_kinematics(
            work, placed.labels, placed.placed, data, np.arange(len(data.times)), _frame_accuracy(slip_goals, settings),
            _priors(placed.plan, settings), positions, settings.restart_from_static, settings.inferred_sd_mm,
            slip_goals, settings.fresh_start_margin, settings.doubtful_prior_deg)
        angles, flags = spine_angles(work / "ik.mot", work / "ik_marker_errors.sto", placed.plan, data, toward_others)
        weights = mean_weights(data.weights(settings.inferred_sd_mm)[:, placed.placed])
        depth = Depth(scale_on_published=settings.depth_scale, source=settings.depth_source,
                      depth_mm={n: round(float(x), 1) for n, x in zip(placed.geometry.names, placed.geometry.depth)})
        skin = _skin_summary(work / "ik.mot", placed, settings, tilt_turn, slip_goals)
        summary = _summary(data, placed, angles, flags, ik_seconds, facing_error, weights, settings, osim, depth, skin)
        with atomic_write(work / "spine_angles.csv") as handle:
            handle.write(_angles_header(placed.plan))
            angles.to_csv(handle, index=False, float_format="%.4f")
        from .plot import angles_plot_png

        with atomic_write(work / "spine_angles.png", "wb") as handle:
            handle.write(angles_plot_png(angles, summary))
        with atomic_write(work / "summary.json") as handle:
            handle.write(strict_json(summary.to_dict()))
        files = publish(work, out_dir)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return OpenSimResult(out_dir, angles, summary, placed.plan, placed.geometry, files)


def _skin_summary(motion: Path, placed: _Placed, settings: OpenSimSettings, tilt_turn: np.ndarray | None,
                  goals: dict[str, CoordinateGoal]) -> SkinModelSummary:
    """The skin model's assumptions and what IK made of them: the tilt correction applied per row
    (largest, deg), per slipping row the slip (mm) at the frame where it peaks, and the share of
    the (frame, slipping row) pairs whose slip was held at the tape's."""
    row_tilt = ("each row kept at its static in-plane angle to the tape midline (turned about its L-R midpoint, "
                "about the tape normal)") if settings.normalise_tilt else "as measured"
    tilt_correction = None
    if tilt_turn is not None:
        with np.errstate(all="ignore"):
            worst = np.nanmax(np.abs(tilt_turn), axis=0)
        tilt_correction = {f"R{r + 1:02d}": round(float(v), 2) for r, v in enumerate(worst) if np.isfinite(v)}
    if settings.slip is None:
        return SkinModelSummary(row_tilt, tilt_correction, None)
    held = [g.held for g in goals.values() if g.held is not None]
    held_share = round(float(np.mean(held)), 4) if held else 0.0
    _, labels, values, _ = read_storage(motion)
    column = {label.split("/")[-2] if label.startswith("/") else label: i for i, label in enumerate(labels)}
    peak = {}
    for r in placed.slipping:
        slip_mm = 1000.0 * values[:, column[slip_coordinate(r)]]
        peak[slip_coordinate(r)] = round(float(slip_mm[np.nanargmax(np.abs(slip_mm))]), 2)
    prior = settings.slip
    pinned = sorted({int(r) for r in placed.marker_rows} - set(placed.slipping))
    use = {"held": "held in each frame at the slip the tape shows where its dots are measured (a locked coordinate), "
                   "solved by IK elsewhere",
           "goal": "solved by IK with a goal at the slip the tape shows", "off": "solved by IK from the markers"}
    slip = SlipSummary(model="each row above the pinned ones on a body translating along its vertebra's superior "
                             f"axis; coordinate <row>_skin_slip (m, 0 = static trial) {use[prior.from_tape]}",
                       from_tape=prior.from_tape, held_share=held_share,
                       pinned_rows=[f"R{r + 1:02d}" for r in pinned],
                       prior=f"{prior_text(prior)}; clamped to +/-{prior.limit_mm:g} mm",
                       prior_weight_per_m2=prior.weight, estimate_weight_per_m2=prior.estimate_weight,
                       at_peak_mm=peak)
    return SkinModelSummary(row_tilt, tilt_correction, slip)


def publish(work: Path, out_dir: Path) -> dict[str, Path]:
    """Rename every finished file from the work folder into ``out_dir`` (replacing old ones)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {}
    for path in sorted(work.iterdir()):
        if path.is_file() and not path.name.startswith("."):
            os.replace(path, out_dir / path.name)
            files[path.name] = out_dir / path.name
    return files


def check_placement(model_file: Path, labels: list[str], expected_mm: np.ndarray,
                    source: str | None = None) -> Placement:
    """Median and worst distance (mm) of the placed markers from their anatomical places, beside
    (lateral, body Z) and in front of/behind (depth, body X) the spine. Raises
    :class:`InputError` beyond :data:`PLACEMENT_LATERAL_MM` / :data:`PLACEMENT_DEPTH_MM`: the
    axes (``[subject] up/facing``) or the level map do not fit the data."""
    placed = marker_locations(model_file, labels)
    offsets = np.array([placed[label][1] - expected_mm[i] for i, label in enumerate(labels) if label in placed])
    lateral, depth = np.abs(offsets[:, 2]), np.abs(offsets[:, 0])
    result = Placement(lateral_median_mm=float(np.median(lateral)), lateral_max_mm=float(lateral.max()),
                       depth_median_mm=float(np.median(depth)), depth_max_mm=float(depth.max()),
                       vertical_median_mm=float(np.median(np.abs(offsets[:, 1]))))
    if result.lateral_median_mm > PLACEMENT_LATERAL_MM or result.depth_median_mm > PLACEMENT_DEPTH_MM:
        raise InputError(source, (
            f"MarkerPlacer put the tape markers {result.lateral_median_mm:.0f} mm beside and "
            f"{result.depth_median_mm:.0f} mm in front of/behind their places over the spine (median; limits "
            f"{PLACEMENT_LATERAL_MM:.0f} / {PLACEMENT_DEPTH_MM:.0f} mm): [subject] up/facing in capture.toml or the "
            "level map do not fit this capture"))
    return result


def spine_angles(motion: Path, errors: Path, plan: ModelPlan, data: TapeMarkers,
                 toward_others: np.ndarray | None = None) -> tuple[pd.DataFrame, np.ndarray]:
    """Per-frame angle table (deg, project signs) from IK's ``.mot``, with marker RMS/max (mm)
    and a ``flag`` column; returns it and the flagged frames' reasons. ``toward_others`` (F,)
    bool: frames solved toward their neighbours' posture (:func:`toward_neighbours`), flagged so."""
    times, labels, values, degrees = read_storage(motion)
    if not degrees:
        values = np.degrees(values)  # every spine coordinate is rotational
    column = {label.split("/")[-2] if label.startswith("/") else label: i for i, label in enumerate(labels)}
    table = pd.DataFrame({"frame": np.arange(len(times)), "time": times})
    at_limit = np.zeros(len(times), bool)
    region_sum: dict[str, np.ndarray] = {}
    for j in plan.driven:
        for dof, rom in zip(DOF, j.rom_deg):
            value = SIGN[dof] * values[:, column[j.coordinate(dof)]]
            table[f"{j.name}_{PROJECT_NAME[dof]}"] = value
            at_limit |= np.abs(value) >= RANGE_FACTOR * rom - LIMIT_MARGIN_DEG
            key = f"{j.region}_{PROJECT_NAME[dof]}"
            region_sum[key] = region_sum.get(key, 0.0) + value
    for key, value in region_sum.items():
        table[key] = value
    _, err_labels, err, _ = read_storage(errors)
    rms = 1000.0 * err[:, err_labels.index("marker_error_RMS")]
    worst = 1000.0 * err[:, err_labels.index("marker_error_max")]
    table["marker_rms"] = rms
    table["marker_rms_observed"] = 1000.0 * err[:, err_labels.index("marker_error_RMS_observed")]
    table["marker_max"] = worst
    n_markers = np.isfinite(data.positions).all(axis=2).sum(axis=1)
    reasons = np.full(len(times), "", dtype=object)
    for mask, why in ((rms > FLAG_RMS_MM, f"marker RMS > {FLAG_RMS_MM:g} mm"),
                      (worst > FLAG_MAX_MM, f"a marker > {FLAG_MAX_MM:g} mm off"),
                      (n_markers[: len(times)] < FLAG_MIN_MARKERS, f"fewer than {FLAG_MIN_MARKERS} markers"),
                      (at_limit, f"a joint at its range limit ({RANGE_FACTOR:g} x published)"),
                      (np.zeros(len(times), bool) if toward_others is None else toward_others,
                       "solved toward the neighbouring frames' posture")):
        reasons[mask] = [f"{r}; {why}" if r else why for r in reasons[mask]]
    table["flag"] = reasons
    return table, reasons


def _angles_header(plan: ModelPlan) -> str:
    joints = ", ".join(j.name for j in plan.driven)
    return ("# spinemocap opensim: inverse-kinematics spine angles. Units: time s; angles deg; marker_rms, "
            "marker_max, marker_rms_observed (over the measured dots) mm.\n# Signs (this project's): flexion = forward bending positive (OpenSim extension "
            "negated); lateral = bending toward the subject's right positive; rotation = axial rotation toward "
            "the subject's left positive. Zero = the static trial's posture.\n"
            f"# Driven joints (child_parent): {joints}. lumbar_* / thoracic_* = sums over the region's driven "
            "joints (lumbar: L5/S1..T12/L1, thoracic: T11/T12..C7/T1).\n# flag: why a frame is not vouched for "
            "(empty = fine).\n")


def _summary(data: TapeMarkers, placed: _Placed, angles: pd.DataFrame, flags: np.ndarray, ik_seconds: float,
             facing_error: float, weights: np.ndarray, settings: OpenSimSettings, osim, depth: Depth,
             skin: SkinModelSummary) -> SpineModelSummary:
    geometry, plan, labels = placed.geometry, placed.plan, placed.labels
    rms = angles["marker_rms"].to_numpy()
    flagged = np.flatnonzero(flags != "")
    reasons: dict[str, int] = {}
    for text in flags[flagged]:
        for why in str(text).split("; "):
            reasons[why] = reasons.get(why, 0) + 1
    bodies: dict[str, list[str]] = {}
    for label in labels:
        name = body_name(geometry.names[geometry.row_body[int(label[1:3]) - 1]])
        bodies.setdefault(name, []).append(label)
    ranges = {c: (float(np.nanmin(angles[c])), float(np.nanmax(angles[c])))
              for c in angles.columns if c.startswith(("lumbar_", "thoracic_"))}
    return SpineModelSummary(
        frames=len(angles),
        fps=data.fps,
        marker_rms_mm=float(np.nanmean(rms)),
        marker_rms_mm_max=float(np.nanmax(rms)),
        # over the measured dots only: inferred ones are placed, not measured, and weigh little in IK
        marker_rms_observed_mm=float(np.nanmean(angles["marker_rms_observed"])),
        marker_max_mm=float(np.nanmax(angles["marker_max"])),
        ms_per_frame=1000.0 * ik_seconds / max(len(angles), 1),
        flagged_frames=[int(f) for f in flagged],
        flag_reasons=reasons,
        warnings=[],
        driven_joints=[j.name for j in plan.driven],
        welded_joints=[j.name for j in plan.joints if not j.driven],
        couplers=[(d, i, round(r, 4)) for d, i, r in plan.couplers],
        coordinates=plan.coordinates,
        markers_by_body=bodies,
        markers_not_placed=[label for label in data.labels if label not in set(labels)],
        marker_weights={label: round(float(w), 3) for label, w in zip(labels, weights)},
        levels_mapped=geometry.mapped,
        scale_to_generic=geometry.scale,
        facing_error_deg=facing_error,
        placement=placed.placement,
        region_ranges_deg=ranges,
        ik_accuracy=settings.accuracy,
        ik_accuracy_note=(f"frames where a slipping row has no slip estimate (its dots not measured) are solved to "
                          f"{max(settings.accuracy, START_ACCURACY):g}") if settings.slip is not None else "",
        ik="OpenSim InverseKinematicsSolver frame by frame: each frame from the previous solution"
           + (f" and from the static pose, the static start's kept unless its objective exceeds "
              f"{1 + settings.fresh_start_margin:g} x the other's" if settings.restart_from_static else "")
           + ", marker weights = label confidence squared per sample, an inferred dot's divided by "
           f"({settings.inferred_sd_mm:g} mm / {OBSERVED_SD_MM:g} mm)^2 (its assumed position SD against an "
           f"observed dot's), joints clamped to {RANGE_FACTOR:g} x their published ranges"
           + ("; each slip coordinate held (locked) where the tape shows its slip, so that frame's solve "
              "is the spine's rotations" if settings.slip is not None and settings.slip.from_tape == "held" else ""),
        opensim_version=str(osim.GetVersion()),
        depth=depth,
        skin_model=skin,
    )
