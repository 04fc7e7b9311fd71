"""Offscreen rendering of one camera with pyvista/VTK, matching the OpenCV camera model exactly.

VTK renders an ideal pinhole image whose projection matrix is set explicitly from the camera's
intrinsics (off-centre principal point, fx != fy), on a canvas with a margin around the image.
Lens distortion is then applied by resampling: every output (distorted) pixel looks up the
undistorted canvas position of its ray (:meth:`Camera.undistort_points`). Pixel ``(0, 0)`` is
the centre of the top-left pixel, as in OpenCV.

Each camera keeps one ``Plotter`` for the whole sequence; per frame only the vertex arrays change.
The tape mask comes from a second, unlit window showing the same geometry: tape strip (without
holes) white, body, band and occluders black, so they hide the tape in the mask exactly as in the
image. That window covers only the tape's bounding box on the canvas (exact shifted projection),
which makes the mask pass cheap at high resolution.

Speed (``spinemocap bench render``): the
software rasteriser's cost grows with the window's pixels (4x multisampling), so the colour image
too is rasterised only over the canvas rectangle the scene covers (:meth:`CameraRenderer.render_window`;
the rest of the canvas is the empty background's colour). The lens resampling then touches only the
output pixels that can see the window. The straightforward reference renderer stays reachable (:meth:`CameraRenderer.render_reference`,
``Scene.render(..., reference=True)``) as the benchmark's peer and the tests' reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..camera import Camera
from .occluders import SPORTS_BRA_RGB
from .reference import ReferenceMeshes

NEAR_MM, FAR_MM = 50.0, 50_000.0


def faces_to_vtk(faces: np.ndarray) -> np.ndarray:
    return np.column_stack([np.full(len(faces), 3), faces]).ravel()


def opengl_projection(K: np.ndarray, width: int, height: int, near: float = NEAR_MM, far: float = FAR_MM) -> np.ndarray:
    """4x4 OpenGL projection (eye coordinates, camera looking down -z, y up) reproducing the
    pinhole ``K`` on a ``width`` x ``height`` pixel window with OpenCV's pixel-centre convention."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.array([
        [2 * fx / width, 0.0, 1 - 2 * (cx + 0.5) / width, 0.0],
        [0.0, 2 * fy / height, 2 * (cy + 0.5) / height - 1, 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0],
    ])


@dataclass
class Appearance:
    """Colours (RGB 0..1) and lighting of a scene."""

    skin_rgb: tuple[float, float, float]
    tape_rgb: tuple[float, float, float] = (0.08, 0.08, 0.10)
    background_rgb: tuple[float, float, float] = (0.35, 0.36, 0.38)
    reference_frame_rgb: tuple[float, float, float] = (0.20, 0.20, 0.21)  # dark anodised aluminium
    reference_marker_rgb: tuple[float, float, float] = (0.95, 0.95, 0.95)  # retro-reflective, lit by the camera
    band_rgb: tuple[float, float, float] = SPORTS_BRA_RGB
    light_position: tuple[float, float, float] = (0.0, 3000.0, 3000.0)
    light_intensity: float = 0.9
    fill_intensity: float = 0.35
    skin_specular: float = 0.08
    skin_specular_power: float = 10.0


@dataclass(frozen=True)
class MeshTexture:
    """An RGB uint8 ``image`` (H, W, 3) laid on a mesh by per-vertex texture ``coordinates``
    (N, 2) in [0, 1]; the mesh is drawn in the image's colours (bilinear, mipmapped), lit as
    without it."""

    image: np.ndarray
    coordinates: np.ndarray

    def material(self, mesh) -> dict:
        """The ``add_mesh`` keywords that draw ``mesh`` (its texture coordinates set here) in this
        texture."""
        import pyvista as pv

        mesh.active_texture_coordinates = np.asarray(self.coordinates, np.float32)
        texture = pv.Texture(np.ascontiguousarray(self.image))
        texture.interpolate, texture.mipmap, texture.repeat = True, True, False
        return {"color": (1.0, 1.0, 1.0), "texture": texture}


@dataclass
class SceneMeshes:
    """Posed geometry of one instant, all in world mm."""

    body_vertices: np.ndarray
    body_normals: np.ndarray
    tape_vertices: np.ndarray
    occluders: Any = None  # pyvista.PolyData or None
    band_vertices: np.ndarray | None = None


class CameraRenderer:
    """Renders a scene as seen by one camera: BGR image and tape mask, both distorted."""

    def __init__(self, camera: Camera, body_faces: np.ndarray, tape_faces_holes: np.ndarray,
                 tape_faces_solid: np.ndarray, appearance: Appearance,
                 band_faces: np.ndarray | None = None, supersample: int = 1,
                 reference: ReferenceMeshes | None = None, band_colours: np.ndarray | None = None,
                 skin_texture: MeshTexture | None = None, tape_texture: MeshTexture | None = None):
        """``reference``: a static reference object (:mod:`spinemocap.synth.reference`) drawn in
        every image: its bars lit like the scene, its markers as uniform bright discs (ambient
        light only: retro-reflectors under the camera's ring light); black in the tape mask.
        ``band_colours``: (N, 3) RGB 0..1 per band vertex (garments of several colours; None:
        ``appearance.band_rgb``); ``skin_texture`` / ``tape_texture``: the body's and the tape's
        (holed strip's) colours as textures (None: their appearance colours)."""
        import pyvista as pv

        from .occluders import sphere_mesh

        self.camera = camera
        self.supersample = int(supersample)
        self._build_lookup()
        W, H = self.canvas_size
        s = self.supersample
        self.plotter = pv.Plotter(off_screen=True, window_size=(W * s, H * s), lighting="none")
        self.plotter.set_background(appearance.background_rgb)
        self.appearance = appearance

        n_body = int(body_faces.max()) + 1
        self.body = pv.PolyData(np.zeros((n_body, 3)), faces_to_vtk(body_faces))
        n_tape = int(max(tape_faces_holes.max(), tape_faces_solid.max())) + 1
        self.tape = pv.PolyData(np.zeros((n_tape, 3)), faces_to_vtk(tape_faces_holes))
        self.tape_solid = pv.PolyData(np.zeros((n_tape, 3)), faces_to_vtk(tape_faces_solid))
        skin = dict(color=appearance.skin_rgb, smooth_shading=False, ambient=0.15, diffuse=0.85,
                    specular=appearance.skin_specular, specular_power=appearance.skin_specular_power)
        if skin_texture is not None:
            skin.update(skin_texture.material(self.body))
        self.body_actor = self.plotter.add_mesh(self.body, **skin)
        self.body_actor.GetProperty().SetInterpolationToGouraud()  # uses the per-frame normals
        tape = dict(color=appearance.tape_rgb, ambient=0.2, diffuse=0.8, specular=0.25, specular_power=20)
        if tape_texture is not None:
            tape.update(tape_texture.material(self.tape))
        self.tape_actor = self.plotter.add_mesh(self.tape, **tape)
        self.band = self.band_actor = None
        if band_faces is not None and len(band_faces):
            self.band = pv.PolyData(np.zeros((int(band_faces.max()) + 1, 3)), faces_to_vtk(band_faces))
            colour: dict = {"color": appearance.band_rgb}
            if band_colours is not None:
                self.band.point_data["colours"] = np.clip(np.asarray(band_colours) * 255 + 0.5, 0, 255).astype(np.uint8)
                colour = {"scalars": "colours", "rgb": True}
            self.band_actor = self.plotter.add_mesh(self.band, ambient=0.2, diffuse=0.8, **colour)
        self.occluder_actor: Any = None
        self.reference_meshes: list[Any] = []  # static: the reference object's frame and markers
        self.reference_actors: list[Any] = []
        self._static_points = np.zeros((0, 3))
        if reference is not None:
            frame = pv.PolyData.from_regular_faces(reference.frame_vertices, reference.frame_faces)
            markers = sphere_mesh(reference.marker_centres, np.full(len(reference.marker_centres), reference.marker_radius),
                                  resolution=24)
            self.reference_meshes = [frame, markers]
            self.reference_actors = [
                self.plotter.add_mesh(frame, color=appearance.reference_frame_rgb, ambient=0.2, diffuse=0.8,
                                      specular=0.0),
                self.plotter.add_mesh(markers, color=appearance.reference_marker_rgb, ambient=1.0, diffuse=0.0,
                                      specular=0.0),
            ]
            self._static_points = np.concatenate([reference.frame_vertices, np.asarray(markers.points)])
        self._add_lights(pv, appearance)
        self._point_camera(self.plotter)
        self._window = (0, 0, *self.canvas_size)  # canvas rectangle the main window shows
        self._show_canvas_region(self.plotter, *self._window)
        self.plotter.camera_set = True
        self._background: np.ndarray | None = None  # (3,) uint8 RGB of an empty canvas pixel
        self._scene_window_size: tuple[int, int] | None = None  # render_window's window (canvas px)
        # the tape mask is rendered in a second, unlit window that shows only the tape's
        # neighbourhood of the canvas (created on first use, grown when the tape needs more room)
        self.mask_plotter = None
        self._mask_occluder_actor: Any = None

    # ------------------------------------------------------------------ set-up
    def _build_lookup(self) -> None:
        """Per output pixel, the undistorted canvas position of its ray (cv2.remap maps)."""
        from scipy.interpolate import RectBivariateSpline

        cam = self.camera
        w, h = cam.size
        # undistort a coarse grid exactly and interpolate: the lens map is smooth, and
        # undistorting every pixel of a 2448x1600 image takes seconds
        xs = np.linspace(0.0, w - 1.0, max(4, w // 16 + 1))
        ys = np.linspace(0.0, h - 1.0, max(4, h // 16 + 1))
        gx, gy = np.meshgrid(xs, ys)
        coarse = cam.undistort_points(np.column_stack([gx.ravel(), gy.ravel()])).reshape(len(ys), len(xs), 2)
        px, py = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
        undistorted = np.stack(
            [RectBivariateSpline(ys, xs, coarse[..., k], kx=3, ky=3)(py, px).ravel() for k in range(2)], axis=1
        )  # (h * w, 2), row-major: pixel (u, v) at index v * w + u
        lo = np.floor(undistorted.min(axis=0)).astype(int)
        hi = np.ceil(undistorted.max(axis=0)).astype(int)
        margin_x = int(max(0, -lo[0], hi[0] - (w - 1))) + 2
        margin_y = int(max(0, -lo[1], hi[1] - (h - 1))) + 2
        self.margin = (margin_x, margin_y)
        self.canvas_size = (w + 2 * margin_x, h + 2 * margin_y)
        self.map_x = (undistorted[:, 0] + margin_x).reshape(h, w).astype(np.float32)
        self.map_y = (undistorted[:, 1] + margin_y).reshape(h, w).astype(np.float32)
        # canvas extent each output column / row reads from: bounds the lens pass of the mask
        self._column_x_range = (self.map_x.min(axis=0), self.map_x.max(axis=0))
        self._row_y_range = (self.map_y.min(axis=1), self.map_y.max(axis=1))

    def _point_camera(self, plotter) -> None:
        cam = self.camera
        vcam = plotter.camera
        center = cam.center
        vcam.SetPosition(*center)
        vcam.SetFocalPoint(*(center + cam.R[2] * 1000.0))
        vcam.SetViewUp(*(-cam.R[1]))

    def _show_canvas_region(self, plotter, x0: int, y0: int, width: int, height: int) -> None:
        """Make ``plotter``'s window (``width`` x ``height`` canvas pixels times the supersampling
        factor) show the undistorted canvas pixels [x0, x0 + width) x [y0, y0 + height): an exact
        pinhole projection of that sub-rectangle."""
        import vtk

        s = self.supersample
        K = self.camera.K.copy()
        K[0, 2] += self.margin[0] - x0
        K[1, 2] += self.margin[1] - y0
        # supersampled canvas: pixel centres scale as (x + 0.5) * s - 0.5
        K[:2, :] *= s
        K[0, 2] += (s - 1) / 2
        K[1, 2] += (s - 1) / 2
        proj = opengl_projection(K, width * s, height * s)
        matrix = vtk.vtkMatrix4x4()
        for i in range(4):
            for j in range(4):
                matrix.SetElement(i, j, proj[i, j])
        vcam = plotter.camera
        vcam.SetExplicitProjectionTransformMatrix(matrix)
        vcam.SetUseExplicitProjectionTransformMatrix(True)

    def _add_lights(self, pv, appearance: Appearance) -> None:
        key = pv.Light(position=appearance.light_position, focal_point=(0, 0, 1000),
                       intensity=appearance.light_intensity, light_type="scene light")
        fill = pv.Light(position=tuple(self.camera.center), focal_point=(0, 0, 1000),
                        intensity=appearance.fill_intensity, light_type="scene light")
        self.plotter.add_light(key)
        self.plotter.add_light(fill)

    # ------------------------------------------------------------------ rendering
    def _update(self, meshes: SceneMeshes) -> None:
        """Load the posed geometry of an instant."""
        self.body.points = meshes.body_vertices
        self.body.point_data["Normals"] = meshes.body_normals
        self.body.point_data.active_normals = meshes.body_normals
        self.tape.points = meshes.tape_vertices
        self.tape_solid.points = meshes.tape_vertices
        if self.band is not None and meshes.band_vertices is not None:
            self.band.points = meshes.band_vertices
        self._show_occluders(meshes.occluders)

    def _show_occluders(self, occluders: Any) -> None:
        """Draw ``occluders`` (PolyData or None) in the main window, in place of the last ones."""
        if self.occluder_actor is not None:
            self.plotter.remove_actor(self.occluder_actor, render=False)
            self.occluder_actor = None
        if occluders is not None and occluders.n_points:
            self.occluder_actor = self.plotter.add_mesh(occluders, color=self.appearance.skin_rgb,
                                                        ambient=0.15, diffuse=0.85, render=False)
            self.occluder_actor.GetProperty().SetInterpolationToGouraud()

    def _canvas_snapshot(self, plotter=None) -> np.ndarray:
        """Render a window as it is set now: undistorted RGB at canvas resolution."""
        plotter = plotter or self.plotter
        plotter.render()
        rgb = plotter.screenshot(return_img=True)
        if self.supersample > 1:
            h, w = rgb.shape[:2]
            rgb = cv2.resize(rgb, (w // self.supersample, h // self.supersample), interpolation=cv2.INTER_AREA)
        return rgb

    def through_lens(self, canvas: np.ndarray) -> np.ndarray:
        """Undistorted canvas (canvas pixels) -> distorted image (H, W), bilinear."""
        return cv2.remap(canvas, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _output_block(self, x0: int, y0: int, x1: int, y1: int) -> tuple[int, int, int, int] | None:
        """Output pixel block (u0, v0, u1, v1) holding every output pixel whose bilinear taps can
        touch the canvas rectangle [x0, x1) x [y0, y1) (conservative: per column and row extents
        of the lens maps), or None when none can."""
        (col_lo, col_hi), (row_lo, row_hi) = self._column_x_range, self._row_y_range
        cols = np.flatnonzero((col_hi > x0 - 1) & (col_lo < x1))
        rows = np.flatnonzero((row_hi > y0 - 1) & (row_lo < y1))
        if len(cols) == 0 or len(rows) == 0:
            return None
        return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1

    def _through_lens_window(self, window: np.ndarray, wx: int, wy: int, fill: np.ndarray | int = 0) -> np.ndarray:
        """Distorted (H, W[, channels]) image of a canvas that is ``window`` at canvas offset
        (``wx``, ``wy``) and ``fill`` elsewhere; only the output block that can see the window is
        resampled (same pixels as :meth:`through_lens` of the whole canvas: bilinear weights sum
        to one, so resampling a uniform area gives back its value)."""
        w, h = self.camera.size
        W, H = self.canvas_size
        ch, cw = window.shape[:2]
        out = np.empty((h, w, *window.shape[2:]), window.dtype)
        out[...] = fill
        block = self._output_block(wx, wy, wx + cw, wy + ch)
        if block is None:
            return out
        u0, v0, u1, v1 = block
        # the window padded with the canvas' fill (2 px, inside the canvas), so that taps just
        # outside the window read the fill as on the whole canvas, and border replication at the
        # canvas edge replicates the same pixels
        px0, py0 = max(wx - 2, 0), max(wy - 2, 0)
        px1, py1 = min(wx + cw + 2, W), min(wy + ch + 2, H)
        padded = np.empty((py1 - py0, px1 - px0, *window.shape[2:]), window.dtype)
        padded[...] = fill
        padded[wy - py0 : wy - py0 + ch, wx - px0 : wx - px0 + cw] = window
        # integer shifts of float32 maps are exact, so the taps and weights are the same
        map_x = self.map_x[v0:v1, u0:u1] - np.float32(px0)
        map_y = self.map_y[v0:v1, u0:u1] - np.float32(py0)
        out[v0:v1, u0:u1] = cv2.remap(padded, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out

    def snapshot(self) -> np.ndarray:
        """Render what the plotter holds now on the whole canvas, through the lens: distorted RGB
        (H, W, 3) uint8."""
        return self.through_lens(self.render_canvas())

    def render_canvas(self, meshes: SceneMeshes | None = None) -> np.ndarray:
        """Load ``meshes`` (None: keep what is loaded) and render the whole canvas: undistorted RGB
        (canvas pixels) uint8, the reference renderer. The geometry stays loaded, so
        :meth:`render_mask_window` right after shows the same instant."""
        if meshes is not None:
            self._update(meshes)
        self._show_window(0, 0, *self.canvas_size)
        return self._canvas_snapshot()

    def render_window(self, meshes: SceneMeshes) -> tuple[np.ndarray, int, int]:
        """Load ``meshes`` and render only the canvas rectangle their projection covers (the rest
        of the canvas is the empty background, :meth:`image_through_lens` fills it in): undistorted
        RGB (h, w, 3) uint8 and the rectangle's origin (x, y) on the canvas. The geometry stays
        loaded, so :meth:`render_mask_window` right after shows the same instant.

        Rasterising a smaller window is most of the gain on the studio's wide views; the window
        is an exact shifted pinhole projection, but its pixels can differ from the whole canvas'
        by rounding on a few anti-aliased edges."""
        self._update(meshes)
        if self._scene_window_size == self.canvas_size:  # grown to the whole canvas: nothing to place
            self._show_window(0, 0, *self.canvas_size)
        else:
            x0, y0, w, h = self._scene_region(meshes)
            width, height = self._scene_window_size or (0, 0)
            if w > width or h > height:  # grow (never shrink: a new size reallocates the framebuffers)
                width, height = self._scene_window_size = self._window_size_for(w, h)
            self._show_window(*self._place_window((x0, y0, w, h), (width, height)), width, height)
        if self._background is None:
            self._background = self._empty_pixel()
        return self._canvas_snapshot(), self._window[0], self._window[1]

    def image_through_lens(self, placed: tuple[np.ndarray, int, int]) -> np.ndarray:
        """Distorted RGB (H, W, 3) uint8 image from :meth:`render_window`'s result: the window
        resampled through the lens on a canvas of empty background (thread-safe: no VTK)."""
        window, wx, wy = placed
        assert self._background is not None
        return self._through_lens_window(window, wx, wy, fill=self._background)

    def _show_window(self, x0: int, y0: int, width: int, height: int) -> None:
        """Make the main window show the canvas rectangle [x0, x0 + width) x [y0, y0 + height)."""
        if (width, height) != self._window[2:]:
            s = self.supersample
            self.plotter.window_size = (width * s, height * s)
        self._show_canvas_region(self.plotter, x0, y0, width, height)
        self._window = (x0, y0, width, height)

    def background_pixel(self) -> np.ndarray:
        """(3,) uint8 RGB of the empty background (measured once)."""
        if self._background is None:
            self._background = self._empty_pixel()
        return self._background

    def _empty_pixel(self) -> np.ndarray:
        """(3,) uint8 RGB the main window renders where nothing is drawn (the background)."""
        actors = [a for a in (self.body_actor, self.tape_actor, self.band_actor, self.occluder_actor,
                              *self.reference_actors) if a is not None]
        shown = [bool(a.GetVisibility()) for a in actors]
        for actor in actors:
            actor.SetVisibility(False)
        pixel = self._canvas_snapshot()[0, 0].copy()
        for actor, visible in zip(actors, shown):
            actor.SetVisibility(visible)
        return pixel

    def _window_size_for(self, width: int, height: int) -> tuple[int, int]:
        """Window size (canvas pixels) for a region of ``width`` x ``height``, with room to move."""
        W, H = self.canvas_size
        return min(W, int(width * 1.25) + 8), min(H, int(height * 1.25) + 8)

    def _place_window(self, region: tuple[int, int, int, int], size: tuple[int, int]) -> tuple[int, int]:
        """Origin (x, y) on the canvas of a window of ``size`` centred on ``region``, inside the canvas."""
        x0, y0, w, h = region
        cw, ch = size
        W, H = self.canvas_size
        return int(np.clip(x0 - (cw - w) // 2, 0, W - cw)), int(np.clip(y0 - (ch - h) // 2, 0, H - ch))

    def _scene_region(self, meshes: SceneMeshes, pad: int = 4) -> tuple[int, int, int, int]:
        """Canvas rectangle (x0, y0, width, height) holding the projection of everything drawn
        (body, tape, band, occluders), ``pad`` pixels wider; the whole canvas when a point lies
        closer than the near plane (its triangles' projection is unbounded)."""
        parts = [meshes.body_vertices, meshes.tape_vertices, self._static_points]
        if meshes.band_vertices is not None:
            parts.append(meshes.band_vertices)
        if meshes.occluders is not None and meshes.occluders.n_points:
            parts.append(np.asarray(meshes.occluders.points))
        points = np.concatenate(parts)
        if (self.camera.depth(points) <= NEAR_MM).any():
            return (0, 0, *self.canvas_size)
        return self._canvas_region(points, pad) or (0, 0, 1, 1)

    def _tape_region(self, tape_vertices: np.ndarray, pad: int = 4) -> tuple[int, int, int, int] | None:
        """Canvas rectangle (x0, y0, width, height) holding the tape's projection, or None."""
        return self._canvas_region(tape_vertices, pad)

    def _canvas_region(self, points: np.ndarray, pad: int) -> tuple[int, int, int, int] | None:
        """Canvas rectangle (x0, y0, width, height) holding the projection of world ``points``
        (mm) in front of the camera, ``pad`` pixels wider, clipped to the canvas; None if empty."""
        uv = self.camera.project(points, distort=False)
        uv = uv[np.isfinite(uv).all(axis=1)] + np.array(self.margin)
        if len(uv) == 0:
            return None
        W, H = self.canvas_size
        x0, y0 = np.maximum(np.floor(uv.min(axis=0)).astype(int) - pad, 0)
        x1, y1 = np.minimum(np.ceil(uv.max(axis=0)).astype(int) + pad + 1, (W, H))
        if x1 <= x0 or y1 <= y0:
            return None
        return int(x0), int(y0), int(x1 - x0), int(y1 - y0)

    def render(self, meshes: SceneMeshes, with_mask: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Colour image (H, W, 3) RGB uint8 and tape mask (H, W) bool (None if not asked)."""
        rgb = self.image_through_lens(self.render_window(meshes))
        if not with_mask:
            return rgb, None
        return rgb, self._render_mask(meshes)

    def render_reference(self, meshes: SceneMeshes, with_mask: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`render` in its straightforward reference form (the mask resampled over the whole canvas): the peer of
        ``spinemocap bench render`` and the tests' reference."""
        rgb = self.through_lens(self.render_canvas(meshes))
        if not with_mask:
            return rgb, None
        return rgb, self._render_mask_reference(meshes)

    def _mask_window(self, width: int, height: int):
        """The unlit mask plotter, at least ``width`` x ``height`` canvas pixels large."""
        import pyvista as pv

        s = self.supersample
        if self.mask_plotter is not None:
            cw, ch = self._mask_size
            if width <= cw and height <= ch:
                return self.mask_plotter
            self.mask_plotter.close()
        size = self._window_size_for(width, height)
        plotter = pv.Plotter(off_screen=True, window_size=(size[0] * s, size[1] * s), lighting="none")
        plotter.set_background("black")
        plotter.add_mesh(self.body, color="black", lighting=False)
        plotter.add_mesh(self.tape_solid, color="white", lighting=False)
        if self.band is not None:
            plotter.add_mesh(self.band, color="black", lighting=False)
        for mesh in self.reference_meshes:
            plotter.add_mesh(mesh, color="black", lighting=False)
        self._point_camera(plotter)
        plotter.camera_set = True
        self.mask_plotter, self._mask_size, self._mask_occluder_actor = plotter, size, None
        return plotter

    def _render_mask(self, meshes: SceneMeshes) -> np.ndarray:
        """(H, W) bool tape silhouette, hidden by the body, band and occluders like the image:
        the mask window's green channel through the lens, resampled only where it can land."""
        return self.mask_through_lens(self.render_mask_window(meshes))

    def mask_through_lens(self, placed: tuple[np.ndarray, int, int] | None) -> np.ndarray:
        """(H, W) bool tape mask from :meth:`render_mask_window`'s result (thread-safe: no VTK)."""
        if placed is None:
            return np.zeros(self.camera.size[::-1], bool)
        window, wx, wy = placed
        return self._through_lens_window(np.ascontiguousarray(window[..., 1]), wx, wy) > 127

    def _render_mask_reference(self, meshes: SceneMeshes) -> np.ndarray:
        """:meth:`_render_mask` in its straightforward reference form (the window pasted into a whole black canvas, all
        of it resampled): the peer of ``spinemocap bench render`` and the tests' reference."""
        canvas = np.zeros((self.canvas_size[1], self.canvas_size[0], 3), np.uint8)
        placed = self.render_mask_window(meshes)
        if placed is not None:
            window, wx, wy = placed
            canvas[wy : wy + window.shape[0], wx : wx + window.shape[1]] = window
        return self.through_lens(canvas)[..., 1] > 127

    def render_mask_window(self, meshes: SceneMeshes) -> tuple[np.ndarray, int, int] | None:
        """Render the unlit mask window around the tape: undistorted RGB (h, w, 3) uint8 of a
        canvas rectangle and its origin (x, y) on the canvas (canvas pixels), or None when the
        tape projects nowhere on the canvas."""
        region = self._tape_region(meshes.tape_vertices)
        if region is None:
            return None
        x0, y0, w, h = region
        plotter = self._mask_window(w, h)
        cw, ch = self._mask_size
        wx, wy = self._place_window(region, self._mask_size)
        self._show_canvas_region(plotter, wx, wy, cw, ch)
        if self._mask_occluder_actor is not None:
            plotter.remove_actor(self._mask_occluder_actor, render=False)
            self._mask_occluder_actor = None
        if meshes.occluders is not None and meshes.occluders.n_points:
            self._mask_occluder_actor = plotter.add_mesh(meshes.occluders, color="black", lighting=False,
                                                         render=False)
        return self._canvas_snapshot(plotter), wx, wy

    def close(self) -> None:
        self.plotter.close()
        if self.mask_plotter is not None:
            self.mask_plotter.close()
