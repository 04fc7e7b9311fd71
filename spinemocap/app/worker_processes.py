"""What every local worker-process pool of the application needs (the batch's trials, the
cameras of :mod:`~spinemocap.app.camera_processes`): workers that leave when their parent dies,
and a stop that waits a grace period and then kills."""

from __future__ import annotations

import os
import threading
import time
from multiprocessing.process import BaseProcess
from typing import Iterable


def exit_with_parent(parent_pid: int) -> None:
    """In a worker: start a daemon thread that ends this process as soon as ``parent_pid`` is no
    longer its parent (the parent died: no orphans keep running)."""
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="watch-parent").start()


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(0.5)
    os._exit(1)


def join_or_kill(processes: Iterable[BaseProcess], grace_s: float) -> None:
    """Wait up to ``grace_s`` seconds in all for ``processes`` to exit, then kill what is left."""
    processes = list(processes)
    deadline = time.monotonic() + grace_s
    for process in processes:
        process.join(max(deadline - time.monotonic(), 0.0))
        if process.is_alive():
            process.kill()
            process.join(1.0)


def processes_cpu_s(pids: Iterable[int]) -> float:
    """CPU seconds (user + system) the live processes ``pids`` have used so far (NaN without psutil)."""
    try:
        import psutil
    except ImportError:  # pragma: no cover - psutil is a dependency
        return float("nan")
    total = 0.0
    for pid in pids:
        try:
            times = psutil.Process(pid).cpu_times()
        except psutil.Error:
            continue
        total += times.user + times.system
    return total
