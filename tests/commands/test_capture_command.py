"""``spinemocap capture init``: a capture folder from image folders and a rig, read back by the
tracker's reader; impossible offsets and pairs refused by name."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from spinemocap.capture import Capture
from spinemocap.commands import capture as capture_command
from spinemocap.fileio import InputError


def test_init_from_image_folders_reads_back_the_same_images(tiny_capture, parse, tmp_path, capsys):
    folders = sorted((tiny_capture / "images").iterdir())
    out = tmp_path / "imported"
    args = parse("capture", "init", out, "--images", *folders, "--calibration", tiny_capture / "rig.toml",
                 "--fps", "25", "--subject", "S07")
    assert capture_command.run_init(args) == 0
    assert "capture written" in capsys.readouterr().out
    imported, original = Capture.open(out), Capture.open(tiny_capture)
    assert imported.camera_names == original.camera_names and imported.n_frames == 3 and imported.fps == 25.0
    for a, b in zip(imported.frame_source().read(1), original.frame_source().read(1)):
        np.testing.assert_array_equal(a, b)


def test_offsets_and_pairs_are_checked():
    assert capture_command._offsets([("cam2", "-0.2s"), ("cam3", "0.05")]) == {"cam2": -0.2, "cam3": 0.05}
    with pytest.raises(InputError, match="--offset.*cam2=soon"):
        capture_command._offsets([("cam2", "soon")])
    assert capture_command._pair("cam1=a.mp4") == ("cam1", "a.mp4")
    with pytest.raises(argparse.ArgumentTypeError, match="CAMERA=VALUE"):
        capture_command._pair("cam1")
