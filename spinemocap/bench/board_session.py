"""A studio board session with the traits of a real lab's recording, rendered with its exact rig
as the truth: a ChArUco board printed with inverted colours and held by hand, filmed at a low
frame rate (6 fps) by wide-angle cameras with strong barrel distortion, some mounted turned by
90 degrees (portrait images), and motion blur on the frames where the hand moves fast.

Frames: world mm, Z up. The board is rendered exactly as in
:mod:`spinemocap.bench.calibration_scenes` (:class:`BoardRenderer`); a motion-blurred frame is
the mean of the board rendered at evenly spaced poses over the exposure (the true pose is the
middle one). Videos are written losslessly (:class:`spinemocap.capture.VideoWriter`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from calibration.boards import BoardSpec
from calibration.check import RigComparison, compare_rigs
from spinemocap.camera import Camera, Rig
from spinemocap.capture import VideoWriter
from spinemocap.fileio import InputError
from spinemocap.geometry import umeyama

from .calibration_scenes import BoardRenderer, board_visible

#: The board of the studio session: 4 x 5 squares of 54 mm, 40.5 mm markers, inverted print.
STUDIO_BOARD = "charuco:4x5:54:40.5:DICT_4X4_1000:inverted"
Pose = tuple[np.ndarray, np.ndarray]


def make_studio_rig(n_cameras: int = 4, size: tuple[int, int] = (640, 360), turned: tuple[int, ...] = (1, 3),
                    radius_mm: float = 800.0, target_mm=(0.0, 0.0, 1100.0), seed: int = 0) -> Rig:
    """``n_cameras`` cameras on an arc of 140 degrees around ``target_mm``, 1.1-1.5 m high,
    wide-angle (horizontal field about 70 degrees) with strong barrel distortion (k1 -0.28 to
    -0.34, k2 0.06 to 0.10, small decentring); the cameras in ``turned`` are mounted turned by
    90 degrees (their images are portrait: ``size`` swapped)."""
    rng = np.random.default_rng(seed)
    cameras = []
    for i in range(n_cameras):
        azimuth = np.radians(-70 + 140 * i / max(n_cameras - 1, 1) + rng.uniform(-5, 5))
        position = np.asarray(target_mm) + [radius_mm * np.sin(azimuth), -radius_mm * np.cos(azimuth), 0.0]
        position[2] = rng.uniform(1100, 1500)
        forward = np.asarray(target_mm) - position
        sideways = np.cross(forward, [0.0, 0.0, 1.0])
        rotated = i in turned
        w, h = (size[1], size[0]) if rotated else size
        up = sideways * (1 if i % 2 else -1) if rotated else (0.0, 0.0, 1.0)
        dist = (rng.uniform(-0.34, -0.28), rng.uniform(0.06, 0.10), rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3), 0.0)
        principal = ((w - 1) / 2 + rng.uniform(-6, 6), (h - 1) / 2 + rng.uniform(-6, 6))
        cameras.append(Camera.look_at(f"cam_{i}", position, target_mm, (w, h), rng.uniform(0.72, 0.78) * max(size),
                                      up=up, dist=dist, principal_point=principal))
    return Rig(cameras)


def handheld_poses(rig: Rig, board: BoardSpec, n_frames: int, fps: float, seed: int = 0,
                   centre_mm=(0.0, 0.0, 1100.0)) -> tuple[list[Pose], list[Pose]]:
    """A board held by hand and turned slowly from camera to camera: per frame the board pose
    at mid-exposure and its velocity over one frame interval (rotation vector, translation;
    board -> world). The centre wanders +-300 mm (+-200 mm in height) around ``centre_mm`` (sums of slow sinusoids);
    the printed face turns toward an azimuth sweeping over the cameras, tilted up to ~25 deg."""
    rng = np.random.default_rng(seed)
    times = np.arange(n_frames + 1) / fps
    duration = max(times[-1], 1e-9)
    freqs = rng.uniform(0.1, 0.4, (3, 5))
    phases = rng.uniform(0, 2 * np.pi, (3, 5))
    amps = np.array([300.0, 300.0, 200.0, 0.3, 0.3])
    wobble = np.sum(np.sin(2 * np.pi * freqs[:, None, :] * times[None, :, None] + phases[:, None, :]), axis=0) / 3 * amps
    azimuths = np.array([np.arctan2(c.center[0] - centre_mm[0], -(c.center[1] - centre_mm[1])) for c in rig])
    sweep = azimuths.min() + (azimuths.max() - azimuths.min()) * 0.5 * (1 - np.cos(2 * np.pi * times / duration))
    w_mm, h_mm = board.size_mm
    poses = []
    for k in range(len(times)):
        facing = Rotation.from_euler("zx", [sweep[k], 0.0]).apply([0.0, -1.0, 0.0])
        z = -facing  # board z points into the board, away from the cameras it faces
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        R = Rotation.from_rotvec([wobble[k, 3], 0.0, wobble[k, 4]]).as_matrix() @ R
        centre = np.asarray(centre_mm, float) + wobble[k, :3]
        poses.append((R, centre - R @ np.array([w_mm / 2, h_mm / 2, 0.0])))
    velocity = [(Rotation.from_matrix(poses[k + 1][0] @ poses[k][0].T).as_rotvec(), poses[k + 1][1] - poses[k][1])
                for k in range(n_frames)]
    return poses[:n_frames], velocity


@dataclass
class StudioSession:
    """A rendered board session: ``images[camera][frame]`` (grey uint8), the true ``rig``, the
    board (as printed), the board pose at each frame's mid-exposure and the ``blurred`` frames."""

    rig: Rig
    board: BoardSpec
    fps: float
    images: dict[str, list[np.ndarray]]
    poses: list[Pose]
    blurred: list[int]

    def seen_by(self, frame: int) -> list[str]:
        """The cameras that see the whole printed face in ``frame``."""
        R, t = self.poses[frame]
        return [cam.name for cam in self.rig if board_visible(cam, self.board, R, t, max_angle_deg=70.0)]


def render_studio_session(rig: Rig | None = None, board: BoardSpec | None = None, n_frames: int = 36,
                          fps: float = 6.0, blur_every: int = 6, blur_speedup: float = 1.5, seed: int = 0,
                          progress: bool = True, glass: bool = False, facing: Rig | None = None) -> StudioSession:
    """Render the studio session (see the module doc). Every ``blur_every``-th frame is exposed
    for 1/30 s while the hand moves ``blur_speedup`` times faster than on average (the motion
    smeared over the exposure); the others are sharp (exposure 1/250 s). ``facing``: the cameras
    the board is turned toward (default: all); ``glass``: the board is printed on glass, so a
    camera behind it sees the pattern mirrored instead of a blank back."""
    rig = rig or make_studio_rig(seed=seed)
    board = board or BoardSpec.parse(STUDIO_BOARD)
    poses, velocity = handheld_poses(facing or rig, board, n_frames, fps, seed)
    renderer = BoardRenderer(board, supersample=1)
    rng = np.random.default_rng(seed + 1)
    blurred = list(range(blur_every // 2, n_frames, blur_every)) if blur_every else []
    images: dict[str, list[np.ndarray]] = {cam.name: [] for cam in rig}
    for k in tqdm(range(n_frames), desc="studio board session", disable=not progress, leave=False):
        smear = blur_speedup * fps / 30.0 if k in blurred else fps / 250.0
        offsets = np.linspace(-0.5, 0.5, 5 if k in blurred else 1) * smear
        exposure = [(Rotation.from_rotvec(s * velocity[k][0]).as_matrix() @ poses[k][0],
                     poses[k][1] + s * velocity[k][1]) for s in offsets]
        for cam in rig:
            frames = [renderer.render(cam, _seen_through(cam, R, t) if glass else R, t, rng, noise_sigma=0.0
                                      ).astype(np.float32) for R, t in exposure]
            image = np.mean(frames, axis=0) + rng.normal(0, 2.0, frames[0].shape)
            images[cam.name].append(np.clip(np.round(image), 0, 255).astype(np.uint8))
    return StudioSession(rig, board, fps, images, poses, blurred)


#: Board z negated: the renderer reads only the board's x and y axes and its normal, so this
#: (improper) pose makes a camera behind the board see the printed face, as through glass.
_THROUGH_GLASS = np.diag([1.0, 1.0, -1.0])


def _seen_through(cam: Camera, R_wb: np.ndarray, t_wb: np.ndarray) -> np.ndarray:
    """The board rotation to render for ``cam``: as is in front of the board, through the glass
    (:data:`_THROUGH_GLASS`) from behind it (on the side board z points to)."""
    behind = (cam.center - t_wb) @ R_wb[:, 2] > 0
    return R_wb @ _THROUGH_GLASS if behind else R_wb


def write_studio_session(session: StudioSession, out: str | os.PathLike, suffix: str = ".avi") -> list[Path]:
    """Write one video per camera (``OUT/<camera><suffix>``, lossless, at the session's rate) and
    the true rig ``OUT/rig_true.toml``; returns the video paths in camera order."""
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise InputError(out, "output folder is not empty; give a new folder")
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for cam in session.rig:
        path = out / f"{cam.name}{suffix}"
        writer = VideoWriter(path, session.fps, cam.size)
        try:
            for image in session.images[cam.name]:
                writer.write(np.repeat(image[..., None], 3, axis=2))
        except BaseException:
            writer.abort()
            raise
        writer.close()
        paths.append(path)
    session.rig.to_toml(out / "rig_true.toml")
    return paths


# ---------------------------------------------------------------------- scoring
@dataclass
class RigScore:
    """A calibrated rig against the true one, after the rigid fit of the camera centres (a board
    calibration without floor frames has its own world frame): per camera centre error (mm) and
    orientation error (deg), and every pair's baseline ratio and relative rotation difference."""

    centre_error_mm: dict[str, float]
    rotation_error_deg: dict[str, float]
    comparison: RigComparison

    @property
    def worst_centre_mm(self) -> float:
        return max(self.centre_error_mm.values())

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: per camera errors, then the worst pair's baseline ratio error and
        relative rotation difference (deg)."""
        return {"centre_error_mm": self.centre_error_mm, "rotation_error_deg": self.rotation_error_deg,
                "worst_baseline_error": self.comparison.worst_baseline_error,
                "worst_rotation_diff_deg": self.comparison.worst_rotation_deg}


def score_rig(estimated: Rig, truth: Rig) -> RigScore:
    """Score ``estimated`` against ``truth`` (cameras matched by name; see :class:`RigScore`)."""
    est = [estimated[name] for name in truth.names]
    A = np.array([cam.center for cam in est])
    B = np.array([cam.center for cam in truth])
    R, t, _ = umeyama(A, B, with_scale=False)
    centre = {cam.name: float(np.linalg.norm(R @ a + t - b)) for cam, a, b in zip(truth, A, B)}
    # a camera's orientation in the truth's frame: world -> camera rotation of the fitted rig is R_cam R^T
    rotation = {true.name: float(np.degrees(Rotation.from_matrix(e.R @ R.T @ true.R.T).magnitude()))
                for e, true in zip(est, truth)}
    return RigScore(centre, rotation, compare_rigs(Rig(est), truth))


# ---------------------------------------------------------------------- benchmark
@dataclass(frozen=True)
class SessionRow:
    """One studio board session calibrated from its videos (:func:`session_row`): image size
    (px), frames, frame rate, seed, the board variant that read it, usable views and left-out
    reasons (counts) per camera, reprojection RMS per camera (px), our rig's score and the peer's
    (the initial pose graph), and seconds of rendering plus writing and of calibration."""

    size: list[int]
    frames: int
    fps: float
    seed: int
    read_as: str
    usable_views: dict[str, int]
    left_out: dict[str, dict[str, int]]
    rms_px: dict[str, float]
    ours: RigScore
    peer_initial_pose_graph: RigScore
    seconds: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields in order, the scores as :meth:`RigScore.to_dict`."""
        return {"size": self.size, "frames": self.frames, "fps": self.fps, "seed": self.seed, "read_as": self.read_as,
                "usable_views": self.usable_views, "left_out": self.left_out, "rms_px": self.rms_px,
                "ours": self.ours.to_dict(), "peer_initial_pose_graph": self.peer_initial_pose_graph.to_dict(),
                "seconds": self.seconds}


def session_row(size: tuple[int, int], n_frames: int, seed: int, folder: Path) -> SessionRow:
    """Render, write and calibrate one studio session from its videos alone (board options and
    intrinsics found), scored against the truth; the peer in the same run: the initial pose
    graph alone (consensus spanning tree, no adjustment) with each camera's own OpenCV intrinsics."""
    import time

    from calibration.extrinsics import initial_pose_graph

    from ..app.calibrate import calibrate_recordings, intrinsics_from_session

    t0 = time.perf_counter()
    session = render_studio_session(make_studio_rig(size=size, seed=seed), n_frames=n_frames, seed=seed, progress=False)
    videos = write_studio_session(session, folder)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    calibrated = calibrate_recordings(videos, BoardSpec.parse(STUDIO_BOARD.replace(":inverted", "")), progress=False)
    t_calibrate = time.perf_counter() - t0
    result = calibrated.result
    used = calibrated.session.read_as or session.board
    intrinsics, _ = intrinsics_from_session(calibrated.session, used)
    poses, _, _, _ = initial_pose_graph(intrinsics, used, calibrated.session.detections())
    start = Rig([Camera(c.name, c.K, c.dist, R, t, c.size) for c, (R, t) in zip(intrinsics, poses)])
    return SessionRow(size=list(size), frames=n_frames, fps=session.fps, seed=seed, read_as=str(used),
                      usable_views={c.name: len(c.usable) for c in calibrated.session.cameras},
                      left_out={c.name: dict(c.reasons()) for c in calibrated.session.cameras},
                      rms_px=result.rms_px, ours=score_rig(result.rig, session.rig),
                      peer_initial_pose_graph=score_rig(start, session.rig),
                      seconds={"render_and_write": t_render, "calibrate": t_calibrate})


def run_session_benchmark(size: tuple[int, int] = (960, 540), n_frames: int = 96, seeds: tuple[int, ...] = (0, 1),
                          out: str | os.PathLike = "bench_calibration_session.json") -> list[SessionRow]:
    """:func:`session_row` per seed; prints a table and writes the rows (and the machine) as JSON
    (``{"machine": ..., "rows": [...]}``); returns the rows."""
    import json
    import platform
    import tempfile

    from spinemocap.fileio import atomic_write

    rows = []
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(session_row(size, n_frames, seed, Path(tmp) / "videos"))
    print(f"studio board session, {size[0]}x{size[1]}, {n_frames} frames at 6 fps, 4 cameras (2 turned 90 deg); "
          "goal: centres <= 1 mm, baselines 2 %, relative rotations 1 deg, RMS < 1 px")
    print(f"{'seed':>5}{'centre mm':>11}{'rot deg':>9}{'baseline %':>12}{'rel rot deg':>13}{'RMS px':>8}"
          f"{'peer centre':>13}{'peer rel rot':>14}{'s':>6}")
    for row in rows:
        o, p = row.ours, row.peer_initial_pose_graph
        print(f"{row.seed:>5}{o.worst_centre_mm:>11.3f}{max(o.rotation_error_deg.values()):>9.3f}"
              f"{100 * o.comparison.worst_baseline_error:>12.3f}{o.comparison.worst_rotation_deg:>13.3f}"
              f"{max(row.rms_px.values()):>8.3f}{p.worst_centre_mm:>13.3f}"
              f"{p.comparison.worst_rotation_deg:>14.3f}{row.seconds['calibrate']:>6.1f}")
    report = {"machine": f"{platform.machine()}, {os.cpu_count()} CPUs", "rows": [row.to_dict() for row in rows]}
    with atomic_write(out) as handle:
        json.dump(report, handle, indent=1)
    print(f"wrote {out}")
    return rows
