"""A Vicon wand wave in the synthetic studio (``spinemocap synth --vicon``): the studio's cameras
film the 5-marker T-wand (:class:`calibration.wand.WandSpec`) waved through the volume they
share, and the virtual Vicon records the same markers, so that ``spinemocap calibrate wand``
can co-register the camera rig with the Vicon (transform and clock offset).

The subject has not stepped in yet: nothing hides the wand. Frames and clocks:

- Images: the studio's true rig (``rig.toml`` holds the calibrated one, off by the realism
  level's calibration error), the capture's frame rate; camera ``c``'s frame ``i`` shows the wand
  at studio time ``i / fps + sync_offset_s[c]`` (the capture's per-camera clock errors). Markers
  are rendered as spheres (bright discs of the exact projected radius, antialiased, on a dark
  background, blurred, with the capture's sensor noise) by the synthetic wand renderer
  (:func:`spinemocap.synth.wand.render_wand_frame`).
- Vicon: the same marker centres mapped into the Vicon frame (``X_v = R X + t``), sampled at the
  Vicon rate on the Vicon clock (frame ``j`` at ``t_vicon = j / rate`` = studio time ``t_vicon -
  clock_offset_s``), with the Vicon's noise: exactly the truth of the virtual Vicon's trial.
- The wave: the synthetic wand's smooth random wave
  (:func:`spinemocap.synth.wand.wand_trajectory`), its centre moved and its sweep
  scaled (:func:`plan_wave`) so that the whole wand stays in view of at least two cameras in
  most frames; at low frame rates it is slowed down (highest wave frequency at most fps / 8) and
  lengthened to at least :data:`MIN_FRAMES` frames.

Written beside the capture: ``wand/<camera>/000000.png`` (grey), ``wand/vicon_wand.c3d``
(WAND1..WAND5, Vicon frame and rate) and ``wand/README.txt`` (the commands); the truth goes into
``groundtruth.npz`` (``wand_*``, with the ``vicon_*`` transform and offset).
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from calibration.wand import WandSpec

from ..bodymodel.virtual_vicon import ViconSetup
from ..camera import Rig
from ..fileio import InputError
from ..synth.wand import render_wand_frame, wand_trajectory
from .c3d_inputs import write_vicon_wand_c3d

log = logging.getLogger(__name__)

WAND_DIR = "wand"
VICON_WAND_FILE = "vicon_wand.c3d"
MIN_FRAMES = 80  # the co-registration needs 20 identified frames; the speed correlation wants more
HIGHEST_WAVE_HZ = 1.2  # of wand_trajectory's sinusoids
MARGIN_PX = 8.0
MIN_SEEN_SHARE = 0.3  # less: no wand wave (the co-registration would rest on a few frames)
MIN_MARKER_RADIUS_PX = 1.5  # smaller spots are lost by the blob detector (4 px area minimum)


@dataclass
class WavePlan:
    """Where the wand is waved: the wave's centre (studio mm), the scale of its sweep (1 = the
    calibration bench's +-400 mm), the slow-down of its motion (1 = as in the bench), its
    frames at the cameras' rate, and the share of frames whose markers are all in view of at
    least two cameras."""

    centre_mm: np.ndarray
    sweep_scale: float
    time_scale: float
    n_frames: int
    fps: float
    seen_share: float


def wave_markers(wand: WandSpec, plan: WavePlan, studio_time_s: np.ndarray, seed: int) -> np.ndarray:
    """(T, M, 3) true marker centres (studio frame, mm) at studio times (s)."""
    raw = wand_trajectory(np.asarray(studio_time_s, float) * plan.time_scale, wand.points_mm, seed, np.zeros(3))
    centroid = raw.mean(axis=1, keepdims=True)  # the bench's wave centre + its sweep
    return raw - centroid + plan.centre_mm + plan.sweep_scale * centroid


def full_views(rig: Rig, markers: np.ndarray, radius_mm: float) -> np.ndarray:
    """(T, C) bool: camera c sees all of a frame's markers (T, M, 3): in front, inside the image
    (``MARGIN_PX``), big enough to detect, and the wand's plane not seen edge-on (a T-wand seen
    within 20 deg of its plane cannot be identified)."""
    T = len(markers)
    out = np.zeros((T, len(rig)), bool)
    flat = markers.reshape(-1, 3)
    normal = np.cross(markers[:, 2] - markers[:, 0], markers[:, 4] - markers[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    for c, cam in enumerate(rig):
        depth = cam.depth(flat).reshape(T, -1)
        uv = cam.project(flat)
        inside = cam.in_image(uv, MARGIN_PX).reshape(T, -1)
        radius_px = cam.K[0, 0] * radius_mm / np.maximum(depth, 1.0)
        view = cam.center - markers.mean(axis=1)
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        face_on = np.abs(np.einsum("td,td->t", view, normal)) > np.sin(np.radians(20.0))
        out[:, c] = np.all((depth > 200.0) & inside & (radius_px >= MIN_MARKER_RADIUS_PX), axis=1) & face_on
    return out


def plan_wave(rig: Rig, target_mm: np.ndarray, wand: WandSpec, fps: float, seconds: float, seed: int) -> WavePlan:
    """Choose the wave's centre and sweep: candidates on the cameras' mean line of sight through
    ``target_mm`` (the volume they share), from the target to 2.5 m beyond it, sweeps from the
    bench's full +-400 mm down to a fifth; the plan with the highest share of frames seen whole
    by two or more cameras plus mean share of cameras that see the whole wand wins (ties: the
    wider sweep, then the nearer centre)."""
    time_scale = min(1.0, fps / (8.0 * HIGHEST_WAVE_HZ))
    n_frames = max(int(round(seconds * fps)), MIN_FRAMES)
    times = np.arange(n_frames) / fps
    axes = [(target_mm - c.center) / np.linalg.norm(target_mm - c.center) for c in rig]
    away = np.mean(axes, axis=0)  # along the cameras' mean line of sight (down where they look down)
    away = away / np.linalg.norm(away) if np.linalg.norm(away) > 1e-6 else np.array([0.0, -1.0, 0.0])
    best: tuple[float, WavePlan] | None = None
    for push in np.arange(0.0, 2501.0, 250.0):
        for sweep in (1.0, 0.7, 0.45, 0.3, 0.2):
            plan = WavePlan(np.asarray(target_mm, float) + push * away, sweep, time_scale, n_frames, fps, 0.0)
            seen = full_views(rig, wave_markers(wand, plan, times, seed), wand.marker_diameter_mm / 2)
            plan.seen_share = float(np.mean(seen.sum(axis=1) >= 2))
            score = plan.seen_share + float(seen.mean())  # + the mean share of cameras that see it whole
            if best is None or score > best[0] + 0.02:
                best = (score, plan)
    assert best is not None
    return best[1]


@dataclass
class StudioWandWave:
    """A wand wave written by :func:`write_wand_wave`: its plan, true markers ``world_mm`` (F, M, 3)
    at the nominal frame times (studio frame), the Vicon's ``vicon_mm`` (J, M, 3) (Vicon frame,
    frame j at Vicon time j / rate, NaN never: nothing hides the wand) and the folder."""

    wand: WandSpec
    plan: WavePlan
    world_mm: np.ndarray
    vicon_mm: np.ndarray
    vicon_rate_hz: float
    folder: Path

    def groundtruth(self) -> dict[str, np.ndarray]:
        """Arrays for ``groundtruth.npz`` (prefix ``wand_``)."""
        return {"wand_world_mm": self.world_mm, "wand_fps": np.array(self.plan.fps),
                "wand_labels": np.array(self.wand.labels), "wand_layout_mm": self.wand.points_mm,
                "wand_vicon_rate_hz": np.array(self.vicon_rate_hz), "wand_centre_mm": self.plan.centre_mm,
                "wand_seen_share": np.array(self.plan.seen_share)}


def write_wand_wave(scene, setup: ViconSetup, out: str | os.PathLike, seconds: float = 4.0,
                    progress: bool = True) -> StudioWandWave | None:
    """Render the wand wave of a built studio ``scene`` recorded by a Vicon set up as ``setup``
    into ``out/wand/`` (see the module doc; the folder appears whole or not at all). None (and a
    warning) when the rig cannot film it: the whole T-wand in view of two cameras in less than
    :data:`MIN_SEEN_SHARE` of the frames (e.g. the ``tiny`` preset, whose 3 narrow views overlap
    only in a volume smaller than the wand)."""
    if not seconds > 0:
        raise InputError("seconds", f"must be positive (got {seconds:g}); 0 turns the wand wave off")
    wand = WandSpec()
    seed = int(scene.rng_seed)
    plan = plan_wave(scene.rig, scene.target, wand, scene.fps, seconds, seed)
    if plan.seen_share < MIN_SEEN_SHARE:
        log.warning("no wand wave: the whole T-wand (360 x 400 mm) is in view of two cameras in only %.0f %% of "
                    "the frames wherever it is waved; use more cameras, wider views (e.g. `preset=artificial` or "
                    "`preset=studio`) or `wand_seconds=0`", 100 * plan.seen_share)
        return None
    nominal = np.arange(plan.n_frames) / plan.fps
    world = wave_markers(wand, plan, nominal, seed)
    vicon_frames = int(np.ceil((nominal[-1] + setup.clock_offset_s + 0.5) * setup.rate_hz)) + 1
    vicon_time = np.arange(vicon_frames) / setup.rate_hz
    rng = np.random.default_rng([seed, 17])
    truth_v = wave_markers(wand, plan, vicon_time - setup.clock_offset_s, seed) @ setup.R.T + setup.t
    vicon = truth_v + rng.normal(0.0, setup.noise_mm, truth_v.shape)
    out = Path(out)
    final = out / WAND_DIR
    tmp = Path(tempfile.mkdtemp(prefix=f".{WAND_DIR}.", dir=out))
    try:
        _render_images(scene, wand, plan, seed, tmp, progress)
        write_vicon_wand_c3d(tmp / VICON_WAND_FILE, vicon, setup.rate_hz, wand)
        (tmp / "README.txt").write_text(wand_readme(out, scene.rig.names, plan, setup))
        if final.exists():  # a wave of an earlier synth into the same folder: replaced, like its images
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return StudioWandWave(wand, plan, world, vicon, setup.rate_hz, final)


def _render_images(scene, wand: WandSpec, plan: WavePlan, seed: int, folder: Path, progress: bool) -> None:
    """``folder/<camera>/NNNNNN.png``: each camera at its own clock (``scene.sync_offsets_s``)."""
    rng = np.random.default_rng([seed, 18])
    sigma = float(scene.config.noise or 0.0)
    nominal = np.arange(plan.n_frames) / plan.fps
    with tqdm(total=plan.n_frames * len(scene.rig), desc="wand wave", unit=" images", disable=not progress) as bar:
        for c, cam in enumerate(scene.rig):
            markers = wave_markers(wand, plan, nominal + float(scene.sync_offsets_s[c]), seed)
            # sensor noise from a small bank of fields (fresh noise per frame costs more than the render)
            bank = rng.normal(0.0, sigma, (5, cam.size[1], cam.size[0])).astype(np.float32)
            (folder / cam.name).mkdir(parents=True)
            for f, frame_markers in enumerate(markers):
                image = render_wand_frame(cam, frame_markers, wand.marker_diameter_mm / 2, bank[rng.integers(5)])
                if not cv2.imwrite(str(folder / cam.name / f"{f:06d}.png"), image):
                    raise OSError(f"cannot write {folder / cam.name / f'{f:06d}.png'}")
                bar.update()


def wand_readme(capture: Path, cameras: list[str], plan: WavePlan, setup: ViconSetup) -> str:
    """The wand folder's README: what is there and the commands that use it."""
    videos = " ".join(f"{capture}/{WAND_DIR}/{name}" for name in cameras)
    return "\n".join([
        f"Wand wave of {capture.name}: the 5-marker T-wand (WAND1..WAND5, layout in calibration/wand.py) waved",
        f"through the cameras' shared volume, {plan.n_frames} frames at {plan.fps:g} fps per camera "
        f"({100 * plan.seen_share:.0f} % of them with the whole wand in view of >= 2 cameras), and the Vicon's",
        f"recording of it ({VICON_WAND_FILE}: {setup.rate_hz:g} Hz, Vicon frame and clock). Truth in ../groundtruth.npz",
        "(vicon_R, vicon_t_mm, vicon_clock_offset_s: t_vicon = t_rgb + offset; wand_world_mm).", "",
        "# the capture's rig in the Vicon frame (prints the clock offset)",
        f"spinemocap calibrate wand --rig {capture}/rig.toml --videos {videos} --vicon "
        f"{capture}/{WAND_DIR}/{VICON_WAND_FILE} --fps {plan.fps:g} --out {capture}/{WAND_DIR}/rig_vicon.toml",
        "# cross-validation of tracked dots against the Vicon, transform from the wand",
        f"spinemocap crossval TRACKED.c3d {capture}/vicon.c3d --capture {capture} --out CROSSVAL "
        f"--rig-vicon {capture}/{WAND_DIR}/rig_vicon.toml", ""])


@dataclass(frozen=True)
class RegistrationErrors:
    """An estimated rig -> Vicon transform against the truth (:func:`registration_errors`):
    rotation error (deg), mean and largest point error (mm) over the capture's true dots, and the
    clock offset's error (ms; None when no offset was estimated)."""

    rotation_error_deg: float
    point_error_mean_mm: float
    point_error_max_mm: float
    offset_error_ms: float | None = None

    def to_dict(self) -> dict[str, float]:
        """The JSON object (``offset_error_ms`` only when estimated)."""
        out = {"rotation_error_deg": self.rotation_error_deg, "point_error_mean_mm": self.point_error_mean_mm,
               "point_error_max_mm": self.point_error_max_mm}
        if self.offset_error_ms is not None:
            out["offset_error_ms"] = self.offset_error_ms
        return out


def registration_errors(groundtruth: dict, R: np.ndarray, t: np.ndarray,
                        offset_s: float | None = None) -> RegistrationErrors:
    """How far an estimated rig -> Vicon transform ``X_v = R X + t`` (and clock offset, s) is from
    the truth in ``groundtruth`` (``vicon_R``, ``vicon_t_mm``, ``vicon_clock_offset_s``): rotation
    error (deg), mean and max point error (mm) over the capture's true dots (every frame), offset
    error (ms)."""
    R_true, t_true = np.asarray(groundtruth["vicon_R"]), np.asarray(groundtruth["vicon_t_mm"])
    points = np.asarray(groundtruth["dots"], float).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    error = np.linalg.norm(points @ R.T + t - (points @ R_true.T + t_true), axis=1)
    offset = None if offset_s is None else float(1000 * (offset_s - float(groundtruth["vicon_clock_offset_s"])))
    return RegistrationErrors(rotation_error_deg=float(np.degrees(Rotation.from_matrix(R @ R_true.T).magnitude())),
                              point_error_mean_mm=float(error.mean()), point_error_max_mm=float(error.max()),
                              offset_error_ms=offset)
