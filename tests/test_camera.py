import numpy as np
import pytest

from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError


def make_camera(dist=(-0.12, 0.05, 0.001, -0.0008, -0.01)):
    cam = Camera.look_at("cam1", (400, -2500, 1300), (0, 0, 1200), (2448, 1600), 2400.0, dist=dist,
                         principal_point=(1210.3, 812.7))
    cam.K[1, 1] = 2395.0  # fx != fy
    return cam


def test_look_at_puts_target_at_principal_point_and_up_is_up():
    cam = make_camera(dist=(0, 0, 0, 0, 0))
    uv = cam.project(np.array([[0, 0, 1200.0], [0, 0, 1300.0]]))
    assert np.allclose(uv[0], cam.K[:2, 2])
    assert uv[1, 1] < uv[0, 1]  # higher in the world -> smaller row index
    assert np.allclose(cam.center, (400, -2500, 1300))


def test_projection_matches_opencv():
    import cv2

    cam = make_camera()
    pts = np.random.default_rng(0).uniform([-300, -200, 900], [300, 200, 1600], (50, 3))
    ours = cam.project(pts)
    ref, _ = cv2.projectPoints(pts, cam.rvec, cam.t, cam.K, cam.dist)
    assert np.allclose(ours, ref.reshape(-1, 2), atol=1e-6)


def test_undistort_round_trip_and_rays():
    cam = make_camera()
    pts = np.random.default_rng(1).uniform([-300, -200, 900], [300, 200, 1600], (100, 3))
    uv = cam.project(pts)
    assert np.allclose(cam.project(pts, distort=False), cam.undistort_points(uv), atol=1e-6)
    origin, dirs = cam.rays(uv)
    to_pts = pts - origin
    to_pts /= np.linalg.norm(to_pts, axis=1, keepdims=True)
    assert np.allclose(dirs, to_pts, atol=1e-8)


def test_points_behind_camera_are_nan():
    cam = make_camera()
    assert np.isnan(cam.project(np.array([[400, -4000, 1300.0]]))).all()


def test_rig_toml_round_trip(tmp_path):
    rig = Rig([make_camera(), Camera.look_at("cam2", (-1500, -2000, 1200), (0, 0, 1100), (640, 480), 600)])
    rig.to_toml(tmp_path / "rig.toml")
    back = Rig.from_toml(tmp_path / "rig.toml")
    pts = np.array([[10.0, 20, 1100], [-50, 30, 1250]])
    assert back.names == ["cam1", "cam2"]
    assert np.allclose(back.project(pts), rig.project(pts), atol=1e-9)


def test_rig_errors(tmp_path):
    with pytest.raises(ValueError, match="duplicate"):
        Rig([make_camera(), make_camera()])
    (tmp_path / "rig.toml").write_text('units = "mm"\n')
    with pytest.raises(InputError, match="rig.toml.*no \\[\\[camera\\]\\]"):
        Rig.from_toml(tmp_path / "rig.toml")
    with pytest.raises(InputError, match="file not found"):
        Rig.from_toml(tmp_path / "absent.toml")
