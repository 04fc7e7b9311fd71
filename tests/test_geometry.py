import cv2
import numpy as np

from spinemocap.camera import Camera
from spinemocap.geometry import triangulate_dlt, umeyama


def test_triangulation_is_exact_and_ignores_unused_cameras():
    cams = [Camera.look_at(f"c{i}", (x, -2500, 1300), (0, 0, 1100), (1280, 960), 1500, dist=(-0.1, 0.02, 0, 0, 0))
            for i, x in enumerate((-1500, 0, 1500))]
    points = np.random.default_rng(0).uniform([-150, -80, 900], [150, 80, 1400], (20, 3))
    P = np.stack([c.projection_matrix for c in cams])
    uv = np.stack([c.undistort_points(c.project(points)) for c in cams], axis=1)  # (N, C, 2)
    used = np.ones((20, 3), bool)
    used[::2, 1] = False
    uv[::2, 1] = 1e6  # garbage where a camera is unused must not matter
    np.testing.assert_allclose(triangulate_dlt(P, uv, used), points, atol=1e-6)


def test_umeyama_recovers_a_similarity_and_a_pure_rotation():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(30, 3)) * 100
    R = cv2.Rodrigues(np.array([0.3, -0.2, 1.1]))[0]
    t = np.array([10.0, -40.0, 250.0])
    R_est, t_est, s_est = umeyama(src, 1.5 * src @ R.T + t)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-7)
    assert abs(s_est - 1.5) < 1e-9
    R_rigid, t_rigid, s_rigid = umeyama(src, src @ R.T + t, with_scale=False)
    np.testing.assert_allclose(R_rigid, R, atol=1e-9)
    np.testing.assert_allclose(t_rigid, t, atol=1e-7)
    assert s_rigid == 1.0
