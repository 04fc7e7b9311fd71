"""The virtual Vicon of ``synth --vicon``: gaps where its camera ring loses sight of a marker (the
body hides it), and the wand wave that ``calibrate wand`` turns into the rig -> Vicon transform and
clock offset, which ``crossval --rig-vicon`` then uses. One small studio trial (artificial layout
at 512x384, 1.5 s at 30 fps, no body frames rendered) serves every test but the last, which runs
``bench vicon-wand`` end to end on its own trial."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

FRONT = ("CLAV", "STRN", "LASI", "RASI")  # (the front head markers may show past the side of the head)
BACK = ("C7", "LPSI", "RPSI", "VT_R01", "VT_R07")


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    """A capture folder (capture.toml, rig.toml, groundtruth.npz with the dots) plus what
    ``synth --vicon`` adds: vicon.c3d, wand/ and the vicon_/wand_ truth."""
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from spinemocap.app.virtual_vicon import write_scene_vicon
    from spinemocap.capture import Capture
    from spinemocap.synth import SynthConfig
    from spinemocap.synth.scene import build_scene

    out = tmp_path_factory.mktemp("studio")
    config = SynthConfig.preset("artificial", frames=45, fps=30.0, size=(512, 384))
    scene = build_scene(config)
    dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])
    Capture(root=out, name="trial", fps=scene.fps, n_frames=scene.n_frames, rig=scene.calibrated_rig,
            tape=scene.tape).save()
    np.savez(out / "groundtruth.npz", dots=dots)
    vicon = write_scene_vicon(scene, out, wand_seconds=2.7, progress=False)
    return out, scene, dots, vicon


def test_front_markers_gap_when_only_back_cameras_exist(studio):
    """Three Vicon cameras behind the subject (the back faces +Y), the facing test off: the body
    (the ray against the posed mesh) hides the front markers from all of them, the back markers
    stay seen; the default ring around the subject keeps them all."""
    from spinemocap.app.virtual_vicon import record_scene
    from spinemocap.bodymodel.virtual_vicon import ViconCameraRing, ViconSetup

    _, scene, _, default = studio
    ring = ViconCameraRing(azimuths_deg=(60.0, 90.0, 120.0), heights_mm=(2200.0,), max_view_angle_deg=180.0)
    vicon = record_scene(scene, ViconSetup(rate_hz=50.0, cameras=ring))
    index = {label: k for k, label in enumerate(vicon.labels)}
    front, back = [index[m] for m in FRONT], [index[m] for m in BACK]
    assert vicon.occluded[:, front].all() and np.isnan(vicon.positions[:, front]).all()
    assert not vicon.occluded[:, back].any() and np.isfinite(vicon.positions[:, back]).all()
    assert (vicon.cameras_seeing[:, back] >= 2).all() and (vicon.cameras_seeing[:, front] <= 1).all()
    assert not default.dropped.any()  # random dropouts are off unless asked for
    assert not default.occluded[:, [default.labels.index(m) for m in FRONT + BACK]].any()
    assert (default.cameras_seeing >= 0).all() and default.camera_centres.shape == (8, 3)


def test_a_marker_facing_away_is_not_seen():
    """The facing test alone (nothing blocks): a marker is seen by the cameras within
    ``max_view_angle_deg`` of its normal only."""
    from spinemocap.bodymodel.virtual_vicon import cameras_seeing

    marker, normal = np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]])
    cameras = np.array([[500.0, 3000.0, 0.0], [3000.0, 500.0, 0.0], [3000.0, -300.0, 0.0], [0.0, -3000.0, 0.0]])
    never = lambda starts, ends: np.zeros(len(starts), bool)  # noqa: E731
    assert cameras_seeing(marker, normal, cameras, never, 100.0).tolist() == [3]  # 9.5, 80.5 and 95.7 deg, not 180
    assert cameras_seeing(marker, normal, cameras, never, 90.0).tolist() == [2]
    always = lambda starts, ends: np.ones(len(starts), bool)  # noqa: E731
    assert cameras_seeing(marker, normal, cameras, always, 180.0).tolist() == [0]


def test_synth_vicon_writes_a_wand_wave(studio):
    import exporters

    out, scene, _, vicon = studio
    truth = np.load(out / "groundtruth.npz")
    world, fps = truth["wand_world_mm"], float(truth["wand_fps"])
    assert fps == scene.fps and world.shape == (81, 5, 3)  # 2.7 s at 30 fps (at least MIN_FRAMES = 80)
    layout = np.linalg.norm(world[:, 0] - world[:, 2], axis=1)
    np.testing.assert_allclose(layout, 240.0, atol=1e-6)  # WAND1-WAND3: the T-wand's long side
    for cam in scene.rig.names:
        assert len(list((out / "wand" / cam).glob("*.png"))) == 81
    table = exporters.read(out / "wand" / "vicon_wand.c3d")
    assert table.labels == ["WAND1", "WAND2", "WAND3", "WAND4", "WAND5"] and table.fps == 200.0
    # the Vicon's wand at Vicon frame j is the studio's wand at time j / 200 - offset, moved to its frame
    frames, points = table.dense()
    t_vicon = 10 / fps + vicon.setup.clock_offset_s  # RGB frame 10 on the Vicon clock
    seen = np.array([[np.interp(t_vicon, frames / 200.0, points[:, m, k]) for k in range(3)] for m in range(5)])
    expected = world[10] @ truth["vicon_R"].T + truth["vicon_t_mm"]
    assert np.abs(seen - expected).max() < 1.5  # Vicon noise 0.2 mm, linear interpolation
    assert "spinemocap calibrate wand" in (out / "wand" / "README.txt").read_text()


def test_calibrate_wand_recovers_the_transform_and_offset_and_crossval_uses_it(studio, tmp_path, capsys):
    import exporters
    from spinemocap.app.crossval import rig_transform
    from spinemocap.app.wand_wave import registration_errors
    from spinemocap.cli import main
    from spinemocap.markers import MarkerTable

    out, scene, dots, vicon = studio
    rig_vicon = tmp_path / "rig_vicon.toml"
    assert main(["calibrate", "wand", "--rig", str(out / "rig.toml"), "--videos",
                 *[str(out / "wand" / cam) for cam in scene.rig.names], "--vicon", str(out / "wand" / "vicon_wand.c3d"),
                 "--fps", str(scene.fps), "--out", str(rig_vicon)]) == 0
    offset_ms = float(re.search(r"time offset \(t_vicon - t_rgb\): ([-+.\d]+) ms", capsys.readouterr().out).group(1))
    truth = dict(np.load(out / "groundtruth.npz"))
    R, t, scale = rig_transform(scene.calibrated_rig, rig_vicon)
    errors = registration_errors(truth, scale * R, t, offset_ms / 1000)
    assert errors.offset_error_ms is not None and abs(errors.offset_error_ms) < 0.5
    assert errors.rotation_error_deg < 0.05 and errors.point_error_max_mm < 1.0, errors

    noisy = dots + np.random.default_rng(1).normal(0.0, 0.1, dots.shape)
    exporters.write(MarkerTable.from_arrays(scene.labels, noisy, scene.fps), tmp_path / "tracked.c3d")
    assert main(["crossval", str(tmp_path / "tracked.c3d"), str(out / "vicon.c3d"), "--capture", str(out),
                 "--out", str(tmp_path / "cv"), "--rig-vicon", str(rig_vicon)]) == 0
    alignment = json.loads((tmp_path / "cv" / "summary.json").read_text())["alignment"]
    np.testing.assert_allclose(alignment["rotation"], R, atol=1e-9)  # the wand's transform, not re-estimated
    assert abs(alignment["clock_offset_s"] - vicon.setup.clock_offset_s) < 1e-3


def test_bench_vicon_wand_scores_the_wand_and_both_crossval_alignments_against_the_truth(tmp_path, capsys):
    """``spinemocap bench vicon-wand`` closes the loop on one small ideal trial: the wand's transform
    and clock offset match the virtual Vicon's truth; crossval with the transform read back from
    the written rig file carries the wand's rotation (only the offset estimated), the tape-marker
    peer estimates both; the JSON, the plot and the table are written."""
    pytest.importorskip("torch").set_num_threads(1)
    from spinemocap.cli import main

    out = tmp_path / "vicon_wand.json"
    assert main(["bench", "vicon-wand", "--levels", "ideal", "--frames", "10", "--size", "512x384",
                 "--wand-seconds", "2", "--no-progress", "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())["levels"]
    wand, from_rig, from_markers = row["wand"], row["crossval_rig_vicon"], row["crossval_markers"]
    assert abs(wand["offset_error_ms"]) < 0.5
    assert wand["rotation_error_deg"] < 0.05 and wand["point_error_max_mm"] < 1.0, wand
    assert from_rig["estimated"] == "offset" and from_markers["estimated"] == "offset+transform"
    assert from_rig["rotation_error_deg"] == pytest.approx(wand["rotation_error_deg"], abs=1e-6)
    assert from_rig["scale"] == pytest.approx(wand["scale"], rel=1e-9)
    assert set(from_markers["angles"]) == set(from_rig["angles"]) and "lumbar_flexion" in from_rig["angles"]
    assert out.with_suffix(".png").stat().st_size > 0
    table = capsys.readouterr().out
    assert all(method in table for method in ("wand", "crossval_rig_vicon", "crossval_markers"))


def test_registration_errors_measure_a_known_turn_shift_and_clock_offset():
    from scipy.spatial.transform import Rotation

    from spinemocap.app.wand_wave import registration_errors

    truth = {"vicon_R": np.eye(3), "vicon_t_mm": np.zeros(3), "vicon_clock_offset_s": 0.010,
             "dots": np.array([[[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]], [[np.nan] * 3, [0.0, 100.0, 0.0]]])}
    turn = Rotation.from_euler("z", 0.5, degrees=True).as_matrix()
    errors = registration_errors(truth, turn, np.array([0.0, 0.0, 2.0]), offset_s=0.0125)
    assert errors.rotation_error_deg == pytest.approx(0.5)
    assert errors.point_error_mean_mm > 2.0 and errors.point_error_max_mm == pytest.approx(
        np.hypot(2.0, 2 * 100.0 * np.sin(np.radians(0.25))))
    assert errors.offset_error_ms == pytest.approx(2.5)
    assert list(registration_errors(truth, np.eye(3), np.zeros(3)).to_dict()) == [
        "rotation_error_deg", "point_error_mean_mm", "point_error_max_mm"]  # no offset estimated, none written
