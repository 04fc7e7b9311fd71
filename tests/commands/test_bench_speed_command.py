"""``spinemocap bench speed``: a capture to replay that is not there is an input error naming the
folder (exit status 2), before anything is rendered or tracked."""

from __future__ import annotations

from spinemocap.cli import main
from spinemocap.commands import bench_speed


def test_the_command_is_registered_under_bench(parse):
    args = parse("bench", "speed", "--preset", "tiny", "--frames", 3)
    assert args.func is bench_speed.run and (args.preset, args.frames, args.parallel) == ("tiny", 3, "threads")


def test_a_missing_capture_is_named(tmp_path, capsys):
    missing = tmp_path / "no_capture"
    assert main(["bench", "speed", "--capture", str(missing), "--frames", "2", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "capture folder not found" in err
    assert list(tmp_path.iterdir()) == []  # nothing written
