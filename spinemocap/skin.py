"""Points bound to a body's skin, and a tape laid as a taut strip up the back of any body mesh (core).

The one tape-laying toolkit: the studio (``spinemocap.synth.tape_on_skin``) lays its tape with
:class:`BackChart` and adds taping tension and skin strain; the body models
(``spinemocap.bodymodel``) lay theirs with :class:`LaidTape`, the same chart without them. Everything
here takes a rest mesh (vertices (V, 3) mm, faces (T, 3)) plus the body's vertebral level heights,
so any body model (anny, SMPL, SMPL-X) carries a tape. Frame: the studio's (mm, Z up, the body
facing ``-Y`` at rest, so the back faces ``+Y``; the subject's left ``+X``).

A point is bound by a triangle index and barycentric weights (plus an offset along the
interpolated normal or in the triangle's local frame), so in any pose of the same topology it is
the same combination of the posed triangle's corners: the tape stretches and bends with the skin.

The tape is laid as a taut strip: :class:`BackProfile` is the strip's midline (the outer convex
envelope of horizontal sections of the back, parametrised by arc length); :class:`BackChart` is a
grid of nodes ``(s, u)`` on the strip's surface (``s`` arc length along the midline, ``u`` toward
the subject's right = ``-X``, as in :mod:`spinemocap.tape`), each bound to the skin under it, so it
follows the skin in any pose; a tape point with flat coordinates ``(u, v)`` lies at chart
coordinates ``(u, s0 + v)`` (``s0``: the start level's arc length), interpolated bilinearly from
the posed nodes. Where the strip bridges a hollow (the gluteal cleft, the groove over the spinous
processes) its points float at the height of the section's convex envelope.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from .tape import TapeSpec

log = logging.getLogger(__name__)


@functools.lru_cache(maxsize=1)
def anny_model():
    """The anny body model, loaded once per process for the studio and the body models alike
    (anny is imported here, not at module level: it is heavy; its first load on a machine
    compiles kernels, ~40 s)."""
    import anny

    log.info("loading the anny body model")
    return anny.Anny()

# Vertebral levels from the sacrum (S1) to C7 and typical adult segment heights (vertebral body +
# disc, mm) used only as relative weights between the two end landmarks. Approximate by design.
LEVELS = ("S1", "L5", "L4", "L3", "L2", "L1", "T12", "T11", "T10", "T9", "T8", "T7", "T6",
          "T5", "T4", "T3", "T2", "T1", "C7")
SEGMENT_MM = (38, 38, 37, 36, 35, 31, 29, 28, 27, 26, 25, 24, 23, 22, 21, 20, 19, 18)
# The one level table of every body (the studio's and the body models'): the table above extended
# down to S2 (the PSIS landmark), placed from surface anatomy by :func:`surface_level_heights`.
S2_S1_SEGMENT_MM = 25
SURFACE_LEVELS = ("S2", *LEVELS)
_SURFACE_SEGMENT_MM = (S2_S1_SEGMENT_MM, *SEGMENT_MM)
# Surface-anatomy figures used to place the levels:
# - the posterior superior iliac spines (the "dimples of Venus") lie at the level of S2;
# - the hip joint centre lies 30 % of the inter-ASIS distance (IAD) below the ASIS and 36 % of it
#   lateral of the midline (Bell, Pedersen & Brand 1990, J Biomech 23:617), so the hip joints
#   give the ASIS height; standing, the PSIS sit about 20 mm above the ASIS (anterior pelvic tilt
#   of ~10 deg over ~12 cm from ASIS to PSIS);
# - the vertebra prominens (C7) sits at the cervico-thoracic junction (anny's ``neck01`` head,
#   SMPL's ``neck`` joint);
# - checks of the result on anny (tests/synth/test_synth_realism.py): the iliac-crest (supracristal,
#   Tuffier's) line falls at L4/L5 about 6-8 cm above the PSIS line, the inferior angle of the
#   scapula near T7.
HJC_BELOW_ASIS_IAD = 0.30
HJC_LATERAL_IAD = 0.36
PSIS_ABOVE_ASIS_MM = 20.0
Z_UP = (0.0, 0.0, 1.0)  # the studio's up axis


def psis_height(hip_left: np.ndarray, hip_right: np.ndarray, up: tuple[float, float, float] | np.ndarray = Z_UP) -> float:
    """Rest height (mm, along the unit ``up`` axis) of the posterior superior iliac spines (the S2
    level), from the rest hip joint centres (mm, any frame) through Bell et al.'s regression (see
    :data:`HJC_BELOW_ASIS_IAD`): the hip centres' mean height plus 30 % of the inter-ASIS distance
    (their half-separation across ``up`` / 0.36) plus :data:`PSIS_ABOVE_ASIS_MM`."""
    hip_left, hip_right, up = (np.asarray(v, float) for v in (hip_left, hip_right, up))
    across = hip_left - hip_right
    across = across - float(across @ up) * up
    inter_asis = 0.5 * float(np.linalg.norm(across)) / HJC_LATERAL_IAD
    hip_height = 0.5 * (float(hip_left @ up) + float(hip_right @ up))
    return hip_height + HJC_BELOW_ASIS_IAD * inter_asis + PSIS_ABOVE_ASIS_MM


def surface_level_heights(hip_left: np.ndarray, hip_right: np.ndarray, c7: np.ndarray,
                          up: tuple[float, float, float] | np.ndarray = Z_UP) -> dict[str, float]:
    """Rest height (mm, along the unit ``up`` axis) of each level of :data:`SURFACE_LEVELS`, from
    body-agnostic landmarks of the rest body (mm, one frame): the hip joint centres give S2 at the
    PSIS (:func:`psis_height`), ``c7`` (the cervico-thoracic junction joint) gives C7, the levels
    between are spread by the typical segment heights."""
    z0, z1 = psis_height(hip_left, hip_right, up), float(np.asarray(c7, float) @ np.asarray(up, float))
    cum = np.concatenate([[0.0], np.cumsum(_SURFACE_SEGMENT_MM)]) / sum(_SURFACE_SEGMENT_MM)
    return {name: float(z0 + c * (z1 - z0)) for name, c in zip(SURFACE_LEVELS, cum)}


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


def bind_to_nearest(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> FramedBinding:
    """Bind (N, 3) points to their closest points on a (posed) mesh, each keeping its offset
    from there in the triangle's local frame, so the binding reproduces points that lie off the
    skin (tracked dots on a tape bridging a hollow, markers) exactly in this pose and follows the
    skin's rotation in others."""
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
    return FramedBinding(vertices, faces, triangles, weights, np.asarray(points, float))


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


BRIDGE_HALF_WIDTH_MM = 30.0  # the strip spans hollows over its width plus its transverse stretch
CHART_STEP_MM = 2.0  # chart node spacing along the tape
CHART_U_STEP_MM = 2.5  # chart node spacing across the tape


class BackProfile(ArcProfile):
    """The midline of a taut strip laid up the rest back, parametrised by arc length (mm).

    Horizontal rays from behind (``-Y``) sample the back's surface across the strip's width
    (``|x| <= BRIDGE_HALF_WIDTH_MM``) every ``step_mm`` of height from 60 mm below the lowest
    vertebral level of ``level_heights`` (level name -> rest height z, mm; it must hold ``C7``) up
    the back of the neck (to where the head overhangs it); at each height the strip spans the
    hollows (the gluteal cleft, the groove over the spinous processes) like a taut chord, so its
    midline lies on the outer convex envelope of the section, not in the cleft. The midline is
    smoothed lightly and parametrised by arc length.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, level_heights: dict[str, float],
                 step_mm: float = 2.0):
        z = np.arange(min(level_heights.values()) - 60.0, level_heights["C7"] + 150.0, step_mm)
        x = np.linspace(-BRIDGE_HALF_WIDTH_MM, BRIDGE_HALF_WIDTH_MM, 25)
        behind = np.asarray(vertices)[:, 1].max() - 50.0  # rays run 100 mm either side of this
        zz, xx = np.meshgrid(z, x, indexing="ij")
        starts = np.column_stack([xx.ravel(), np.full(xx.size, behind), zz.ravel()])
        forward = np.tile([0.0, -1.0, 0.0], (len(starts), 1))
        _, hits = cast_onto_skin(vertices, faces, starts, forward, missing_ok=True)
        depth = (behind - hits[:, 1]).reshape(len(z), len(x))  # grows into the body
        # up the neck the profile ends where a ray misses or the back of the head overhangs it
        missed = np.flatnonzero(np.isnan(depth).any(axis=1))
        if len(missed) and z[missed[0]] <= level_heights["C7"]:
            raise ValueError(f"the back of this body is not where the tape is laid (no skin at "
                             f"height {z[missed[0]]:.0f} mm)")
        end = missed[0] if len(missed) else len(z)
        z, depth = z[:end], depth[:end]
        mid = len(x) // 2
        y = behind - np.array([outer_envelope(x, row)[mid] for row in depth])
        neck = np.flatnonzero(z > level_heights["C7"])
        overhang = neck[y[neck] > np.minimum.accumulate(y[neck]) + 2.0]
        if len(overhang):
            z, y = z[: overhang[0]], y[: overhang[0]]
        kernel = np.ones(5) / 5
        y = np.convolve(np.pad(y, 2, mode="edge"), kernel, mode="valid")
        super().__init__(np.column_stack([np.zeros_like(z), y, z]))


class FramedBinding:
    """Points bound to a mesh with an offset in the local frame of their triangle: ``triangles``
    (N,), barycentric ``weights`` (N, 3) of the skin point under each, and ``offsets`` (N, 3) mm
    of the point from it along (edge tangent, second tangent, interpolated normal). Follows the
    skin's rotation where a plain normal offset would swing sideways in a fold."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, triangles: np.ndarray, weights: np.ndarray,
                 points: np.ndarray):
        self.triangles, self.weights = triangles, weights
        base, frame = self._frames(vertices, faces, vertex_normals(vertices, faces))
        self.offsets = np.einsum("nkd,nd->nk", frame, points - base)

    def _frames(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        corners = np.asarray(vertices, float)[faces[self.triangles]]
        base = np.einsum("nk,nkd->nd", self.weights, corners)
        n = np.einsum("nk,nkd->nd", self.weights, np.asarray(normals, float)[faces[self.triangles]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        e1 = corners[:, 1] - corners[:, 0]
        e1 -= np.einsum("nd,nd->n", e1, n)[:, None] * n
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        return base, np.stack([e1, np.cross(n, e1), n], axis=1)  # (N, 3 axes, 3)

    def points(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) bound points on a posed mesh with vertex ``normals`` (computed if not given)."""
        if normals is None:
            normals = vertex_normals(vertices, faces)
        base, frame = self._frames(vertices, faces, normals)
        return base + np.einsum("nk,nkd->nd", self.offsets, frame)

    def sequence(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(F, N, 3) bound points over (F, V, 3) posed meshes."""
        return np.stack([self.points(v, faces) for v in vertices])


class BackChart:
    """Taut-strip coordinates over the back of a rest mesh (vertices (V, 3) mm, faces (T, 3);
    ``level_heights`` as for :class:`BackProfile`): a grid of nodes ``(s, u)`` (arc length along
    the :class:`BackProfile` from its bottom, and offset toward the subject's right, mm), each on
    the surface a taut strip laid along the midline takes (bridging the hollows across the strip),
    bound to the skin. Any tape point is interpolated from the posed nodes around it."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, level_heights: dict[str, float]):
        self.rest_vertices, self.faces = np.asarray(vertices, float), np.asarray(faces)
        self.profile = BackProfile(self.rest_vertices, self.faces, level_heights)
        self.s = np.arange(0.0, self.profile.arc[-1], CHART_STEP_MM)
        self.u = np.arange(-BRIDGE_HALF_WIDTH_MM, BRIDGE_HALF_WIDTH_MM + 1e-9, CHART_U_STEP_MM)
        ss, uu = np.meshgrid(self.s, self.u, indexing="ij")
        starts, inward = self.lay(np.column_stack([uu.ravel(), ss.ravel()]))
        triangles, hits = cast_onto_skin(self.rest_vertices, self.faces, starts, inward)
        depth = np.einsum("nd,nd->n", hits - starts, inward).reshape(ss.shape)
        envelope = np.array([outer_envelope(self.u, row) for row in depth])
        rest = starts + envelope.reshape(-1, 1) * inward
        self.bridge_mm = (depth - envelope)  # (Ns, Nu) how far the strip floats above the skin
        weights = barycentric(self.rest_vertices[self.faces[triangles]], hits)
        self.binding = FramedBinding(self.rest_vertices, self.faces, triangles, weights, rest)
        self.rest_grid = rest.reshape(len(self.s), len(self.u), 3)
        self.rest_segments = np.linalg.norm(np.diff(self.rest_grid, axis=0), axis=2)  # (Ns - 1, Nu)

    def lay(self, us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Chart coordinates (N, 2) ``(u, s)`` mm -> points in the profile's plane shifted ``u``
        toward the subject's right, and the inward directions (in the sagittal plane, normal to the
        profile) along which they are projected onto the skin."""
        return self.profile.across(us)

    def arc_at_height(self, z_mm: float) -> float:
        return self.profile.arc_at_height(z_mm)

    def posed_grid(self, vertices: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(Ns, Nu, 3) node positions (mm) on a posed mesh."""
        if normals is None:
            normals = vertex_normals(vertices, self.faces)
        return self.binding.points(vertices, self.faces, normals).reshape(len(self.s), len(self.u), 3)

    def interpolate(self, grid: np.ndarray, us: np.ndarray) -> np.ndarray:
        """Bilinear interpolation of a node field ``grid`` (Ns, Nu, ...) at chart coordinates
        ``us`` (N, 2) ``(u, s)``; linear extrapolation beyond the chart's ends."""
        fi = (us[:, 1] - self.s[0]) / CHART_STEP_MM
        fj = (us[:, 0] - self.u[0]) / CHART_U_STEP_MM
        i = np.clip(np.floor(fi).astype(int), 0, len(self.s) - 2)
        j = np.clip(np.floor(fj).astype(int), 0, len(self.u) - 2)
        a, b = fi - i, fj - j
        extra = (slice(None),) + (None,) * (grid.ndim - 2)
        a, b = a[extra], b[extra]
        return ((1 - a) * (1 - b) * grid[i, j] + a * (1 - b) * grid[i + 1, j]
                + (1 - a) * b * grid[i, j + 1] + a * b * grid[i + 1, j + 1])


@dataclass
class ChartPoints:
    """Points fixed on a :class:`BackChart` at chart coordinates ``us`` (N, 2) ``(u, s)`` mm:
    read off any posed mesh of the chart's topology."""

    chart: BackChart
    us: np.ndarray

    def points(self, vertices: np.ndarray, faces: np.ndarray | None = None,
               normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) positions (mm) on a posed mesh (``faces`` must be the chart's, if given)."""
        return self.chart.interpolate(self.chart.posed_grid(vertices, normals), self.us)

    def sequence(self, vertices: np.ndarray, faces: np.ndarray | None = None) -> np.ndarray:
        """(F, N, 3) positions over (F, V, 3) posed meshes."""
        return np.stack([self.points(v) for v in vertices])


class LaidTape:
    """A tape laid as a taut strip along the spine of a rest mesh from ``start_level`` at its spec
    (no taping tension; the studio, :mod:`spinemocap.synth.tape_on_skin`, lays it the same way and
    adds tension and skin strain): ``dots`` are the dot centres (the holes' centres on the tape's
    underside; labels ``spec.graph.labels``) on the :class:`BackChart`; ``row_levels`` the nearest
    vertebral level of each row. ``level_heights``: level name -> rest height z (mm)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, level_heights: dict[str, float], spec: TapeSpec,
                 start_level: str = "L4", chart: BackChart | None = None):
        if start_level not in level_heights:
            raise ValueError(f"unknown tape start level {start_level!r}; known: {list(level_heights)}")
        self.vertices, self.faces = np.asarray(vertices, float), np.asarray(faces)
        self.spec, self.start_level, self.level_heights = spec, start_level, level_heights
        self.chart = chart if chart is not None else BackChart(self.vertices, self.faces, level_heights)
        self.s0 = self.chart.arc_at_height(level_heights[start_level])
        if self.s0 - spec.end_margin_mm < self.chart.s[0] or self.s0 + spec.length_mm - spec.end_margin_mm > self.chart.s[-1]:
            raise ValueError(f"a {spec.n_rows}-row tape starting at {start_level} does not fit on the back "
                             f"({self.chart.s[-1] - self.s0:.0f} mm of midline above it); use fewer rows or "
                             f"a lower start level")
        self.dots = ChartPoints(self.chart, self.material(spec.graph.uv_mm))
        rest_dots = self.dot_positions(self.vertices)
        row_z = [rest_dots[spec.graph.row == r, 2].mean() for r in range(spec.n_rows)]
        self.row_levels = [min(level_heights, key=lambda name: abs(level_heights[name] - z)) for z in row_z]

    @property
    def labels(self) -> list[str]:
        return list(self.spec.graph.labels)

    def material(self, uv: np.ndarray) -> np.ndarray:
        """Flat tape coordinates (N, 2) mm -> chart coordinates ``(u, s)`` mm of the tape as laid."""
        uv = np.asarray(uv, float)
        return np.column_stack([uv[:, 0], self.s0 + uv[:, 1]])

    def dot_positions(self, vertices: np.ndarray) -> np.ndarray:
        """(D, 3) dot centres (mm) on a posed mesh of the same topology."""
        return self.dots.points(vertices)


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
