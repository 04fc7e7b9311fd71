"""The one frame-selection syntax (spinemocap.frames) and its users: the tracker's ``frames`` and
the calibration's ``--floor-frames``."""

from __future__ import annotations

import pytest

from spinemocap.app.run import select_frames
from spinemocap.fileio import InputError
from spinemocap.frames import parse_frames


@pytest.mark.parametrize("spec,n_frames,expected", [
    ("0:5", 10, [0, 1, 2, 3, 4]),
    (":3", 10, [0, 1, 2]),
    ("7:", 10, [7, 8, 9]),
    ("0:10:4", 10, [0, 4, 8]),
    ("0,5,9", 10, [0, 5, 9]),
    ("9, 0:2 ,5", 10, [0, 1, 5, 9]),  # ascending, spaces ignored
    ("0:4,2:6", 10, [0, 1, 2, 3, 4, 5]),  # overlaps counted once
    ("8:20", 10, [8, 9]),  # a slice is cut to the capture, as Python's are
    ("0:3,7", None, [0, 1, 2, 7]),  # the number of frames unknown
])
def test_selections(spec, n_frames, expected):
    assert parse_frames(spec, n_frames) == expected


@pytest.mark.parametrize("spec,n_frames,problem", [
    ("", 10, "empty frame selection"),
    ("0,,3", 10, "empty part"),
    ("0-9", 10, "cannot read '0-9'"),
    ("1:2:3:4", 10, "cannot read"),
    ("a:b", 10, "cannot read"),
    ("-1", 10, "negative frame"),
    ("0:10:0", 10, "step 0"),
    ("12", 10, "beyond the capture's 10 frames"),
    ("5:", None, "needs its end"),
    ("10:20", 10, "selects no frame of the 10"),
    ("4:2", 10, "selects no frame"),
])
def test_bad_selections_name_the_parameter(spec, n_frames, problem):
    with pytest.raises(InputError, match=problem) as caught:
        parse_frames(spec, n_frames, parameter="--floor-frames")
    assert caught.value.source == "--floor-frames"


def test_the_tracker_takes_consecutive_frames_only():
    assert select_frames(None, 6) == range(6)
    assert select_frames("2:4", 6) == range(2, 4)
    assert select_frames(range(1, 3), 6) == range(1, 3)
    for bad in ("0:6:2", "0,2", [0, 2]):
        with pytest.raises(InputError, match="consecutive frames") as caught:
            select_frames(bad, 6)
        assert caught.value.source == "frames"
    with pytest.raises(InputError, match="not all in the capture"):
        select_frames(range(4, 8), 6)


@pytest.mark.parametrize("sub,floor", [("wand-wave", ["0-9"]), ("extrinsics", ["0", "1-2"])])
def test_calibrate_floor_frames_use_the_syntax(sub, floor, tmp_path, capsys):
    from spinemocap.cli import main

    files = ["--videos" if sub == "wand-wave" else "--views", str(tmp_path / "v")]
    if sub == "extrinsics":
        files += ["--board", "checkerboard:4x7:60"]
    args = ["calibrate", sub, "--intrinsics", str(tmp_path / "a.toml"), *files, "--floor-frames", *floor,
            "--out", str(tmp_path / "rig.toml")]
    assert main(args) == 2  # checked before any file is read
    assert "--floor-frames: cannot read" in capsys.readouterr().err
