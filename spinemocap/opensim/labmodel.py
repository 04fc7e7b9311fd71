"""The tape markers on a lab's own OpenSim model (``spinemocap opensim --model FILE.osim --bodies MAP.toml``).

``MAP.toml`` names the model body of each vertebra the lab model has (keys ``S1`` (sacrum) ...
``T1`` and ``head_neck``; a ``[bodies]`` table or top level)::

    S1 = "sacrum"
    L5 = "lumbar5"
    L4 = "lumbar4"
    T12 = "thoracic12"

Every tape dot goes on the body of the vertebra under its row (:mod:`geometry`), or of the nearest
vertebra along the spine the map names. The model's default pose is taken to face OpenSim's +X
with Y up (OpenSim's convention, and the frame of the TRC written here), so a dot's first place is
its static position shifted by the offset between the mapped vertebrae's centres and the bodies'
origins; MarkerPlacer then moves the markers onto the static trial, and IK solves the model's own
coordinates. ``spine_angles.csv`` holds those coordinates as the lab model defines them (OpenSim
signs; rotational ones in degrees), since their meaning is the lab's.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np
import numpy.typing as npt
import pandas as pd

from ..fileio import InputError, atomic_write, read_toml, strict_json
from ..markers import MarkerTable
from ..tape import TapeSpec
from .geometry import CHAIN, HEAD_NECK, LevelRows, spine_geometry
from .pipeline import (
    FLAG_RMS_MM,
    OpenSimResult,
    OpenSimSettings,
    inverse_kinematics,
    place_markers,
    prepare,
    publish,
    work_folder,
)
from .summary import LabModelSummary
from .tools import IK_ACCURACY, mean_weights, read_storage, require_opensim


def read_body_map(path: str | os.PathLike) -> dict[str, str]:
    """{vertebra: body name} from ``MAP.toml``; unknown vertebra names are an :class:`InputError`."""
    data = read_toml(path)
    table = data.get("bodies", data)
    known = set(CHAIN) | {HEAD_NECK}
    bad = [k for k in table if k not in known]
    if bad or not table:
        raise InputError(path, f"keys must be vertebrae {list(CHAIN)} or {HEAD_NECK!r}; got {bad or 'none'}")
    return {str(k): str(v) for k, v in table.items()}


def run_lab_model(markers: MarkerTable, tape: TapeSpec, levels: LevelRows, up: npt.ArrayLike,
                  facing: Sequence[float], out_dir: str | os.PathLike, model_file: str | os.PathLike,
                  bodies_file: str | os.PathLike, static: MarkerTable | None = None,
                  settings: OpenSimSettings | None = None,
                  source: str | None = None) -> OpenSimResult[LabModelSummary]:
    """Attach, place and solve on the lab's model; same outputs as :func:`pipeline.run_opensim`
    (``settings.depth_scale`` places the vertebral centres; the lab's model has no skin slip; IK
    solved to ``settings.accuracy`` but at most :data:`tools.IK_ACCURACY`)."""
    osim = require_opensim()
    settings = settings or OpenSimSettings()
    body_map = read_body_map(bodies_file)
    data, st, rows, facing_error = prepare(markers, tape, up, facing, static, settings, source)
    geometry = spine_geometry(rows, levels, settings.depth_scale, source)
    model = osim.Model(str(model_file))
    missing = [b for b in body_map.values() if not model.getBodySet().contains(b)]
    if missing:
        raise InputError(bodies_file, f"bodies {missing} are not in {model_file}")
    state = model.initSystem()
    mapped = [geometry.names.index(v) for v in body_map]
    graph = tape.graph
    placed = np.flatnonzero(np.isfinite(st.positions).all(axis=1))
    origins, rotations = {}, {}
    for vertebra, body in body_map.items():
        X = model.getBodySet().get(body).getTransformInGround(state)
        origins[vertebra] = 1000.0 * np.array([X.p()[i] for i in range(3)])
        rotations[vertebra] = np.array([[X.R().get(r, c) for c in range(3)] for r in range(3)])
    shift = np.mean([origins[v] for v in body_map], axis=0) - geometry.centre[mapped].mean(axis=0)
    labels: list[str] = []
    on_body: dict[str, list[str]] = {}
    for d in placed:
        k = int(geometry.row_body[graph.row[d]])
        vertebra = geometry.names[min(mapped, key=lambda m: abs(m - k))]
        body = model.getBodySet().get(body_map[vertebra])
        location = rotations[vertebra].T @ (st.positions[d] + shift - origins[vertebra]) / 1000.0
        model.addMarker(osim.Marker(graph.labels[d], body, osim.Vec3(*[float(x) for x in location])))
        labels.append(graph.labels[d])
        on_body.setdefault(body_map[vertebra], []).append(graph.labels[d])
    model.finalizeConnections()
    out_dir = Path(out_dir)
    work = work_folder(out_dir)
    try:
        model.printToXML(str(work / "model_generic.osim"))
        place_markers(work, labels, placed, st)
        # no skin slips on a lab's model: at most OpenSim's accuracy (the held slips' 1e-7 took ~15 s a
        # frame on the studio's spine carrying the tape's markers as a lab model)
        accuracy = max(settings.accuracy, IK_ACCURACY)
        ik_seconds, _ = inverse_kinematics(work, labels, placed, data, np.arange(len(data.times)), accuracy)
        angles = _coordinates_table(work / "ik.mot", work / "ik_marker_errors.sto")
        rms = angles["marker_rms"].to_numpy()
        flagged_frames = [int(f) for f in np.flatnonzero(rms > FLAG_RMS_MM)]
        summary = LabModelSummary(
            frames=len(angles), fps=data.fps, model=str(model_file), bodies_map=body_map,
            marker_rms_mm=float(np.nanmean(rms)), marker_rms_mm_max=float(np.nanmax(rms)),
            ms_per_frame=1000.0 * ik_seconds / max(len(angles), 1), flagged_frames=flagged_frames,
            flag_reasons={f"marker RMS > {FLAG_RMS_MM:g} mm": len(flagged_frames)} if flagged_frames else {},
            warnings=[],
            driven_joints=[c for c in angles.columns if c not in ("frame", "time", "marker_rms", "marker_max")],
            markers_by_body=on_body, facing_error_deg=facing_error,
            marker_weights=dict(zip(labels, np.round(mean_weights(data.weights()[:, placed]), 3).tolist())))
        with atomic_write(work / "spine_angles.csv") as handle:
            handle.write(f"# spinemocap opensim on the lab model {Path(model_file).name}: its own coordinates as "
                         "solved by IK. Units: time s; rotational coordinates deg, translational m; marker_rms, "
                         "marker_max mm. Signs: as the model defines them.\n")
            angles.to_csv(handle, index=False, float_format="%.4f")
        with atomic_write(work / "summary.json") as handle:
            handle.write(strict_json(summary.to_dict()))
        files = publish(work, out_dir)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return OpenSimResult(out_dir, angles, summary, None, geometry, files)


def _coordinates_table(motion: Path, errors: Path) -> pd.DataFrame:
    times, labels, values, _ = read_storage(motion)
    table = pd.DataFrame({"frame": np.arange(len(times)), "time": times})
    for i, label in enumerate(labels):
        table[label] = values[:, i]
    _, err_labels, err, _ = read_storage(errors)
    table["marker_rms"] = 1000.0 * err[:, err_labels.index("marker_error_RMS")]
    table["marker_max"] = 1000.0 * err[:, err_labels.index("marker_error_max")]
    return table
