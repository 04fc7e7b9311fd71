"""The studio's realism: taping tension, calibration and sync errors, skin strain (Schober), the
taut strip from the sacrum, motions that reach the limits and the realism levels. Measured from
the ground truth and the written files."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.capture import Capture
from spinemocap.synth import SynthConfig, build_scene, write_capture


def test_tape_tension_spreads_the_dots_on_the_skin_but_not_the_spec(tmp_path):
    """20 % tension: the rows sit ~20 % farther apart than the roll's spec (uneven by a few
    percent along the tape), the width keeps the spec, capture.toml keeps the roll's spec."""
    config = SynthConfig.preset("tiny", frames=1, rows=9, tape_tension=0.2, seed=3, motion="neutral")
    out = write_capture(config, tmp_path / "cap", progress=False)
    gt = np.load(out / "groundtruth.npz")
    spec = Capture.open(out).tape
    assert spec.row_pitch_mm == 25.0 and spec.n_rows == 9  # what a lab enters: the roll's spec
    assert float(gt["tape_tension"]) == 0.2
    assert abs(gt["laid_stretch"].mean() - 1.2) < 0.01
    assert 0.01 < gt["laid_stretch"].max() - gt["laid_stretch"].min() < 0.12  # uneven by a few percent
    stretch = gt["row_stretch"][0]
    assert abs(stretch.mean() - 1.2) < 0.02, stretch  # measured between the rendered dots
    np.testing.assert_allclose(stretch, gt["laid_stretch"], atol=0.02)
    np.testing.assert_allclose(gt["width_stretch"][0], 1.0, atol=0.04)  # tension acts along the tape
    # the same seed without tension lays the spec exactly
    plain = build_scene(SynthConfig.preset("tiny", frames=1, rows=9, seed=3, motion="neutral"))
    np.testing.assert_allclose(plain.groundtruth["row_stretch"][0], 1.0, atol=0.01)


def test_calibration_error_writes_a_rig_off_by_the_asked_rms_and_keeps_the_truth(tmp_path):
    """The written rig.toml reprojects the true dots with ~1.5 px RMS per camera; the images and
    the ground truth's uv come from the true rig stored in groundtruth.npz."""
    from spinemocap.camera import Camera, Rig

    config = SynthConfig.preset("tiny", frames=2, calibration_error_px=1.5, seed=2)
    out = write_capture(config, tmp_path / "cap", progress=False)
    gt = np.load(out / "groundtruth.npz")
    written = Capture.open(out).rig
    true_rig = Rig([Camera(name, K, d, R, t, cam.size) for name, K, d, R, t, cam in
                    zip(gt["camera_names"], gt["rig_K"], gt["rig_dist"], gt["rig_R"], gt["rig_t"], written)])
    for f in range(2):
        np.testing.assert_allclose(true_rig.project(gt["dots"][f]), gt["uv"][f], atol=1e-6)
    dots = gt["dots"].reshape(-1, 3)
    for c, cam in enumerate(written):
        error = cam.project(dots) - true_rig[c].project(dots)
        rms = np.sqrt(np.mean(np.sum(error**2, axis=1)))
        assert 1.2 < rms < 1.8, (cam.name, rms)
        assert abs(gt["calibration_rms_px"][c] - 1.5) < 0.01
        # rotations, centres and focal lengths all moved
        assert not np.allclose(cam.R, true_rig[c].R, atol=1e-7)
        assert np.linalg.norm(cam.center - true_rig[c].center) > 1e-3
        assert cam.K[0, 0] != true_rig[c].K[0, 0]
    # without the option the written rig is the true one
    exact = build_scene(SynthConfig.preset("tiny", frames=1, seed=2))
    assert exact.calibrated_rig is exact.rig and not exact.groundtruth["calibration_rms_px"].any()


def test_sync_error_renders_each_camera_at_its_own_clock():
    """2 ms RMS of clock offsets (zero mean): each camera's uv is the projection of the dots at
    its own time; in the forehand's fast swing that differs from the nominal time's projection."""
    config = SynthConfig.preset("tiny", frames=2, fps=1 / 0.675, motion="forehand", sync_error_ms=2.0, seed=4)
    scene = build_scene(config)
    offsets = scene.groundtruth["sync_offset_s"]
    assert abs(np.sqrt(np.mean(offsets**2)) - 0.002) < 1e-9 and abs(offsets.mean()) < 1e-12
    frame = 1
    for c, cam in enumerate(scene.rig):
        v, n = scene._posed(frame, offset_s=float(offsets[c]))
        own = cam.project(scene.tape_on_skin.dot_positions(v, n))
        np.testing.assert_allclose(scene.groundtruth["uv"][frame, c], own, atol=1e-9)
    nominal = scene.rig.project(scene.groundtruth["dots"][frame])
    assert np.abs(nominal - scene.groundtruth["uv"][frame]).max() > 0.3
    scene.close()
