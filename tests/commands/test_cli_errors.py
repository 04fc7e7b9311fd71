"""Errors of the library name the parameter; the command line names its flag instead."""

from __future__ import annotations

import pytest

from calibration.boards import BoardSpec
from calibration.extrinsics import bundle_adjust
from calibration.wand import WandSpec
from spinemocap.cli import build_parser, flag_of, invoked_parsers, main
from spinemocap.fileio import InputError


def test_the_library_names_the_parameter():
    with pytest.raises(InputError) as board:
        BoardSpec.parse("hexagon:3")
    with pytest.raises(InputError) as wand:
        WandSpec.parse("zigzag")
    with pytest.raises(InputError) as backend:
        bundle_adjust(None, None, {}, [], {}, backend="gauss")  # type: ignore[arg-type]  # checked first
    assert (board.value.source, wand.value.source, backend.value.source) == ("board", "wand", "backend")
    assert "--" not in str(board.value) + str(wand.value) + str(backend.value)


def test_parameters_map_to_the_invoked_commands_flags():
    parser = build_parser()
    args = parser.parse_args(["calibrate", "wand-wave", "--intrinsics", "a.toml", "--videos", "v0", "v1", "--out", "r.toml"])
    parsers = invoked_parsers(parser, args)
    assert [p.prog for p in parsers][-1].endswith("calibrate wand-wave")
    assert flag_of("wand", parsers) == "--wand"
    assert flag_of("floor_frames", parsers) == "--floor-frames"
    assert flag_of("backend", parsers) == "--ba"
    assert flag_of("sources", parsers) == "--videos"
    assert flag_of("board", parsers) is None  # not an option of this command: the library's wording stays


def test_the_cli_prints_the_flag(tmp_path, capsys):
    assert main(["calibrate", "extrinsics", "--intrinsics", str(tmp_path / "a.toml"), "--views", str(tmp_path),
                 "--board", "hexagon:3", "--out", str(tmp_path / "rig.toml")]) == 2
    err = capsys.readouterr().err
    assert "error: --board: cannot parse board 'hexagon:3'" in err
