"""``spinemocap detector run``: dots of a capture's frames written per camera image with an
overlay; a folder that is not a capture refused naming it."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.commands import detector as detector_command
from spinemocap.fileio import InputError


def test_run_on_one_frame_of_a_capture_writes_dots_and_overlays(tiny_capture, parse, tmp_path, capsys):
    out = tmp_path / "dots"
    args = parse("detector", "run", tiny_capture, "--name", "classical", "--frames", "1", "--out", out)
    assert detector_command._run(args) == 0
    tables = sorted(out.glob("*_dots.csv"))
    assert len(tables) == 3 and len(list(out.glob("*_overlay.png"))) == 3
    printed = capsys.readouterr().out
    for table in tables:
        dots = np.loadtxt(table, delimiter=",", skiprows=1, ndmin=2)
        assert len(dots) > 10 and ((dots[:, :2] >= 0) & (dots[:, :2] < [480, 360])).all()
        assert f"{table.name.removesuffix('_dots.csv')}: {len(dots)} dots" in printed


def test_a_folder_that_is_not_a_capture_is_refused(parse, tmp_path):
    with pytest.raises(InputError, match="must be a capture"):
        detector_command._run(parse("detector", "run", tmp_path, "--name", "classical"))
