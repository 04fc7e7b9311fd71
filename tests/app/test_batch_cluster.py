"""A batch on a Dask cluster survives what clusters do: a worker killed in the middle of a trial
(the trial runs again elsewhere, with the same result) and a scheduler that goes away (a clear
error; the rerun does only what is left)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest
from test_analysis_batch import LEVELS_TOML, _write_trial

from spinemocap.app.batch import run_batch
from spinemocap.fileio import InputError

distributed = pytest.importorskip("distributed")


def _study(root: Path, n_subjects: int) -> Path:
    for k in range(n_subjects):
        folder = root / f"S{k:02d}"
        folder.mkdir(parents=True)
        (folder / "levels.toml").write_text(LEVELS_TOML)
        _write_trial(folder / "pre" / "trial01", 20.0 + 2 * k, n_frames=20)
    return root


def _outputs(out: Path) -> dict[str, str]:
    """Every trial's angle table, by trial (the results a rerun must reproduce exactly)."""
    return {str(p.parent.relative_to(out)): p.read_text() for p in sorted(out.rglob("angles.csv"))}


def _kill_once_plugin(marker: Path, delay_s: float):
    """A worker plugin that kills its own worker process (SIGKILL) ``delay_s`` after the first
    trial starts executing anywhere in the cluster (``marker`` records which one)."""

    class KillOnce(distributed.WorkerPlugin):
        def setup(self, worker):
            self.worker = worker

        def transition(self, key, start, finish, **kwargs):
            if finish != "executing" or not str(key).startswith("trial-"):
                return
            try:
                fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return
            os.write(fd, str(key).encode())
            os.close(fd)
            threading.Timer(delay_s, os.kill, (os.getpid(), signal.SIGKILL)).start()

    return KillOnce()


def test_a_worker_killed_mid_trial_gives_the_same_results_as_the_local_pool(tmp_path):
    from distributed import Client, LocalCluster

    study = _study(tmp_path / "study", 4)
    local = run_batch(study, tmp_path / "local", source="groundtruth", workers=1, progress=False)
    assert {t.summary.status for t in local.trials} == {"ok"}
    marker = tmp_path / "killed"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster.scheduler_address) as client:
        client.register_plugin(_kill_once_plugin(marker, delay_s=0.1))
        result = run_batch(study, tmp_path / "cluster", source="groundtruth", scheduler=cluster.scheduler_address,
                           progress=False)
    assert marker.exists(), "no worker was killed"
    assert {t.summary.status for t in result.trials} == {"ok"} and len(result.trials) == 4
    assert _outputs(tmp_path / "cluster") == _outputs(tmp_path / "local")


def test_a_scheduler_that_goes_away_is_a_clear_error_and_the_rerun_resumes(tmp_path):
    from distributed import LocalCluster

    study = _study(tmp_path / "study", 8)
    out = tmp_path / "out"
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None)
    failure: list[BaseException] = []

    def batch() -> None:
        try:
            run_batch(study, out, source="groundtruth", scheduler=cluster.scheduler_address, progress=False)
        except BaseException as exc:    # noqa: B036 - handed to the test thread
            failure.append(exc)

    runner = threading.Thread(target=batch)
    runner.start()
    deadline = time.monotonic() + 120
    while not list(out.rglob("summary.json")) and time.monotonic() < deadline:
        time.sleep(0.05)
    cluster.close()                       # the scheduler goes away mid-batch
    runner.join(timeout=120)
    assert not runner.is_alive()
    (error,) = failure
    assert isinstance(error, InputError)
    assert "the Dask scheduler went away after" in str(error) and "run the same command" in str(error)
    done_before = {str(p.parent) for p in out.rglob("summary.json")}
    assert 1 <= len(done_before) < 8
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as again:
        result = run_batch(study, out, source="groundtruth", scheduler=again.scheduler_address, progress=False)
    assert {t.summary.status for t in result.trials} == {"ok"} and len(result.trials) == 8
    skipped = {t.summary.key for t in result.trials if t.skipped}
    assert {str(Path(d).relative_to(out)) for d in done_before} <= skipped
    assert json.loads((out / "batch.json").read_text())["trials"][0]["status"] == "ok"
