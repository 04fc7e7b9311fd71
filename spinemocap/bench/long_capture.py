"""Memory of ``spinemocap track --chunk-frames`` against the capture's length.

A long capture is made cheaply from a short rendered one (:func:`looped_capture`): its images and
masks played forward and back again (0, 1, ..., n-1, n-2, ..., 1, 0, 1, ...), as links to the
rendered files, so the tape moves without a jump however long the capture. Each length is tracked
in its own process (:func:`measure_run`), its resident set size (RSS, the process and its children)
sampled as it runs, next to the frames the saved chunks hold. Peak RSS flat in the length is the
claim; the samples give RSS against the frames done within a run too.

    spinemocap bench long-capture BASE_CAPTURE OUT_DIR --lengths 600 2400 6000
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..app.long_capture import CHUNK_DIR
from ..capture import MANIFEST, Capture
from ..fileio import atomic_write, read_toml, write_toml

if TYPE_CHECKING:
    import psutil

SAMPLE_S = 0.5


def pingpong(frame: int, n_base: int) -> int:
    """The base frame shown at long-capture frame ``frame``: forward, then back, then forward."""
    if n_base == 1:
        return 0
    period = 2 * (n_base - 1)
    k = frame % period
    return k if k < n_base else period - k


def looped_capture(base: Path, out: Path, n_frames: int) -> Path:
    """A capture folder ``out`` of ``n_frames`` frames whose images and masks are links to
    ``base``'s (an image capture with masks), played forward and back (:func:`pingpong`). No ground
    truth is copied (the looped frames have none of their own)."""
    capture = Capture.open(base)
    if capture.media != "images":
        raise ValueError(f"{base}: needs an image capture")
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    shutil.copy(base / capture.rig_file, out / capture.rig_file)
    manifest = read_toml(base / MANIFEST)
    manifest["capture"]["n_frames"] = int(n_frames)
    write_toml(out / MANIFEST, manifest)
    for kind in ("images", "masks"):
        for camera in capture.camera_names:
            source = base / kind / camera
            target = out / kind / camera
            target.mkdir(parents=True)
            suffix = next(source.iterdir()).suffix
            for frame in range(n_frames):
                os.symlink((source / f"{pingpong(frame, capture.n_frames):06d}{suffix}").resolve(),
                           target / f"{frame:06d}{suffix}")
    return out


@dataclass
class RunMemory:
    """One tracked length: ``peak_rss_mb`` (the sampled peak of the process and its children,
    MiB), ``wall_s``, and the samples: ``t_s``, ``rss_mb`` and ``frames_done`` (frames in the saved
    chunks at that time)."""

    n_frames: int
    chunk_frames: int
    peak_rss_mb: float
    wall_s: float
    t_s: list[float] = field(default_factory=list)
    rss_mb: list[float] = field(default_factory=list)
    frames_done: list[int] = field(default_factory=list)


def _rss_mb(process: psutil.Process) -> float:
    import psutil

    try:
        members = [process, *process.children(recursive=True)]
        return sum(p.memory_info().rss for p in members if p.is_running()) / 2**20
    except psutil.NoSuchProcess:
        return 0.0


def measure_run(capture: Path, out: Path, chunk_frames: int, detector: str = "mask") -> RunMemory:
    """Track ``capture`` with ``spinemocap track --chunk-frames`` in a new process, sampling its
    RSS every :data:`SAMPLE_S` s."""
    import psutil

    n_frames = Capture.open(capture).n_frames
    if out.exists():
        shutil.rmtree(out)
    command = [sys.executable, "-m", "spinemocap.cli", "track", str(capture), "--out", str(out),
               "--detector", detector, "--no-progress", "--chunk-frames", str(chunk_frames)]
    start = time.perf_counter()
    process = psutil.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    run = RunMemory(n_frames, chunk_frames, 0.0, 0.0)
    while process.poll() is None:
        rss = _rss_mb(process)
        done = len(list((out / CHUNK_DIR).glob("chunk_*.npz"))) * chunk_frames if (out / CHUNK_DIR).is_dir() else (
            n_frames if (out / "markers.csv").is_file() else 0)
        run.t_s.append(round(time.perf_counter() - start, 2))
        run.rss_mb.append(round(rss, 1))
        run.frames_done.append(min(done, n_frames))
        time.sleep(SAMPLE_S)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited with {process.returncode}")
    run.wall_s = round(time.perf_counter() - start, 1)
    run.peak_rss_mb = max(run.rss_mb, default=0.0)
    return run


def plot(runs: list[RunMemory], path: Path, peer: list[RunMemory] | None = None, peer_name: str = "peer") -> None:
    """Peak RSS against length (and a ``peer``'s runs, e.g. another build's, dashed), and
    RSS against frames done within each of ``runs``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    lengths = [r.n_frames for r in runs]
    top = 1.2 * max(r.peak_rss_mb for r in runs + (peer or []))
    left.plot(lengths, [r.peak_rss_mb for r in runs], "o-", label="this version")
    if peer:
        left.plot([r.n_frames for r in peer], [r.peak_rss_mb for r in peer], "s--", label=peer_name)
        left.legend()
    left.set_xlabel("capture length (frames)")
    left.set_ylabel("peak RSS (MiB)")
    left.set_ylim(0, top)
    left.set_title(f"track --chunk-frames {runs[0].chunk_frames}: peak RSS")
    for r in runs:
        alive = np.array(r.rss_mb) > 0   # samples before the process started or after it ended: none
        right.plot(np.array(r.frames_done)[alive], np.array(r.rss_mb)[alive], label=f"{r.n_frames} frames", lw=1)
    right.set_xlabel("frames in completed chunks")
    right.set_ylabel("RSS (MiB)")
    right.set_ylim(0, top)
    right.set_title("RSS during each run")
    right.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def load_runs(path: Path) -> list[RunMemory]:
    """Runs saved by :func:`main` (``long_capture_memory.json``)."""
    return [RunMemory(**run) for run in json.loads(Path(path).read_text())]


def run_benchmark(base: Path, out: Path, lengths: Sequence[int], chunk_frames: int = 300,
                  peer: Path | None = None, say: Callable[[str], None] = print) -> list[RunMemory]:
    """Track a looped capture of each length in ``lengths`` (frames) from ``base`` in chunks of
    ``chunk_frames``; write ``out``/long_capture_memory.json (after every run) and .png (``peer``:
    a previous run's JSON drawn beside); returns the runs."""
    runs: list[RunMemory] = []
    for n in lengths:
        capture = looped_capture(base, out / f"capture_{n}", n)
        run = measure_run(capture, out / f"tracked_{n}", chunk_frames)
        runs.append(run)
        say(f"{n} frames: peak RSS {run.peak_rss_mb:.0f} MiB, {run.wall_s:.0f} s")
        shutil.rmtree(capture)
        with atomic_write(out / "long_capture_memory.json") as handle:
            json.dump([asdict(r) for r in runs], handle)
    plot(runs, out / "long_capture_memory.png", load_runs(peer) if peer else None)
    return runs
