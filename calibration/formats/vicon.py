"""Vicon Nexus camera calibration (``.xcp``, XML; read and write).

Structure as Nexus exports it::

    <Cameras VERSION="1.0">
      <Camera DEVICEID="cam1" USERID="1" NAME="cam1" TYPE="Video" SENSOR_SIZE="w h"
              PIXEL_ASPECT_RATIO="fx/fy" SKEW="0" ...>
        <KeyFrames>
          <KeyFrame FRAME="0" POSITION="x y z" ORIENTATION="qx qy qz qw" FOCAL_LENGTH="fx"
                    PRINCIPAL_POINT="cx cy" VICON_RADIAL="k1 k2" IMAGE_ERROR="px" WORLD_ERROR="mm"/>
        </KeyFrames>
      </Camera>
    </Cameras>

Our mapping (read and write use the same one):

* ``POSITION``: camera centre in the world, mm.
* ``ORIENTATION``: unit quaternion, scalar last, of the camera -> world rotation (the rotation
  whose columns are the camera axes in the world; as Pose2Sim reads it, ``R_wc = R(q)^T``).
* ``FOCAL_LENGTH`` = fx in px; fy = fx / ``PIXEL_ASPECT_RATIO``; ``PRINCIPAL_POINT`` = (cx, cy) px.
* ``VICON_RADIAL = "k1 k2"`` is read as OpenCV's k1, k2 on normalized coordinates (what
  Pose2Sim does). Vicon's radial model has no tangential or k6 terms, so a camera with non-zero
  p1, p2 or k3 is written with an extra ``SPINEMOCAP_DISTORTION="k1 k2 p1 p2 k3"`` attribute
  that our reader prefers (Nexus ignores unknown attributes); Nexus itself sees only k1, k2.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np
from scipy.spatial.transform import Rotation

from spinemocap.camera import MAX_ABS_POSE_MM, Camera, Rig
from spinemocap.fileio import InputError, atomic_write, reading

QUATERNION_TOLERANCE = 1e-5  # |q| - 1 allowed (text rounding); beyond: not a rotation, never renormalised


def _floats(text: str | None, n: int, what: str) -> list[float]:
    if text is None:
        raise KeyError(what)
    values = [float(v) for v in text.split()]
    if len(values) < n:
        raise ValueError(f"{what} has {len(values)} values, expected {n}")
    return values


def read_xcp(path: str | os.PathLike) -> Rig:
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, LookupError, ValueError) as exc:
        raise InputError(path, f"not a readable Vicon .xcp XML file ({exc})") from exc
    cameras: list[Camera] = []
    with reading(path, "Vicon calibration"):
        for node in root.iter("Camera"):
            name = node.get("NAME") or node.get("DEVICEID") or f"cam{len(cameras) + 1}"
            try:
                cameras.append(_camera(node, name))
            except (KeyError, ValueError, TypeError, AttributeError, ArithmeticError) as exc:
                raise InputError(path, f"camera {name!r}: missing or bad field {exc}") from exc
        if not cameras:
            raise InputError(path, "no <Camera> entries")
        return Rig(cameras)


def _camera(node: ET.Element, name: str) -> Camera:
    key = node.find("KeyFrames/KeyFrame")
    if key is None:
        raise KeyError("KeyFrames/KeyFrame")
    w, h = _floats(node.get("SENSOR_SIZE"), 2, "SENSOR_SIZE")[:2]
    fx = _floats(key.get("FOCAL_LENGTH"), 1, "FOCAL_LENGTH")[0]
    aspect = float(node.get("PIXEL_ASPECT_RATIO", "1"))
    if not (np.isfinite(aspect) and aspect > 0):
        raise ValueError(f"PIXEL_ASPECT_RATIO = {aspect} must be finite and positive")
    fy = fx / aspect
    cx, cy = _floats(key.get("PRINCIPAL_POINT"), 2, "PRINCIPAL_POINT")[:2]
    skew = float(node.get("SKEW", "0"))
    if key.get("SPINEMOCAP_DISTORTION"):
        dist = _floats(key.get("SPINEMOCAP_DISTORTION"), 5, "SPINEMOCAP_DISTORTION")[:5]
    else:
        k1, k2 = (_floats(key.get("VICON_RADIAL"), 2, "VICON_RADIAL") if key.get("VICON_RADIAL") else [0, 0])[:2]
        dist = [k1, k2, 0.0, 0.0, 0.0]
    q = np.array(_floats(key.get("ORIENTATION"), 4, "ORIENTATION")[:4])
    if not (np.isfinite(q).all() and abs(np.linalg.norm(q) - 1.0) <= QUATERNION_TOLERANCE):
        raise ValueError(f"ORIENTATION {q.tolist()} is not a unit quaternion (norm {np.linalg.norm(q):.6g})")
    R = Rotation.from_quat(q).as_matrix().T
    centre = np.array(_floats(key.get("POSITION"), 3, "POSITION")[:3])
    if not np.isfinite(centre).all() or np.abs(centre).max() > MAX_ABS_POSE_MM:
        raise ValueError(f"POSITION {centre.tolist()} must be finite and within {MAX_ABS_POSE_MM:g} mm")
    K = np.array([[fx, skew, cx], [0, fy, cy], [0, 0, 1]])
    return Camera(name, K, np.asarray(dist, float), R, -R @ centre, (int(round(w)), int(round(h))))


def write_xcp(rig: Rig, path: str | os.PathLike, image_error_px: dict[str, float] | None = None) -> None:
    rig.validate(path)
    root = ET.Element("Cameras", VERSION="1.0")
    for i, cam in enumerate(rig, start=1):
        node = ET.SubElement(root, "Camera", {
            "DEVICEID": cam.name, "USERID": str(i), "NAME": cam.name, "TYPE": "Video",
            "SENSOR_SIZE": f"{cam.size[0]} {cam.size[1]}",
            "PIXEL_ASPECT_RATIO": repr(float(cam.K[0, 0] / cam.K[1, 1])),
            "SKEW": repr(float(cam.K[0, 1])),
        })
        q = Rotation.from_matrix(cam.R.T).as_quat()  # x y z w, camera -> world
        attrs = {
            "FRAME": "0",
            "POSITION": " ".join(repr(float(v)) for v in cam.center),
            "ORIENTATION": " ".join(repr(float(v)) for v in q),
            "FOCAL_LENGTH": repr(float(cam.K[0, 0])),
            "PRINCIPAL_POINT": f"{float(cam.K[0, 2])!r} {float(cam.K[1, 2])!r}",
            "VICON_RADIAL": f"{float(cam.dist[0])!r} {float(cam.dist[1])!r}",
            "IMAGE_ERROR": repr(float((image_error_px or {}).get(cam.name, 0.0))),
            "WORLD_ERROR": "0",
        }
        if np.any(cam.dist[2:] != 0):
            attrs["SPINEMOCAP_DISTORTION"] = " ".join(repr(float(v)) for v in cam.dist)
        ET.SubElement(ET.SubElement(node, "KeyFrames"), "KeyFrame", attrs)
    ET.indent(root)
    with atomic_write(path, "wb") as handle:
        ET.ElementTree(root).write(handle, encoding="UTF-8", xml_declaration=True)
