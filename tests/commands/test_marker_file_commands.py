"""``spinemocap crossval``, ``bodyfit`` and ``opensim`` refuse a marker file that is not there
naming it, before any work or output."""

from __future__ import annotations

import pytest

from spinemocap.commands import bodyfit as bodyfit_command
from spinemocap.commands import crossval as crossval_command
from spinemocap.commands import opensim as opensim_command
from spinemocap.fileio import InputError


def test_crossval_refuses_missing_tracked_dots(parse, tiny_capture, tmp_path):
    args = parse("crossval", tmp_path / "tracked.c3d", tmp_path / "vicon.c3d", "--capture", tiny_capture,
                 "--out", tmp_path / "out")
    with pytest.raises(InputError, match="tracked.c3d"):
        crossval_command.run_crossval(args)
    assert not (tmp_path / "out").exists()


def test_bodyfit_refuses_a_missing_marker_file(parse, tmp_path):
    with pytest.raises(InputError, match="walk.c3d"):
        bodyfit_command.run_bodyfit(parse("bodyfit", tmp_path / "walk.c3d", "--out", tmp_path / "out", "--no-progress"))
    assert not (tmp_path / "out" / "summary.json").exists()


def test_opensim_refuses_missing_results(parse, tiny_capture, tmp_path):
    pytest.importorskip("opensim")
    with pytest.raises(InputError, match="no-results"):
        opensim_command.run_opensim_command(parse("opensim", tmp_path / "no-results", "--capture", tiny_capture,
                                                  "--out", tmp_path / "out"))
