"""Intrinsics from rendered board views (exact planar renders with a known camera) and from the
real Pose2Sim demo photos; view rejection and bad-input errors."""


import cv2
import numpy as np
import pytest
from repo_paths import SHARED

from calibration.boards import BoardSpec, detect_board, view_problem
from calibration.formats.qualisys import read_qca
from calibration.intrinsics import calibrate_intrinsics, iter_images
from spinemocap.bench.calibration_scenes import make_ring_rig, render_intrinsic_views
from spinemocap.cli import main
from spinemocap.fileio import InputError

DEMO = SHARED / "data" / "calibration" / "pose2sim_demo"


@pytest.fixture(scope="module")
def camera():
    return make_ring_rig(1, size=(1024, 768), seed=3)[0]


@pytest.mark.parametrize("board_text", ["charuco:6x5:120", "checkerboard:7x5:100"])
def test_synthetic_intrinsics_recover_focal(camera, board_text):
    board = BoardSpec.parse(board_text)
    images = render_intrinsic_views(camera, board, 14, seed=11)
    result = calibrate_intrinsics(((f"v{i}", im) for i, im in enumerate(images)), board, "c", progress=False)
    assert len(result.views) >= 12
    assert result.rms_px < 0.2
    assert abs(result.camera.K[0, 0] / camera.K[0, 0] - 1) < 0.002
    assert abs(result.camera.K[1, 1] / camera.K[1, 1] - 1) < 0.002
    assert np.max(np.abs(result.camera.K[:2, 2] - camera.K[:2, 2])) < 3.0
    assert 0 < result.coverage <= 1
    assert all(v.rms_px < 0.3 for v in result.views)


def test_blurred_and_missing_views_are_rejected(camera):
    board = BoardSpec.parse("charuco:6x5:120")
    sharp = render_intrinsic_views(camera, board, 1, seed=4)[0]
    blurred = cv2.GaussianBlur(sharp, (0, 0), 4.0)
    det = detect_board(sharp, board)
    assert view_problem(det, board, camera.size) is None
    det_blur = detect_board(blurred, board)
    assert det_blur is None or "blurred" in view_problem(det_blur, board, camera.size)
    empty = np.full_like(sharp, 90)
    assert view_problem(detect_board(empty, board), board, camera.size) == "board not found"


def test_too_few_views_and_mixed_sizes(camera, tmp_path, capsys):
    board = BoardSpec.parse("charuco:6x5:120")
    images = render_intrinsic_views(camera, board, 3, seed=5)
    with pytest.raises(InputError, match="only 3 usable board views.*Capture again"):
        calibrate_intrinsics(((f"v{i}", im) for i, im in enumerate(images)), board, progress=False)
    for i, im in enumerate(images):
        cv2.imwrite(str(tmp_path / f"{i}.png"), im)
    cv2.imwrite(str(tmp_path / "9.png"), cv2.resize(images[0], (512, 384)))
    code = main(["calibrate", "intrinsics", str(tmp_path), "--board", "charuco:6x5:120", "--out", str(tmp_path / "o.toml")])
    assert code == 2
    assert "calibrate each camera/resolution separately" in capsys.readouterr().err
    assert not (tmp_path / "o.toml").exists()
    with pytest.raises(InputError, match="cannot parse board"):
        BoardSpec.parse("charuco:6x5")


def test_real_checkerboard_photos_match_qualisys():
    if not (DEMO / "cam01").is_dir():
        pytest.skip("shared calibration data not present")
    board = BoardSpec.parse("checkerboard:4x7:60")
    reference = read_qca(DEMO / "Calib.qca.txt")
    for name in ("cam01", "cam02"):
        result = calibrate_intrinsics(iter_images(DEMO / name), board, name, progress=False)
        assert result.rms_px < 1.0
        assert result.camera.size == (1088, 1920)
        f_ref = reference[name].K[0, 0]
        assert abs(result.camera.K[0, 0] / f_ref - 1) < 0.01, (result.camera.K[0, 0], f_ref)
        # the distortion agrees with the file's raw (not /64) coefficients
        assert abs(result.camera.dist[0] - reference[name].dist[0]) < 0.01


def test_intrinsics_cli_writes_rig(camera, tmp_path, capsys):
    board = BoardSpec.parse("charuco:6x5:120")
    for i, im in enumerate(render_intrinsic_views(camera, board, 6, seed=6)):
        cv2.imwrite(str(tmp_path / f"{i:02d}.png"), im)
    out = tmp_path / "cam.toml"
    assert main(["calibrate", "intrinsics", str(tmp_path), "--board", "charuco:6x5:120", "--out", str(out),
                 "--name", "camA"]) == 0
    text = capsys.readouterr().out
    assert "RMS" in text and "coverage" in text
    from spinemocap.camera import Rig

    rig = Rig.from_toml(out)
    assert rig.names == ["camA"]
    assert abs(rig[0].K[0, 0] / camera.K[0, 0] - 1) < 0.01


def test_intrinsics_from_a_video(camera, tmp_path):
    board = BoardSpec.parse("charuco:6x5:120")
    images = render_intrinsic_views(camera, board, 6, seed=8)
    path = tmp_path / "board.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, camera.size)
    assert writer.isOpened()
    for image in images:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    frames = list(iter_images(path, max_video_frames=4))
    assert [name for name, _ in frames] == ["board.avi#0", "board.avi#2", "board.avi#3", "board.avi#5"]
    result = calibrate_intrinsics(iter_images(path), board, progress=False)
    assert len(result.views) == 6
    assert abs(result.camera.K[0, 0] / camera.K[0, 0] - 1) < 0.01
