"""A full disk while results are written: a clear error naming the folder, and no set of marker
files left that a rerun would take as complete."""

from __future__ import annotations

import errno
import shutil
import subprocess

import numpy as np
import pytest

import exporters
from spinemocap.app.results import RESULTS_MANIFEST, results_complete, results_run_id, write_markers
from spinemocap.cli import main
from spinemocap.fileio import OutputError, atomic_write
from spinemocap.markers import MarkerTable


def _table(n_frames: int, shift: float = 0.0) -> MarkerTable:
    labels = [f"R{r:02d}{c}" for r in range(1, 14) for c in "LR"]
    pos = np.random.default_rng(2).normal(0, 100, size=(n_frames, len(labels), 3)) + shift
    return MarkerTable.from_arrays(labels, pos, fps=100.0)


@pytest.fixture()
def small_disk(tmp_path):
    """A 256 KiB tmpfs: a real file system that fills up (needs the right to mount, e.g. root)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.decode().strip()}")
    yield mount
    subprocess.run(["umount", str(mount)], check=False)


def test_a_full_disk_keeps_the_previous_set_and_names_the_folder(small_disk):
    out = small_disk / "results"
    write_markers(_table(5), out)
    before = results_run_id(out)
    with pytest.raises(OutputError, match=r"results: cannot write the marker files: no space left on the device"):
        write_markers(_table(400, 3.0), out)
    assert results_run_id(out) == before and not list(out.glob(".~*"))


def test_a_full_disk_on_a_fresh_folder_leaves_nothing_taken_as_complete(small_disk):
    out = small_disk / "fresh"
    with pytest.raises(OutputError, match=str(out)):
        write_markers(_table(400), out)
    assert not results_complete(out) and not (out / RESULTS_MANIFEST).exists() and not list(out.glob(".~*"))


def test_an_export_to_a_full_disk_exits_2_with_the_reason(tmp_path, small_disk, capsys):
    source = tmp_path / "big.csv"
    exporters.write(_table(1500), source)           # ~620 KB of C3D: more than the disk
    target = small_disk / "big.c3d"
    assert main(["-q", "export", str(source), "--format", "c3d", "--out", str(target)]) == 2
    err = capsys.readouterr().err
    assert "no space left on the device" in err and str(small_disk) in err and "Traceback" not in err
    assert not target.exists() and not list(small_disk.glob(".~*"))


def test_enospc_from_any_writer_becomes_an_output_error(tmp_path):
    """Where no small file system can be mounted: the errno alone decides the translation."""
    with pytest.raises(OutputError, match=r"a\.txt: no space left") as caught, atomic_write(tmp_path / "a.txt") as h:
        h.write("partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert caught.value.source == str(tmp_path) and list(tmp_path.iterdir()) == []
    with pytest.raises(PermissionError), atomic_write(tmp_path / "b.txt"):
        raise PermissionError(errno.EACCES, "denied")        # other errors pass unchanged
