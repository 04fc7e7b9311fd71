"""``spinemocap view --no-video``: the 3D viewer of the tracked frames; a selection outside the
capture refused naming the flag."""

from __future__ import annotations

import pytest

from spinemocap.cli import main
from spinemocap.commands import view as view_command
from spinemocap.fileio import InputError


def test_the_viewer_alone_is_written_where_asked(tiny_capture, tracked, parse, tmp_path, capsys):
    out = tmp_path / "view"
    assert view_command.run_view(parse("view", tiny_capture, tracked, "--no-video", "--frames", "0:3:2", "--out", out)) == 0
    page = out / "tape3d.html"
    assert page.is_file() and "3D viewer" in capsys.readouterr().out
    assert not list(out.glob("*.mp4"))
    assert view_command.default_out(tracked) == tracked / "view"


def test_frames_outside_the_capture_are_refused_by_the_flag(tiny_capture, tracked, parse, tmp_path, capsys):
    with pytest.raises(InputError, match="frames: frame selection '5:9' selects no frame of the 3"):
        view_command.run_view(parse("view", tiny_capture, tracked, "--no-video", "--frames", "5:9", "--out", tmp_path))
    assert main(["view", str(tiny_capture), str(tracked), "--no-video", "--frames", "5:9", "--out", str(tmp_path)]) == 2
    assert "error: --frames: frame selection '5:9' selects no frame of the 3" in capsys.readouterr().err
