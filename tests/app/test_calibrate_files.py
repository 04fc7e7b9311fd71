"""A board calibration's files: the rig, its residuals, the residual plot and the 3D picture,
written where asked and read back as what was calibrated."""

from __future__ import annotations

import cv2
import numpy as np

from calibration.boards import BoardSpec
from calibration.check import load_residuals
from calibration.formats import read_rig
from spinemocap.app.calibrate import calibrate_recordings, write_calibration
from spinemocap.bench.calibration_scenes import make_ring_rig, render_board_capture
from spinemocap.camera import Camera, Rig

BOARD = BoardSpec.parse("charuco:6x5:120")


def test_the_calibration_files_hold_the_calibrated_rig(tmp_path):
    truth = make_ring_rig(3, size=(800, 600), seed=2)
    capture = render_board_capture(truth, BOARD, 6, seed=4, n_floor=1)
    for cam in truth:
        (tmp_path / cam.name).mkdir()
        for f, image in enumerate(capture.images[cam.name]):
            cv2.imwrite(str(tmp_path / cam.name / f"{f:03d}.png"), image)
    lenses = Rig([Camera(c.name, c.K, c.dist, np.eye(3), np.zeros(3), c.size) for c in truth])
    calibrated = calibrate_recordings([tmp_path / c.name for c in truth], BOARD, lenses, floor_frames=[0],
                                      refine_intrinsics=False, progress=False)
    out = tmp_path / "out" / "rig.toml"
    out.parent.mkdir()
    files = write_calibration(calibrated, out)
    assert (files.rig, files.residual_plot, files.rig_3d) == (str(out), f"{out}.residuals.png", f"{out}.rig3d.png")
    written = Rig.from_toml(out)
    for ours, read in zip(calibrated.result.rig, written):
        np.testing.assert_allclose(read.center, ours.center, atol=1e-6)
    residuals = load_residuals(out)
    assert residuals is not None and set(residuals) == set(calibrated.result.residuals)
    assert all((tmp_path / "out" / name).stat().st_size > 10_000 for name in ("rig.toml.residuals.png", "rig.toml.rig3d.png"))
    elsewhere = write_calibration(calibrated, tmp_path / "pose2sim.toml", "pose2sim", tmp_path / "plot.png")
    assert elsewhere.residual_plot == str(tmp_path / "plot.png") and (tmp_path / "plot.png").is_file()
    assert "cam_01" in (tmp_path / "pose2sim.toml").read_text()  # Pose2Sim's flavour, cameras as its sections
    assert [c.name for c in read_rig(tmp_path / "pose2sim.toml")] == [c.name for c in truth]
