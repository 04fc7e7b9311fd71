"""Small synthetic tape scenes shared by tests of the tracker's stages, the rig refinement and
the reference object: a tape on a curved back, cameras behind it and their blobs."""

from __future__ import annotations

import cv2
import numpy as np

from spinemocap.camera import Camera, Rig
from spinemocap.geometry import triangulate_dlt
from spinemocap.tape import TapeSpec
from spinemocap.views import ViewDots

SPEC = TapeSpec(n_rows=13)  # the paper's artificial tape: 32 dots, 91 target edges


def tape_on_back(spec: TapeSpec, centre=(0.0, 800.0, 1000.0)) -> np.ndarray:
    """(D, 3) dots on a back curved across (u) and along (v) the spine; back faces +Y."""
    u, v = spec.graph.uv_mm[:, 0], spec.graph.uv_mm[:, 1]
    y = centre[1] + 0.0015 * (v - v.mean()) ** 2 + 0.004 * u**2
    return np.column_stack([centre[0] - u, y, centre[2] + v])


def rig_behind(n: int = 4) -> Rig:
    """n cameras on a 120 degree arc behind the subject, 2 m away, alternating heights."""
    cams = []
    for k, a in enumerate(np.deg2rad(np.linspace(-60, 60, n))):
        pos = (2000 * np.sin(a), 800 + 2000 * np.cos(a), 1300 + 150 * (k % 2))
        cams.append(Camera.look_at(f"cam{k + 1}", pos, (0, 800, 1150), (1280, 800), 1500.0))
    return Rig(cams)


def blobs(rig: Rig, dots: np.ndarray, noise_px=0.0, clutter=0, hidden=None, seed=0) -> list[ViewDots]:
    """Per-camera blobs: projections (+ noise) of the dots not ``hidden`` (C, D) + clutter."""
    rng = np.random.default_rng(seed)
    out = []
    for c, cam in enumerate(rig):
        uv = cam.project(dots)
        if hidden is not None:
            uv = uv[~hidden[c]]
        uv = uv + rng.normal(0, noise_px, uv.shape)
        if clutter:
            uv = np.vstack([uv, rng.uniform(uv.min(0) - 30, uv.max(0) + 30, (clutter, 2))])
        out.append(ViewDots(c, uv, np.ones(len(uv))))
    return out


def sequence(n: int = 6) -> np.ndarray:
    """(F, D, 3) mm: the tape swept through the volume (0.5 m across, 0.4 m up, turning 50 deg)
    over ``n`` frames: a rig's inconsistency shows in the dots' shape only over such a sweep."""
    dots = tape_on_back(SPEC)
    centre = dots.mean(axis=0)
    poses = []
    for f in range(n):
        turn = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(-25 + 10 * f)]))[0]
        poses.append((dots - centre) @ turn.T + centre + [-250 + 100 * f, 0.0, -200 + 80 * f])
    return np.stack(poses)


def pixels_of(rig: Rig, poses: np.ndarray, noise_px: float = 0.1) -> np.ndarray:
    """(F, D, C, 2) distorted pixels of every dot in every camera, with noise."""
    rng = np.random.default_rng(0)
    return np.stack([np.stack([cam.project(p) + rng.normal(0, noise_px, (len(p), 2)) for cam in rig], axis=1)
                     for p in poses])


def triangulated(rig: Rig, pixels: np.ndarray) -> np.ndarray:
    """(F, D, 3) mm: the dots triangulated from their pixels through ``rig``."""
    P = np.stack([c.projection_matrix for c in rig])
    out = []
    for frame in pixels:
        undistorted = np.stack([cam.undistort_points(frame[:, c]) for c, cam in enumerate(rig)], axis=1)
        out.append(triangulate_dlt(P, undistorted, np.ones(undistorted.shape[:2], bool)))
    return np.stack(out)
