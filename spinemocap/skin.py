"""Points bound to a body's skin, and a tape laid along the spine of any body mesh (core).

Body-agnostic generalisation of the studio's tape laying (``spinemocap.synth.tape_on_skin``,
which works on anny only and builds its taut strip from the binding, ray casting, arc-length
profile and convex bridge here): everything here takes a rest mesh (vertices (V, 3) mm, faces
(T, 3)) plus the body's spine chain and vertebral level heights, so any body model (anny, SMPL,
SMPL-X) carries a tape. Frame: the studio's (mm, Z up, the body facing ``-Y`` at rest, so the back faces
``+Y``; the subject's left ``+X``).

A point is bound by a triangle index and barycentric weights (plus an optional height along the
interpolated normal), so in any pose of the same topology it is the same convex combination of
the posed triangle's corners: the tape stretches and bends with the skin.

The tape is laid as in the studio: the sagittal profile of the back (the mesh cut by ``x = 0``,
back side only) is parametrised by arc length; a tape point with flat coordinates ``(u, v)``
(``v`` along the tape from the first row, ``u`` across, positive toward the subject's right =
``-X``) is placed ``v`` mm along the profile above the start level, shifted ``u`` mm to the right
and projected onto the skin; where the tape bridges the groove over the spinous processes the
points float at the height of the cross-section's convex envelope.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .tape import TapeSpec

# Vertebral levels from the sacrum (S1) to C7 and typical adult segment heights (vertebral body +
# disc, mm) used only as relative weights to place the levels along a body model's spine between
# its S1 and C7/T1 joints (the studio, spinemocap.synth.body, extends the table down to S2).
# Approximate by design.
LEVELS = ("S1", "L5", "L4", "L3", "L2", "L1", "T12", "T11", "T10", "T9", "T8", "T7", "T6",
          "T5", "T4", "T3", "T2", "T1", "C7")
SEGMENT_MM = (38, 38, 37, 36, 35, 31, 29, 28, 27, 26, 25, 24, 23, 22, 21, 20, 19, 18)
LEVEL_FRACTIONS = np.concatenate([[0.0], np.cumsum(SEGMENT_MM)]) / sum(SEGMENT_MM)  # S1 = 0 ... C7 = 1


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) area-weighted unit vertex normals of a triangle mesh."""
    v = np.asarray(vertices, float)
    tri = v[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    weights = np.repeat(fn, 3, axis=0)
    idx = np.asarray(faces).ravel()
    n = np.column_stack([np.bincount(idx, weights[:, d], minlength=len(v)) for d in range(3)])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


@dataclass
class SkinBinding:
    """Points bound to a triangle mesh: ``triangles`` (N,) face indices, ``weights`` (N, 3)
    barycentric weights and ``heights`` (N,) mm above the skin along the interpolated normal."""

    triangles: np.ndarray
    weights: np.ndarray
    heights: np.ndarray | None = None

    def surface_points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(N, 3) the skin points under the bound points (any pose of the same topology)."""
        corners = np.asarray(vertices)[faces[self.triangles]]
        return np.einsum("nk,nkd->nd", self.weights, corners)

    def points(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) bound positions on a posed mesh (its vertex ``normals`` computed if needed)."""
        p = self.surface_points(vertices, faces)
        if self.heights is None or not np.any(self.heights):
            return p
        if normals is None:
            normals = vertex_normals(vertices, faces)
        return p + self.heights[:, None] * self.normals(normals, faces)

    def normals(self, vertex_normals_: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(N, 3) unit normals interpolated from per-vertex normals."""
        n = self.surface_points(vertex_normals_, faces)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)

    def sequence(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(F, N, 3) bound positions over (F, V, 3) posed meshes."""
        return np.stack([self.points(v, faces) for v in vertices])


def _polydata(vertices: np.ndarray, faces: np.ndarray):
    import pyvista as pv

    return pv.PolyData(np.asarray(vertices, float), np.column_stack([np.full(len(faces), 3), faces]).ravel())


def barycentric(corners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric weights of points lying in triangles ``corners`` (N, 3, 3), clipped
    into the triangle."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00 = np.einsum("nd,nd->n", v0, v0)
    d01 = np.einsum("nd,nd->n", v0, v1)
    d11 = np.einsum("nd,nd->n", v1, v1)
    d20 = np.einsum("nd,nd->n", v2, v0)
    d21 = np.einsum("nd,nd->n", v2, v1)
    den = d00 * d11 - d01 * d01
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    w = np.clip(np.column_stack([1 - w1 - w2, w1, w2]), 0.0, 1.0)
    return w / w.sum(axis=1, keepdims=True)


def cast_onto_skin(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, directions: np.ndarray,
                   missing_ok: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """First skin hits of the rays ``points - 100 d -> points + 100 d``: triangle indices (N,)
    and hit points (N, 3) mm; a ray that misses raises, or with ``missing_ok`` gives triangle -1
    and NaN."""
    import vtk

    tree = vtk.vtkOBBTree()
    tree.SetDataSet(_polydata(vertices, faces))
    tree.BuildLocator()
    hits, cells = vtk.vtkPoints(), vtk.vtkIdList()
    triangles = np.empty(len(points), dtype=np.int64)
    projected = np.empty((len(points), 3))
    nudge = np.array([1e-3, 0.0, 0.0])  # mirror-symmetric meshes have edges on x = 0
    for i, (p, d) in enumerate(zip(np.asarray(points, float) + nudge, np.asarray(directions, float))):
        tree.IntersectWithLine(p - 100.0 * d, p + 100.0 * d, hits, cells)
        if hits.GetNumberOfPoints() == 0:
            if not missing_ok:
                raise ValueError(f"point {i} at {p.round(1)} does not lie over the skin")
            triangles[i], projected[i] = -1, np.nan
            continue
        triangles[i] = cells.GetId(0)
        projected[i] = hits.GetPoint(0)
    return triangles, projected


def bind_to_surface(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, directions: np.ndarray,
                    heights: np.ndarray | None = None) -> SkinBinding:
    """Bind (N, 3) points to the skin along inward unit ``directions`` (first skin hit), then
    float them ``heights`` (N,) mm back out along the skin normal."""
    triangles, projected = cast_onto_skin(vertices, faces, points, directions)
    weights = barycentric(np.asarray(vertices, float)[faces[triangles]], projected)
    return SkinBinding(triangles, weights, None if heights is None else np.asarray(heights, float))


def bind_to_nearest(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> SkinBinding:
    """Bind (N, 3) points to their closest points on a (posed) mesh; ``heights`` keep each
    point's signed distance along the interpolated normal, so the binding reproduces points that
    lie off the skin (tracked dots on a tape, markers)."""
    import vtk

    locator = vtk.vtkCellLocator()
    locator.SetDataSet(_polydata(vertices, faces))
    locator.BuildLocator()
    closest = [0.0, 0.0, 0.0]
    cell, sub, dist2 = vtk.reference(0), vtk.reference(0), vtk.reference(0.0)
    triangles = np.empty(len(points), dtype=np.int64)
    surface = np.empty((len(points), 3))
    for i, p in enumerate(np.asarray(points, float)):
        locator.FindClosestPoint(p, closest, cell, sub, dist2)
        triangles[i], surface[i] = int(cell), closest
    weights = barycentric(np.asarray(vertices, float)[faces[triangles]], surface)
    binding = SkinBinding(triangles, weights)
    normals = binding.normals(vertex_normals(vertices, faces), faces)
    binding.heights = np.einsum("nd,nd->n", np.asarray(points, float) - binding.surface_points(vertices, faces),
                                normals)
    return binding


class ArcProfile:
    """A midline up the back in the sagittal plane ``x = 0``: ``points`` (K, 3) mm from bottom to
    top, parametrised by arc length ``arc`` (K,) mm from its first point."""

    def __init__(self, points: np.ndarray):
        self.points = np.asarray(points, float)
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(seg)])

    def arc_at_height(self, z_mm: float) -> float:
        """Arc length (mm) where the profile reaches the height ``z_mm``."""
        return float(np.interp(z_mm, self.points[:, 2], self.arc))

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Profile points (N, 3) and unit upward tangents (N, 3) at arc lengths ``s``."""
        s = np.asarray(s, float)

        def interp(q: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(q, self.arc, self.points[:, k]) for k in range(3)])

        t = interp(s + 1.0) - interp(s - 1.0)
        return interp(s), t / np.linalg.norm(t, axis=1, keepdims=True)

    def across(self, us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates (N, 2) ``(u, s)`` mm -> the profile points at arc lengths ``s`` shifted ``u``
        toward the subject's right (``-X``), and the inward unit directions (in the sagittal plane,
        normal to the profile) along which they are projected onto the skin."""
        us = np.asarray(us)
        p, tangent = self.at(us[:, 1])
        right = np.array([-1.0, 0.0, 0.0])
        inward = np.cross(tangent, right)
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
        return p + us[:, :1] * right, inward


class BackProfile(ArcProfile):
    """The sagittal midline of the back on a rest mesh, parametrised by arc length (mm).
    ``spine_chain`` (K, 3): rest spine joints from the sacrum (S1) to C7, bottom to top."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, spine_chain: np.ndarray, step_mm: float = 2.0):
        section = _polydata(vertices, faces).slice(normal="x", origin=(0.0, 0.0, 0.0)).points
        chain = np.asarray(spine_chain, float)
        z_lo, z_hi = chain[0, 2] - 120.0, chain[-1, 2] + 40.0
        inside = (section[:, 2] > z_lo) & (section[:, 2] < z_hi)
        spine_y = np.interp(section[:, 2], chain[:, 2], chain[:, 1])
        back = section[inside & (section[:, 1] > spine_y)]
        z = np.arange(z_lo, z_hi, step_mm)
        bins = np.digitize(back[:, 2], z)
        zs, ys = [], []
        for b in np.unique(bins):  # the outermost slice point per z bin: y(z) near the midline
            sel = bins == b
            k = np.argmax(back[sel, 1])
            zs.append(back[sel][k, 2])
            ys.append(back[sel][k, 1])
        order = np.argsort(zs)
        zs_a, ys_a = np.array(zs)[order], np.array(ys)[order]
        ys_a = np.convolve(np.pad(ys_a, 2, mode="edge"), np.ones(5) / 5, mode="valid")
        super().__init__(np.column_stack([np.zeros_like(zs_a), ys_a, zs_a]))


class LaidTape:
    """A tape laid along the spine of a rest mesh (see the module docstring): ``dots`` is the
    binding of the dot centres (labels: ``spec.graph.labels``); ``row_levels`` the nearest
    vertebral level of each row. ``level_heights``: level name -> rest height z (mm)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, spine_chain: np.ndarray,
                 level_heights: dict[str, float], spec: TapeSpec, start_level: str = "L4"):
        if start_level not in level_heights:
            raise ValueError(f"unknown tape start level {start_level!r}; known: {list(level_heights)}")
        self.vertices, self.faces = np.asarray(vertices, float), np.asarray(faces)
        self.spec, self.start_level, self.level_heights = spec, start_level, level_heights
        self.profile = BackProfile(self.vertices, self.faces, spine_chain)
        self.s0 = self.profile.arc_at_height(level_heights[start_level])
        s_end = self.s0 + (spec.n_rows - 1) * spec.row_pitch_mm + spec.end_margin_mm
        if self.s0 - spec.end_margin_mm < 0 or s_end > self.profile.arc[-1]:
            raise ValueError(f"a {spec.n_rows}-row tape starting at {start_level} does not fit on the back "
                             f"({self.profile.arc[-1]:.0f} mm of midline); use fewer rows or a lower start level")
        uv = spec.graph.uv_mm
        self.dots = bind_to_surface(self.vertices, self.faces, *self.lay(uv), self.bridge_heights()(uv))
        rest_dots = self.dots.points(self.vertices, self.faces)
        row_z = [rest_dots[spec.graph.row == r, 2].mean() for r in range(spec.n_rows)]
        self.row_levels = [min(level_heights, key=lambda name: abs(level_heights[name] - z)) for z in row_z]

    @property
    def labels(self) -> list[str]:
        return list(self.spec.graph.labels)

    def lay(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat tape coordinates (N, 2) mm -> 3D rest positions near the skin and the inward
        directions along which they are projected onto it."""
        uv = np.asarray(uv, float)
        return self.profile.across(np.column_stack([uv[:, 0], self.s0 + uv[:, 1]]))

    def bridge_heights(self):
        """Interpolator ``(N, 2) uv -> (N,)`` heights (mm) at which the taut tape bridges the
        hollows of each cross-section (its outer convex envelope)."""
        from scipy.interpolate import RegularGridInterpolator

        spec = self.spec
        u = np.linspace(-spec.width_mm / 2, spec.width_mm / 2, 26)
        v = np.arange(-spec.end_margin_mm, spec.length_mm - spec.end_margin_mm + 1.0, 2.0)
        uu, vv = np.meshgrid(u, v)
        start, inward = self.lay(np.column_stack([uu.ravel(), vv.ravel()]))
        _, hit = cast_onto_skin(self.vertices, self.faces, start, inward)
        depth = np.einsum("nd,nd->n", hit - start, inward).reshape(len(v), len(u))
        heights = np.array([row - outer_envelope(u, row) for row in depth])
        interpolate = RegularGridInterpolator((v, u), heights, bounds_error=False, fill_value=None)
        return lambda points_uv: np.maximum(interpolate(np.asarray(points_uv)[:, ::-1]), 0.0)

    def dot_positions(self, vertices: np.ndarray) -> np.ndarray:
        """(D, 3) dot centres (mm) on a posed mesh of the same topology."""
        return self.dots.points(vertices, self.faces)


def outer_envelope(u: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """The convex bridge over a cross-section: the lower convex hull of (u, depth) (depth grows
    into the body), evaluated at ``u``. A taut strip spans hollows instead of following them."""
    hull: list[int] = []
    for i in range(len(u)):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            cross = (u[b] - u[a]) * (depth[i] - depth[a]) - (depth[b] - depth[a]) * (u[i] - u[a])
            if cross <= 0:  # b lies on or above the chord a-i: not on the lower hull
                hull.pop()
            else:
                break
        hull.append(i)
    return np.interp(u, u[hull], depth[hull])
