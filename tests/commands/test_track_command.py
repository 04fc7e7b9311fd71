"""``spinemocap track``: labelled markers of every frame with the accuracy printed for a synthetic
capture; options that need another refused by name before any work."""

from __future__ import annotations

import re

import pytest

from spinemocap.app.results import read_results
from spinemocap.commands import track as track_command
from spinemocap.fileio import InputError


def test_track_writes_every_frame_and_prints_its_accuracy(tiny_capture, tracked, parse, tmp_path, capsys):
    table = read_results(tracked)
    assert table.n_frames == 3 and {"markers.csv", "markers.trc", "markers.c3d"} <= {p.name for p in tracked.iterdir()}
    summary = track_command.accuracy_summary(table, tiny_capture)
    mean = float(re.search(r"mean ([\d.]+) mm", summary).group(1))
    assert mean < 2.0 and "label swaps 0" in summary
    # two frames of the three, as the flag's syntax says
    assert track_command.run_track(parse("-q", "track", tiny_capture, "--out", tmp_path / "two", "--detector", "mask",
                                         "--frames", "1:3", "--no-progress")) == 0
    out = capsys.readouterr().out
    assert "tracked 2 frames" in out and "accuracy vs ground truth" in out
    assert read_results(tmp_path / "two").n_frames == 2


@pytest.mark.parametrize("flags, named", [
    (["--refine-sync"], "--refine-sync"),
    (["--reference", "ref.toml"], "--reference"),
    (["--chunk-frames", "2", "--refine-rig"], "--chunk-frames"),
])
def test_options_that_need_another_are_refused_by_name(flags, named, tiny_capture, parse, tmp_path):
    with pytest.raises(InputError, match=named):
        track_command.run_track(parse("track", tiny_capture, "--out", tmp_path / "out", *flags))
    assert not (tmp_path / "out" / "markers.csv").exists()
