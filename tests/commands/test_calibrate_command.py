"""``spinemocap calibrate convert`` and ``check``: a rig converted to Pose2Sim and Vicon and back
agrees with itself; a rig moved agrees no more (exit 1); the residuals' absence is said."""

from __future__ import annotations

import pytest

from calibration.formats import read_rig, write_rig
from spinemocap.bench.calibration_scenes import make_ring_rig
from spinemocap.commands import calibrate as calibrate_command
from spinemocap.fileio import InputError


def test_convert_and_check_against_the_original(parse, tmp_path, capsys):
    rig = make_ring_rig(4, size=(640, 480), seed=2)
    write_rig(rig, tmp_path / "rig.toml")
    for target, flavour in (("pose2sim.toml", ["--format", "pose2sim"]), ("rig.xcp", [])):
        assert calibrate_command._convert(parse("calibrate", "convert", tmp_path / "rig.toml", tmp_path / target,
                                                *flavour)) == 0
        assert "converted 4 cameras" in capsys.readouterr().out
        check = parse("calibrate", "check", tmp_path / target, "--against", tmp_path / "rig.toml")
        assert calibrate_command._check(check) == 0
    assert len(read_rig(tmp_path / "rig.xcp")) == 4
    moved = read_rig(tmp_path / "rig.toml")
    moved[1].t[0] += 100.0  # one camera 10 cm off: the baselines it spans change by more than 2 %
    write_rig(moved, tmp_path / "moved.toml")
    assert calibrate_command._check(parse("calibrate", "check", tmp_path / "moved.toml", "--against",
                                          tmp_path / "rig.toml")) == 1


def test_check_without_residuals_prints_the_cameras_and_says_how_to_measure(parse, tmp_path, capsys):
    write_rig(make_ring_rig(2, size=(640, 480), seed=0), tmp_path / "rig.toml")
    assert calibrate_command._check(parse("calibrate", "check", tmp_path / "rig.toml")) == 0
    assert "no reprojection residuals" in capsys.readouterr().out
    with pytest.raises(InputError, match="--views.*--board is needed"):
        calibrate_command._check(parse("calibrate", "check", tmp_path / "rig.toml", "--views", tmp_path))
