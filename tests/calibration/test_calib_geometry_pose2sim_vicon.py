"""The calibration's geometry helpers and the Pose2Sim / Vicon writers and readers, module by
module: a point triangulated from exact pixels, a rigid fit of a moved model, rigs written and
read back projecting the same pixels, damaged files refused naming them."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.formats.pose2sim import is_pose2sim, read_pose2sim, write_pose2sim
from calibration.formats.vicon import read_xcp, write_xcp
from calibration.geometry import rigid_fit, triangulate
from spinemocap.bench.calibration_scenes import make_ring_rig
from spinemocap.fileio import InputError, read_toml
from spinemocap.geometry import rotation_matrices

POINTS = np.random.default_rng(1).uniform([-400, -400, 600], [400, 400, 1600], (20, 3))


def _rig():
    rig = make_ring_rig(4, size=(640, 480), seed=3)
    for k, cam in enumerate(rig):
        cam.dist[:] = [-0.08 + 0.02 * k, 0.03, 0.0, 0.0, 0.0]
    return rig


def test_triangulate_recovers_a_point_from_its_distorted_pixels():
    rig = _rig()
    for point in POINTS[:5]:
        pixels = np.stack([cam.project(point[None])[0] for cam in rig])
        np.testing.assert_allclose(triangulate(list(rig), pixels), point, atol=1e-6)


def test_rigid_fit_recovers_the_motion_and_reports_the_rms():
    R = rotation_matrices(np.array([[0.3, -0.2, 0.9]]))[0]
    t = np.array([10.0, -20.0, 300.0])
    R_fit, t_fit, rms = rigid_fit(POINTS, POINTS @ R.T + t)
    np.testing.assert_allclose(R_fit, R, atol=1e-9)
    np.testing.assert_allclose(t_fit, t, atol=1e-6)
    assert rms < 1e-6
    _, _, noisy_rms = rigid_fit(POINTS, POINTS @ R.T + t + np.random.default_rng(0).normal(0, 1.0, POINTS.shape))
    assert 0.5 < noisy_rms < 2.0


def _projections(rig) -> np.ndarray:
    return np.stack([cam.project(POINTS) for cam in rig])


@pytest.mark.parametrize("fmt", ["pose2sim", "vicon"])
def test_a_rig_written_and_read_back_projects_the_same_pixels(fmt, tmp_path):
    rig = _rig()
    if fmt == "pose2sim":
        path = tmp_path / "Calib.toml"
        write_pose2sim(rig, path, error_px=0.2)
        assert is_pose2sim(read_toml(path))
        back = read_pose2sim(path)
    else:
        path = tmp_path / "rig.xcp"
        write_xcp(rig, path)
        back = read_xcp(path)
    assert [c.name for c in back] == [c.name for c in rig]
    assert np.abs(_projections(back) - _projections(rig)).max() < 0.01


def test_damaged_pose2sim_and_vicon_files_are_refused_naming_them(tmp_path):
    pose2sim = tmp_path / "Calib.toml"
    write_pose2sim(_rig(), pose2sim)
    pose2sim.write_text(pose2sim.read_text().replace("size = [", 'size = "large"\nsize_gone = [', 1))
    with pytest.raises(InputError, match="Calib.toml"):
        read_pose2sim(pose2sim)
    xcp = tmp_path / "rig.xcp"
    xcp.write_text("<Cameras><Camera")
    with pytest.raises(InputError, match="rig.xcp"):
        read_xcp(xcp)


@pytest.mark.parametrize("gone", [("matrix",), ("rotation", "translation")])
def test_a_pose2sim_camera_table_lacking_an_entry_is_refused_not_dropped(tmp_path, gone):
    from calibration.formats import read_rig
    from spinemocap.fileio import write_toml

    path = tmp_path / "Calib.toml"
    write_pose2sim(_rig(), path)
    data = read_toml(path)
    for key in gone:
        del data["cam_02"][key]
    write_toml(path, data)
    name = data["cam_02"]["name"]
    lacking = ", ".join(repr(key) for key in gone)
    with pytest.raises(InputError, match=rf"Calib\.toml.*\[cam_02\] \('{name}'\) lacks {lacking}"):
        read_rig(path)  # the rig of the other three cameras is never returned
    for key in gone:
        del data["cam_01"][key], data["cam_03"][key], data["cam_04"][key]
    write_toml(path, data)
    with pytest.raises(InputError, match=rf"\[cam_01\] .* lacks {lacking}"):
        read_rig(path)  # no camera has it: still read as a Pose2Sim file, not as ours
