"""OpenSim's own tools on the tape markers: TRC writing, MarkerPlacer (ScaleTool) and
InverseKinematicsTool setups, runs and their outputs read back.

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
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from ..fileio import InputError

INFERRED_WEIGHT = 0.2  # IK weight of a marker-frame the tracker inferred (observed = 1)


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


def marker_weights(status: np.ndarray) -> np.ndarray:
    """(D,) IK task weight per marker from its (F, D) status: observed frames count 1, inferred
    :data:`INFERRED_WEIGHT`, averaged over the frames the marker is not missing in; 0 for a
    marker missing throughout (its task is switched off). Missing samples are NaN in the TRC,
    which OpenSim's IK skips frame by frame."""
    observed = (status == "observed").sum(axis=0)
    inferred = (status == "inferred").sum(axis=0)
    present = observed + inferred
    with np.errstate(invalid="ignore", divide="ignore"):
        w = (observed + INFERRED_WEIGHT * inferred) / present
    return np.where(present > 0, w, 0.0)


def write_trc(path: str | os.PathLike, labels: Sequence[str], times: np.ndarray, positions_mm: np.ndarray,
              fps: float) -> Path:
    """TRC in metres through OpenSim's own ``TRCFileAdapter`` (NaN = missing sample)."""
    osim = require_opensim()
    F, D = positions_mm.shape[:2]
    table = osim.TimeSeriesTableVec3()
    names = osim.StdVectorString()
    for label in labels:
        names.append(str(label))
    table.setColumnLabels(names)
    metres = np.asarray(positions_mm, float) / 1000.0
    for f in range(F):
        row = osim.RowVectorVec3(D)
        for d in range(D):
            x, y, z = metres[f, d]
            row[d] = osim.Vec3(float(x), float(y), float(z))
        table.appendRow(float(times[f]), row)
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
                   priors: dict[str, float] | None = None) -> Path:
    """``setup_ik.xml``: one marker task per label; errors reported to ``<name>_ik_marker_errors.sto``.
    ``priors``: {coordinate: weight} of coordinate tasks pulling toward the default value (0)."""
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
    for coordinate, weight in (priors or {}).items():
        task = osim.IKCoordinateTask()
        task.setName(coordinate)
        task.setApply(True)
        task.setWeight(float(weight))
        task.setValueType(osim.IKCoordinateTask.DefaultValue)
        tasks.cloneAndAppend(task)
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
