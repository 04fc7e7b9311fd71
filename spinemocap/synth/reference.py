"""The studio's reference object: an L-frame on a stand beside the athlete, rendered for real.

A lab fixes its world frame with a reference object of known geometry (Vicon's L-frame); the
studio places :meth:`spinemocap.reference.ReferenceObject.lframe` on a stand at the subject's left
(+X), a little behind the back plane toward the cameras (:data:`PLACEMENT_MM` from the tape's rest
centre), upright, its markers facing the cameras. There every camera of the ``artificial`` layout
sees all five markers 60-200 px inside the image and at least ~60 px from the tape over the
``mixed`` motion, and the frame cannot cover the tape: the rays
from the cameras to the tape pass it on the body's side. The arms stand in front of the
subject's left arm (as seen from the cameras), so the body never hides a marker; a falling ball
can, now and then (the ground truth's ``reference_visible``).

Rendering: 14 mm markers as spheres lit only by their own ambient term, a uniform bright disc
as retro-reflective markers look under a camera's ring light (so shading cannot pull their
centroid); the arms (20 x 10 mm aluminium bars) behind the markers and a 20 mm pole down to the
floor. The object joins the occluders of the tape's visibility and the tape masks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Rig
from ..reference import ReferenceObject

# Pose of the studio's L-frame: object x (short arm) -> world -X (toward the body), object y
# (long arm) -> world +Z (up), object z -> world +Y (toward the cameras); the corner marker at
# the tape's rest centre + PLACEMENT_MM.
STUDIO_ROTATION = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
PLACEMENT_MM = np.array([370.0, 130.0, -140.0])
BAR_SECTION_MM = (20.0, 10.0)  # width in the object's plane, depth behind the markers
POLE_MM = 20.0
MIN_CAMERAS = 2  # every marker in at least this many images, or the layout cannot use the reference
IMAGE_MARGIN_PX = 10.0


@dataclass
class ReferenceMeshes:
    """The object's geometry (world mm): ``frame_vertices`` / ``frame_faces`` the bars and the
    pole, ``marker_centres`` (N, 3) and ``marker_radius`` the spheres."""

    frame_vertices: np.ndarray
    frame_faces: np.ndarray
    marker_centres: np.ndarray
    marker_radius: float


def studio_reference(target_mm: np.ndarray, rig: Rig) -> ReferenceObject:
    """The L-frame placed for a scene whose tape's rest centre is ``target_mm``; ValueError when
    a marker falls inside fewer than :data:`MIN_CAMERAS` images of ``rig`` (a layout whose views
    are too narrow for it, such as ``tiny``)."""
    reference = ReferenceObject.lframe(STUDIO_ROTATION, np.asarray(target_mm, float) + PLACEMENT_MM)
    world = reference.world_mm
    seen = np.zeros(reference.n_markers, int)
    for cam in rig:
        inside = cam.in_image(cam.project(world), margin=IMAGE_MARGIN_PX) & (cam.depth(world) > 0)
        seen += inside
    if (seen < MIN_CAMERAS).any():
        raise ValueError(f"the reference object does not fit the views of this layout: markers "
                         f"{[label for label, n in zip(reference.labels, seen) if n < MIN_CAMERAS]} are inside fewer "
                         f"than {MIN_CAMERAS} camera images (per marker: {seen.tolist()})")
    return reference


def _box(a: np.ndarray, b: np.ndarray, across: np.ndarray, width: float, depth: float,
         back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box from ``a`` to ``b`` (mm), ``width`` along ``across`` and ``depth`` along ``back``:
    8 vertices, 12 triangles (outward winding not needed: the renderer lights both sides)."""
    u, v = across * width / 2, back * depth / 2
    corners = [p + su * u + sv * v for p in (a, b) for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    quads = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    faces = [tri for q in quads for tri in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))]
    return np.array(corners), np.array(faces)


def _spanning_edges(points: np.ndarray) -> list[tuple[int, int]]:
    """Edges of the minimum spanning tree of ``points`` (Prim): the bars of a frame that holds
    every marker (the L-frame's two arms)."""
    n = len(points)
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    inside, edges = [0], []
    while len(inside) < n:
        outside = [j for j in range(n) if j not in inside]
        i, j = min(((i, j) for i in inside for j in outside), key=lambda e: d[e])
        edges.append((i, j))
        inside.append(j)
    return edges


def reference_meshes(reference: ReferenceObject, floor_z_mm: float = 0.0) -> ReferenceMeshes:
    """The object's bars (the markers' spanning tree, behind the markers), a pole from its lowest
    bar end down to the floor, and the marker spheres; all in world mm."""
    world, R = reference.world_mm, reference.rotation
    radius = reference.marker_diameter_mm / 2
    normal = R[:, 2]  # object z: the side the markers face
    width, depth = BAR_SECTION_MM
    back = -normal
    shift = back * (radius + depth / 2)
    parts_v: list[np.ndarray] = []
    parts_f: list[np.ndarray] = []
    for i, j in _spanning_edges(reference.markers_mm):
        a, b = world[i] + shift, world[j] + shift
        along = (b - a) / np.linalg.norm(b - a)
        across = np.cross(normal, along)
        # bars run a little past the end markers, so they hold them
        v, f = _box(a - along * width / 2, b + along * width / 2, across, width, depth, back)
        parts_f.append(f + sum(len(p) for p in parts_v))
        parts_v.append(v)
    low = world[np.argmin(world[:, 2])] + shift + back * (depth / 2 + POLE_MM / 2)
    if low[2] > floor_z_mm:
        v, f = _box(low, np.array([low[0], low[1], floor_z_mm]), np.cross(back, [0.0, 0.0, 1.0]) / max(
            np.linalg.norm(np.cross(back, [0.0, 0.0, 1.0])), 1e-9), POLE_MM, POLE_MM, back)
        parts_f.append(f + sum(len(p) for p in parts_v))
        parts_v.append(v)
    return ReferenceMeshes(np.concatenate(parts_v), np.concatenate(parts_f), world, radius)
