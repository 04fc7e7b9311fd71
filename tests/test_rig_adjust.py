"""The shared rig adjustment recovers known rigs: a rigid target with a reference camera (Ceres and
scipy agree), moving free points with clock offsets and a focal scale under priors, and a world
frame fixed by control points."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError
from spinemocap.rig_adjust import (
    AdjustmentSettings,
    CameraPriors,
    FixedPoints,
    FreePoints,
    RigAdjustment,
    RigidTarget,
)


def ring(n: int = 4, radius_mm: float = 2000.0) -> Rig:
    """``n`` cameras on a circle around the origin, 1.2 m up, looking at it."""
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n + 0.3
        position = [radius_mm * np.cos(a), radius_mm * np.sin(a), 1200.0]
        cams.append(Camera.look_at(f"cam{k}", position, [0, 0, 0], (800, 600), 800.0, dist=(-0.1, 0.02, 0, 0, 0)))
    return Rig(cams)


def perturbed(rig: Rig, rng: np.random.Generator, centre_mm: float, rotation_deg: float) -> Rig:
    """Every camera turned by ~``rotation_deg`` and its centre moved by ~``centre_mm``."""
    cams = []
    for cam in rig:
        R = Rotation.from_rotvec(np.radians(rotation_deg) * rng.normal(size=3)).as_matrix() @ cam.R
        centre = cam.center + centre_mm * rng.normal(size=3)
        cams.append(Camera(cam.name, cam.K, cam.dist, R, -R @ centre, cam.size))
    return Rig(cams)


def centre_errors(a: Rig, b: Rig) -> np.ndarray:
    return np.array([np.linalg.norm(x.center - y.center) for x, y in zip(a, b)])


def seen(rig: Rig, cam: int, points: np.ndarray, rng: np.random.Generator, noise_px: float) -> np.ndarray:
    return rig[cam].project(points) + rng.normal(0, noise_px, (len(points), 2))


def test_a_rigid_target_gives_the_true_rig_with_ceres_and_scipy_alike():
    rng = np.random.default_rng(1)
    truth = ring(3)
    grid = np.stack(np.meshgrid(np.arange(7), np.arange(5)), axis=-1).reshape(-1, 2) * 60.0
    model = np.column_stack([grid - grid.mean(axis=0), np.zeros(len(grid))])
    poses = [(Rotation.from_rotvec(rng.normal(0, 0.4, 3)).as_matrix(), rng.normal(0, 150, 3)) for _ in range(10)]
    cam, frame, corner, uv = [], [], [], []
    for f, (R, t) in enumerate(poses):
        for c in range(len(truth)):
            cam.append(np.full(len(model), c))
            frame.append(np.full(len(model), f))
            corner.append(np.arange(len(model)))
            uv.append(seen(truth, c, model @ R.T + t, rng, 0.1))
    start_poses = [(Rotation.from_rotvec(rng.normal(0, 0.003, 3)).as_matrix() @ R, t + rng.normal(0, 3, 3))
                   for R, t in poses]
    given = Rig([truth[0], *perturbed(truth, rng, 10.0, 0.3).cameras[1:]])  # camera 0 holds the gauge
    target = RigidTarget(model, start_poses, *map(np.concatenate, (cam, frame, corner, uv)))
    rigs = {}
    for backend in ("ceres", "scipy"):
        adjustment = RigAdjustment(given, target=target, settings=AdjustmentSettings(backend=backend, tolerance=1e-12))
        adjusted = adjustment.solve()
        assert adjusted.backend == backend
        assert np.sqrt(np.mean(adjusted.target_errors_px ** 2)) < 0.2  # the noise's 0.14 px
        rigs[backend] = adjusted.rig
    start_error = centre_errors(given, truth).max()
    for rig in rigs.values():
        assert centre_errors(rig, truth).max() < 0.1 * start_error
        assert np.allclose(rig[0].R, truth[0].R) and np.allclose(rig[0].t, truth[0].t)
    assert centre_errors(rigs["ceres"], rigs["scipy"]).max() < 0.05


def moving_points(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) mm points within 300 mm of the origin and their (n, 3) velocities, up to ~1.5 m/s."""
    return rng.uniform(-300, 300, (n, 3)), rng.normal(0, 800, (n, 3))


def test_free_points_give_the_clock_offsets_and_focal_scales_under_priors():
    rng = np.random.default_rng(2)
    truth = ring(4)
    offsets_s = np.array([0.0, 0.004, -0.003, 0.002])
    focal = np.array([1.0, 1.01, 0.99, 1.0])
    scaled = Rig([Camera(c.name, np.diag([f, f, 1.0]) @ c.K, c.dist, c.R, c.t, c.size) for c, f in zip(truth, focal)])
    X, V = moving_points(rng, 300)
    cam = np.repeat(np.arange(4), len(X))
    point = np.tile(np.arange(len(X)), 4)
    uv = np.concatenate([seen(scaled, c, X + offsets_s[c] * V, rng, 0.1) for c in range(4)])
    given = perturbed(truth, rng, 2.0, 0.05)
    width = np.ones(4)
    settings = AdjustmentSettings(intrinsics="focal", clock_offsets=True, reference=None,
                                  priors=CameraPriors(20 * width, np.radians(0.5) * width), backend="ceres")
    adjustment = RigAdjustment(given, points=FreePoints(cam, point, uv, X + rng.normal(0, 2, X.shape), V),
                               settings=settings)
    assert adjustment.ceres_unfit() is not None  # priors and clock offsets: scipy's
    before = adjustment.initial()
    adjusted = adjustment.solve()
    assert adjusted.backend == "scipy"
    assert np.sqrt(np.mean(before.point_errors_px ** 2)) > 2.0
    assert np.sqrt(np.mean(adjusted.point_errors_px ** 2)) < 0.2
    assert np.abs(adjusted.clock_offsets_s - offsets_s).max() < 2e-4
    # a focal length trades against the camera's distance on a small volume: 1 % told apart to ~0.3 %
    assert np.abs(adjusted.focal_scale - focal).max() < 4e-3
    assert abs((adjusted.focal_scale[1] - adjusted.focal_scale[2]) - 0.02) < 4e-3
    # a weight of 0 leaves an observation out: a wild one then changes nothing (a Huber scale at
    # the start's residual level, as a first solve from a rig this far off needs with weights)
    wild = uv.copy()
    wild[0] += 40.0
    weights = np.ones(len(uv))
    weights[0] = 0.0
    again = RigAdjustment(given, points=FreePoints(cam, point, wild, X, V), settings=settings).solve(
        weights=weights, loss_scale_px=3.0)
    assert np.abs(again.clock_offsets_s - adjusted.clock_offsets_s).max() < 1e-5
    assert again.point_errors_px[0] > 30.0


def test_control_points_fix_the_world_frame():
    rng = np.random.default_rng(3)
    truth = ring(4)
    X, _ = moving_points(rng, 150)
    cam = np.repeat(np.arange(4), len(X))
    point = np.tile(np.arange(len(X)), 4)
    uv = np.concatenate([seen(truth, c, X, rng, 0.1) for c in range(4)])
    markers = np.array([[0.0, 0, 0], [400, 0, 0], [0, 300, 0], [0, 0, 200], [300, 300, 100]])
    control = FixedPoints(np.tile(markers, (4, 1)), np.repeat(np.arange(4), len(markers)),
                          np.concatenate([seen(truth, c, markers, rng, 0.05) for c in range(4)]), weight=3.0)
    # the given rig: the true one with its world moved 8 mm and turned 0.3 deg, plus camera errors
    shifted = perturbed(truth, rng, 1.0, 0.02).transformed(Rotation.from_rotvec([0, 0, 0.005]).as_matrix(),
                                                           np.array([8.0, -5.0, 3.0]))
    width = np.ones(4)
    settings = AdjustmentSettings(reference=None, priors=CameraPriors(20 * width, np.radians(0.5) * width),
                                  exact_steps=True, max_evaluations=200)
    points = FreePoints(cam, point, uv, X + rng.normal(0, 3, X.shape))
    plain = RigAdjustment(shifted, points=points, settings=settings).solve()
    pinned = RigAdjustment(shifted, points=points, control=control, settings=settings).solve()
    moved = centre_errors(plain.rig, truth).mean()
    assert moved > 5.0  # the dots alone keep the given world frame
    assert centre_errors(pinned.rig, truth).mean() < 0.25 * moved
    assert np.sqrt(np.mean(pinned.control_errors_px ** 2)) < 0.2


def test_an_inconsistent_problem_is_an_input_error():
    rig = ring(2)
    points = FreePoints(np.zeros(2, int), np.zeros(2, int), np.zeros((2, 2)), np.zeros((1, 3)))
    with pytest.raises(InputError, match="nothing to adjust"):
        RigAdjustment(rig)
    with pytest.raises(InputError, match="backend"):
        RigAdjustment(rig, points=points, settings=AdjustmentSettings(backend="g2o"))  # type: ignore[arg-type]  # an unknown backend on purpose
    with pytest.raises(InputError, match="reference camera 5"):
        RigAdjustment(rig, points=points, settings=AdjustmentSettings(reference=5))
    with pytest.raises(InputError, match="velocities"):
        RigAdjustment(rig, points=points, settings=AdjustmentSettings(clock_offsets=True))
