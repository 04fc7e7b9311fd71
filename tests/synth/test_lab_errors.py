"""A lab's set-up errors in the studio: each camera of the written rig reprojects the true dots
with exactly the requested RMS, and the clock offsets are zero-mean with exactly the requested RMS."""

from __future__ import annotations

import numpy as np
import pytest
from tape_scenes import SPEC, rig_behind, tape_on_back

from spinemocap.synth.lab_errors import clock_offsets_s, perturb_rig, reprojection_rms_px


@pytest.mark.parametrize("target_px", [0.5, 2.0])
def test_each_camera_reprojects_the_dots_with_the_requested_rms(target_px):
    rig, dots = rig_behind(4), tape_on_back(SPEC)
    perturbed, reached = perturb_rig(rig, dots, target_px, np.random.default_rng(5))
    np.testing.assert_allclose(reached, target_px, rtol=1e-6)
    for true, written in zip(rig, perturbed):
        assert reprojection_rms_px(true, written, dots) == pytest.approx(target_px, rel=1e-6)
        assert not np.allclose(true.R, written.R) and not np.allclose(true.center, written.center)
        assert reprojection_rms_px(true, true, dots) == 0.0


def test_no_calibration_error_keeps_the_rig():
    rig = rig_behind(3)
    same, reached = perturb_rig(rig, tape_on_back(SPEC), 0.0, np.random.default_rng(0))
    assert same is rig and (reached == 0).all()


def test_clock_offsets_are_zero_mean_with_the_requested_rms():
    offsets = clock_offsets_s(6, 3.0, np.random.default_rng(2))
    assert offsets.mean() == pytest.approx(0.0, abs=1e-15)
    assert np.sqrt(np.mean(offsets**2)) == pytest.approx(0.003, rel=1e-12)
    assert (clock_offsets_s(1, 3.0, np.random.default_rng(2)) == 0).all()
    assert (clock_offsets_s(4, 0.0, np.random.default_rng(2)) == 0).all()
