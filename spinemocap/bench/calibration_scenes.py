"""Synthetic calibration captures with a known rig: board sequences and a Vicon wand wave.

Boards are planar, so they are rendered exactly (the printed face only; a camera behind the
board sees its blank back): every (2x supersampled) pixel is
back-projected through the :class:`~spinemocap.camera.Camera` model (undistort -> ray), the ray
is intersected with the board plane and the board texture is sampled there (``cv2.remap``);
then the image is area-downsampled, mildly blurred and given sensor noise. The wand's markers
are spheres rendered as bright discs of the exact projected radius ``f r / sqrt(d^2 - r^2)``.

Frames: world mm, Z up. A board pose ``(R_wb, t_wb)`` maps board points (see
:mod:`calibration.boards`) to the world, ``X_w = R_wb X_b + t_wb``. The wand's Vicon side is the
same marker positions mapped by a known similarity ``X_v = s R X_w + t`` and sampled at the Vicon
rate on the Vicon clock, ``t_vicon = t_rgb + offset``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from calibration.boards import BoardSpec
from calibration.wand import WandSpec
from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError, write_toml
from spinemocap.synth.wand import render_wand_frame, wand_trajectory

#: The floor board lies face up with its pattern origin at the world origin: board x = world x,
#: board y = world -y, board z (into the board) = world -z.
FLOOR_POSE = (np.diag([1.0, -1.0, -1.0]), np.zeros(3))


# ---------------------------------------------------------------------- rig
def make_ring_rig(n_cameras: int = 6, size: tuple[int, int] = (800, 600), radius_mm: float = 2400.0,
                  target_mm=(360.0, -240.0, 700.0), seed: int = 0) -> Rig:
    """``n_cameras`` cameras on a ring around ``target_mm`` at 1.6-2.0 m height, with slightly
    different focal lengths (about the image width in px), principal points and barrel/pincushion distortion."""
    rng = np.random.default_rng(seed)
    cameras = []
    for i in range(n_cameras):
        angle = 2 * np.pi * i / n_cameras + rng.uniform(-0.15, 0.15)
        position = np.asarray(target_mm) + [radius_mm * np.cos(angle), radius_mm * np.sin(angle), 0.0]
        position[2] = rng.uniform(1600, 2000)
        principal = (size[0] / 2 - 0.5 + rng.uniform(-8, 8), size[1] / 2 - 0.5 + rng.uniform(-8, 8))
        dist = (rng.uniform(-0.12, 0.04), rng.uniform(-0.02, 0.06), 0.0, 0.0, 0.0)
        cameras.append(Camera.look_at(f"cam{i + 1}", position, target_mm, size, rng.uniform(0.97, 1.05) * size[0],
                                      dist=dist, principal_point=principal))
    return Rig(cameras)


# ---------------------------------------------------------------------- board rendering
class BoardRenderer:
    """Renders one board into one camera for any board pose (rays cached per camera)."""

    def __init__(self, board: BoardSpec, px_per_mm: float = 2.0, supersample: int = 2,
                 margin_squares: float = 0.5, texture_blur_mm: float = 1.5):
        self.board, self.ppm, self.ss = board, px_per_mm, supersample
        self.margin_mm = margin_squares * board.square_mm
        pattern = board.texture(px_per_mm)
        pad = int(round(self.margin_mm * px_per_mm))
        texture = cv2.copyMakeBorder(pattern, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
        # Pre-filter the texture (about one image pixel at working distances) so that the sparse
        # supersamples do not alias the square edges: corners stay unbiased to ~0.02 px.
        self.texture = cv2.GaussianBlur(texture.astype(np.float32), (0, 0), texture_blur_mm * px_per_mm)
        self._rays: dict[str, np.ndarray] = {}

    def _camera_rays(self, cam: Camera) -> np.ndarray:
        """(H*ss, W*ss, 3) unit-free ray directions in camera coordinates (z = 1)."""
        if cam.name not in self._rays:
            w, h = cam.size
            s = self.ss
            u, v = np.meshgrid((np.arange(w * s) + 0.5) / s - 0.5, (np.arange(h * s) + 0.5) / s - 0.5)
            xy = cam.undistort_points(np.column_stack([u.ravel(), v.ravel()]), normalized=True)
            rays = np.dstack([xy.reshape(h * s, w * s, 2), np.ones((h * s, w * s))])
            self._rays[cam.name] = rays.astype(np.float32)
        return self._rays[cam.name]

    def render(self, cam: Camera, R_wb: np.ndarray, t_wb: np.ndarray, rng: np.random.Generator,
               blur_sigma_px: float = 0.6, noise_sigma: float = 2.0, background: float = 90.0) -> np.ndarray:
        """Grey uint8 image of the board at pose (R_wb, t_wb) seen by ``cam``."""
        rays = self._camera_rays(cam)
        # Board frame expressed in camera coordinates: X_c = R_cb X_b + t_cb.
        R_cb = cam.R @ R_wb
        t_cb = cam.R @ t_wb + cam.t
        normal = R_cb[:, 2]
        # Ray X = d * ray meets the plane normal . (X - t_cb) = 0 at d = normal . t_cb / normal . ray;
        # board (x, y) = R_cb[:, :2]^T (X - t_cb), evaluated as a 3x3 linear map of the ray / depth.
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.float32(normal @ t_cb) / (rays @ normal.astype(np.float32))
            xy = rays @ (R_cb[:, :2] * self.ppm).astype(np.float32)
            offset = ((self.margin_mm - R_cb[:, :2].T @ t_cb) * self.ppm - 0.5).astype(np.float32)
            map_xy = xy * depth[..., None] + offset
        map_xy[~((depth > 0) & np.isfinite(depth))] = -1e4
        if normal @ t_cb > 0:  # the printed face (looking along -z_board) faces the camera
            tex = self.texture * (190.0 / 255.0) + 30.0  # printed black 30, white 220
        else:  # the camera sees the board's blank back
            tex = np.full_like(self.texture, 150.0)
        big = cv2.remap(tex, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=background)
        w, h = cam.size
        image = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
        if blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
        image = image + rng.normal(0, noise_sigma, image.shape)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)


def board_visible(cam: Camera, board: BoardSpec, R_wb: np.ndarray, t_wb: np.ndarray,
                  max_angle_deg: float = 60.0, margin_px: float = 10.0) -> bool:
    """The whole board is in front of ``cam``, inside the image and seen at most
    ``max_angle_deg`` from its normal (front face)."""
    w_mm, h_mm = board.size_mm
    corners = np.array([[0, 0, 0], [w_mm, 0, 0], [w_mm, h_mm, 0], [0, h_mm, 0]], float) @ R_wb.T + t_wb
    if np.any(cam.depth(corners) <= 0):
        return False
    if not np.all(cam.in_image(cam.project(corners), margin_px)):
        return False
    to_cam = cam.center - corners.mean(axis=0)
    front = -R_wb[:, 2]  # the printed face looks along -z_board
    cos = front @ to_cam / np.linalg.norm(to_cam)
    return cos > np.cos(np.radians(max_angle_deg))


def random_board_pose(board: BoardSpec, rng: np.random.Generator, centre_mm, facing_mm,
                      spread_mm: float = 300.0, tilt_deg: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """A board pose near ``centre_mm`` whose printed face looks roughly toward ``facing_mm``."""
    centre = np.asarray(centre_mm, float) + rng.uniform(-spread_mm, spread_mm, 3)
    front = np.asarray(facing_mm, float) - centre
    front /= np.linalg.norm(front)
    front = Rotation.from_rotvec(rng.normal(0, np.radians(tilt_deg) / 2, 3)).apply(front)
    z = -front / np.linalg.norm(front)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    R = R @ Rotation.from_rotvec([0, 0, rng.uniform(-0.4, 0.4)]).as_matrix()
    w_mm, h_mm = board.size_mm
    return R, centre - R @ np.array([w_mm / 2, h_mm / 2, 0.0])


@dataclass
class BoardCapture:
    """Synchronized board frames: ``images[cam][frame]`` (grey uint8), ``poses[frame]``."""

    rig: Rig
    board: BoardSpec
    images: dict[str, list[np.ndarray]]
    poses: list[tuple[np.ndarray, np.ndarray]]


def floor_poses(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The board lying face up on the floor: :data:`FLOOR_POSE` first, then shifted and turned
    copies (for a better Z-up estimate)."""
    shifts = [(0, 0, 0), (-800, 500, 0), (700, -1000, 0), (-700, -900, 0)]
    poses = []
    for k in range(n):
        turn = Rotation.from_euler("z", 25 * k, degrees=True).as_matrix()
        poses.append((turn @ FLOOR_POSE[0], np.asarray(shifts[k % len(shifts)], float)))
    return poses


def half_turn(board: BoardSpec, R_wb: np.ndarray, t_wb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The board pose turned by half a turn about its normal through the pattern's centre."""
    w_mm, h_mm = board.size_mm
    centre = R_wb @ np.array([w_mm / 2, h_mm / 2, 0.0]) + t_wb
    R = R_wb @ np.diag([-1.0, -1.0, 1.0])
    return R, centre - R @ np.array([w_mm / 2, h_mm / 2, 0.0])


def render_board_capture(rig: Rig, board: BoardSpec, n_frames: int, seed: int = 1,
                         n_floor: int = 1, min_cameras: int = 2, renderer: BoardRenderer | None = None,
                         half_turns: bool = False, **render_kwargs) -> BoardCapture:
    """``n_frames`` synchronized frames of ``board``: the first ``n_floor`` lie on the floor
    (:func:`floor_poses`, frame 0 at :data:`FLOOR_POSE`), the rest are waved in front of the rig,
    each fully visible to at least ``min_cameras`` cameras. ``half_turns``: every other waved
    frame is held turned by half a turn (upside down), as people do."""
    rng = np.random.default_rng(seed)
    renderer = renderer or BoardRenderer(board)
    centre = np.mean([c.center for c in rig], axis=0)
    centre[2] = 900.0
    poses: list[tuple[np.ndarray, np.ndarray]] = floor_poses(n_floor)
    attempts = 0
    while len(poses) < n_frames:
        attempts += 1
        if attempts > 200 * n_frames:
            raise RuntimeError("could not place the board in view of enough cameras")
        a, b = rng.choice(len(rig), 2, replace=False)
        facing = (rig[int(a)].center + rig[int(b)].center) / 2
        pose = random_board_pose(board, rng, centre, facing)
        if half_turns and len(poses) % 2:
            pose = half_turn(board, *pose)
        if sum(board_visible(cam, board, *pose) for cam in rig) >= min_cameras:
            poses.append(pose)
    images = {cam.name: [renderer.render(cam, R, t, rng, **render_kwargs) for R, t in poses] for cam in rig}
    return BoardCapture(rig, board, images, poses)


def render_intrinsic_views(cam: Camera, board: BoardSpec, n_views: int, seed: int = 2,
                           renderer: BoardRenderer | None = None, **render_kwargs) -> list[np.ndarray]:
    """``n_views`` images of ``board`` held in front of one camera at varied tilts and image
    positions (each fully visible), for single-camera intrinsics."""
    rng = np.random.default_rng(seed)
    renderer = renderer or BoardRenderer(board)
    images: list[np.ndarray] = []
    attempts = 0
    forward = cam.R[2]
    while len(images) < n_views:
        attempts += 1
        if attempts > 500 * n_views:
            raise RuntimeError("could not place the board in view")
        distance = rng.uniform(900, 1600) * 800 / cam.K[0, 0] * max(board.size_mm) / 720
        ray_xy = rng.uniform(-0.25, 0.25, 2)
        centre = cam.center + distance * (forward + ray_xy[0] * cam.R[0] + ray_xy[1] * cam.R[1])
        R, t = random_board_pose(board, rng, centre, cam.center, spread_mm=0.0, tilt_deg=70.0)
        if board_visible(cam, board, R, t, max_angle_deg=55.0):
            images.append(renderer.render(cam, R, t, rng, **render_kwargs))
    return images


@dataclass
class CalibrationSession:
    """What a lab records to calibrate a rig: per camera ``intrinsic[cam]`` board images (that
    camera alone) and the synchronized multi-camera ``capture`` (floor frames first)."""

    intrinsic: dict[str, list[np.ndarray]]
    capture: BoardCapture
    floor_frames: list[int]


def render_calibration_session(rig: Rig, board: BoardSpec, n_intrinsic: int = 15, n_frames: int = 20,
                               n_floor: int = 3, seed: int = 1, half_turns: bool = False) -> CalibrationSession:
    """Render a full synthetic calibration session for ``rig`` (deterministic for a seed);
    ``half_turns``: see :func:`render_board_capture`."""
    renderer = BoardRenderer(board)
    intrinsic = {cam.name: render_intrinsic_views(cam, board, n_intrinsic, seed=seed * 100 + k, renderer=renderer)
                 for k, cam in enumerate(rig)}
    capture = render_board_capture(rig, board, n_frames, seed=seed, n_floor=n_floor, renderer=renderer,
                                   half_turns=half_turns)
    return CalibrationSession(intrinsic, capture, list(range(n_floor)))


# ---------------------------------------------------------------------- wand wave
@dataclass
class WandWave:
    """A rendered wand wave: ``images[cam][frame]`` (grey uint8) at ``fps`` on the RGB clock,
    true marker positions ``world_mm`` (F, 5, 3) at those frames, and the Vicon side
    ``vicon_mm`` (J, 5, 3) at ``vicon_rate`` Hz on the Vicon clock. Truth: ``X_v = scale R X_w +
    t``, ``t_vicon = t_rgb + offset_s``."""

    rig: Rig
    wand: WandSpec
    fps: float
    images: dict[str, list[np.ndarray]]
    world_mm: np.ndarray
    vicon_rate: float
    vicon_mm: np.ndarray
    R: np.ndarray
    t: np.ndarray
    scale: float
    offset_s: float


def render_wand_wave(rig: Rig, wand: WandSpec | None = None, duration_s: float = 6.0, fps: float = 50.0,
                     vicon_rate: float = 100.0, offset_s: float = 0.0237, seed: int = 3,
                     vicon_rotation_deg=(0.0, 0.0, 37.0), vicon_translation_mm=(412.0, -1250.0, 15.0),
                     noise_sigma: float = 2.0) -> WandWave:
    """Render a wand wave for every camera and sample its Vicon side (see :class:`WandWave`).
    Vicon marker noise is 0.05 mm (Vicon's typical residual)."""
    wand = wand or WandSpec()
    rng = np.random.default_rng(seed)
    centre = np.mean([c.center for c in rig], axis=0)
    centre[2] = 1100.0
    t_rgb = np.arange(int(duration_s * fps)) / fps
    world = wand_trajectory(t_rgb, wand.points_mm, seed, centre)
    # Vicon samples the same motion on its own clock: Vicon time tv shows the wand at RGB time tv - offset.
    t_vicon = np.arange(int((duration_s + 1.0) * vicon_rate)) / vicon_rate - 0.5
    vicon_world = wand_trajectory(t_vicon - offset_s, wand.points_mm, seed, centre)
    R = Rotation.from_euler("xyz", vicon_rotation_deg, degrees=True).as_matrix()
    t = np.asarray(vicon_translation_mm, float)
    vicon = vicon_world @ R.T + t + rng.normal(0, 0.05, vicon_world.shape)
    keep = t_vicon >= 0
    images = render_marker_frames(rig, world, wand, rng, noise_sigma)
    return WandWave(rig, wand, fps, images, world, vicon_rate, vicon[keep], R, t, 1.0, offset_s)


def render_marker_frames(rig: Rig, world_mm: np.ndarray, wand: WandSpec, rng: np.random.Generator,
                         noise_sigma: float = 2.0) -> dict[str, list[np.ndarray]]:
    """``images[cam][frame]`` of the wand markers ``world_mm`` (F, M, 3) in every camera."""
    # Sensor noise drawn from a small bank of fields (fresh noise per frame costs more than the render).
    bank = rng.normal(0, noise_sigma, (7, rig[0].size[1], rig[0].size[0])).astype(np.float32)
    images = {}
    for cam in rig:
        noise = bank if cam.size == rig[0].size else rng.normal(0, noise_sigma, (7, cam.size[1], cam.size[0]))
        images[cam.name] = [render_wand_frame(cam, markers, wand.marker_diameter_mm / 2, noise[rng.integers(7)])
                            for markers in world_mm]
    return images


def wand_on_floor(wand: WandSpec) -> list[np.ndarray]:
    """Marker positions (world mm) of the wand lying on the floor, its first ``x_axis`` marker
    above the world origin and the direction to the second along +X: once for a T-wand; for a
    linear wand a second placement along +Y (an L), since one line does not fix the floor."""
    lift = np.array([0.0, 0.0, wand.height_on_floor_mm])
    a, b = wand.x_axis
    along = wand.points_mm[b] - wand.points_mm[a]
    angle = np.arctan2(along[1], along[0])
    flat = Rotation.from_euler("z", -angle).apply(wand.points_mm - wand.points_mm[a])
    placements = [flat + lift]
    if wand.kind != "t":
        placements.append(Rotation.from_euler("z", 90, degrees=True).apply(flat) + lift)
    return placements


@dataclass
class WandCalibrationWave:
    """A wand-wave calibration capture: ``images[cam][frame]`` with the wand lying on the floor in
    ``floor_frames`` (first) and waved through the volume after; true markers ``world_mm``."""

    rig: Rig
    wand: WandSpec
    fps: float
    images: dict[str, list[np.ndarray]]
    world_mm: np.ndarray
    floor_frames: list[int]


def render_wand_calibration(rig: Rig, wand: WandSpec, duration_s: float = 4.0, fps: float = 50.0,
                            floor_frames_per_placement: int = 3, seed: int = 5, noise_sigma: float = 2.0,
                            floor_noise_mm: float = 0.0) -> WandCalibrationWave:
    """Render a wand-wave calibration: the wand lying still on the floor (:func:`wand_on_floor`,
    ``floor_frames_per_placement`` frames per placement), then ``duration_s`` of waving."""
    rng = np.random.default_rng(seed)
    floor = [markers + rng.normal(0, floor_noise_mm, markers.shape) for markers in wand_on_floor(wand)
             for _ in range(floor_frames_per_placement)]
    centre = np.mean([c.center for c in rig], axis=0)
    centre[2] = 1100.0
    wave = wand_trajectory(np.arange(int(duration_s * fps)) / fps, wand.points_mm, seed, centre)
    world = np.concatenate([np.asarray(floor).reshape(-1, wand.n_markers, 3), wave])
    images = render_marker_frames(rig, world, wand, rng, noise_sigma)
    return WandCalibrationWave(rig, wand, fps, images, world, list(range(len(floor))))


# ---------------------------------------------------------------------- a session on disk
def write_calibration_session(out: str | os.PathLike, board: BoardSpec, wand: WandSpec, n_cameras: int = 6,
                              size: tuple[int, int] = (800, 600), n_intrinsic: int = 12, n_frames: int = 16,
                              wand_seconds: float = 3.0, seed: int = 0, progress: bool = True) -> str:
    """Write a synthetic calibration session to the new folder ``out`` and return its README text:
    ``rig_true.toml`` (the truth), ``intrinsics/CAM/`` (board images per camera),
    ``board/CAM/`` (synchronized board frames, the first 3 on the floor; board half-turned in
    every other waved frame), ``wand/CAM/`` (wand on the floor first, then waved; 50 fps),
    ``session.toml`` (board, wand, floor frames) and ``README.txt`` (the commands to run)."""
    out = Path(out)
    if out.exists():
        raise InputError(out, "output folder exists; give a new folder")
    rig = make_ring_rig(n_cameras, size=size, seed=seed)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent if str(out.parent) else "."))
    try:
        with tqdm(total=3, desc="synthetic calibration", disable=not progress) as bar:
            session = render_calibration_session(rig, board, n_intrinsic, n_frames, n_floor=3, seed=seed + 1,
                                                 half_turns=True)
            bar.update()
            wave = render_wand_calibration(rig, wand, duration_s=wand_seconds, seed=seed + 5)
            bar.update()
            for cam in rig:
                _write_images(tmp / "intrinsics" / cam.name, session.intrinsic[cam.name])
                _write_images(tmp / "board" / cam.name, session.capture.images[cam.name])
                _write_images(tmp / "wand" / cam.name, wave.images[cam.name])
            bar.update()
        rig.to_toml(tmp / "rig_true.toml")
        write_toml(tmp / "session.toml", {"board": str(board), "wand": wand_text(wand), "fps": wave.fps,
                                          "board_floor_frames": session.floor_frames,
                                          "wand_floor_frames": wave.floor_frames, "cameras": rig.names})
        readme = _session_readme(out, rig, board, wand, session.floor_frames, wave.floor_frames)
        (tmp / "README.txt").write_text(readme)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return readme


def wand_text(wand: WandSpec) -> str:
    """The ``--wand`` text that parses back to ``wand``."""
    if wand.kind == "t":
        return "t"
    return "linear:" + ":".join(f"{x:g}" for x in wand.points_mm[1:, 0])


def _write_images(folder: Path, images: list[np.ndarray]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k, image in enumerate(images):
        cv2.imwrite(str(folder / f"{k:04d}.png"), image)


def _session_readme(out: Path, rig: Rig, board: BoardSpec, wand: WandSpec, board_floor: list[int],
                    wand_floor: list[int]) -> str:
    names = rig.names
    intr = " ".join(f"{out}/{n}_intrinsics.toml" for n in names)
    lines = [f"Synthetic calibration session: {len(rig)} cameras, board {board}, wand {wand_text(wand)}.",
             f"The true rig is {out}/rig_true.toml (world mm, Z up). Calibrate it three ways:", "",
             "# 1. intrinsics, one camera at a time"]
    lines += [f"spinemocap calibrate intrinsics {out}/intrinsics/{n} --board {board} --name {n} "
              f"--out {out}/{n}_intrinsics.toml" for n in names]
    lines += ["", "# 2. extrinsics from the board (frames " + ",".join(map(str, board_floor)) + " lie on the floor)",
              f"spinemocap calibrate extrinsics --intrinsics {intr} --views "
              + " ".join(f"{out}/board/{n}" for n in names)
              + f" --board {board} --floor-frames {' '.join(map(str, board_floor))} --out {out}/rig_board.toml",
              "", f"# 3. extrinsics from the wand wave alone (frames {wand_floor[0]}-{wand_floor[-1]}: wand on the floor)",
              f"spinemocap calibrate wand-wave --intrinsics {intr} --videos "
              + " ".join(f"{out}/wand/{n}" for n in names)
              + f" --wand {wand_text(wand)} --floor-frames {wand_floor[0]}-{wand_floor[-1]} --out {out}/rig_wand.toml",
              ""]
    return "\n".join(lines)
