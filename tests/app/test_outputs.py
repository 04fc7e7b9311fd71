"""Outputs stay whole. Atomic writes get the umask's permissions (not mkstemp's 0600)
and leave nothing behind; temporary files of a killed process are removed by the next write;
markers.csv/.trc/.c3d form one set with a manifest, a mix of two runs is detected."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

import exporters
from spinemocap.app.results import RESULTS_MANIFEST, results_run_id, write_markers
from spinemocap.fileio import InputError, atomic_path, atomic_write, clean_stale_temps, temp_name
from spinemocap.markers import MarkerTable


@pytest.fixture()
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_atomic_outputs_respect_the_umask_and_keep_a_replaced_files_mode(tmp_path, umask_022):
    with atomic_write(tmp_path / "a.txt") as handle:
        handle.write("x")
    with atomic_path(tmp_path / "b.bin") as tmp:
        tmp.write_bytes(b"y")
    assert _mode(tmp_path / "a.txt") == 0o644 and _mode(tmp_path / "b.bin") == 0o644
    os.chmod(tmp_path / "a.txt", 0o640)
    with atomic_write(tmp_path / "a.txt") as handle:
        handle.write("z")
    assert _mode(tmp_path / "a.txt") == 0o640 and (tmp_path / "a.txt").read_text() == "z"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin"]


def test_a_failing_write_leaves_the_old_file_and_no_temporary(tmp_path):
    (tmp_path / "a.txt").write_text("old")
    with pytest.raises(KeyboardInterrupt), atomic_write(tmp_path / "a.txt") as handle:
        handle.write("half")
        raise KeyboardInterrupt
    assert (tmp_path / "a.txt").read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_temporaries_of_a_killed_process_are_removed_by_the_next_write(tmp_path):
    dead, alive = _dead_pid(), os.getppid()
    left = tmp_path / f".~a.txt.{dead}.0123abcd.tmp"
    staging = tmp_path / f".~markers.{dead}.89abcdef"
    busy = tmp_path / f".~a.txt.{alive}.0123abcd.tmp"  # another live writer's: kept
    for path in (left, busy):
        path.write_text("partial")
    staging.mkdir()
    (staging / "markers.csv").write_text("partial")
    with atomic_write(tmp_path / "a.txt") as handle:
        handle.write("new")
    assert not left.exists() and busy.exists() and staging.exists()  # only a.txt's own temporaries
    assert set(clean_stale_temps(tmp_path)) == {staging}
    assert temp_name(tmp_path / "markers.c3d").name.startswith(f".~markers.c3d.{os.getpid()}.")


def _table(shift: float = 0.0) -> MarkerTable:
    pos = np.random.default_rng(1).normal(0, 100, size=(5, 3, 3)) + shift
    return MarkerTable.from_arrays(["R01L", "R01R", "R02L"], pos, fps=100.0)


def test_marker_files_are_one_set_and_a_mix_of_two_runs_is_detected(tmp_path, umask_022):
    out = tmp_path / "res"
    paths = write_markers(_table(), out)
    first = results_run_id(out)
    assert [p.name for p in paths] == ["markers.csv", "markers.trc", "markers.c3d"]
    assert all(_mode(p) == 0o644 for p in paths) and not list(out.glob(".~*"))
    other = write_markers(_table(5.0), tmp_path / "other")
    write_markers(_table(), out)
    second = results_run_id(out)
    assert second != first
    os.replace(other[1], out / "markers.trc")  # a kill between two renames: files of two runs
    with pytest.raises(InputError, match=r"markers.trc does not belong to the run"):
        results_run_id(out)
    (out / RESULTS_MANIFEST).unlink()  # a kill after the old manifest was removed
    with pytest.raises(InputError, match=r"incomplete set of marker files"):
        results_run_id(out)


def test_a_failing_writer_leaves_the_previous_set_whole(tmp_path, monkeypatch):
    out = tmp_path / "res"
    write_markers(_table(), out)
    before = results_run_id(out)
    real = exporters.write_parts

    def failing(parts, path, *args, **kwargs):
        if Path(path).suffix == ".c3d":
            raise OSError("disk full")
        return real(parts, path, *args, **kwargs)

    monkeypatch.setattr(exporters, "write_parts", failing)
    with pytest.raises(OSError, match="disk full"):
        write_markers(_table(3.0), out)
    assert results_run_id(out) == before and not list(out.glob(".~*"))


def test_report_of_one_capture_reuses_a_complete_tracked_set(tmp_path):
    """`spinemocap demo`'s report step hands the tracked set to the batch, which must reuse it
    (this capture has no images: tracking again would fail)."""
    from spinemocap.analysis.bent_tape import write_bent_capture
    from spinemocap.app.batch import groundtruth_markers, load_results
    from spinemocap.app.report import report_capture
    from spinemocap.capture import Capture
    from spinemocap.tape import TapeSpec

    capture = tmp_path / "cap"
    write_bent_capture(capture, TapeSpec(n_rows=9), 20.0, 12, fps=50.0)
    (capture / "levels.toml").write_text('[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n')
    tracked = write_markers(groundtruth_markers(Capture.open(capture)), tmp_path / "tracked")
    report_capture(capture, tmp_path / "report", markers_csv=tracked[0])
    (result,) = load_results(tmp_path / "report")
    assert result.status == "ok" and result.source == "tracked", result
