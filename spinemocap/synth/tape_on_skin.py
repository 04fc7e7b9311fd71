"""Laying the tape on the skin as a taut strip, binding it to the body mesh, and the skin under it.

Laying (on the neutral, "rest" pose): a taut strip laid up the back from a start level spans the
hollows across its width (the gluteal cleft, the groove over the spinous processes) instead of
following them, as real kinesiology tape does. The laying is core's (:mod:`spinemocap.skin`,
shared with the body models): its ``BackProfile`` is the strip's midline (the
outer convex envelope of horizontal sections of the back, parametrised by arc length);
its ``BackChart`` is a grid of nodes ``(s, u)`` on the strip's surface (``s`` arc length along
the midline, ``u`` toward the subject's right = ``-X``, as in :mod:`spinemocap.tape`), each
bound to the skin under it by a triangle, barycentric weights and an offset in the triangle's
local frame, so it follows the skin in any pose.

A tape point with flat coordinates ``(u, v)`` of the roll's spec lies on the skin material at
``(u, s0 + laid_v(v))``: ``s0`` is the start level's arc length and ``laid_v`` the taping tension
(:class:`TapeTension`). In a posed frame the skin slides along anny's surface by the skin strain
of :mod:`spinemocap.synth.skin_strain` (anchored below the sacrum), and every tape point is
interpolated bilinearly from the posed chart nodes: dots, their normals and the rendered strip
all follow the same mapping.

The rendered tape is a fine strip mesh (1 mm grid) with the dots cut out as holes (hole edges
snapped onto the circles), floated the tape's thickness (``TapeSpec.thickness_mm``) above the
strip's surface along its normal so the skin shows through the holes. Ground-truth dot centres
are the holes' centres on the tape's underside.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..skin import BackChart, bind_to_surface
from ..tape import TapeSpec
from .body import Body
from .skin_strain import SkinStrain, StrainRegions

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


def back_chart(body: Body) -> BackChart:
    """The taut-strip chart over the back of the studio's body at rest (core :class:`BackChart`),
    its profile starting 60 mm below S2."""
    return BackChart(body.rest_vertices, body.faces, body.level_heights())


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


@dataclass
class TapeStrip:
    """Flat tape geometry: grid vertices ``uv`` (N, 2) mm, triangles with holes ``faces_holes``
    and without ``faces_solid`` (the mask silhouette)."""

    uv: np.ndarray
    faces_holes: np.ndarray
    faces_solid: np.ndarray

    @classmethod
    def build(cls, spec: TapeSpec, step_mm: float = 1.0) -> TapeStrip:
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
    """A tape laid on a body as a taut strip from ``start_level`` up the back (see the module
    docstring): its material points, the skin binding of the chart under it and the keypoints.
    :meth:`pose` places it on a posed body, with the skin's strain when one is given."""

    def __init__(self, body: Body, spec: TapeSpec, start_level: str = "S1", tension: TapeTension = TapeTension(),
                 chart: BackChart | None = None):
        heights = body.level_heights()
        if start_level not in heights:
            raise ValueError(f"unknown tape start level {start_level!r}; known: {list(heights)}")
        self.body, self.spec, self.start_level, self.tension = body, spec, start_level, tension
        self.chart = chart if chart is not None else back_chart(body)
        self.s0 = self.chart.arc_at_height(heights[start_level])
        self.regions = StrainRegions(*(self.chart.arc_at_height(heights[name]) for name in ("S1", "L1", "T10")))
        v_ends = self.s0 + tension.laid_v(spec, np.array([-spec.end_margin_mm, spec.length_mm - spec.end_margin_mm]))
        if v_ends[0] < self.chart.s[0] or v_ends[1] > self.chart.s[-1]:
            raise ValueError(
                f"a {spec.n_rows}-row tape ({spec.length_mm:.0f} mm, laid {v_ends[1] - v_ends[0]:.0f} mm long) "
                f"starting at {start_level} does not fit on the back below the head "
                f"({self.chart.s[-1] - self.s0:.0f} mm of midline above {start_level}, up the back of the neck); "
                f"use fewer rows or a lower start level"
            )
        self.strip = TapeStrip.build(spec)
        self.dot_material = self.material(spec.graph.uv_mm)
        self.strip_material = self.material(self.strip.uv)
        self.keypoint_names = list(KEYPOINT_NAMES)
        self.keypoints = bind_to_surface(body.rest_vertices, body.faces, *back_keypoints(body))
        rest_dots = self.pose(body.rest_vertices).dots()
        self._check_lies_flat(rest_dots)
        row_z = [rest_dots[spec.graph.row == r, 2].mean() for r in range(spec.n_rows)]
        self.row_levels = [body.nearest_level(z) for z in row_z]

    def material(self, uv: np.ndarray) -> np.ndarray:
        """Flat tape coordinates (N, 2) of the roll's spec -> material chart coordinates ``(u, s)``
        of the skin under them as laid (stretched along the tape by the taping tension), mm."""
        uv = np.asarray(uv, float)
        return np.column_stack([uv[:, 0], self.s0 + self.tension.laid_v(self.spec, uv[:, 1])])

    def level_rows(self) -> dict[str, float]:
        """Fractional 1-based row at which each vertebral level (and junction ``"T12/L1"``-style
        midpoint of two adjacent levels) lies on the rest tape, measured along the strip; NaN
        beyond the first and last rows."""
        spec = self.spec
        row_s = self.material(np.column_stack([np.zeros(spec.n_rows), np.arange(spec.n_rows) * spec.row_pitch_mm]))[:, 1]
        heights = self.body.level_heights()
        names = list(heights)
        points = dict(heights)
        for lower, upper in zip(names[:-1], names[1:]):
            points[f"{upper}/{lower}"] = 0.5 * (heights[lower] + heights[upper])
        rows = np.arange(1, spec.n_rows + 1, dtype=float)
        out = {}
        for name, z in points.items():
            s = self.chart.arc_at_height(z)
            out[name] = float(np.interp(s, row_s, rows)) if row_s[0] <= s <= row_s[-1] else float("nan")
        return out

    def pose(self, vertices: np.ndarray, normals: np.ndarray | None = None, strain: SkinStrain | None = None,
             angles_deg: np.ndarray | None = None) -> PosedTape:
        """The tape on a posed body (vertices (V, 3) mm, vertex normals), its skin strained by
        ``strain`` for the spine's [flexion, lateral bending, axial rotation] ``angles_deg``."""
        return PosedTape(self, vertices, normals, strain, angles_deg)

    def dot_positions(self, vertices: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """(D, 3) dot centres (mm) on a posed mesh without skin strain (see :meth:`pose`)."""
        return self.pose(vertices, normals).dots()

    def _check_lies_flat(self, rest_dots: np.ndarray) -> None:
        """Refuse a lay that a real tape could not take: at rest, every solid dot distance must
        match the laid tape's within the tape's stretch tolerance (a strip too curved for a flat
        tape there). The taut strip bridges the gluteal cleft, so starts down to S2 lie flat."""
        graph = self.spec.graph
        edges = graph.edges[graph.solid]
        flat = self.material(graph.uv_mm)
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
                f"the back is too curved there for a flat strip); start the tape elsewhere"
            )


class PosedTape:
    """A tape on one posed body: node grid of the chart, the skin's strain, dots and strip."""

    def __init__(self, tape: TapeOnSkin, vertices: np.ndarray, normals: np.ndarray | None,
                 strain: SkinStrain | None, angles_deg: np.ndarray | None):
        self.tape, self.chart = tape, tape.chart
        self.grid = self.chart.posed_grid(vertices, normals)
        d_u = np.gradient(self.grid, axis=1)
        d_s = np.gradient(self.grid, axis=0)
        n = np.cross(d_u, d_s)  # outward: u runs to the subject's right, s up the back
        self.normal_grid = n / np.linalg.norm(n, axis=2, keepdims=True)
        self.strain = strain if strain is not None and strain.enabled else None
        self.angles = np.zeros(3) if angles_deg is None else np.asarray(angles_deg, float)
        self._column_map = self._slide(self.strain) if self.strain is not None else None

    def _slide(self, strain: SkinStrain) -> np.ndarray:
        """(Ns, Nu) chart coordinate ``s`` where the material that rested at node ``s_i`` of column
        ``j`` lies now: the skin slides along anny's surface so that, from an anchor below the
        sacrum (which does not move), the posed arc length of the material follows the strain."""
        chart = self.chart
        posed_seg = np.linalg.norm(np.diff(self.grid, axis=0), axis=2)
        s_mid = 0.5 * (chart.s[1:] + chart.s[:-1])
        eps = strain.longitudinal(s_mid[:, None], chart.u[None, :], self.angles, self.tape.regions)
        target_seg = chart.rest_segments * (1.0 + eps)
        anchor = int(np.clip(np.searchsorted(chart.s, self.tape.regions.s_sacrum - 40.0), 0, len(chart.s) - 1))
        zero = np.zeros((1, len(chart.u)))
        posed = np.concatenate([zero, np.cumsum(posed_seg, axis=0)])
        target = np.concatenate([zero, np.cumsum(target_seg, axis=0)])
        posed -= posed[anchor]
        target -= target[anchor]
        far = 1000.0  # beyond the chart's end: extend with unit slope
        out = np.empty_like(posed)
        for j in range(len(chart.u)):
            out[:, j] = np.interp(target[:, j], np.append(posed[:, j], posed[-1, j] + far),
                                  np.append(chart.s, chart.s[-1] + far))
        return out

    def chart_coordinates(self, material: np.ndarray) -> np.ndarray:
        """Material coordinates (N, 2) ``(u, s)`` -> where that skin lies now on the chart."""
        if self._column_map is None or self.strain is None:
            return material
        s = self.chart.interpolate(self._column_map, material)
        u = material[:, 0] * (1.0 + self.strain.transverse(material[:, 1], self.angles, self.tape.regions))
        return np.column_stack([u, s])

    def points(self, material: np.ndarray) -> np.ndarray:
        """(N, 3) positions (mm) of material points on the tape's underside."""
        return self.chart.interpolate(self.grid, self.chart_coordinates(material))

    def normals(self, material: np.ndarray) -> np.ndarray:
        """(N, 3) outward unit normals of the tape at material points."""
        n = self.chart.interpolate(self.normal_grid, self.chart_coordinates(material))
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def dots(self) -> np.ndarray:
        """(D, 3) dot centres (mm): the holes' centres on the tape's underside."""
        return self.points(self.tape.dot_material)

    def dot_normals(self) -> np.ndarray:
        return self.normals(self.tape.dot_material)

    def strip_vertices(self) -> np.ndarray:
        """(N, 3) strip mesh vertices on the tape's top surface (one thickness out)."""
        material = self.tape.strip_material
        return self.points(material) + self.tape.spec.thickness_mm * self.normals(material)


def rows_to_pass(chart: BackChart, spec: TapeSpec, s0: float, tension: TapeTension, height_mm: float,
                 rows_above: int = 2) -> int:
    """The smallest odd row count of tape ``spec`` whose tape, laid from arc length ``s0`` with
    ``tension``, has ``rows_above`` rows above the height ``height_mm`` (mm) at rest -- or, where
    the back above the start is too short for that (high starts), the most rows that fit (>= 3)."""
    target = chart.arc_at_height(height_mm) - s0
    n = max(3, 2 * rows_above + 1)
    while n < 99:
        longer = replace(spec, n_rows=n)
        if tension.laid_v(longer, np.array([(n - rows_above) * longer.row_pitch_mm]))[0] > target:
            break
        n += 2

    def fits(rows: int) -> bool:
        longer = replace(spec, n_rows=rows)
        end = longer.length_mm - longer.end_margin_mm
        return bool(s0 + tension.laid_v(longer, np.array([end]))[0] <= chart.s[-1])

    while n > 3 and not fits(n):
        n -= 2
    return n

