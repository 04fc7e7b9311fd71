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
