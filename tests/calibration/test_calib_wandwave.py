"""Wand-wave calibration alone (no board): a six-camera rig recovered from a rendered wave of
the T-wand and of a 2-marker linear wand, with the right scale and the floor frame from the wand
on the floor; the CLI and the synthetic session writer."""

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.check import load_residuals
from calibration.wand import WandSpec, detect_wand_views, identify_linear_wand
from calibration.wandwave import calibrate_wand_wave
from spinemocap.bench.calibration_scenes import make_ring_rig, render_wand_calibration
from spinemocap.camera import Camera, Rig
from spinemocap.cli import main
from spinemocap.fileio import InputError


def _unposed(rig: Rig, focal_error: float = 0.0) -> Rig:
    """The rig's lenses without poses; ``focal_error``: relative focal error (alternating sign)
    plus a 1 px principal-point error, as per-camera board intrinsics leave them."""
    cams = []
    for k, c in enumerate(rig):
        K = c.K.copy()
        if focal_error:
            K[0, 0] *= 1 + focal_error * (-1) ** k
            K[1, 1] *= 1 + focal_error * (-1) ** k
            K[:2, 2] += 1.0
        cams.append(Camera(c.name, K, c.dist, np.eye(3), np.zeros(3), c.size))
    return Rig(cams)


@functools.lru_cache(maxsize=None)
def _wave(wand_text: str, seconds: float):
    wand = WandSpec.parse(wand_text)
    truth = make_ring_rig(6, size=(800, 600), seed=1)
    wave = render_wand_calibration(truth, wand, duration_s=seconds, seed=7)
    frames = ([wave.images[c.name][f] for c in truth] for f in range(len(wave.world_mm)))
    return truth, wave, detect_wand_views(frames, wand, progress=False)


@pytest.mark.parametrize("wand_text, seconds", [("t", 2.0), ("linear:600", 1.6)])
def test_wand_wave_alone_recovers_the_rig_and_its_scale(wand_text, seconds):
    truth, wave, views = _wave(wand_text, seconds)
    # board intrinsics 0.05 % and 1 px off: the wand wave's adjustment refines them
    result = calibrate_wand_wave(_unposed(truth, 5e-4), views, wave.wand, wave.floor_frames, progress=False)
    for true, est in zip(truth, result.rig):
        assert np.linalg.norm(est.center - true.center) < 2.0
        assert np.degrees(Rotation.from_matrix(est.R @ true.R.T).magnitude()) < 0.1
    # scale: camera-to-camera distances as in the truth (not only up to a factor)
    true_d = np.linalg.norm(truth[0].center - truth[3].center)
    assert abs(np.linalg.norm(result.rig[0].center - result.rig[3].center) / true_d - 1) < 5e-4
    assert len(result.length_error_mm) > 50
    assert result.length_rms_mm < 0.5
    assert all(r < 0.2 for r in result.rms_px.values())
    text = result.summary()
    assert "wand length" in text and "error RMS" in text


def test_bad_wands_and_floors():
    with pytest.raises(InputError, match="cannot parse wand"):
        WandSpec.parse("linear:")
    with pytest.raises(InputError, match="too near the middle"):
        WandSpec.parse("linear:300:600")
    wand = WandSpec.parse("linear:200:600")
    # three collinear blobs; the end nearer the middle marker is WAND1, in any blob order
    blobs = np.array([[500.0, 100.0], [100.0, 100.0], [300.0 * 2 / 3 + 100 / 3, 100.0]])
    ordered = identify_linear_wand(blobs, wand)
    assert np.allclose(ordered[0], [100, 100]) and np.allclose(ordered[2], [500, 100])
    truth, wave, views = _wave("linear:600", 1.6)
    with pytest.raises(InputError, match="lie on one line"):  # only the first placement: no plane
        calibrate_wand_wave(_unposed(truth), views, wave.wand, wave.floor_frames[:3], progress=False)


def test_synth_calibration_and_wand_wave_cli(tmp_path, capsys):
    out = tmp_path / "session"
    code = main(["synth-calibration", str(out), "--board", "checkerboard:4x7:120", "--wand", "t", "--cameras", "3",
                 "--size", "640", "--intrinsic-views", "2", "--frames", "5", "--wand-seconds", "1.6", "--seed", "2"])
    assert code == 0
    readme = capsys.readouterr().out
    assert "calibrate wand-wave" in readme and "calibrate extrinsics" in readme
    truth = Rig.from_toml(out / "rig_true.toml")
    assert len(list((out / "wand" / "cam1").glob("*.png"))) == 3 + 80
    assert len(list((out / "board" / "cam2").glob("*.png"))) == 5
    rig_out = tmp_path / "rig.toml"
    code = main(["calibrate", "wand-wave", "--intrinsics", str(out / "rig_true.toml"), "--videos",
                 *[str(out / "wand" / n) for n in truth.names], "--wand", "t", "--floor-frames", "0:3",
                 "--out", str(rig_out)])
    assert code == 0
    assert "wand length" in capsys.readouterr().out
    rig = Rig.from_toml(rig_out)
    for true, est in zip(truth, rig):
        assert np.linalg.norm(est.center - true.center) < 3.0
    assert (tmp_path / "rig.toml.wand_length.png").stat().st_size > 10_000
    assert (tmp_path / "rig.toml.residuals.png").stat().st_size > 10_000
    residuals = load_residuals(rig_out)
    assert residuals is not None and set(residuals) == set(truth.names)
    # the same session's checkerboard frames through `calibrate extrinsics`
    board_rig = tmp_path / "board.toml"
    code = main(["calibrate", "extrinsics", "--intrinsics", str(out / "rig_true.toml"), "--views",
                 *[str(out / "board" / n) for n in truth.names], "--board", "checkerboard:4x7:120",
                 "--floor-frames", "0", "1", "2", "--fixed-intrinsics", "--out", str(board_rig)])
    assert code == 0
    for true, est in zip(truth, Rig.from_toml(board_rig)):
        assert np.linalg.norm(est.center - true.center) < 10.0
    assert main(["synth-calibration", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
