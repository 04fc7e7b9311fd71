"""``spinemocap synth``: a capture the tracker reads, its summary on screen; bad sizes and
numbers refused by the parser, a negative wand wave by name."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from spinemocap.capture import Capture
from spinemocap.commands import synth as synth_command
from spinemocap.fileio import InputError


def test_synth_writes_a_capture_with_masks_and_ground_truth(tiny_capture):
    capture = Capture.open(tiny_capture)
    assert capture.n_frames == 3 and len(capture.camera_names) == 3 and capture.has_groundtruth
    assert len(list((tiny_capture / "masks").rglob("*.png"))) == 9
    images = capture.frame_source().read(2)
    assert all(image is not None and image.shape[:2] == (360, 480) for image in images)
    truth = capture.groundtruth()
    assert np.isfinite(np.asarray(truth["dots"])).all()


def test_sizes_and_per_camera_numbers_are_checked_by_the_parser(parse):
    assert synth_command._size("1024X768") == (1024, 768)
    assert synth_command._numbers("1,2.5") == (1.0, 2.5)
    with pytest.raises(argparse.ArgumentTypeError, match="1024x768"):
        synth_command._size("1024by768")
    with pytest.raises(argparse.ArgumentTypeError, match="one per camera"):
        synth_command._numbers("1,x")
    with pytest.raises(SystemExit):
        parse("synth", "out", "--size", "big")


def test_a_negative_wand_wave_is_refused_by_its_flag(parse, tmp_path):
    with pytest.raises(InputError, match="--wand-seconds.*must be positive"):
        synth_command.run_synth(parse("synth", tmp_path / "x", "--wand-seconds", "-1"))
    assert not (tmp_path / "x").exists()
