"""``spinemocap bench ...`` commands refuse impossible settings by name before any rendering, and
``bench view`` times a small made capture end to end (one JSON line per run)."""

from __future__ import annotations

import json

import pytest

from spinemocap.commands import (
    bench_detect,
    bench_gauge,
    bench_long_capture,
    bench_realism,
    bench_sync,
    bench_track,
    bench_vicon_wand,
    bench_view,
)
from spinemocap.fileio import InputError


def test_bench_view_times_a_made_capture(parse, capsys):
    args = parse("bench", "view", "--made", "96x64x2", "--frames", "3", "--repeat", "1", "--scale", "1")
    assert args.func is bench_view.run and bench_view.run(args) == 0
    (line,) = capsys.readouterr().out.strip().splitlines()
    run = json.loads(line)
    assert run["capture"] == "96x64x2" and run["frames"] == 3 and run["cameras"] == 2
    assert run["frames_per_cpu_s"] > 0 and run["video_MiB"] > 0


@pytest.mark.parametrize("argv, named", [
    (["bench", "view"], "--capture"),
    (["bench", "gauge", "--json", "g.json", "--rigs", "0"], "bench gauge"),
    (["bench", "gauge", "--json", "g.json", "--levels", "25"], "bench gauge"),
    (["bench", "realism", "--json", "r.json", "--cases", "no such case"], "--cases"),
    (["bench", "sync", "--scenarios", "nope", "--out", "s"], "--scenarios"),
    (["bench", "track", "--config", "missing.toml"], "missing.toml"),
    (["bench", "track", "--weights", "missing.pt"], "missing.pt"),
    (["bench", "realism", "--json", "r.json", "--weights", "missing.pt"], "missing.pt"),
    (["bench", "vicon-wand", "--frames", "0"], "bench vicon-wand"),
    (["bench", "long-capture", "no-base", "out"], "no-base"),
])
def test_impossible_settings_are_refused_by_name(argv, named, parse, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = parse(*argv)
    assert args.func in {bench_view.run, bench_gauge.run, bench_realism.run, bench_sync.run, bench_track.run,
                         bench_vicon_wand.run, bench_long_capture.run}
    with pytest.raises(InputError, match=named):
        args.func(args)
    assert not any(tmp_path.iterdir())  # nothing written


def test_bench_detect_refuses_missing_weights_before_rendering(parse, tmp_path):
    args = parse("bench", "detect", "--json", tmp_path / "d.json", "--sets", "tiny", "--weights", tmp_path / "w.pt")
    with pytest.raises(InputError, match="w.pt"):
        bench_detect.run(args)
    assert not (tmp_path / "d.json").exists()


def test_bench_adapt_needs_its_work_folder_and_results_file(parse, capsys):
    from spinemocap.commands import bench_adapt

    args = parse("bench", "adapt", "--work", "w", "--json", "a.json", "--frames", 12, "--epochs", 2)
    assert args.func is bench_adapt.run and (args.frames, args.epochs, args.steps) == (12, 2, 30)
    with pytest.raises(SystemExit) as exit_:
        parse("bench", "adapt", "--work", "w")
    assert exit_.value.code == 2 and "--json" in capsys.readouterr().err
