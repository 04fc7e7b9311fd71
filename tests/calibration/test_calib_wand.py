"""Vicon wand co-registration on a rendered wand wave with a known Vicon transform and clock
offset; marker identification; bad Vicon files."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.wand import WandSpec, coregister, identify_wand
from spinemocap.app.c3d_inputs import read_vicon_wand, write_vicon_wand_c3d
from spinemocap.bench.calibration_scenes import make_ring_rig, render_wand_wave
from spinemocap.fileio import InputError


@pytest.fixture(scope="module")
def wave():
    return render_wand_wave(make_ring_rig(6, size=(800, 600), seed=0), duration_s=3.0, fps=50.0,
                            vicon_rate=100.0, offset_s=0.0237, seed=3)


def test_recovers_vicon_transform_and_offset(wave, tmp_path):
    c3d_path = tmp_path / "wand.c3d"
    write_vicon_wand_c3d(c3d_path, wave.vicon_mm, wave.vicon_rate, wave.wand)
    frames = ([wave.images[c.name][f] for c in wave.rig] for f in range(len(wave.world_mm)))
    result = coregister(wave.rig, frames, wave.fps, read_vicon_wand(c3d_path, wave.wand), progress=False)
    assert abs(result.offset_s - wave.offset_s) < 0.001
    assert np.degrees(Rotation.from_matrix(result.R @ wave.R.T).magnitude()) < 0.1
    assert np.linalg.norm(result.t - wave.t) < 1.0
    assert abs(result.scale - 1) < 0.001
    assert result.n_frames > 100
    assert set(result.residual_mm) == set(wave.wand.labels)
    assert all(r < 1.0 for r in result.residual_mm.values())
    # the rig in the Vicon frame projects Vicon-frame points where the original projects rig points
    moved = result.rig_in_vicon
    world = wave.world_mm[40]
    in_vicon = world @ wave.R.T + wave.t
    assert np.max(np.abs(moved.project(in_vicon) - wave.rig.project(world))) < 0.5
    assert "ms" in result.summary()


def test_identify_wand_is_order_free_and_rejects_ambiguity():
    wand = WandSpec()
    pixels = wand.points_mm[:, :2] * np.array([0.8, -0.7]) + [400, 300]
    rng = np.random.default_rng(1)
    shuffled = pixels[rng.permutation(5)]
    np.testing.assert_allclose(identify_wand(shuffled, wand), pixels)
    assert identify_wand(pixels[:4], wand) is None
    line = np.column_stack([np.linspace(0, 400, 5), np.full(5, 100.0)])
    assert identify_wand(line, wand) is None


def test_vicon_c3d_without_wand_markers(tmp_path):
    other = WandSpec(labels=("A", "B", "C", "D", "E"))
    path = tmp_path / "bad.c3d"
    write_vicon_wand_c3d(path, np.zeros((50, 5, 3)) + np.arange(5)[:, None], 100.0, other)
    with pytest.raises(InputError, match=r"wand markers \['WAND1'.*Label the wand's markers"):
        read_vicon_wand(path, WandSpec())
    with pytest.raises(InputError):
        read_vicon_wand(tmp_path / "missing.c3d", WandSpec())
    short = tmp_path / "short.c3d"
    write_vicon_wand_c3d(short, np.zeros((10, 5, 3)) + np.arange(5)[:, None], 100.0, WandSpec())
    with pytest.raises(InputError, match="only 10 frames"):
        read_vicon_wand(short, WandSpec())


def test_wand_cli_on_image_folders(tmp_path, capsys):
    import cv2

    from spinemocap.cli import main

    wave = render_wand_wave(make_ring_rig(3, size=(640, 480), seed=4), duration_s=2.0, fps=50.0, offset_s=-0.0412, seed=7)
    wave.rig.to_toml(tmp_path / "rig.toml")
    write_vicon_wand_c3d(tmp_path / "wand.c3d", wave.vicon_mm, wave.vicon_rate, wave.wand)
    for cam in wave.rig:
        (tmp_path / cam.name).mkdir()
        for f, image in enumerate(wave.images[cam.name]):
            cv2.imwrite(str(tmp_path / cam.name / f"{f:04d}.png"), image)
    out = tmp_path / "rig_vicon.xcp"
    code = main(["calibrate", "wand", "--rig", str(tmp_path / "rig.toml"), "--videos",
                 *[str(tmp_path / c.name) for c in wave.rig], "--vicon", str(tmp_path / "wand.c3d"),
                 "--fps", "50", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "-41." in printed and "WAND5" in printed
    from calibration.formats import read_rig

    moved = read_rig(out)
    world = wave.world_mm[30]
    assert np.max(np.abs(moved.project(world @ wave.R.T + wave.t) - wave.rig.project(world))) < 0.5
    # a rig/video count mismatch is a clear error
    assert main(["calibrate", "wand", "--rig", str(tmp_path / "rig.toml"), "--videos", str(tmp_path / "cam1"),
                 "--vicon", str(tmp_path / "wand.c3d"), "--fps", "50", "--out", str(out)]) == 2
    assert "one per camera" in capsys.readouterr().err


def test_wand_refines_perturbed_extrinsics(wave):
    from calibration.wand import detect_wand_views, refine_rig_with_wand, triangulate_wand_views
    from spinemocap.camera import Camera, Rig

    rng = np.random.default_rng(0)
    perturbed = [wave.rig[0]]
    for cam in list(wave.rig)[1:]:
        dR = Rotation.from_rotvec(rng.normal(0, 1, 3) * np.radians(0.3) / np.sqrt(3)).as_matrix()
        R = dR @ cam.R
        centre = cam.center + rng.normal(0, 4.0, 3)
        perturbed.append(Camera(cam.name, cam.K, cam.dist, R, -R @ centre, cam.size))
    perturbed = Rig(perturbed)
    frames = ([wave.images[c.name][f] for c in wave.rig] for f in range(len(wave.world_mm)))
    views = detect_wand_views(frames, wave.wand, progress=False)
    refined = refine_rig_with_wand(perturbed, views, triangulate_wand_views(perturbed, views, wave.wand, 10.0),
                                   wave.wand, progress=False)
    for true, before, after in zip(wave.rig, perturbed, refined):
        err_after = np.linalg.norm(after.center - true.center)
        assert err_after < 2.0
        assert np.degrees(Rotation.from_matrix(after.R @ true.R.T).magnitude()) < 0.1
        assert err_after <= np.linalg.norm(before.center - true.center) + 1e-6


def test_wand_c3d_round_trip_through_the_one_reader(tmp_path):
    """The wand C3D is written and read by exporters' C3D (the one reader): markers, gaps and rate survive."""
    points = np.random.default_rng(2).uniform(-500, 500, (30, 5, 3))
    points[4, 2] = np.nan
    write_vicon_wand_c3d(tmp_path / "w.c3d", points, 200.0, WandSpec())
    vicon = read_vicon_wand(tmp_path / "w.c3d", WandSpec())
    assert vicon.rate == 200.0
    assert np.isnan(vicon.points_mm[4, 2]).all()
    np.testing.assert_allclose(vicon.points_mm, points, atol=1e-3)
