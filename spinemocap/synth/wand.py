"""A waved marker wand: its smooth random motion and its images (retro-reflective spheres as bright
discs on a dark, noisy background). Used by the calibration scenes and the studio's wand wave."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import Camera


def wand_trajectory(times_s: np.ndarray, points_mm: np.ndarray, seed: int, centre_mm) -> np.ndarray:
    """(T, M, 3) world marker positions (mm) at ``times_s`` (T,) of a smoothly waved wand whose
    markers lie at ``points_mm`` (M, 3) in its own frame: a sum of a few random sinusoids
    (0.2-1.2 Hz, drawn from ``seed``) for the centre (+-400 mm about ``centre_mm``) and for the
    orientation (rotation vector)."""
    rng = np.random.default_rng(seed)
    freqs = rng.uniform(0.2, 1.2, (4, 6))
    phases = rng.uniform(0, 2 * np.pi, (4, 6))
    amps = np.concatenate([rng.uniform(60, 160, (4, 3)), rng.uniform(0.15, 0.45, (4, 3))], axis=1)
    signal = np.sum(amps[:, None, :] * np.sin(2 * np.pi * freqs[:, None, :] * times_s[None, :, None]
                                               + phases[:, None, :]), axis=0)
    base = Rotation.from_euler("x", 90, degrees=True)  # wand plane roughly vertical, facing the ring
    rotations = Rotation.from_rotvec(signal[:, 3:]) * base
    local = np.asarray(points_mm, float) - np.mean(points_mm, axis=0)
    return np.stack([rot.apply(local) for rot in rotations]) + (np.asarray(centre_mm) + signal[:, None, :3])


def render_wand_frame(cam: Camera, markers_mm: np.ndarray, radius_mm: float, noise: np.ndarray,
                      background: float = 25.0) -> np.ndarray:
    """Dark grey image with each marker sphere as a bright anti-aliased disc of the exact
    projected radius, nearer spheres drawn last, plus the sensor ``noise`` field (H, W)."""
    w, h = cam.size
    image = np.full((h, w), background, np.float32)
    depth = cam.depth(markers_mm)
    centres = cam.project(markers_mm)
    fx = cam.K[0, 0]
    w, h = cam.size
    sub = (np.arange(8) + 0.5) / 8 - 0.5  # 8x8 supersamples per pixel: exact area coverage
    for k in np.argsort(-depth):
        if depth[k] <= radius_mm or not np.all(np.isfinite(centres[k])):
            continue
        r_px = fx * radius_mm / np.sqrt(depth[k] ** 2 - radius_mm ** 2)
        (u, v), reach = centres[k], int(np.ceil(r_px)) + 1
        u0, u1 = max(int(np.floor(u)) - reach, 0), min(int(np.ceil(u)) + reach + 1, w)
        v0, v1 = max(int(np.floor(v)) - reach, 0), min(int(np.ceil(v)) + reach + 1, h)
        if u0 >= u1 or v0 >= v1:
            continue
        su = (np.arange(u0, u1)[:, None] + sub[None]).ravel()
        sv = (np.arange(v0, v1)[:, None] + sub[None]).ravel()
        inside = ((sv[:, None] - v) ** 2 + (su[None] - u) ** 2) <= r_px ** 2
        cover = inside.reshape(v1 - v0, 8, u1 - u0, 8).mean(axis=(1, 3))
        patch = image[v0:v1, u0:u1]
        patch[:] = patch * (1 - cover) + 235.0 * cover
    image = cv2.GaussianBlur(image, (0, 0), 0.5) + noise
    return np.clip(np.round(image), 0, 255).astype(np.uint8)
