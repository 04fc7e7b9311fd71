"""Errors of the library name the parameter; the command line names its flag instead."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from calibration.boards import BoardSpec
from calibration.extrinsics import bundle_adjust
from calibration.wand import WandSpec
from spinemocap.cli import build_parser, main, plain_warning
from spinemocap.commands._flags import FlagNames, flag_of, invoked_parsers, show_flags_of, shown, with_flags
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


def test_parameters_named_in_a_problem_become_the_commands_flags():
    parser = build_parser()
    init = invoked_parsers(parser, parser.parse_args(["capture", "init", "out", "--videos", "v", "--calibration", "r"]))
    speed = invoked_parsers(parser, parser.parse_args(["bench", "speed"]))
    rendered = with_flags("`fix_size=crop` does not fit; pass `force=True`; name it with `mapping` or `named`; "
                          "give it with `fps`; `method='motion'`", init)
    assert rendered == ("--fix-size crop does not fit; pass --force; name it with --map or --video; "
                        "give it with --fps; `method='motion'`")  # no --method in capture init: the library's words
    assert with_flags("turn prediction off (`frames_at_once=N` or `predict=False`)", speed) == \
        "turn prediction off (--frames-at-once N or --no-predict)"


def test_the_application_names_parameters_and_the_cli_their_flags(tmp_path, capsys):
    from spinemocap.app.capture_init import init_capture
    from spinemocap.app.streaming import SpeedOptions

    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "capture.toml").write_text("")
    with pytest.raises(InputError) as existing:
        init_capture(tmp_path / "cap", tmp_path / "rig.toml", media=[])
    with pytest.raises(InputError) as predicted:
        SpeedOptions(frames_at_once=2)
    assert "`force=True`" in existing.value.problem and predicted.value.source == "frames_at_once"
    assert "--" not in str(existing.value) + str(predicted.value)

    assert main(["capture", "init", str(tmp_path / "cap"), "--videos", "v.mp4", "--calibration", "r.toml"]) == 2
    assert "choose a new folder or pass --force to replace it" in capsys.readouterr().err
    assert main(["bench", "speed", "--preset", "tiny", "--candidate-workers", "1"]) == 2
    assert "error: --candidate-workers: the candidate workers build frames ahead of the tracker, which prediction " \
           "cannot wait for: turn prediction off (--frames-at-once N or --no-predict)" in capsys.readouterr().err
    assert shown("`predict=False`") == "`predict=False`"  # after the command: the library's words again


def _parsers(*argv: str):
    parser = build_parser()
    return invoked_parsers(parser, parser.parse_args(list(argv)))


def test_texts_the_application_prints_or_logs_name_parameters_and_read_as_flags():
    from spinemocap.app.sync import SyncEstimate, format_estimate

    estimate = SyncEstimate(("cam1", "cam2"), np.array([0.0, 0.01]), np.array([0.0, 0.005]), "motion")
    table = format_estimate(estimate)
    assert "try more `seconds`, or `method='audio'` with a clap" in table and "--" not in table
    assert "try more --seconds, or --method audio with a clap" in with_flags(table, _parsers("capture", "sync", "c"))
    synth = _parsers("synth", "out", "--vicon")
    assert with_flags("(e.g. `preset=artificial` or `preset=studio`) or `wand_seconds=0`", synth) == \
        "(e.g. --preset artificial or --preset studio) or --wand-seconds 0"
    assert flag_of("methods", _parsers("bench", "opensim")) == "--methods"
    assert flag_of("fix_size", _parsers("capture", "init", "o", "--videos", "v", "--calibration", "r")) == "--fix-size"


class Collected(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def test_the_running_command_renders_printed_and_logged_texts():
    show_flags_of([])
    assert shown("try more `seconds`") == "try more `seconds`"  # no command running: the library's words
    handler = Collected()
    handler.addFilter(FlagNames())
    logger = logging.getLogger("spinemocap.test_flags")
    logger.addHandler(handler)
    try:
        show_flags_of(_parsers("capture", "sync", "c"))
        assert shown("try more `seconds`") == "try more --seconds"
        logger.warning("only %d %% seen: use `method='audio'`", 40)
        assert handler.messages == ["only 40 % seen: use --method audio"]
        show_flags_of(_parsers("bench", "speed"))
        assert plain_warning("turn `predict=False`", UserWarning, "x.py", 1) == "spinemocap: warning: turn --no-predict\n"
    finally:
        logger.removeHandler(handler)
        show_flags_of([])
