"""The calibration benchmarks' scenes and scores: a ring of cameras looking at the volume, a
studio rig with turned cameras, rig errors that are zero for the truth and the displacement of a
moved camera."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.bench.board_session import make_studio_rig, score_rig
from spinemocap.bench.calibration import AdjustedRig, BoardRow, RigErrors, WandWaveRow, headline, rig_errors
from spinemocap.bench.calibration_scenes import make_ring_rig


def test_the_ring_looks_at_its_target_from_its_radius():
    target = np.array([360.0, -240.0, 700.0])
    rig = make_ring_rig(6, size=(800, 600), seed=0, target_mm=target)
    assert len(rig) == 6
    for cam in rig:
        uv = cam.project(target[None])[0]
        assert np.abs(uv - [400, 300]).max() < 10  # the target at the image centre (principal point +- 8 px)
        assert np.linalg.norm(cam.center[:2] - target[:2]) == pytest.approx(2400.0)


def test_rig_errors_are_zero_for_the_truth_and_the_displacement_of_a_moved_camera():
    truth = make_ring_rig(4, size=(640, 480), seed=1)
    assert all(abs(v) < 1e-9 for v in rig_errors(truth, truth).to_dict().values())
    moved = make_ring_rig(4, size=(640, 480), seed=1)
    moved[2].t[:] = moved[2].t + moved[2].R @ np.array([3.0, 0.0, 0.0])  # centre moved 3 mm
    errors = rig_errors(truth, moved)
    assert errors.centre_mm == pytest.approx(3.0, rel=1e-6) and errors.rotation_deg < 1e-9


def test_the_studio_session_rig_turns_the_cameras_it_names():
    rig = make_studio_rig(4, size=(640, 360), turned=(1, 3))
    sizes = [tuple(cam.size) for cam in rig]
    assert sizes[0] == (640, 360) and sizes[1] == (360, 640) and sizes[3] == (360, 640)
    assert score_rig(rig, rig).worst_centre_mm == pytest.approx(0.0, abs=1e-9)
    shifted = make_studio_rig(4, size=(640, 360), turned=(1, 3))
    shifted[0].t[:] = shifted[0].t + shifted[0].R @ np.array([0.0, 0.0, 5.0])
    score = score_rig(shifted, rig)  # one camera 5 mm off: the rigid fit of the centres spreads it
    assert 0.5 < score.worst_centre_mm < 5.0 and score.comparison.worst_baseline_error > 0
    written = score.to_dict()
    assert list(written) == ["centre_error_mm", "rotation_error_deg", "worst_baseline_error", "worst_rotation_diff_deg"]
    assert written["centre_error_mm"] == score.centre_error_mm
    assert written["worst_baseline_error"] == score.comparison.worst_baseline_error


def _board(seed: int, ceres_mm: float, scipy_s: float) -> BoardRow:
    def adjusted(mm: float, seconds: float) -> AdjustedRig:
        return AdjustedRig(RigErrors(0.1, mm, 0.05), seconds, seconds / 2, 0.2, 0.3, 0)

    return BoardRow("charuco:6x5:120", seed, [640, 480], 20, 16, RigErrors(0.2, 9.0, 0.4),
                    {"render": 1.0, "detect_intrinsics": 2.0},
                    {"ceres": adjusted(ceres_mm, 2.0), "scipy": adjusted(ceres_mm + 1, scipy_s)})


def test_the_rows_write_their_json_keys_in_order_and_the_headline_takes_the_worst_seed():
    boards = [_board(0, 1.0, 10.0), _board(1, 1.5, 30.0)]
    row = boards[0].to_dict()
    assert list(row) == ["board", "seed", "size", "intrinsic_views", "frames", "peer_no_ba", "seconds",
                         "ba_ceres", "ba_scipy", "ours_ba"]
    assert row["ours_ba"] == row["ba_ceres"] == {"focal_pct": 0.1, "centre_mm": 1.0, "rotation_deg": 0.05,
                                                 "seconds": 2.0, "cpu_seconds": 1.0, "rms_px": 0.2,
                                                 "board_rms_mm": 0.3, "views_left_out": 0}
    wave = WandWaveRow("t", 0, 200, "ChArUco session's", RigErrors(0.0, 2.0, 0.06), 0.4, 1.2, 0.3,
                       RigErrors(0.0, 1.0, 0.03), 0.2, {"render": 1.0})
    assert list(wave.to_dict())[4:7] == ["focal_pct", "centre_mm", "rotation_deg"]
    assert wave.to_dict()["true_intrinsics"] == {"focal_pct": 0.0, "centre_mm": 1.0, "rotation_deg": 0.03,
                                                 "length_rms_mm": 0.2}
    worst = headline(boards, [boards[1]], [wave])
    assert worst.charuco_centre_error_mm == 1.5 and worst.ba_centre_error_mm_scipy == 2.5
    assert worst.ba_speedup_ceres_vs_scipy == 15.0 and worst.wandwave_centre_error_mm == 2.0
    assert worst.goals == {"checkerboard_within_1.5x_charuco": True, "wandwave_within_1.5x_charuco": True,
                           "wand_length_rms_le_0.5mm": True, "ba_le_3s": True}
    assert list(worst.to_dict())[-2:] == ["ba_speedup_ceres_vs_scipy", "goals"]
