"""Bundle adjustment through Ceres (pycolmap) recovers a known rig as well as the scipy path,
from the same perturbed start on the same noisy board observations."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.boards import BoardDetection, BoardSpec
from calibration.extrinsics import bundle_adjust
from spinemocap.bench.calibration_scenes import board_visible, make_ring_rig, random_board_pose
from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError

BOARD = BoardSpec.parse("charuco:6x5:120")


def _problem(n_frames: int = 12, n_own: int = 4, noise_px: float = 0.05, seed: int = 0):
    """Truth in the first camera's frame; board frames shared by >= 2 cameras plus ``n_own``
    close-up frames per camera (as its intrinsic views); every corner observed with noise."""
    rng = np.random.default_rng(seed)
    ring = make_ring_rig(4, size=(800, 600), seed=seed)
    ref = ring[0]
    truth = Rig([Camera(c.name, c.K, c.dist, c.R @ ref.R.T, c.t - c.R @ ref.R.T @ ref.t, c.size) for c in ring])
    model = BOARD.object_points()
    centre = np.mean([c.center for c in ring], axis=0)
    centre[2] = 900.0
    world_boards = []
    while len(world_boards) < n_frames:
        a, b = rng.choice(len(ring), 2, replace=False)
        pose = random_board_pose(BOARD, rng, centre, (ring[int(a)].center + ring[int(b)].center) / 2)
        if sum(board_visible(cam, BOARD, *pose) for cam in ring) >= 2:
            world_boards.append((pose, [cam.name for cam in ring if board_visible(cam, BOARD, *pose)]))
    for cam in ring:
        while sum(names == [cam.name] for _, names in world_boards) < n_own:
            ahead = cam.center + 1300 * cam.R[2] + rng.uniform(-250, 250, 3)
            pose = random_board_pose(BOARD, rng, ahead, cam.center, spread_mm=0, tilt_deg=50)
            if board_visible(cam, BOARD, *pose):
                world_boards.append((pose, [cam.name]))
    boards, detections = {}, {c.name: {} for c in truth}
    for f, ((R_w, t_w), names) in enumerate(world_boards):
        R, t = ref.R @ R_w, ref.R @ t_w + ref.t  # board -> first camera's frame
        boards[f] = (R, t)
        for cam in truth:
            if cam.name in names:
                px = cam.project(model @ R.T + t)
                detections[cam.name][f] = BoardDetection(np.arange(len(model)), px + rng.normal(0, noise_px, px.shape))
    # a start as good as the PnP spanning tree's (about 0.1 deg and a few mm off)
    start_poses = [(Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix() @ c.R, c.t + rng.normal(0, 3, 3))
                   if k else (c.R, c.t) for k, c in enumerate(truth)]
    start_boards = {f: (Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix() @ R, t + rng.normal(0, 2, 3))
                    for f, (R, t) in boards.items()}
    start = Rig([Camera(c.name, c.K, c.dist, np.eye(3), np.zeros(3), c.size) for c in truth])
    return truth, start, detections, start_poses, start_boards


def _errors(truth: Rig, rig: Rig) -> tuple[float, float, float]:
    centre = max(np.linalg.norm(e.center - t.center) for t, e in zip(truth, rig))
    rot = max(np.degrees(Rotation.from_matrix(e.R @ t.R.T).magnitude()) for t, e in zip(truth, rig))
    focal = max(abs(e.K[0, 0] / t.K[0, 0] - 1) for t, e in zip(truth, rig))
    return centre, rot, focal


def test_ceres_recovers_a_known_rig_as_well_as_scipy():
    """True lenses, poses started about as far off as the PnP tree leaves them. (With the
    lenses refined too both backends reach the same rig; the six-camera checkerboard test
    covers that path with Ceres.)"""
    truth, start, detections, poses, boards = _problem()
    rigs, errors = {}, {}
    for backend in ("ceres", "scipy"):
        rigs[backend], _, _ = bundle_adjust(start, BOARD, detections, poses, boards, progress=False, backend=backend,
                                            refine_intrinsics=False)
        errors[backend] = _errors(truth, rigs[backend])
    ceres, scipy_ = errors["ceres"], errors["scipy"]
    start_errors = _errors(truth, Rig([Camera(c.name, c.K, c.dist, R, t, c.size) for c, (R, t) in zip(start, poses)]))
    assert ceres[0] < 3.0 and ceres[1] < 0.06
    assert ceres[0] < 0.5 * start_errors[0] and ceres[1] < 0.5 * start_errors[1]
    assert ceres[0] <= 1.1 * scipy_[0] + 0.05
    assert ceres[1] <= 1.1 * scipy_[1] + 0.002
    # both minimize the same cost: the same rig to a small fraction of the error
    for a, b in zip(rigs["ceres"], rigs["scipy"]):
        assert np.linalg.norm(a.center - b.center) < 0.2
    # the reference camera stays where it was
    assert np.allclose(rigs["ceres"][0].R, np.eye(3)) and np.allclose(rigs["ceres"][0].t, 0)


def test_unknown_backend_and_k3_fallback():
    truth, start, detections, poses, boards = _problem(n_frames=3, n_own=1)
    with pytest.raises(InputError, match="unknown bundle adjustment backend"):
        bundle_adjust(start, BOARD, detections, poses, boards, progress=False, backend="g2o")
    with_k3 = Rig([Camera(c.name, c.K, np.r_[c.dist[:4], 0.01], c.R, c.t, c.size) for c in start])
    rig, _, _ = bundle_adjust(with_k3, BOARD, detections, poses, boards, progress=False, refine_intrinsics=False)
    assert all(cam.dist[4] == 0.01 for cam in rig)  # scipy path keeps k3
