"""Camera calibration: boards, intrinsics, extrinsics with bundle adjustment, Vicon wand
co-registration and calibration file formats. Depends only on spinemocap's core modules
(:mod:`spinemocap.camera`, :mod:`spinemocap.geometry`, :mod:`spinemocap.markers`,
:mod:`spinemocap.fileio`, ...); the Vicon C3D is read by the application layer
(:mod:`spinemocap.app.c3d_inputs`, with ``exporters.read``) and handed in as a marker table.

Pipeline (one module per step):

* :mod:`calibration.boards` — board spec (checkerboard / ChArUco; polarity, ChArUco layout and
  mirrored views, found when not given), detection, view checks;
* :mod:`calibration.intrinsics` — one camera's K and distortion from board views;
* :mod:`calibration.extrinsics` — PnP spanning tree + bundle adjustment (the rig adjustment of
  :mod:`spinemocap.rig_adjust`, Ceres through pycolmap by default), world frame from the floor
  (ChArUco or checkerboard; the checkerboard's corner order in :mod:`calibration.boards`);
* :mod:`calibration.wandwave` — all extrinsics from a wand wave alone (essential matrices,
  spanning tree, wand scale, rigid-wand bundle adjustment, floor from the wand on the floor);
* :mod:`calibration.wand` — wands (T, linear): identify, triangulate; Vicon co-registration:
  clock offset, similarity transform;
* :mod:`calibration.formats` — ours, Pose2Sim/Anipose TOML, Qualisys .qca.txt, Vicon .xcp;
* :mod:`calibration.check` — per-camera table and reprojection-error plot, comparison with
  another calibration of the same cameras;
* :mod:`calibration.geometry` — triangulation, rigid fits (shared helpers);

The benchmark (``spinemocap bench calibration``) and the synthetic renders of boards and a wand
wave it and the tests use live in the application layer: :mod:`spinemocap.bench.calibration`,
:mod:`spinemocap.bench.calibration_scenes`, :mod:`spinemocap.bench.board_session` (a studio board
session with a real lab's traits); board calibration from recordings (videos or image folders per
camera) is :mod:`spinemocap.app.calibrate`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

# public name -> defining module (imported on first access: OpenCV and SciPy load only when used)
_PUBLIC = {
    "BoardSpec": "calibration.boards",
    "detect_board": "calibration.boards",
    "calibrate_intrinsics": "calibration.intrinsics",
    "calibrate_extrinsics": "calibration.extrinsics",
    "calibrate_wand_wave": "calibration.wandwave",
    "WandSpec": "calibration.wand",
    "coregister": "calibration.wand",
    "vicon_wand_from_table": "calibration.wand",
    "read_rig": "calibration.formats",
    "write_rig": "calibration.formats",
}

__all__ = list(_PUBLIC)


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
