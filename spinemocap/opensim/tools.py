"""OpenSim's own tools on the tape markers: TRC writing, MarkerPlacer (ScaleTool) and
InverseKinematicsTool setups, runs and their outputs read back; inverse kinematics frame by frame
with OpenSim's ``InverseKinematicsSolver`` (:func:`solve_ik`), so that every marker carries its own
weight in every frame.

Every setup file names its inputs and outputs relative to its own folder (ScaleTool resolves
relative paths against the setup file), so the folder can be opened and re-run unchanged in the
OpenSim GUI. MarkerPlacer's static pose is in radians, IK's ``.mot`` in degrees; both are read
back with OpenSim's own readers and converted explicitly.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..fileio import InputError
from ..markers import INFERRED, MISSING, OBSERVED

INFERRED_CONFIDENCE = 0.6  # label confidence of an inferred dot when the table has none (observed: 1)
# Position uncertainty (SD, mm) of an observed (triangulated) dot and of an inferred one (placed by
# the tape model or filled in time: on deep bends several to tens of mm off)
OBSERVED_SD_MM = 1.0
INFERRED_SD_MM = 10.0
# IK solver accuracy (the SimTK assembler's tolerance; OpenSim's default). Near a solution its
# stopping tests are absolute, so it stops short of the optimum along the directions the markers
# hardly see (a twist shared by the pelvis and the levels is under-read); a tighter accuracy costs
# several times the time per frame and reads forward bending worse with the slips solved from the
# markers (docs/decisions/0005-ik-solver-accuracy.md).
IK_ACCURACY = 1e-5
# A solve from far off (the static pose, see _better_of_two_starts) first runs to this accuracy,
# then on to a tighter one when one is asked (far faster than going straight there, to the same
# solution).
START_ACCURACY = 1e-5


def require_opensim():
    """Import ``opensim`` or raise :class:`InputError` saying how to install it."""
    try:
        import opensim
    except ImportError as exc:
        raise InputError("spinemocap opensim", "the OpenSim Python package is not installed: "
                         "pip install 'spinemocap[opensim]' (or `make setup`, which installs it); "
                         f"import failed with: {exc}") from None
    return opensim


def quiet_opensim() -> None:
    """OpenSim logs every IK frame at info level; keep warnings only."""
    osim = require_opensim()
    osim.Logger.setLevelString("warn")


def marker_weights(status: np.ndarray, confidence: np.ndarray | None = None,
                   inferred_sd_mm: float = INFERRED_SD_MM) -> np.ndarray:
    """(F, D) IK task weight of every marker sample: the square of its label confidence (0..1,
    ``markers.csv``'s ``confidence`` column: observed 1, inferred 0.6, times 0.5 for each flag that
    puts the frame's labels in doubt), or, where the confidence is unknown (NaN, or no column),
    1 for an observed sample and :data:`INFERRED_CONFIDENCE` squared for an inferred one; 0 where
    missing. Squared: a weight multiplies a squared marker error, like an inverse variance. An
    inferred sample's weight is further divided by (``inferred_sd_mm`` / :data:`OBSERVED_SD_MM`)^2:
    its position was placed by the tape model or filled in time, not measured, and is that much
    less certain."""
    status = np.asarray(status)
    fallback = np.where(status == OBSERVED, 1.0, np.where(status == INFERRED, INFERRED_CONFIDENCE, 0.0))
    if confidence is None:
        confidence = np.full(status.shape, np.nan)
    known = np.clip(np.where(np.isfinite(confidence), confidence, fallback), 0.0, 1.0)
    precision = np.where(status == INFERRED, (OBSERVED_SD_MM / inferred_sd_mm) ** 2, 1.0)
    return np.where(status == MISSING, 0.0, known**2 * precision)


def mean_weights(weights: np.ndarray) -> np.ndarray:
    """(D,) mean of (F, D) per-sample weights over the samples present (weight > 0); 0 for a
    marker missing throughout. The setup files hold these (one weight per marker task)."""
    present = weights > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(present, weights, 0.0).sum(axis=0) / present.sum(axis=0)
    return np.where(present.any(axis=0), mean, 0.0)


def marker_table(labels: Sequence[str], times: np.ndarray, metres: np.ndarray):
    """OpenSim's ``TimeSeriesTableVec3`` of markers ``labels`` at ``times`` (F,) s, positions
    ``metres`` (F, D, 3) in m (NaN = missing sample)."""
    osim = require_opensim()
    F, D = metres.shape[:2]
    table = osim.TimeSeriesTableVec3()
    # a plain list: SWIG converts it to the std::vector itself, whichever of OpenSim's modules
    # defined the StdVectorString proxy class
    table.setColumnLabels([str(label) for label in labels])
    for f in range(F):
        row = osim.RowVectorVec3(D)
        for d in range(D):
            x, y, z = metres[f, d]
            row[d] = osim.Vec3(float(x), float(y), float(z))
        table.appendRow(float(times[f]), row)
    return table


def write_trc(path: str | os.PathLike, labels: Sequence[str], times: np.ndarray, positions_mm: np.ndarray,
              fps: float) -> Path:
    """TRC in metres through OpenSim's own ``TRCFileAdapter`` (NaN = missing sample)."""
    osim = require_opensim()
    table = marker_table(labels, times, np.asarray(positions_mm, float) / 1000.0)
    table.addTableMetaDataString("DataRate", f"{fps:.10g}")
    table.addTableMetaDataString("CameraRate", f"{fps:.10g}")
    table.addTableMetaDataString("Units", "m")
    osim.TRCFileAdapter().write(table, str(path))
    return Path(path)


def _task_set(osim, labels: Sequence[str], weights: np.ndarray, tasks) -> None:
    for label, weight in zip(labels, weights):
        task = osim.IKMarkerTask()
        task.setName(str(label))
        task.setApply(bool(weight > 0))
        task.setWeight(float(max(weight, 0.0)))
        tasks.cloneAndAppend(task)


def write_scale_setup(folder: Path, generic_model: str, static_trc: str, time_range: tuple[float, float],
                      labels: Sequence[str], weights: np.ndarray, output_model: str, static_pose: str) -> Path:
    """``setup_scale.xml``: no scaling (the model is built to the subject), MarkerPlacer on the
    static trial moving the model markers onto it."""
    osim = require_opensim()
    tool = osim.ScaleTool()
    tool.setName("spinemocap_static")
    tool.setSubjectMass(70.0)
    tool.getGenericModelMaker().setModelFileName(generic_model)
    tool.getModelScaler().setApply(False)
    placer = tool.getMarkerPlacer()
    placer.setApply(True)
    placer.setStaticPoseFileName(static_trc)
    times = osim.ArrayDouble()
    times.append(float(time_range[0]))
    times.append(float(time_range[1]))
    placer.setTimeRange(times)
    placer.setOutputModelFileName(output_model)
    placer.setOutputMotionFileName(static_pose)
    placer.setMoveModelMarkers(True)
    _task_set(osim, labels, weights, placer.getIKTaskSet())
    path = folder / "setup_scale.xml"
    tool.printToXML(str(path))
    return path


def write_ik_setup(folder: Path, model_file: str, trc: str, time_range: tuple[float, float],
                   labels: Sequence[str], weights: np.ndarray, output_motion: str, accuracy: float,
                   priors: dict[str, float] | None = None, goal_file: str | None = None,
                   goal_weights: dict[str, float] | None = None) -> Path:
    """``setup_ik.xml``: one marker task per label; errors reported to ``<name>_ik_marker_errors.sto``.
    ``priors``: {coordinate: weight} of coordinate tasks pulling toward the default value (0);
    ``goal_weights``: {coordinate: weight} of coordinate tasks pulling toward the values in
    ``goal_file`` (the tool's coordinate file, see :func:`write_coordinate_goals`; OpenSim's setup
    holds one weight per task, so frames whose weight differs get this one in a re-run). The
    coordinate tasks' weights are written divided by the marker tasks' total weight: OpenSim's IK
    averages the marker errors by weight but sums the coordinate tasks (see
    :meth:`_FrameSolver.solve`)."""
    osim = require_opensim()
    tool = osim.InverseKinematicsTool()
    tool.setName("spinemocap")
    tool.set_model_file(model_file)
    tool.setMarkerDataFileName(trc)
    tool.setStartTime(float(time_range[0]))
    tool.setEndTime(float(time_range[1]))
    tool.setOutputMotionFileName(output_motion)
    tool.set_report_errors(True)
    tool.set_results_directory(".")
    tool.set_accuracy(float(accuracy))
    # get_IKTaskSet().cloneAndAppend() silently adds nothing from Python: use the upd_ accessor
    tasks = tool.upd_IKTaskSet()
    _task_set(osim, labels, weights, tasks)
    marker_total = float(np.clip(weights, 0.0, None).sum()) or 1.0
    for weights_by_coordinate, value_type in ((priors, osim.IKCoordinateTask.DefaultValue),
                                              (goal_weights, osim.IKCoordinateTask.FromFile)):
        for coordinate, weight in (weights_by_coordinate or {}).items():
            task = osim.IKCoordinateTask()
            task.setName(coordinate)
            task.setApply(True)
            task.setWeight(float(weight) / marker_total)
            task.setValueType(value_type)
            tasks.cloneAndAppend(task)
    if goal_weights:
        if goal_file is None:
            raise ValueError("coordinate goals from a file need goal_file")
        tool.setCoordinateFileName(goal_file)
    path = folder / "setup_ik.xml"
    tool.printToXML(str(path))
    return path


@contextlib.contextmanager
def _tool_output(setup: Path, tool: str) -> Iterator[None]:
    """Hold back what OpenSim's tools print on the C++ side (model summaries, "Model is not
    scaled" for a MarkerPlacer-only ScaleTool); on failure raise :class:`InputError` with it."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 1)
        failure: BaseException | None = None
        try:
            yield
        except (RuntimeError, InputError) as exc:
            failure = exc
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
        if failure is not None:
            captured.seek(0)
            text = captured.read().decode("utf-8", "replace").strip()[-2000:]
            raise InputError(setup, f"OpenSim's {tool} failed: {failure}\n{text}") from None


def run_scale(setup: Path) -> None:
    """Run a ScaleTool setup file (paths inside resolve against its folder)."""
    osim = require_opensim()
    with _tool_output(setup, "ScaleTool (MarkerPlacer)"):
        if not osim.ScaleTool(str(setup)).run():
            raise RuntimeError("run() returned false")


def run_ik(setup: Path) -> None:
    """Run an InverseKinematicsTool setup file from its own folder."""
    osim = require_opensim()
    cwd = os.getcwd()
    os.chdir(setup.parent)
    try:
        with _tool_output(setup, "InverseKinematicsTool"):
            if not osim.InverseKinematicsTool(setup.name).run():
                raise RuntimeError("run() returned false")
    finally:
        os.chdir(cwd)


def read_storage(path: Path) -> tuple[np.ndarray, list[str], np.ndarray, bool]:
    """(times, column labels, values (F, C), in_degrees) of a .mot/.sto through OpenSim's reader."""
    osim = require_opensim()
    table = osim.TimeSeriesTable(str(path))
    labels = list(table.getColumnLabels())
    times = np.array(table.getIndependentColumn())
    values = table.getMatrix().to_numpy()
    degrees = False
    if table.hasTableMetaDataKey("inDegrees"):
        degrees = table.getTableMetaDataAsString("inDegrees").strip().lower() == "yes"
    return times, labels, np.asarray(values, float).reshape(len(times), len(labels)), degrees


def marker_locations(model_file: Path, labels: Sequence[str]) -> dict[str, tuple[str, np.ndarray]]:
    """{label: (body name, location in the body frame in mm)} of a model's markers."""
    osim = require_opensim()
    model = osim.Model(str(model_file))
    out = {}
    markers = model.getMarkerSet()
    for label in labels:
        if markers.contains(label):
            m = markers.get(label)
            loc = m.get_location()
            out[label] = (m.getParentFrameName().split("/")[-1], 1000.0 * np.array([loc[0], loc[1], loc[2]]))
    return out


def body_rotations(model_file: Path, motion: Path, bodies: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """(times (F,), rotations (F, B, 3, 3)) of ``bodies`` in ground for every row of an IK motion
    (degrees converted to radians for rotational coordinates)."""
    osim = require_opensim()
    model = osim.Model(str(model_file))
    state = model.initSystem()
    times, labels, values, degrees = read_storage(motion)
    coords = model.getCoordinateSet()
    columns = []
    for i, label in enumerate(labels):
        name = label.split("/")[-2] if label.startswith("/") else label
        if coords.contains(name):
            c = coords.get(name)
            rotational = c.getMotionType() == osim.Coordinate.Rotational
            columns.append((c, i, np.pi / 180.0 if (degrees and rotational) else 1.0))
    body_set = model.getBodySet()
    handles = [body_set.get(b) for b in bodies]
    out = np.empty((len(times), len(bodies), 3, 3))
    for f in range(len(times)):
        for c, i, factor in columns:
            c.setValue(state, float(values[f, i]) * factor, False)
        model.realizePosition(state)
        for b, body in enumerate(handles):
            R = body.getTransformInGround(state).R()
            out[f, b] = [[R.get(r, k) for k in range(3)] for r in range(3)]
    return times, out


@dataclass
class IKSolution:
    """Inverse kinematics of a trial: ``coordinates`` (C names), ``values`` (F, C) in the model's
    units (rad, m), ``rotational`` (C,) bool, per-frame marker RMS and worst marker error (mm, over
    the markers present) and ``markers`` (F,) how many were present."""

    times: np.ndarray
    coordinates: list[str]
    values: np.ndarray
    rotational: np.ndarray
    marker_rms_mm: np.ndarray
    marker_max_mm: np.ndarray
    markers: np.ndarray
    seconds: float
    observed_rms_mm: np.ndarray  # (F,) marker RMS over the observed (measured) samples only

    def with_frames(self, frames: np.ndarray, other: IKSolution) -> IKSolution:
        """This solution with its ``frames`` (indices, in order) replaced by ``other``, a solution
        of those frames alone on the same model; ``seconds`` add up."""
        values, rms, worst = self.values.copy(), self.marker_rms_mm.copy(), self.marker_max_mm.copy()
        markers, observed = self.markers.copy(), self.observed_rms_mm.copy()
        values[frames], rms[frames], worst[frames] = other.values, other.marker_rms_mm, other.marker_max_mm
        markers[frames], observed[frames] = other.markers, other.observed_rms_mm
        return replace(self, values=values, marker_rms_mm=rms, marker_max_mm=worst, markers=markers,
                       observed_rms_mm=observed, seconds=self.seconds + other.seconds)


@dataclass(frozen=True)
class CoordinateGoal:
    """A coordinate goal that changes from frame to frame: ``values`` (F,) in the coordinate's
    units (rad, m) and ``weights`` (F,) per unit^2, beside the frame's marker errors in m^2 summed by
    weight (a goal of weight 1 per m^2 weighs as one marker of weight 1); ``held`` (F,)
    bool (None = never): frames where the coordinate is held at its value (OpenSim's locked,
    prescribed coordinate, left out of the solve) instead of pulled toward it."""

    values: np.ndarray
    weights: np.ndarray
    held: np.ndarray | None = None

    def held_at(self, frame: int) -> bool:
        """Whether the coordinate is held at its value in ``frame``."""
        return self.held is not None and bool(self.held[frame])

    def at(self, frames: np.ndarray) -> CoordinateGoal:
        """The goal over ``frames`` (indices or a bool mask of the goal's frames), in their order."""
        return CoordinateGoal(self.values[frames], self.weights[frames], None if self.held is None else self.held[frames])


class _FrameSolver:
    """A fresh ``InverseKinematicsSolver`` per solve of a frame: OpenSim drops the goal of a
    coordinate once a solve has held it locked, so a solver is not reused across solves."""

    def __init__(self, osim, model, table, labels: Sequence[str], weights: np.ndarray, present: np.ndarray,
                 goals: dict[str, CoordinateGoal]):
        self.osim, self.model, self.table, self.labels = osim, model, table, list(labels)
        self.weights, self.present, self.goals = weights, present, goals
        coords = model.getCoordinateSet()
        self.coordinates = {name: coords.get(name) for name in goals}
        self.every = [coords.get(i) for i in range(coords.getSize())]
        self.clamped = [c for c in self.every if c.get_clamped()]  # the model's ranges

    def marker_weight_sum(self, frame: int) -> float:
        """The total weight of the markers present in ``frame`` (1 where none is)."""
        total = float(self.weights[frame][self.present[frame]].sum())
        return total if total > 0 else 1.0

    def solve(self, state, frame: int, accuracy: float):
        """Set the frame's held coordinates in ``state``, solve from the other coordinates there
        to ``accuracy`` and return the solver (its marker errors are the frame's), every clamped
        coordinate inside its range. The solve runs without the ranges first and again with them
        only where a coordinate left its range: with the coupled joints' constraints the solver
        is an interior-point one, which, given the ranges, can take a hundred times longer to
        reach the same solution inside them. Where a coordinate leaves its range, the solve with
        the ranges starts again from ``state`` as it was given (the unclamped solution may lie in
        another valley)."""
        start = [c.getValue(state) for c in self.every]
        for coordinate in self.clamped:
            coordinate.setClamped(state, False)
        solver = self._assemble(state, frame, accuracy)
        inside = all(c.getRangeMin() <= c.getValue(state) <= c.getRangeMax() for c in self.clamped)
        for coordinate in self.clamped:
            coordinate.setClamped(state, True)
        if inside:
            return solver
        for coordinate, value in zip(self.every, start):
            if not coordinate.getLocked(state):
                coordinate.setValue(state, value, False)
        return self._assemble(state, frame, accuracy)

    def _assemble(self, state, frame: int, accuracy: float):
        """One solve of ``frame`` from ``state`` with the ranges clamped there. OpenSim's IK
        divides the weighted squared marker errors by the markers' total weight but adds each
        coordinate goal's term as weighted: every goal's weight is divided by the frame's total
        marker weight here, so that a goal weighs against the markers' weighted sum (a goal of
        weight (marker SD / goal SD)^2 acts as a Gaussian prior of that SD)."""
        osim = self.osim
        marker_total = self.marker_weight_sum(frame)
        weight_set = osim.SetMarkerWeights()
        for d, label in enumerate(self.labels):  # a missing sample's weight is ignored (NaN marker)
            weight = float(self.weights[frame, d]) if self.present[frame, d] else 1.0
            weight_set.cloneAndAppend(osim.MarkerWeight(str(label), weight))
        references = osim.SimTKArrayCoordinateReference()
        for name, goal in self.goals.items():
            value, weight = _goal_at(goal, frame)
            coordinate = self.coordinates[name]
            coordinate.setLocked(state, False)  # a locked coordinate keeps its value
            if goal.held_at(frame):
                coordinate.setValue(state, value, False)
                coordinate.setLocked(state, True)
            reference = osim.CoordinateReference(name, osim.Constant(value))
            reference.setWeight(weight / marker_total)
            references.push_back(reference)
        solver = osim.InverseKinematicsSolver(self.model, osim.MarkersReference(self.table, weight_set), references)
        solver.setAccuracy(float(accuracy))
        solver.assemble(state)
        return solver


def solve_ik(model_file: Path, labels: Sequence[str], times: np.ndarray, positions_mm: np.ndarray,
             weights: np.ndarray, priors: dict[str, float] | None = None,
             accuracy: float | np.ndarray = IK_ACCURACY,
             restart: bool = True, observed: np.ndarray | None = None,
             goals: dict[str, CoordinateGoal] | None = None, fresh_start_margin: float = 0.0) -> IKSolution:
    """OpenSim's ``InverseKinematicsSolver`` on every frame of ``positions_mm`` (F, D, 3; OpenSim
    ground, mm; NaN = missing), each marker weighted per frame by ``weights`` (F, D) and each frame
    started from the previous frame's solution (the first from the model's default pose, where it
    was built: the static trial) and, with ``restart``, from the default pose too, keeping the
    static start's solution unless its objective exceeds (1 + ``fresh_start_margin``) x the
    other's. ``observed`` (F, D) bool: the measured samples, over which
    ``observed_rms_mm`` is taken (default: all present); ``accuracy``: the solver's, one or (F,)
    per frame. ``priors``: {coordinate: weight} of coordinate goals toward the
    coordinate's default value (weight per unit^2, beside marker errors in m^2 summed by weight); ``goals``: coordinate
    goals whose value and weight change per frame, or coordinates held per frame
    (:class:`CoordinateGoal`). Coordinates the model clamps stay inside their ranges."""
    osim = require_opensim()
    model = osim.Model(str(model_file))
    state = model.initSystem()
    F, D = positions_mm.shape[:2]
    metres = np.asarray(positions_mm, float) / 1000.0
    present = np.isfinite(metres).all(axis=2) & (weights > 0)
    metres = np.where(present[..., None], metres, np.nan)  # a sample of weight 0 is a missing one
    coords = model.getCoordinateSet()
    all_goals = {name: CoordinateGoal(np.full(F, coords.get(name).getDefaultValue()), np.full(F, float(weight)))
                 for name, weight in (priors or {}).items()}
    all_goals.update(goals or {})
    frames = _FrameSolver(osim, model, marker_table(labels, times, metres), labels, weights, present, all_goals)
    frame_accuracy = np.broadcast_to(np.asarray(accuracy, float), (F,))
    column = {label: d for d, label in enumerate(labels)}
    coordinate_list = [coords.get(i) for i in range(coords.getSize())]
    values = np.zeros((F, len(coordinate_list)))
    rms, worst, count = np.full(F, np.nan), np.full(F, np.nan), np.zeros(F, int)
    observed_rms = np.full(F, np.nan)
    measured = present if observed is None else present & np.asarray(observed, bool)
    errors = osim.SimTKArrayDouble()
    started = time.perf_counter()
    for f in range(F):
        state.setTime(float(times[f]))
        # a full solve from the coordinates held in the state: the previous frame's solution (the
        # first frame's from the default pose, the static trial's); Assembler::track's few steps
        # stopped short of the solution at 12 frames/s
        solver = _solve(frames, state, f, float(frame_accuracy[f]), far=f == 0)
        order = [solver.getMarkerNameForIndex(i) for i in range(solver.getNumMarkersInUse())]
        in_order = [column[name] for name in order]
        values[f] = [c.getValue(state) for c in coordinate_list]
        if f > 0 and restart:
            values[f], solver = _better_of_two_starts(frames, solver, state, f, coordinate_list, values[f],
                                                      np.where(present[f, in_order], weights[f, in_order], 0.0),
                                                      float(frame_accuracy[f]), fresh_start_margin)
        solver.computeCurrentMarkerErrors(errors)
        err = np.array([errors.getElt(i) for i in range(errors.size())])
        used = present[f, in_order] & np.isfinite(err)
        count[f] = int(used.sum())
        if used.any():
            rms[f] = 1000.0 * float(np.sqrt(np.mean(err[used] ** 2)))
            worst[f] = 1000.0 * float(err[used].max())
        seen = used & measured[f, in_order]
        if seen.any():
            observed_rms[f] = 1000.0 * float(np.sqrt(np.mean(err[seen] ** 2)))
    rotational = np.array([c.getMotionType() == osim.Coordinate.Rotational for c in coordinate_list])
    return IKSolution(np.asarray(times, float), [c.getName() for c in coordinate_list], values, rotational,
                      rms, worst, count, time.perf_counter() - started, observed_rms)


def _solve(frames: _FrameSolver, state, frame: int, accuracy: float, far: bool):
    """Solve ``frame`` from the coordinates in ``state`` to ``accuracy`` (from ``far`` off, to
    :data:`START_ACCURACY` first); returns the last solver."""
    if far and accuracy < START_ACCURACY:
        frames.solve(state, frame, START_ACCURACY)
    return frames.solve(state, frame, accuracy)


def _goal_at(goal: CoordinateGoal, frame: int) -> tuple[float, float]:
    return float(goal.values[frame]), float(goal.weights[frame])


def _ik_cost(solver, state, goals: list, marker_weights: np.ndarray) -> float:
    """The objective OpenSim's IK minimises at ``state`` (see :meth:`_FrameSolver.solve`): weighted
    squared marker errors (m^2) plus the coordinate goals' terms (``goals``: (coordinate, weight,
    goal value)), divided by the markers' total weight (``marker_weights``: the solver's markers in
    its order, 0 where missing)."""
    squared = require_opensim().SimTKArrayDouble()
    solver.computeCurrentSquaredMarkerErrors(squared)
    err = np.array([squared.getElt(i) for i in range(squared.size())])
    cost = float(np.nansum(marker_weights * err))
    total = float(marker_weights.sum())
    return (cost + sum(w * (c.getValue(state) - goal) ** 2 for c, w, goal in goals)) / (total if total > 0 else 1.0)


def _better_of_two_starts(frames: _FrameSolver, solver, state, frame: int, coordinate_list: list,
                          from_previous: np.ndarray, marker_weights: np.ndarray, accuracy: float,
                          margin: float) -> tuple[np.ndarray, object]:
    """Solve ``frame`` again from the default pose (the static trial) and keep that solution unless
    its objective exceeds (1 + ``margin``) x the previous frame's start's (a far bend the static
    start cannot reach; a margin keeps the choice from hanging on small differences along a valley
    the markers hardly see); ``state`` is left at the kept one, returned with its solver. Along
    the directions the markers hardly see (a pelvis turn against the levels' axial rotations) a
    solve from the previous frame stops wherever the solver's tolerance is met, so the solution
    would depend on the path; where both starts end equally good, the static start's does not.
    The solve from the default pose runs to :data:`START_ACCURACY` first, then to ``accuracy``."""
    goals = [(frames.coordinates[name], *_goal_at(goal, frame)[::-1]) for name, goal in frames.goals.items()]
    cost_previous = _ik_cost(solver, state, goals, marker_weights)
    for c in coordinate_list:  # a held (locked) coordinate keeps its value
        if not c.getLocked(state):
            c.setValue(state, c.getDefaultValue(), False)
    for c, _, goal in goals:  # a coordinate with a goal starts at it
        if not c.getLocked(state):
            c.setValue(state, goal, False)
    fresh_solver = _solve(frames, state, frame, accuracy, far=True)
    fresh = np.array([c.getValue(state) for c in coordinate_list])
    if _ik_cost(fresh_solver, state, goals, marker_weights) <= (1.0 + margin) * cost_previous:
        return fresh, fresh_solver
    for c, value in zip(coordinate_list, from_previous):
        if not c.getLocked(state):
            c.setValue(state, float(value), False)
    solver = frames.solve(state, frame, accuracy)  # back onto the previous-start solution (already converged)
    return np.array([c.getValue(state) for c in coordinate_list]), solver


def write_coordinate_goals(path: Path, times: np.ndarray, goals: dict[str, CoordinateGoal]) -> None:
    """The goals' values per frame (coordinate units: m for translations) as an OpenSim storage
    file, the coordinate file ``setup_ik.xml`` names for its ``FromFile`` coordinate tasks."""
    osim = require_opensim()
    names = list(goals)
    _write_sto(osim, path, times, names, np.column_stack([goals[n].values for n in names]),
               {"inDegrees": "no", "DataType": "double"})


def write_ik_outputs(folder: Path, solution: IKSolution, motion: str = "ik.mot",
                     errors: str = "ik_marker_errors.sto") -> None:
    """``ik.mot`` (coordinates, rotational ones in degrees, ``inDegrees=yes``) and
    ``ik_marker_errors.sto`` (``marker_error_RMS`` / ``marker_error_max``, as OpenSim's
    InverseKinematicsTool writes them, and ``marker_error_RMS_observed`` over the measured dots;
    metres), through OpenSim's own STO writer."""
    osim = require_opensim()
    values = np.where(solution.rotational, np.degrees(solution.values), solution.values)
    _write_sto(osim, folder / motion, solution.times, solution.coordinates, values,
               {"inDegrees": "yes", "DataType": "double"})
    metres = np.column_stack([solution.marker_rms_mm, solution.marker_max_mm, solution.observed_rms_mm]) / 1000.0
    _write_sto(osim, folder / errors, solution.times, ["marker_error_RMS", "marker_error_max",
                                                       "marker_error_RMS_observed"], metres,
               {"inDegrees": "no", "DataType": "double"})


def _write_sto(osim, path: Path, times: np.ndarray, labels: Sequence[str], values: np.ndarray,
               meta: dict[str, str]) -> None:
    table = osim.TimeSeriesTable()
    table.setColumnLabels([str(label) for label in labels])  # a plain list, as in marker_table
    for f, t in enumerate(times):
        row = osim.RowVector(len(labels))
        for c in range(len(labels)):
            row[c] = float(values[f, c])
        table.appendRow(float(t), row)
    for key, value in meta.items():
        table.addTableMetaDataString(key, value)
    osim.STOFileAdapter.write(table, str(path))
