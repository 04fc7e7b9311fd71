"""A reference object of known geometry in the capture volume: what fixes a lab's world frame.

A lab's calibration puts the world where its reference object is (Vicon's L-frame on the floor,
a checkerboard at a surveyed place). The tape's dots alone cannot tell where the world is (a
similarity common to all cameras moves every triangulated dot and changes no residual), so
``spinemocap track --refine-rig`` holds the reference's markers as control points: their world
positions are known, their blobs are found in the images (:mod:`spinemocap.detect.reference`),
and the bundle adjustment keeps the refined rig's world frame on them
(:mod:`spinemocap.track.rig_refine`).

``reference.toml`` (named by ``capture.toml``'s ``[capture] reference``, or given with
``spinemocap track --reference FILE``)::

    [reference]
    name = "L-frame"
    marker_diameter_mm = 14.0
    labels = ["REF1", "REF2", "REF3", "REF4", "REF5"]
    # marker centres in the object's own frame (mm): the object's design, from its maker
    markers_mm = [[0.0, 0.0, 0.0], [80.0, 0.0, 0.0], [190.0, 0.0, 0.0], [0.0, 110.0, 0.0], [0.0, 250.0, 0.0]]
    [reference.pose]
    # where the object stands in the world: x_world = R x_object + t (mm); the identity when the
    # object defines the world (Vicon's "set volume origin")
    rotation = [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]
    translation_mm = [370.0, 189.0, 993.0]

Units mm, world Z up (as the rig).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .fileio import InputError, read_toml, write_toml

# The studio's L-frame (object frame, mm): a short arm along x with markers at 0, 80 and 190 mm
# and a long arm along y at 0, 110 and 250 mm, all in one plane (z = 0), markers 14 mm across.
# The unequal spacings tell the arms and their ends apart (as Vicon's L-frame and wand).
LFRAME_LABELS = ("REF1", "REF2", "REF3", "REF4", "REF5")
LFRAME_MARKERS_MM = ((0.0, 0.0, 0.0), (80.0, 0.0, 0.0), (190.0, 0.0, 0.0), (0.0, 110.0, 0.0), (0.0, 250.0, 0.0))
LFRAME_MARKER_DIAMETER_MM = 14.0


@dataclass
class ReferenceObject:
    """Markers at known places: ``markers_mm`` (N, 3) centres in the object's own frame,
    ``rotation`` (3, 3) and ``translation_mm`` (3,) its pose (``x_world = R x_object + t``),
    ``marker_diameter_mm`` the markers' size, ``labels`` (N,) their names."""

    name: str
    labels: list[str]
    markers_mm: np.ndarray
    marker_diameter_mm: float
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.labels = [str(label) for label in self.labels]
        self.markers_mm = np.asarray(self.markers_mm, float).reshape(-1, 3)
        self.rotation = np.asarray(self.rotation, float).reshape(3, 3)
        self.translation_mm = np.asarray(self.translation_mm, float).reshape(3)
        problems = self.problems()
        if problems:
            raise ValueError("invalid reference object: " + "; ".join(problems))

    @classmethod
    def lframe(cls, rotation: np.ndarray | None = None, translation_mm: np.ndarray | None = None) -> ReferenceObject:
        """The studio's L-frame (:data:`LFRAME_MARKERS_MM`) at a pose (default: defining the world)."""
        return cls("L-frame", list(LFRAME_LABELS), np.array(LFRAME_MARKERS_MM), LFRAME_MARKER_DIAMETER_MM,
                   np.eye(3) if rotation is None else rotation, np.zeros(3) if translation_mm is None else translation_mm)

    @property
    def n_markers(self) -> int:
        return len(self.markers_mm)

    @property
    def world_mm(self) -> np.ndarray:
        """(N, 3) marker centres in the world (mm)."""
        return self.markers_mm @ self.rotation.T + self.translation_mm

    def problems(self) -> list[str]:
        """What makes this object unusable as a world reference (empty when none): at least 3
        markers not on one line (a line leaves a rotation free), distinct finite positions,
        one label per marker, a proper rotation, a positive marker size."""
        out = []
        if len(self.labels) != len(self.markers_mm):
            out.append(f"{len(self.labels)} labels for {len(self.markers_mm)} markers")
        elif len(set(self.labels)) != len(self.labels):
            out.append(f"labels repeat: {self.labels}")
        if not np.isfinite(self.markers_mm).all() or not np.isfinite(self.translation_mm).all():
            out.append("marker positions and translation must be finite numbers")
        elif len(self.markers_mm) < 3:
            out.append(f"needs at least 3 markers to fix a world frame (has {len(self.markers_mm)})")
        else:
            centred = self.markers_mm - self.markers_mm.mean(axis=0)
            spread = np.linalg.svd(centred, compute_uv=False)
            if spread[1] < 1e-3 * max(spread[0], 1e-9):
                out.append("the markers lie on one line (a rotation about it stays free): use an L or a plate")
            gaps = np.linalg.norm(self.markers_mm[:, None] - self.markers_mm[None], axis=2)
            if (gaps + np.eye(len(gaps)) * 1e9).min() < self.marker_diameter_mm:
                out.append("two markers are closer than a marker's diameter")
        R = self.rotation
        if not np.isfinite(R).all() or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            out.append("pose rotation must be a proper rotation matrix (orthonormal, determinant +1)")
        if not (np.isfinite(self.marker_diameter_mm) and self.marker_diameter_mm > 0):
            out.append(f"marker_diameter_mm must be positive (got {self.marker_diameter_mm})")
        return out

    def to_dict(self) -> dict:
        return {"reference": {
            "name": self.name, "marker_diameter_mm": float(self.marker_diameter_mm), "labels": list(self.labels),
            "markers_mm": self.markers_mm.tolist(),
            "pose": {"rotation": self.rotation.tolist(), "translation_mm": self.translation_mm.tolist()}}}

    def to_toml(self, path: str | os.PathLike) -> None:
        """Write ``reference.toml`` (atomically)."""
        write_toml(path, self.to_dict())

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> ReferenceObject:
        """Read a ``reference.toml``; :class:`InputError` naming the file for anything missing or
        impossible."""
        data = read_toml(path).get("reference")
        if not isinstance(data, dict):
            raise InputError(path, "missing [reference] table")
        pose = data.get("pose", {})
        if not isinstance(pose, dict):
            raise InputError(path, "[reference.pose] must be a table")
        for key in ("labels", "markers_mm", "marker_diameter_mm"):
            if key not in data:
                raise InputError(path, f"[reference] lacks {key!r}")
        try:
            return cls(str(data.get("name", "reference")), list(data["labels"]), np.asarray(data["markers_mm"], float),
                       float(data["marker_diameter_mm"]), np.asarray(pose.get("rotation", np.eye(3)), float),
                       np.asarray(pose.get("translation_mm", np.zeros(3)), float))
        except (TypeError, ValueError) as exc:
            raise InputError(path, str(exc)) from None
