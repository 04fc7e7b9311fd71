"""Pose2Sim / Anipose calibration TOML (read and write).

One table per camera (``[cam_01]`` ...) with ``name``, ``size = [w, h]`` (px), ``matrix`` (3x3 K,
px), ``distortions`` (OpenCV k1 k2 p1 p2 [k3]), ``rotation`` (Rodrigues vector, world -> camera),
``translation`` (world -> camera, **metres**) and ``fisheye = false``; plus ``[metadata]``.
Pose2Sim's world is Z up like ours, so only the length unit changes (mm <-> m). k3 is written
only when non-zero (Pose2Sim writes four coefficients; both tools pass the list to OpenCV).
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError, read_toml, reading, write_toml

#: The entries every camera table needs; a table holding any camera entry is a camera table.
REQUIRED_KEYS = ("matrix", "size", "rotation", "translation")
CAMERA_KEYS = frozenset({*REQUIRED_KEYS, "distortions", "fisheye"})


def is_pose2sim(data: dict) -> bool:
    """True when ``data`` (a parsed TOML file) holds a Pose2Sim/Anipose camera table."""
    return any(_is_camera_table(v) for v in data.values())


def _is_camera_table(entry: object) -> bool:
    return isinstance(entry, dict) and not CAMERA_KEYS.isdisjoint(entry)


def rig_from_pose2sim(data: dict, source: str | os.PathLike | None = None) -> Rig:
    with reading(source, "Pose2Sim calibration"):
        return _rig(data, source)


def _rig(data: dict, source: str | os.PathLike | None) -> Rig:
    cameras = []
    for key, entry in data.items():
        if not _is_camera_table(entry):
            continue
        missing = [name for name in REQUIRED_KEYS if name not in entry]
        if missing:  # never dropped: a rig without one of its cameras would look whole
            raise InputError(source, f"camera table [{key}] ({entry.get('name', key)!r}) lacks "
                                     f"{', '.join(repr(name) for name in missing)}: every camera needs 'matrix' (3x3 K, "
                                     "px), 'size' ([w, h] px), 'rotation' (Rodrigues vector) and 'translation' (m)")
        try:
            if entry.get("fisheye", False):
                raise InputError(source, f"[{key}] is a fisheye camera; only the pinhole model is supported")
            rvec = np.asarray(entry["rotation"], float).reshape(3, 1)
            if not np.isfinite(rvec).all():
                raise ValueError(f"rotation {rvec.ravel().tolist()} must be finite")
            R = cv2.Rodrigues(rvec)[0]
            size = [float(v) for v in entry["size"]]
            if len(size) != 2 or not all(np.isfinite(v) and abs(v - round(v)) < 1e-6 for v in size):
                raise ValueError(f"size {entry['size']!r} must be two whole numbers of pixels")
            cameras.append(Camera(
                str(entry.get("name", key)), np.asarray(entry["matrix"], float),
                np.asarray(entry.get("distortions", []), float), R, np.asarray(entry["translation"], float) * 1000.0,
                (int(round(size[0])), int(round(size[1]))),
            ))
        except (KeyError, ValueError, TypeError, IndexError, ArithmeticError, cv2.error) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(source, f"[{key}]: missing or bad field ({exc})") from exc
    if not cameras:
        raise InputError(source, "no camera tables (with 'matrix', 'size', 'rotation', 'translation'): not a "
                                 "Pose2Sim/Anipose calibration")
    return Rig(cameras)


def read_pose2sim(path: str | os.PathLike) -> Rig:
    return rig_from_pose2sim(read_toml(path), path)


def write_pose2sim(rig: Rig, path: str | os.PathLike, error_px: float = 0.0) -> None:
    rig.validate(path)
    data = {}
    for i, cam in enumerate(rig, start=1):
        dist = [float(v) for v in (cam.dist if cam.dist[4] != 0 else cam.dist[:4])]
        data[f"cam_{i:02d}"] = {
            "name": cam.name,
            "size": [float(cam.size[0]), float(cam.size[1])],
            "matrix": [[float(v) for v in row] for row in cam.K],
            "distortions": dist,
            "rotation": [float(v) for v in cam.rvec],
            "translation": [float(v) / 1000.0 for v in cam.t],
            "fisheye": False,
        }
    data["metadata"] = {"adjusted": False, "error": float(error_px)}
    write_toml(path, data)
