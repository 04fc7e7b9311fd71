"""Planar pose ambiguity: a small board seen nearly face-on from afar fits two poses almost
equally (IPPE's two solutions), and the better-fitting one is often the wrong one. Corners are
projected exactly (plus 0.15 px noise) into a known rig: both solutions stay candidates, the
pair poses come from the consensus and the joint adjustment keeps the right board poses, where
averaging each frame's best per-camera poses misses."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.boards import BoardDetection, BoardSpec
from calibration.extrinsics import _mean_rotation, _pnp_candidates, calibrate_extrinsics
from spinemocap.camera import Camera, Rig

BOARD = BoardSpec.parse("charuco:4x5:54:40.5:DICT_4X4_1000")


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(3)
    target = np.array([0.0, 0.0, 1000.0])
    cams = []
    for k, azimuth in enumerate(np.radians([-35, 0, 35])):
        position = target + [3200 * np.sin(azimuth), -3200 * np.cos(azimuth), 300.0 * k]
        cams.append(Camera.look_at(f"cam{k}", position, target, (1280, 720), 900.0,
                                   dist=(-0.1, 0.02, 0, 0, 0)))
    rig = Rig(cams)
    model = BOARD.object_points()
    w, h = BOARD.size_mm
    detections = {c.name: {} for c in rig}
    poses = {}
    for f in range(60):
        facing = Rotation.from_euler("z", rng.uniform(-30, 30), degrees=True).apply([0, -1.0, 0])
        z = -facing
        x = np.cross([0, 0, 1.0], z)
        x /= np.linalg.norm(x)
        R = Rotation.from_rotvec(rng.normal(0, 0.12, 3)).as_matrix() @ np.column_stack([x, np.cross(z, x), z])
        centre = target + rng.uniform(-400, 400, 3)
        t = centre - R @ [w / 2, h / 2, 0]
        poses[f] = (R, t)
        for cam in rig:
            pixels = cam.project(model @ R.T + t) + rng.normal(0, 0.15, (len(model), 2))
            if cam.in_image(pixels).all():
                detections[cam.name][f] = BoardDetection(np.arange(len(model)), pixels, 1.0)
    return rig, detections, poses


def _angle(R):
    return float(np.degrees(Rotation.from_matrix(R).magnitude()))


def test_views_are_ambiguous_and_the_best_fit_is_often_wrong(scene):
    rig, detections, poses = scene
    ambiguous = wrong_first = 0
    for cam in rig:
        for f, det in detections[cam.name].items():
            cands = _pnp_candidates(cam, BOARD, det)
            true_R = cam.R @ poses[f][0]
            ambiguous += len(cands) == 2
            wrong_first += _angle(cands[0][0] @ true_R.T) > 8.0  # the mirror solution fits best
            assert min(_angle(R @ true_R.T) for R, _ in cands) < 6.0  # the truth (up to noise) is a candidate
    assert ambiguous > 150 and wrong_first >= 8


def test_joint_adjustment_keeps_the_right_poses(scene):
    rig, detections, poses = scene
    lenses = Rig([Camera(c.name, c.K, c.dist, np.eye(3), np.zeros(3), c.size) for c in rig])
    result = calibrate_extrinsics(lenses, BOARD, detections, refine_intrinsics=False, progress=False)
    ref = rig[0]
    for true, est in zip(rig, result.rig):
        true_rel = true.R @ ref.R.T
        assert _angle(est.R @ true_rel.T) < 0.05
        true_centre = ref.R @ true.center + ref.t  # in the reference camera's frame
        assert np.linalg.norm(est.center - true_centre) < 3.0  # 0.1 % of the 3.2 m distance
    for f, (R_b, _) in result.board_poses.items():  # every board pose is the right solution
        assert _angle(R_b @ (ref.R @ poses[f][0]).T) < 0.5
    # the previous way, each frame's best-fitting pose per camera and their mean, misses
    for cam in list(rig)[1:]:
        shared = sorted(set(detections[ref.name]) & set(detections[cam.name]))
        rel = [_pnp_candidates(cam, BOARD, detections[cam.name][f])[0][0]
               @ _pnp_candidates(ref, BOARD, detections[ref.name][f])[0][0].T for f in shared]
        assert _angle(_mean_rotation(rel) @ (cam.R @ ref.R.T).T) > 0.3
