"""Ctrl-C during a real `spinemocap batch` subprocess stops it within seconds, records
the unfinished trials as interrupted, leaves no worker behind, and a rerun resumes; killing the
batch process (SIGKILL) leaves no orphan worker either."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from repo_paths import ROOT

from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.tape import TapeSpec

N_TRIALS = 4
FRAMES = 600  # ~1-2 s of angle computation per trial on the 2-core CI machine


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    """A CSV manifest of N_TRIALS trials sharing one long ground-truth capture (a short bent-tape
    capture with its motion repeated, so that writing it is quick)."""
    root = tmp_path_factory.mktemp("study")
    capture = root / "capture"
    write_bent_capture(capture, TapeSpec(n_rows=9), 20.0, 30, fps=100.0)
    with np.load(capture / "groundtruth.npz") as data:
        gt = {k: data[k] for k in data.files}
    gt["dots"] = np.concatenate([gt["dots"], gt["dots"][::-1]] * (FRAMES // 60))
    np.savez(capture / "groundtruth.npz", **gt)
    manifest = (capture / "capture.toml").read_text()
    (capture / "capture.toml").write_text(manifest.replace("n_frames = 30", f"n_frames = {len(gt['dots'])}"))
    (root / "levels.toml").write_text('[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n')
    rows = "".join(f"capture,S{k:02d},t1,levels.toml\n" for k in range(N_TRIALS))
    (root / "manifest.csv").write_text("path,subject,trial,levels\n" + rows)
    return root


def _start(study: Path, out: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "OMP_NUM_THREADS": "1"}
    return subprocess.Popen([sys.executable, "-m", "spinemocap", "-q", "batch", str(study / "manifest.csv"),
                             "--out", str(out), "--source", "groundtruth", "--workers", "2", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            # Ctrl-C's default action even when the suite runs in a background job
                            # (whose children inherit SIGINT ignored, and Python keeps it so)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(condition, timeout: float, proc: subprocess.Popen) -> None:
    end = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, f"batch ended early: {proc.communicate()}"
        assert time.monotonic() < end, "timed out waiting for the batch"
        time.sleep(0.05)


def _alive(pids: list[int]) -> list[int]:
    out = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                out.append(pid)
        except psutil.NoSuchProcess:
            pass
    return out


def _summaries(out: Path) -> list[Path]:
    return sorted(out.rglob("summary.json"))


def test_ctrl_c_stops_batch_within_seconds_records_interrupted_and_rerun_resumes(study, tmp_path):
    out = tmp_path / "out"
    proc = _start(study, out)
    _wait_for(lambda: len(_summaries(out)) >= 1, 120, proc)  # one trial done, others running or queued
    workers = [c.pid for c in psutil.Process(proc.pid).children(recursive=True)]
    assert workers, "the batch runs its trials in worker processes"
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    stopped_s = time.monotonic() - sent
    assert proc.returncode == 130 and stopped_s < 5.0, (proc.returncode, stopped_s, err)
    assert "Traceback" not in err and "interrupted" in err
    time.sleep(0.5)
    assert _alive(workers) == []
    finished = len(_summaries(out))
    assert 1 <= finished < N_TRIALS
    log = (out / "batch.log").read_text()
    assert log.count(" interrupted") >= N_TRIALS - finished and "batch interrupted" in log
    assert not [p for p in out.rglob(".~*")], "temporary files left behind"

    proc = _start(study, out)  # resume: finished trials are up to date, the rest are processed
    stdout, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert f"{N_TRIALS} ok ({finished} up to date)" in stdout
    assert len(_summaries(out)) == N_TRIALS


@pytest.mark.slow
def test_killing_the_batch_process_leaves_no_orphan_worker(study, tmp_path):
    out = tmp_path / "out"
    proc = _start(study, out)
    _wait_for(lambda: len(psutil.Process(proc.pid).children(recursive=True)) >= 2, 120, proc)
    time.sleep(0.5)
    workers = [c.pid for c in psutil.Process(proc.pid).children(recursive=True)]
    proc.kill()
    proc.communicate(timeout=10)
    end = time.monotonic() + 5.0
    while _alive(workers) and time.monotonic() < end:
        time.sleep(0.1)
    assert _alive(workers) == [], "workers outlived the killed batch"


@pytest.mark.slow
def test_interrupting_a_dask_batch_cancels_its_queued_trials(study, tmp_path):
    """On a Dask cluster the interrupted batch cancels every queued trial at once and sets the
    stop Event the running trials check; here one worker thread, trials one at a time."""
    from distributed import LocalCluster

    from spinemocap.analysis.angles import AngleSettings
    from spinemocap.app.batch import TrialJob, _execute_dask, discover, trial_out_dir

    out = tmp_path / "out"
    trials = discover(study / "manifest.csv")
    jobs = [TrialJob(t, str(trial_out_dir(out, t)), "groundtruth", None, AngleSettings()) for t in trials]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        running = _execute_dask(jobs, cluster.scheduler_address)
        first = next(running)
        assert first.summary.status == "ok"
        running.close()  # what run_batch does on Ctrl-C
        time.sleep(3.0)  # a running trial (no frame loop with ground truth) may still finish
    assert len(_summaries(out)) <= 2 < N_TRIALS
