"""Pinhole cameras with OpenCV distortion, and rigs of them.

Conventions: world coordinates in millimetres, world Z up. A camera maps a world point ``X`` to
camera coordinates ``x_c = R @ X + t`` (camera looks along +z_c, x_c right, y_c down in the
image), then to normalized ``(x_c/z_c, y_c/z_c)``, then applies OpenCV's radial/tangential
distortion ``(k1, k2, p1, p2, k3)`` and the intrinsics ``K``. Pixel ``(0, 0)`` is the centre of
the top-left pixel, as in OpenCV.

Rig file (TOML)::

    units = "mm"          # translations are in millimetres
    world = "Z up"
    [[camera]]
    name = "cam1"
    size = [2448, 1600]   # width, height in pixels
    fx = 2400.0
    fy = 2400.0
    cx = 1223.5
    cy = 799.5
    distortion = [k1, k2, p1, p2, k3]
    rotation = [[r11, r12, r13], [r21, r22, r23], [r31, r32, r33]]   # world -> camera
    translation = [tx, ty, tz]                                        # world -> camera, mm
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterator, Sequence

import cv2
import numpy as np
import numpy.typing as npt

from .fileio import InputError, read_toml, reading, write_toml
from .geometry import distort

ROTATION_TOLERANCE = 1e-5   # |R R^T - I| and |det R - 1| allowed (text files round); beyond: not a rotation
MAX_FOCAL_PX = 1e6          # a focal length beyond this is a damaged file, not a lens
MAX_SIZE_PX = 100_000       # image width / height
MAX_ABS_POSE_MM = 1e7       # camera translations / centres beyond 10 km are damaged values
MAX_ABS_DISTORTION = 1e4    # OpenCV coefficients are O(1); beyond this the model is meaningless


def _matrix(value, shape: tuple[int, ...], camera: str, what: str) -> np.ndarray:
    """``value`` as a float array of ``shape``; ValueError naming the camera otherwise."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"camera {camera!r}: {what} is not numeric ({exc})") from None
    if shape == (-1,):
        return array.ravel()
    if array.size != int(np.prod(shape)):
        raise ValueError(f"camera {camera!r}: {what} needs {int(np.prod(shape))} numbers, got {array.size}")
    return array.reshape(shape)


def _image_size(value, camera: str) -> tuple[int, int]:
    """``[width, height]`` in whole pixels, each 1..MAX_SIZE_PX; ValueError otherwise."""
    try:
        width, height = (float(v) for v in value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"camera {camera!r}: size must be [width, height] in pixels, got {value!r}") from None
    for v in (width, height):
        if not (np.isfinite(v) and v == int(v) and 1 <= v <= MAX_SIZE_PX):
            raise ValueError(f"camera {camera!r}: size {value!r} must be two whole numbers of pixels "
                             f"in 1..{MAX_SIZE_PX}")
    return int(width), int(height)


def rotation_problem(R: np.ndarray, tolerance: float = ROTATION_TOLERANCE) -> str | None:
    """Why (3, 3) ``R`` is not a proper rotation within ``tolerance`` (None when it is). A matrix
    that is not a rotation is an error, never something to repair."""
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        return "rotation must be a finite 3x3 matrix"
    orthogonality = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if orthogonality > tolerance or abs(det - 1.0) > tolerance:
        return (f"rotation is not a proper rotation matrix (|R R^T - I| = {orthogonality:.2g}, det = {det:.6g}; "
                f"tolerance {tolerance:g})")
    return None


def camera_problems(camera: "Camera") -> list[str]:
    """Everything impossible about a camera: intrinsics finite with positive focal lengths below
    ``MAX_FOCAL_PX``, ``K``'s last row (0, 0, 1), finite principal point and skew, finite
    distortion, a rotation within ``ROTATION_TOLERANCE``, a finite translation and centre within
    ``MAX_ABS_POSE_MM``, a non-empty name. The one camera check every reader and writer uses."""
    out = []
    K, name = camera.K, camera.name
    if not isinstance(name, str) or not name.strip():
        out.append("camera name must be a non-empty string")
    if not np.isfinite(K).all():
        out.append(f"intrinsics must be finite (fx={K[0, 0]}, fy={K[1, 1]}, cx={K[0, 2]}, cy={K[1, 2]})")
    else:
        for label, value in (("fx", K[0, 0]), ("fy", K[1, 1])):
            if not 0 < value <= MAX_FOCAL_PX:
                out.append(f"{label} = {value:g} px must be positive and at most {MAX_FOCAL_PX:g}")
        if K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
            out.append(f"K must be upper triangular with last row (0, 0, 1), got {K.tolist()}")
        if max(abs(K[0, 2]), abs(K[1, 2]), abs(K[0, 1])) > MAX_FOCAL_PX:
            out.append(f"principal point / skew beyond {MAX_FOCAL_PX:g} px")
    if not (np.isfinite(camera.dist).all() and np.abs(camera.dist).max() <= MAX_ABS_DISTORTION):
        out.append(f"distortion must be finite and within {MAX_ABS_DISTORTION:g}, got {camera.dist.tolist()}")
    problem = rotation_problem(camera.R)
    if problem:
        out.append(problem)
    if not (np.isfinite(camera.t).all() and np.abs(camera.t).max() <= MAX_ABS_POSE_MM):
        out.append(f"translation must be finite and within {MAX_ABS_POSE_MM:g} mm, got {camera.t.tolist()}")
    elif problem is None and np.abs(camera.R.T @ camera.t).max() > MAX_ABS_POSE_MM:
        out.append(f"camera centre beyond {MAX_ABS_POSE_MM:g} mm")
    return out


@dataclass
class Camera:
    """One calibrated camera. ``K`` (3, 3); ``dist`` (5,) = k1 k2 p1 p2 k3; ``R`` (3, 3) and
    ``t`` (3,) in mm map world to camera; ``size`` = (width, height) in pixels."""

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]

    def __post_init__(self) -> None:
        self.K = _matrix(self.K, (3, 3), self.name, "K")
        d = np.zeros(5)
        src = _matrix(self.dist, (-1,), self.name, "distortion") if np.size(self.dist) else d
        d[: min(5, src.size)] = src[:5]
        self.dist = d
        self.R = _matrix(self.R, (3, 3), self.name, "rotation")
        self.t = _matrix(self.t, (3,), self.name, "translation")
        self.size = _image_size(self.size, self.name)
        self.validate()

    def problems(self) -> list[str]:
        """Why this camera is impossible (empty list: it is valid). See :func:`camera_problems`."""
        return camera_problems(self)

    def validate(self) -> None:
        """Raise ValueError naming the camera and every problem (see :func:`camera_problems`);
        readers turn it into :class:`InputError` naming their file."""
        found = self.problems()
        if found:
            raise ValueError(f"camera {self.name!r}: " + "; ".join(found))

    # ------------------------------------------------------------------ construction
    @classmethod
    def look_at(
        cls,
        name: str,
        position_mm: npt.ArrayLike,
        target_mm: npt.ArrayLike,
        size: tuple[int, int],
        focal_px: float,
        up: npt.ArrayLike = (0.0, 0.0, 1.0),
        dist: npt.ArrayLike = (0, 0, 0, 0, 0),
        principal_point: tuple[float, float] | None = None,
    ) -> "Camera":
        """A camera at ``position_mm`` looking at ``target_mm`` with world ``up`` pointing up in
        the image. ``principal_point`` defaults to the image centre."""
        position = np.asarray(position_mm, float)
        forward = np.asarray(target_mm, float) - position
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(up, float))
        if np.linalg.norm(right) < 1e-9:
            raise ValueError(f"camera {name!r}: viewing direction is parallel to 'up'")
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])
        w, h = size
        cx, cy = principal_point if principal_point is not None else ((w - 1) / 2, (h - 1) / 2)
        K = np.array([[focal_px, 0, cx], [0, focal_px, cy], [0, 0, 1]], float)
        return cls(name, K, np.asarray(dist, float), R, -R @ position, size)

    # ------------------------------------------------------------------ geometry
    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (mm)."""
        return -self.R.T @ self.t

    @property
    def projection_matrix(self) -> np.ndarray:
        """(3, 4) ``K [R | t]`` for undistorted pixel coordinates."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.R)[0].ravel()

    def to_camera(self, points_mm: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) camera coordinates (mm)."""
        return np.asarray(points_mm, float).reshape(-1, 3) @ self.R.T + self.t

    def depth(self, points_mm: np.ndarray) -> np.ndarray:
        """(N,) z_c of world points (mm); positive in front of the camera."""
        return self.to_camera(points_mm)[:, 2]

    def distort(self, normalized: np.ndarray) -> np.ndarray:
        """Apply the distortion model to (N, 2) normalized image coordinates."""
        return distort(normalized, self.dist)

    def project(self, points_mm: np.ndarray, distort: bool = True) -> np.ndarray:
        """(N, 3) world points -> (N, 2) pixels. Points behind the camera give NaN."""
        pc = self.to_camera(points_mm)
        with np.errstate(divide="ignore", invalid="ignore"):
            normalized = pc[:, :2] / pc[:, 2:3]
        normalized[pc[:, 2] <= 1e-9] = np.nan
        if distort:
            normalized = self.distort(normalized)
        return normalized @ self.K[:2, :2].T + self.K[:2, 2]

    def undistort_points(self, pixels: np.ndarray, normalized: bool = False) -> np.ndarray:
        """(N, 2) distorted pixels -> undistorted pixels (or normalized coordinates)."""
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        if pixels.size == 0:
            return pixels.copy()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        und = cv2.undistortPoints(
            pixels.reshape(-1, 1, 2), self.K, self.dist, criteria=criteria
        ).reshape(-1, 2)
        if normalized:
            return und
        return und @ self.K[:2, :2].T + self.K[:2, 2]

    def rays(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Back-project (N, 2) pixels: returns origin (3,) and (N, 3) unit directions, world."""
        xy = self.undistort_points(pixels, normalized=True)
        dirs_cam = np.column_stack([xy, np.ones(len(xy))])
        dirs = dirs_cam @ self.R  # R^T applied to each row
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return self.center, dirs

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel lies inside the image (minus ``margin`` px)."""
        w, h = self.size
        u, v = pixels[:, 0], pixels[:, 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5 + margin) & (u <= w - 0.5 - margin) & (v >= -0.5 + margin) & (v <= h - 0.5 - margin)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "size": list(self.size),
            "fx": float(self.K[0, 0]),
            "fy": float(self.K[1, 1]),
            "cx": float(self.K[0, 2]),
            "cy": float(self.K[1, 2]),
            "skew": float(self.K[0, 1]),
            "distortion": [float(v) for v in self.dist],
            "rotation": [[float(v) for v in row] for row in self.R],
            "translation": [float(v) for v in self.t],
        }

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "Camera":
        """A camera from a rig file's ``[[camera]]`` table; :class:`InputError` naming ``source``
        for a missing, mistyped or impossible value."""
        if not isinstance(data, dict):
            raise InputError(source, f"a [[camera]] entry must be a table, got {data!r}")
        required = ("name", "size", "fx", "fy", "cx", "cy", "rotation", "translation")
        missing = [k for k in required if k not in data]
        if missing:
            raise InputError(source, f"camera entry {data.get('name', '?')!r} lacks {missing}")
        name = data["name"]
        if not isinstance(name, (str, int)) or isinstance(name, bool):
            raise InputError(source, f"camera name must be a string, got {name!r}")
        for key in ("fx", "fy", "cx", "cy", "skew"):
            value = data.get(key, 0.0)
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise InputError(source, f"camera {name!r}: {key} must be a number, got {value!r}")
        K = np.array(
            [[data["fx"], data.get("skew", 0.0), data["cx"]], [0, data["fy"], data["cy"]], [0, 0, 1]],
            float,
        )
        try:
            return cls(str(name), K, data.get("distortion", [0] * 5), data["rotation"], data["translation"],
                       data["size"])
        except (ValueError, TypeError, OverflowError) as exc:
            raise InputError(source, str(exc)) from exc


@dataclass
class Rig:
    """An ordered set of synchronized cameras with unique names."""

    cameras: list[Camera] = field(default_factory=list)

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"rig has duplicate camera names {dupes}")

    def validate(self, source: str | os.PathLike | None = None) -> "Rig":
        """Check every camera again (:func:`camera_problems`) and the names' uniqueness;
        :class:`InputError` naming ``source`` otherwise. Writers call it before writing."""
        try:
            for camera in self.cameras:
                camera.validate()
            self.__post_init__()
        except ValueError as exc:
            raise InputError(source, str(exc)) from exc
        return self

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for cam in self.cameras:
                if cam.name == key:
                    return cam
            raise KeyError(f"no camera named {key!r} in rig (cameras: {self.names})")
        return self.cameras[key]

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def subset(self, names: Sequence[str]) -> "Rig":
        return Rig([self[n] for n in names])

    def transformed(self, R: np.ndarray, t: np.ndarray, scale: float = 1.0) -> "Rig":
        """The rig expressed in a new world frame ``X_new = scale R X_old + t`` (mm): every
        camera's centre moves with the world, its orientation turns by ``R``, its camera
        coordinates scale with the world; intrinsics unchanged, so every projection is the same."""
        cameras = []
        for cam in self.cameras:
            R_new = cam.R @ np.asarray(R, float).T
            cameras.append(Camera(cam.name, cam.K.copy(), cam.dist.copy(), R_new, scale * cam.t - R_new @ t, cam.size))
        return Rig(cameras)

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (C, N, 2) distorted pixels in every camera."""
        return np.stack([cam.project(points_mm) for cam in self.cameras])

    def to_dict(self) -> dict:
        return {"units": "mm", "world": "Z up", "camera": [c.to_dict() for c in self.cameras]}

    def to_toml(self, path: str | os.PathLike) -> None:
        write_toml(path, self.validate(path).to_dict())

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "Rig":
        units = data.get("units", "mm")
        if units != "mm":
            raise InputError(source, f"rig units {units!r} not supported (expected 'mm')")
        entries = data.get("camera")
        if not entries:
            raise InputError(source, "rig file has no [[camera]] entries")
        if not isinstance(entries, list):
            raise InputError(source, "cameras must be an array of tables ([[camera]]), not a single [camera] table")
        with reading(source, "rig"):
            return cls([Camera.from_dict(e, source) for e in entries])

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "Rig":
        return cls.from_dict(read_toml(path), source=str(path))
