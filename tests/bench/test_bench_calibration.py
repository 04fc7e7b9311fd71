"""The calibration benchmarks' scenes and scores: a ring of cameras looking at the volume, a
studio rig with turned cameras, rig errors that are zero for the truth and the displacement of a
moved camera."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.bench.board_session import make_studio_rig, score_rig
from spinemocap.bench.calibration import rig_errors
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
    assert all(abs(v) < 1e-9 for v in rig_errors(truth, truth).values())
    moved = make_ring_rig(4, size=(640, 480), seed=1)
    moved[2].t[:] = moved[2].t + moved[2].R @ np.array([3.0, 0.0, 0.0])  # centre moved 3 mm
    errors = rig_errors(truth, moved)
    assert errors["centre_mm"] == pytest.approx(3.0, rel=1e-6) and errors["rotation_deg"] < 1e-9


def test_the_studio_session_rig_turns_the_cameras_it_names():
    rig = make_studio_rig(4, size=(640, 360), turned=(1, 3))
    sizes = [tuple(cam.size) for cam in rig]
    assert sizes[0] == (640, 360) and sizes[1] == (360, 640) and sizes[3] == (360, 640)
    assert score_rig(rig, rig).worst_centre_mm == pytest.approx(0.0, abs=1e-9)
    shifted = make_studio_rig(4, size=(640, 360), turned=(1, 3))
    shifted[0].t[:] = shifted[0].t + shifted[0].R @ np.array([0.0, 0.0, 5.0])
    score = score_rig(shifted, rig)  # one camera 5 mm off: the rigid fit of the centres spreads it
    assert 0.5 < score.worst_centre_mm < 5.0 and score.comparison.worst_baseline_error > 0
