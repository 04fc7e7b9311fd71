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
    """Segment/mesh intersection tests against one posed triangle mesh (vertices in mm).

    Nothing is built up front: :meth:`blocked` first keeps only the triangles that can meet any
    of the segments it is asked about (a conservative perspective test, see
    :func:`_triangles_that_can_block`), then casts the segments against a VTK cell locator built
    on those triangles. Whether a segment crosses the mesh is decided triangle by triangle, so
    the answer is the one a locator on the whole mesh gives (the tests compare the two), at a
    fraction of the build cost: the skin's triangles that project onto the tape, and what stands
    in front of it, instead of the whole body."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = np.asarray(vertices, float)
        self.faces = np.asarray(faces)

    def blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(S,) bool: does the segment ``starts[s] -> ends[s]`` cross the mesh? One call for
        all the segments that share a mesh (e.g. every camera seeing the same instant): the
        locator is built once for them."""
        starts, ends = np.asarray(starts, float), np.asarray(ends, float)
        out = np.zeros(len(starts), dtype=bool)
        if len(starts) == 0:
            return out
        keep = np.zeros(len(self.faces), dtype=bool)
        for end in np.unique(ends, axis=0):
            same = np.all(ends == end, axis=1)
            keep |= _triangles_that_can_block(self.vertices, self.faces, end, starts[same])
        if not keep.any():
            return out
        import vtk

        locator = _cell_locator(self.vertices, self.faces[keep])
        t, x, pc = vtk.reference(0.0), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        sub, cell = vtk.reference(0), vtk.reference(0)
        for s, (a, b) in enumerate(zip(starts, ends)):
            out[s] = bool(locator.IntersectWithLine(a, b, 0.0, t, x, pc, sub, cell))
        return out


def _cell_locator(vertices: np.ndarray, faces: np.ndarray):
    """A VTK static cell locator (built ~10x faster than an OBB tree) over ``faces`` (T, 3)."""
    import pyvista as pv
    import vtk

    mesh = pv.PolyData.from_regular_faces(vertices, faces)
    locator = vtk.vtkStaticCellLocator()
    locator.SetDataSet(mesh)
    locator.BuildLocator()
    return locator


# relative slack of the perspective test: far above float64 rounding, far below a triangle
_PROJECTION_SLACK = 1e-7
_LEFT, _RIGHT, _BELOW, _ABOVE, _BEYOND = 1, 2, 4, 8, 16


def _triangles_that_can_block(vertices: np.ndarray, faces: np.ndarray, eye: np.ndarray,
                              starts: np.ndarray) -> np.ndarray:
    """(T,) bool, conservative: triangles ``faces`` (T, 3) of ``vertices`` (V, 3) that may cross
    a segment from a point of ``starts`` (S, 3) to ``eye`` (3,).

    Every point of such a segment but the eye lies on the eye's ray through its start, so a
    triangle crossing it (all corners in front of the eye) projects, from the eye, over the
    start's projection and has a corner no farther along the view axis than the start. A
    triangle whose three corners all lie on the same side of the starts' projected bounding box
    (left, right, below, above, or all beyond the farthest start) cannot (Cohen-Sutherland
    outcodes, with a small slack). Corners at or behind the eye never reject a triangle, and
    every triangle is kept when a start is at or behind the eye. View axis: eye -> mean start."""
    axis = starts.mean(axis=0) - eye
    norm = np.linalg.norm(axis)
    if norm == 0:
        return np.ones(len(faces), dtype=bool)
    z_axis = axis / norm
    helper = np.array([1.0, 0.0, 0.0]) if abs(z_axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(helper, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    frame = np.stack([x_axis, np.cross(z_axis, x_axis), z_axis])  # rows: view x, y, z
    q_starts = (starts - eye) @ frame.T  # (S, 3)
    scale = np.abs(q_starts).max()
    if (q_starts[:, 2] <= _PROJECTION_SLACK * scale).any():
        return np.ones(len(faces), dtype=bool)
    uv_starts = q_starts[:, :2] / q_starts[:, 2:3]
    slack = _PROJECTION_SLACK * (1.0 + np.abs(uv_starts).max())
    lo, hi = uv_starts.min(axis=0) - slack, uv_starts.max(axis=0) + slack
    q = (vertices - eye) @ frame.T  # (V, 3)
    in_front = q[:, 2] > _PROJECTION_SLACK * scale
    uv = q[:, :2] / np.where(in_front, q[:, 2], 1.0)[:, None]
    code = ((uv[:, 0] < lo[0]) * _LEFT | (uv[:, 0] > hi[0]) * _RIGHT | (uv[:, 1] < lo[1]) * _BELOW
            | (uv[:, 1] > hi[1]) * _ABOVE | (q[:, 2] > q_starts[:, 2].max() * (1 + _PROJECTION_SLACK)) * _BEYOND)
    code = np.where(in_front, code, 0).astype(np.uint8)
    return (code[faces[:, 0]] & code[faces[:, 1]] & code[faces[:, 2]]) == 0


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
    candidates = []  # (camera, dot indices facing it inside its image)
    for c, cam in enumerate(rig):
        to_cam = cam.center - dots
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        ok = cam.in_image(uv[c], margin=IMAGE_MARGIN_PX) & (np.einsum("dk,dk->d", to_cam, normals) > cos_max)
        idx = np.flatnonzero(ok)
        if len(idx):
            candidates.append((c, idx))
    if not candidates:
        return visible
    # the body: one batched query for every camera (one locator per posed mesh)
    lifted = np.concatenate([dots[idx] + RAY_LIFT_MM * normals[idx] for _, idx in candidates])
    eyes = np.concatenate([np.repeat(rig[c].center[None], len(idx), axis=0) for c, idx in candidates])
    ok_body = ~caster.blocked(lifted, eyes)
    first = 0
    for c, idx in candidates:
        centre = rig[c].center
        samples = np.concatenate([dots[idx, None, :], rims[idx]], axis=1).reshape(-1, 3)  # (n*5, 3)
        near = _balls_near_view(centre, samples, ball_centres, ball_radii)
        hidden = segments_blocked_by_spheres(
            np.repeat(centre[None], len(samples), axis=0), samples, ball_centres[near], ball_radii[near]
        ).reshape(len(idx), 5)
        ok_balls = ~hidden[:, 0] & (hidden[:, 1:].sum(axis=1) <= 1)
        visible[c, idx] = ok_body[first : first + len(idx)] & ok_balls
        first += len(idx)
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
