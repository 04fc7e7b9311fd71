"""Occluders: skin-coloured balls falling from the sky (the paper's experiment 2) and a sports-bra
band.

Balls: each has a radius, a horizontal position inside a box between the cameras and the back,
and a release time; it falls freely from ``DROP_HEIGHT_MM`` (``z = h - g (t - t0)^2 / 2``) and
passes through the body (no collisions: a ball overlapping a dot hides it from every camera, one
source of the paper's all-camera occlusions). Release times are uniform over the sequence
(starting one fall time early so the first frame already has balls in the air).

Occlusion levels give a ball *density*: ``light`` releases 5000 and ``heavy`` 10000 balls for the
paper's 548 frames at 100 fps (5.48 s); other durations get as many balls as keep the same
density in the air (:func:`balls_for`). The ball size and
box were tuned (``spinemocap bench render``) so the share of dot-frames seen by 4/3/2/1/0 cameras
on the ``artificial`` preset matches the paper's Table 2.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

G_MM_S2 = 9810.0
DROP_HEIGHT_MM = 2600.0
PAPER_DURATION_S = 548 / 100.0
OCCLUSION_LEVELS = {"none": 0, "light": 5000, "heavy": 10000}  # balls per PAPER_DURATION_S
# Tuned against Table 2 (see module docstring): radius range and the box, relative to the tape's
# rest centre (x across, y from the back toward the cameras).
BALL_RADIUS_MM = (9.0, 20.0)
BOX_X_MM = (-450.0, 450.0)
BOX_Y_MM = (-60.0, 900.0)
BOX_Y_POWER = 1.5


def fall_time_s() -> float:
    """Longest time a ball is in the air (released at the drop height, gone below the floor)."""
    return float(np.sqrt(2 * (DROP_HEIGHT_MM + BALL_RADIUS_MM[1]) / G_MM_S2))


def balls_for(level: str, duration_s: float) -> int:
    """Number of balls an occlusion level releases for a sequence of ``duration_s`` seconds:
    balls are released over ``[-fall time, duration]``, so the count scales with that window to
    keep the density of balls in the air equal to the paper's 548-frame sequence."""
    if level not in OCCLUSION_LEVELS:
        raise ValueError(f"unknown occlusion level {level!r}; choose from {list(OCCLUSION_LEVELS)}")
    window = (duration_s + fall_time_s()) / (PAPER_DURATION_S + fall_time_s())
    return int(round(OCCLUSION_LEVELS[level] * window))


@dataclass
class FallingBalls:
    """``radius`` (N,), ``xy`` (N, 2) mm, ``release_s`` (N,)."""

    radius: np.ndarray
    xy: np.ndarray
    release_s: np.ndarray

    @classmethod
    def generate(cls, n: int, duration_s: float, target_mm: np.ndarray, rng: np.random.Generator) -> "FallingBalls":
        fall_s = fall_time_s()
        radius = rng.uniform(*BALL_RADIUS_MM, size=n)
        x = target_mm[0] + rng.uniform(*BOX_X_MM, size=n)
        # denser near the back (BOX_Y_POWER > 1): balls brushing the skin hide a dot from every
        # camera at once, the paper's bursts of all-camera occlusion
        y = target_mm[1] + BOX_Y_MM[0] + (BOX_Y_MM[1] - BOX_Y_MM[0]) * rng.uniform(size=n) ** BOX_Y_POWER
        release = rng.uniform(-fall_s, duration_s, size=n)
        return cls(radius, np.column_stack([x, y]), release)

    def __len__(self) -> int:
        return len(self.radius)

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Balls in the air at time ``t_s``: centres (B, 3) mm and radii (B,)."""
        dt = t_s - self.release_s
        z = DROP_HEIGHT_MM - 0.5 * G_MM_S2 * dt**2
        alive = (dt >= 0) & (z > -self.radius)
        centres = np.column_stack([self.xy[alive], z[alive]])
        return centres, self.radius[alive]


def segments_blocked_by_spheres(origins: np.ndarray, ends: np.ndarray, centres: np.ndarray,
                                radii: np.ndarray) -> np.ndarray:
    """(S,) bool: does segment ``origins[s] -> ends[s]`` pass through any sphere?"""
    if len(centres) == 0:
        return np.zeros(len(ends), dtype=bool)
    d = ends - origins  # (S, 3)
    length2 = np.maximum(np.einsum("sd,sd->s", d, d), 1e-12)
    rel = centres[None, :, :] - origins[:, None, :]  # (S, B, 3)
    s = np.clip(np.einsum("sbd,sd->sb", rel, d) / length2[:, None], 0.0, 1.0)
    closest = origins[:, None, :] + s[..., None] * d[:, None, :]
    dist2 = np.sum((closest - centres[None]) ** 2, axis=2)
    return (dist2 < radii[None] ** 2).any(axis=1)


def sphere_mesh(centres: np.ndarray, radii: np.ndarray, resolution: int = 16):
    """One pyvista PolyData holding all spheres (empty PolyData when there are none): the unit
    sphere template scaled by each radius (mm) and moved to each centre (mm); normals are the
    template's. The template and the triangle connectivity are cached (only the points change
    from one instant to the next)."""
    import pyvista as pv

    if len(centres) == 0:
        return pv.PolyData()
    base_pts, _ = _unit_sphere(resolution)
    n = len(centres)
    pts = (base_pts[None] * radii[:, None, None] + centres[:, None, :]).reshape(-1, 3)
    mesh = pv.PolyData.from_regular_faces(pts, _sphere_faces(resolution, n))
    mesh.point_data.active_normals = np.tile(base_pts, (n, 1))  # unit sphere: normal = position
    return mesh


@functools.lru_cache(maxsize=4)
def _unit_sphere(resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 3) and triangles (T, 3) of pyvista's unit sphere (read-only arrays)."""
    import pyvista as pv

    unit = pv.Sphere(radius=1.0, theta_resolution=resolution, phi_resolution=resolution)
    points, faces = np.array(unit.points, float), unit.faces.reshape(-1, 4)[:, 1:].copy()
    points.flags.writeable = faces.flags.writeable = False
    return points, faces


_FACES_CACHE: dict[int, np.ndarray] = {}


def _sphere_faces(resolution: int, n: int) -> np.ndarray:
    """(n * T, 3) triangles of ``n`` template spheres stored one after the other: a prefix of
    the connectivity of the most spheres asked for so far (grown, never rebuilt per instant)."""
    cached = _FACES_CACHE.get(resolution)
    if cached is None or len(cached) < n * len(_unit_sphere(resolution)[1]):
        base_pts, base_faces = _unit_sphere(resolution)
        grow = max(n, 2 * (0 if cached is None else len(cached) // len(base_faces)))
        cached = (base_faces[None] + (np.arange(grow) * len(base_pts))[:, None, None]).reshape(-1, 3)
        _FACES_CACHE[resolution] = cached
    return cached[: n * len(_unit_sphere(resolution)[1])]


class Garment:
    """A piece of clothing bound to the skin: the torso (arms excluded by ``|x| <
    torso_half_width_mm``) between the heights ``z_low_mm`` and ``z_high_mm`` of the rest mesh,
    giving straight edges; every vertex is bound to the body triangle it lies on (barycentric
    coordinates) and floated ``offset_mm`` off the skin, so the garment moves and stretches with
    the body. Raises ValueError when the slab misses the torso."""

    def __init__(self, body, z_low_mm: float, z_high_mm: float, torso_half_width_mm: float = 175.0,
                 offset_mm: float | None = None):
        import pyvista as pv

        from ..skin import SkinBinding, barycentric

        faces_vtk = np.column_stack([np.full(len(body.faces), 3), body.faces]).ravel()
        mesh = pv.PolyData(body.rest_vertices, faces_vtk)
        centroid = body.rest_vertices[body.faces].mean(axis=1)
        middle, half = (z_low_mm + z_high_mm) / 2, (z_high_mm - z_low_mm) / 2
        near = (np.abs(centroid[:, 2] - middle) < 2 * half) & (np.abs(centroid[:, 0]) < torso_half_width_mm)
        torso = mesh.extract_cells(np.flatnonzero(near)).extract_surface(algorithm=None)
        torso["body_face"] = np.flatnonzero(near)[torso.cell_data["vtkOriginalCellIds"]]
        slab = torso.clip("z", origin=(0, 0, z_high_mm), invert=True)
        slab = slab.clip("-z", origin=(0, 0, z_low_mm), invert=True).triangulate()
        slab = slab.extract_surface(algorithm=None).triangulate()
        if slab.n_cells == 0:
            raise ValueError(f"the garment between heights {z_low_mm:.0f} and {z_high_mm:.0f} mm misses the torso")
        self.faces = slab.faces.reshape(-1, 4)[:, 1:]
        points = np.asarray(slab.points, float)
        self.n_points = len(points)
        # every vertex lies on the body triangle of the cell it came from
        owner = np.full(len(points), -1)
        for cell, tri in zip(np.asarray(slab.cell_data["body_face"]), self.faces):
            owner[tri] = cell
        self.binding = SkinBinding(owner, barycentric(body.rest_vertices[body.faces[owner]], points))
        self._body_faces = body.faces
        self.offset_mm = BAND_OFFSET_MM if offset_mm is None else float(offset_mm)

    def vertices(self, body_vertices: np.ndarray, body_normals: np.ndarray) -> np.ndarray:
        """(N, 3) posed garment vertices, ``offset_mm`` off the skin."""
        p = self.binding.surface_points(body_vertices, self._body_faces)
        return p + self.offset_mm * self.binding.normals(body_normals, self._body_faces)


class SportsBraBand(Garment):
    """A band around the chest (the paper's jogging-bra occlusion): a ``width_mm`` high
    :class:`Garment` centred at ``level_z_mm``, ``BAND_OFFSET_MM`` off the skin."""

    def __init__(self, body, level_z_mm: float, width_mm: float = 60.0, torso_half_width_mm: float = 175.0):
        try:
            super().__init__(body, level_z_mm - width_mm / 2, level_z_mm + width_mm / 2, torso_half_width_mm)
        except ValueError:
            raise ValueError(f"the sports-bra band at height {level_z_mm:.0f} mm misses the torso") from None


SPORTS_BRA_RGB = (0.15, 0.25, 0.55)  # the sports-bra band's colour
ClothingItem = Literal["shorts", "bra_strap"]
CLOTHING_ITEMS: tuple[str, ...] = get_args(ClothingItem)
GARMENT_COLOURS = ((0.05, 0.05, 0.06), (0.92, 0.92, 0.90), (0.45, 0.47, 0.50), (0.10, 0.16, 0.40),
                   (0.85, 0.40, 0.55), (0.60, 0.10, 0.12), (0.20, 0.35, 0.22))


class Clothing:
    """Garments worn together, as one mesh: ``faces`` (M, 3), per-vertex ``colours`` (N, 3) RGB
    0..1 (None when no garment has its own colour: the renderer's band colour; a garment
    without one takes :data:`SPORTS_BRA_RGB`); :meth:`vertices` poses them.
    Garments hide the tape like any solid: the scene draws them black in the tape mask and casts
    the dots' visibility rays against them."""

    def __init__(self, garments: list[tuple[Garment, tuple[float, float, float] | None]]):
        self.garments = [g for g, _ in garments]
        sizes = [g.n_points for g in self.garments]
        offsets = np.cumsum([0] + sizes[:-1])
        self.faces = np.concatenate([g.faces + o for g, o in zip(self.garments, offsets)])
        colours = [c for _, c in garments]
        self.colours = (None if all(c is None for c in colours) else
                        np.concatenate([np.tile(c if c is not None else SPORTS_BRA_RGB, (n, 1))
                                        for c, n in zip(colours, sizes)]))

    def vertices(self, body_vertices: np.ndarray, body_normals: np.ndarray) -> np.ndarray:
        """(N, 3) posed vertices of every garment, in order."""
        return np.concatenate([g.vertices(body_vertices, body_normals) for g in self.garments])


def wear_clothing(body, items: tuple[str, ...], tape_bottom_z_mm: float, rng: np.random.Generator) -> list[tuple[Garment, tuple[float, float, float]]]:
    """The garments ``items`` (:data:`CLOTHING_ITEMS`) on the rest ``body``, drawn from ``rng``:
    ``shorts`` whose waistband lies 15-70 mm below the tape's lower end (``tape_bottom_z_mm``, the
    rest height of its first row's dots) and reach 300 mm down; a sports bra's back ``bra_strap``
    18-40 mm wide across the back somewhere between T10 and T6 (over the tape: it hides the rows it
    crosses, as in a lab). Each in a colour of :data:`GARMENT_COLOURS`. Raises ValueError for an
    unknown item."""
    unknown = [i for i in items if i not in CLOTHING_ITEMS]
    if unknown:
        raise ValueError(f"unknown clothing {unknown}; choose from {list(CLOTHING_ITEMS)}")
    out = []
    heights = body.level_heights()
    for item in CLOTHING_ITEMS:
        if item not in items:
            continue
        colour = GARMENT_COLOURS[int(rng.integers(len(GARMENT_COLOURS)))]
        if item == "shorts":
            top = tape_bottom_z_mm - rng.uniform(15, 70)
            out.append((Garment(body, top - 300.0, top, torso_half_width_mm=190.0), colour))
        else:
            level = rng.uniform(heights["T10"], heights["T6"])
            width = rng.uniform(18, 40)
            out.append((Garment(body, level - width / 2, level + width / 2), colour))
    return out


BAND_OFFSET_MM = 8.0  # the band stands off the skin (fabric thickness + it bridges the tape)
