"""Long captures in chunks: a run killed with SIGKILL resumes from its last completed chunk and
writes the output of an uninterrupted run; chunk boundaries keep the labels continuous."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from spinemocap.app.long_capture import CHUNK_DIR, Chunking, continuity
from spinemocap.cli import main
from spinemocap.fileio import InputError
from spinemocap.tape import TapeSpec

pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from spinemocap.synth import SynthConfig, write_capture

    root = tmp_path_factory.mktemp("long_capture")
    return write_capture(SynthConfig.preset("tiny", frames=9), root / "capture", progress=False)


def _track(capture, out, *extra: str) -> list[str]:
    return ["track", str(capture), "--out", str(out), "--detector", "mask", "--no-progress",
            "--chunk-frames", "3", "--warmup-frames", "2", *extra]


def test_chunk_spans_keep_every_frame_once_and_warm_up_before_each_later_chunk():
    spans = Chunking(4, 2).spans(range(1, 12))
    assert spans == [(1, 1, 5), (3, 5, 9), (7, 9, 12)]
    assert Chunking(100, 25).spans(range(0, 10)) == [(0, 0, 10)]
    with pytest.raises(InputError, match="chunk_frames"):
        Chunking(0, 2)


def test_continuity_finds_a_row_shift_and_refuses_a_foreign_tape():
    tape = TapeSpec(n_rows=9)
    labels = tape.labels
    dots = tape.graph.uv_mm
    previous = np.stack([np.c_[dots, np.zeros(len(dots))] + k for k in range(3)]).astype(float)
    index, distance = continuity(previous, previous.copy(), labels)
    assert np.array_equal(index, np.arange(len(labels))) and distance == 0
    # this chunk called every row one higher: the shift back is found
    shifted = np.full_like(previous, np.nan)
    rows = np.array([int(label[1:3]) for label in labels])
    for d, label in enumerate(labels):
        higher = f"R{rows[d] + 1:02d}{label[3:]}"
        if higher in labels:
            shifted[:, labels.index(higher)] = previous[:, d]
    index, distance = continuity(previous, shifted, labels)
    assert index is not None and distance < 1e-9
    assert all(index[d] == labels.index(f"R{rows[d] + 1:02d}{label[3:]}") for d, label in enumerate(labels)
               if f"R{rows[d] + 1:02d}{label[3:]}" in labels)
    noise = np.random.default_rng(0).normal(0, 200, previous.shape)
    assert continuity(previous, noise, labels)[0] is None


def test_a_killed_run_resumes_with_the_uninterrupted_output(capture, tmp_path, capsys):
    whole = tmp_path / "whole"
    assert main(_track(capture, whole)) == 0
    assert not (whole / CHUNK_DIR).exists()
    resumed = tmp_path / "resumed"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.Popen([sys.executable, "-m", "spinemocap.cli", *_track(capture, resumed)], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not list((resumed / CHUNK_DIR).glob("chunk_00000.npz")) and time.monotonic() < deadline:
        time.sleep(0.05)
        assert run.poll() is None, "the run ended before its first chunk was saved"
    os.kill(run.pid, signal.SIGKILL)
    run.wait()
    assert not (resumed / "markers.csv").exists()
    capsys.readouterr()
    assert main(_track(capture, resumed)) == 0
    assert "taken from an interrupted run" in capsys.readouterr().out
    a, b = pd.read_csv(whole / "markers.csv"), pd.read_csv(resumed / "markers.csv")
    pd.testing.assert_frame_equal(a, b)
    # every dot labelled right in every chunk: the chunk boundaries keep the labels continuous
    table = a.set_index(["frame", "label"])
    truth = np.load(capture / "groundtruth.npz")
    labels = [str(x) for x in truth["labels"]]
    errors = [np.linalg.norm(table.loc[(f, label), ["x", "y", "z"]].to_numpy(float) - truth["dots"][f, d])
              for f in range(9) for d, label in enumerate(labels)]
    assert np.nanmax(errors) < 3.0


def test_a_table_written_in_parts_gives_the_same_files_as_written_whole(tmp_path):
    """The chunked run writes its marker files one saved chunk at a time: byte for byte the files
    of the whole table (missing cameras and flagged frames included)."""
    from spinemocap.app.results import write_marker_parts, write_markers
    from spinemocap.markers import MarkerTable

    rng = np.random.default_rng(3)
    positions = rng.normal(0, 200, (40, 5, 3))
    positions[4:11, 2] = np.nan
    status = np.where(rng.random((40, 5)) < 0.2, "inferred", "observed")
    table = MarkerTable.from_arrays(list("abcde"), positions, 100.0, status=status, n_views=rng.integers(2, 5, (40, 5)),
                                    residual=rng.random((40, 5)), confidence=rng.random((40, 5)), first_frame=7,
                                    meta={"missing_cameras": {"cam2": [8, 9, 10, 30], "cam4": [46]}, "subject": "S"})
    write_markers(table, tmp_path / "whole")
    cuts = [7, 20, 21, 47]
    write_marker_parts(lambda: [table.select(frames=range(a, b)) for a, b in zip(cuts, cuts[1:])], 40,
                       tmp_path / "parts")
    for name in ("markers.csv", "markers.trc", "markers.c3d"):
        assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "parts" / name).read_bytes(), name
    with pytest.raises(Exception, match="41 announced"):
        write_marker_parts(lambda: [table], 41, tmp_path / "short")


def test_the_memory_benchmark_plays_a_short_capture_forward_and_back():
    from spinemocap.bench.long_capture import pingpong

    assert [pingpong(k, 4) for k in range(10)] == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]   # no jump at the turns
    assert [pingpong(k, 1) for k in range(3)] == [0, 0, 0]
