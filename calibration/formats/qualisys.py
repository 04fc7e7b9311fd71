"""Qualisys QTM calibration export (``.qca.txt``, XML), read only.

Mapping (as Pose2Sim converts it; distortion checked against our own board calibration):

* Intrinsics are in sensor sub-pixel units. The sensor spans ``sensorMaxU`` x ``sensorMaxV``
  units over the full ``fov_video_max`` image, so ``px = units * width_px / sensorMaxU`` (about
  1/64; Pose2Sim divides by 64). The principal point is then shifted by the ``fov_video``
  window's ``left``/``top``.
* Distortion ``radialDistortion1..3`` and ``tangentalDistortion1..2`` are used as OpenCV
  k1 k2 k3 / p1 p2 unchanged. Pose2Sim also divides them by 64; an intrinsic calibration of the
  demo studio's own checkerboard photos gives k1 = -0.048, k2 = 0.12..0.15, matching the file's
  raw values (-0.046, 0.14), not the divided ones, so they are dimensionless here.
* ``transform``: ``x y z`` is the camera centre in the world (mm); the matrix ``r11..r33`` read
  row-wise is the world -> camera rotation of QTM's camera frame, whose y and z axes point
  opposite to OpenCV's (image up, looking along -z). OpenCV pose: ``R = diag(1, -1, -1) @ M``,
  ``t = -R @ centre`` (Pose2Sim: transpose twice, then rotate by pi about the camera x axis).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from spinemocap.camera import MAX_ABS_POSE_MM, Camera, Rig, rotation_problem
from spinemocap.fileio import InputError, reading

QTM_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def read_qca(path: str | os.PathLike) -> Rig:
    """Read every camera of a ``.qca.txt`` file as a :class:`Rig` (mm, world as in QTM)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, LookupError, ValueError) as exc:
        raise InputError(path, f"not a readable Qualisys .qca.txt XML file ({exc})") from exc
    cameras = []
    with reading(path, "Qualisys calibration"):
        for index, node in enumerate(root.findall("cameras/camera"), start=1):
            try:
                cameras.append(_camera(node, index))
            except (TypeError, KeyError, ValueError, AttributeError, ArithmeticError) as exc:
                raise InputError(path, f"camera {node.get('serial')!r}: missing or bad field ({exc})") from exc
        if not cameras:
            raise InputError(path, "no <cameras><camera> entries")
        return Rig(cameras)


def _child(node: ET.Element, tag: str) -> ET.Element:
    """The child element ``tag``; KeyError naming it when the camera lacks it."""
    child = node.find(tag)
    if child is None:
        raise KeyError(f"<{tag}>")
    return child


def _attribute(node: ET.Element, name: str) -> str:
    """The attribute ``name`` of ``node``; KeyError naming both when it is missing."""
    value = node.get(name)
    if value is None:
        raise KeyError(f"<{node.tag} {name}=...>")
    return value


def _span(node: ET.Element, low: str, high: str) -> int:
    """Pixels from ``low`` to ``high`` inclusive (a fov element's left/right or top/bottom)."""
    return int(_attribute(node, high)) - int(_attribute(node, low)) + 1


def _scale(pixels: int, intr: dict, axis: str) -> float:
    """Pixels per sensor unit along ``axis`` (U or V)."""
    units = float(intr[f"sensorMax{axis}"]) - float(intr.get(f"sensorMin{axis}", 0))
    if not (np.isfinite(units) and units > 0):
        raise ValueError(f"sensorMax{axis} - sensorMin{axis} = {units} must be positive")
    return pixels / units


def _camera(node: ET.Element, index: int) -> Camera:
    fov = _child(node, "fov_video")
    fov_max = node.find("fov_video_max")
    if fov_max is None:
        fov_max = fov
    intr, pose = _child(node, "intrinsic").attrib, _child(node, "transform").attrib
    width, height = _span(fov, "left", "right"), _span(fov, "top", "bottom")
    su = _scale(_span(fov_max, "left", "right"), intr, "U")
    sv = _scale(_span(fov_max, "top", "bottom"), intr, "V")
    K = np.array([
        [float(intr["focalLengthU"]) * su, float(intr.get("skew", 0)) * su, float(intr["centerPointU"]) * su - int(_attribute(fov, "left"))],
        [0.0, float(intr["focalLengthV"]) * sv, float(intr["centerPointV"]) * sv - int(_attribute(fov, "top"))],
        [0.0, 0.0, 1.0],
    ])
    dist = np.array([float(intr.get(k, 0)) for k in ("radialDistortion1", "radialDistortion2", "tangentalDistortion1",
                                             "tangentalDistortion2", "radialDistortion3")])
    M = np.array([[float(pose[f"r{i}{j}"]) for j in (1, 2, 3)] for i in (1, 2, 3)])
    centre = np.array([float(pose[k]) for k in ("x", "y", "z")])
    R = QTM_TO_OPENCV @ M
    problem = rotation_problem(R)
    if problem:  # never repaired: a matrix that is not a rotation is a damaged file
        raise ValueError(problem)
    U, _, Vt = np.linalg.svd(R)  # remove the text's rounding (within the tolerance just checked)
    R = U @ Vt
    if not np.isfinite(centre).all() or np.abs(centre).max() > MAX_ABS_POSE_MM:
        raise ValueError(f"camera position {centre.tolist()} must be finite and within {MAX_ABS_POSE_MM:g} mm")
    return Camera(node.get("serial") or f"cam{index}", K, dist, R, -R @ centre, (width, height))
