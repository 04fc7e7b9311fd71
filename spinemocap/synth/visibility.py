"""Which camera sees which dot: geometric tests, not guesses.

A dot counts as visible in a camera when
1. its centre projects inside the image (at least ``IMAGE_MARGIN_PX`` from the border);
2. it faces the camera: the angle between the skin normal and the direction to the camera is
   below ``MAX_VIEW_ANGLE_DEG`` (beyond that the hole is a sliver no blob detector finds);
3. no part of the body (or the sports-bra band) lies on the segment from the dot to the camera
   centre: ray casting against the posed mesh (VTK OBB tree);
4. no ball hides its centre, and at most one of four points on its rim (at 80 % of the dot
   radius) is hidden: exact segment/sphere tests.
"""

from __future__ import annotations

import numpy as np

from ..camera import Rig
from .occluders import segments_blocked_by_spheres

MAX_VIEW_ANGLE_DEG = 78.0
IMAGE_MARGIN_PX = 3.0
RAY_LIFT_MM = 2.0  # start rays just above the tape so they do not hit the dot's own skin


class MeshRayCaster:
    """Segment/mesh intersection tests against one posed triangle mesh."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import pyvista as pv
        import vtk

        mesh = pv.PolyData(np.asarray(vertices, float), np.column_stack([np.full(len(faces), 3), faces]).ravel())
        # a static cell locator builds ~10x faster than an OBB tree and we rebuild every frame
        self._locator = vtk.vtkStaticCellLocator()
        self._locator.SetDataSet(mesh)
        self._locator.BuildLocator()
        self._t, self._x, self._pc = vtk.reference(0.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self._sub, self._cell = vtk.reference(0), vtk.reference(0)

    def blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(S,) bool: does the segment ``starts[s] -> ends[s]`` cross the mesh?"""
        out = np.zeros(len(starts), dtype=bool)
        for s, (a, b) in enumerate(zip(starts, ends)):
            out[s] = bool(self._locator.IntersectWithLine(a, b, 0.0, self._t, self._x, self._pc, self._sub, self._cell))
        return out


def rim_points(centres: np.ndarray, normals: np.ndarray, radius_mm: float) -> np.ndarray:
    """(D, 4, 3) four points on each dot's rim (at 80 % radius) in the plane normal to ``normals``."""
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    a = np.cross(normals, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(normals, a)
    r = 0.8 * radius_mm
    return centres[:, None, :] + r * np.stack([a, -a, b, -b], axis=1)


def dot_visibility(rig: Rig, dots: np.ndarray, normals: np.ndarray, uv: np.ndarray,
                   caster: MeshRayCaster, ball_centres: np.ndarray, ball_radii: np.ndarray,
                   dot_radius_mm: float) -> np.ndarray:
    """(C, D) bool visibility of dots (D, 3) with outward ``normals`` (D, 3) and projections
    ``uv`` (C, D, 2), given the posed body ``caster`` and the balls in the air."""
    C, D = len(rig), len(dots)
    visible = np.zeros((C, D), dtype=bool)
    rims = rim_points(dots, normals, dot_radius_mm)
    cos_max = np.cos(np.radians(MAX_VIEW_ANGLE_DEG))
    for c, cam in enumerate(rig):
        centre = cam.center
        to_cam = centre - dots
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        ok = cam.in_image(uv[c], margin=IMAGE_MARGIN_PX) & (np.einsum("dk,dk->d", to_cam, normals) > cos_max)
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        lifted = dots[idx] + RAY_LIFT_MM * normals[idx]
        ok_body = ~caster.blocked(lifted, np.repeat(centre[None], len(idx), axis=0))
        samples = np.concatenate([dots[idx, None, :], rims[idx]], axis=1).reshape(-1, 3)  # (n*5, 3)
        near = _balls_near_view(centre, samples, ball_centres, ball_radii)
        hidden = segments_blocked_by_spheres(
            np.repeat(centre[None], len(samples), axis=0), samples, ball_centres[near], ball_radii[near]
        ).reshape(len(idx), 5)
        ok_balls = ~hidden[:, 0] & (hidden[:, 1:].sum(axis=1) <= 1)
        visible[c, idx] = ok_body & ok_balls
    return visible


def _balls_near_view(camera_centre: np.ndarray, samples: np.ndarray, centres: np.ndarray,
                     radii: np.ndarray) -> np.ndarray:
    """(B,) bool: balls that can touch any segment camera -> sample (a cheap cone pre-filter:
    distance to the segment camera -> sample centroid below radius + samples' spread)."""
    if len(centres) == 0:
        return np.zeros(0, dtype=bool)
    mid = samples.mean(axis=0)
    spread = np.linalg.norm(samples - mid, axis=1).max()
    d = mid - camera_centre
    s = np.clip((centres - camera_centre) @ d / (d @ d), 0.0, 1.0)
    dist = np.linalg.norm(camera_centre + s[:, None] * d - centres, axis=1)
    return dist < radii + spread + 1.0
