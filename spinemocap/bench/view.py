"""``spinemocap bench view``: the time of ``spinemocap view``'s outputs, the labelled videos (per
camera and the grid) and the 3D viewer, on a given capture and results, or on a capture made here
(grey images, a flat 13-row tape: the drawing and encoding cost does not depend on what the images
show). Per run: wall seconds of each output, capture frames written per second (all cameras and
the grid together) of wall time and of this process's CPU time (x264's threads included), the
video size and the machine's load average.
"""

from __future__ import annotations

import os
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from spinemocap.app.results import write_markers
from spinemocap.app.viewer.scene3d import write_viewer
from spinemocap.app.viewer.video import write_videos
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

from .records import JsonRecord


def made_capture(root: Path, width: int, height: int, n_cameras: int, n_frames: int) -> tuple[Path, Path]:
    """A capture of ``n_cameras`` around a flat 13-row tape sliding sideways, grey noisy images,
    and its results folder."""
    focal = 1.3 * width
    cameras = [Camera.look_at(f"cam{k + 1}", (900 * np.sin(a), 1000 * np.cos(a), 1150.0), (0.0, 0.0, 1150.0),
                              (width, height), focal, dist=(-0.1, 0.02, 0, 0, 0))
               for k, a in enumerate(np.linspace(-0.7, 0.7, n_cameras))]
    capture = Capture(root=root / "capture", name="made", fps=100.0, n_frames=n_frames, rig=Rig(cameras),
                      tape=TapeSpec(n_rows=13))
    capture.save()
    rng = np.random.default_rng(0)
    for camera in cameras:
        folder = capture.root / "images" / camera.name
        folder.mkdir(parents=True)
        for frame in range(n_frames):
            grey = np.clip(100 + rng.normal(0, 6, (height, width)), 0, 255).astype(np.uint8)
            cv2.imwrite(str(folder / f"{frame:06d}.png"), cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    uv = capture.tape.graph.uv_mm
    dots = np.stack([-uv[:, 0], np.zeros(len(uv)), 1000.0 + uv[:, 1]], axis=1)
    positions = np.stack([dots + [0.5 * f, 0.0, 0.0] for f in range(n_frames)])
    write_markers(MarkerTable.from_arrays(capture.tape.labels, positions, capture.fps), root / "results")
    return capture.root, root / "results"


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@dataclass(frozen=True)
class ViewRun(JsonRecord):
    """One run of ``bench view`` (:func:`run_benchmark`): the capture (its folder, or the made one's
    WIDTHxHEIGHTxCAMERAS) and the run's number; capture frames and cameras written, the video sizes
    (px), wall seconds and capture frames per second of the videos, their CPU seconds (this
    process, x264's threads included) and frames per CPU second, the 3D viewer's wall seconds, the
    videos' size (MiB) and the machine's 1-minute load average, times rounded to 0.01."""

    capture: str
    run: int
    frames: int
    cameras: int
    sizes: list[tuple[int, int]]
    video_s: float
    frames_per_s: float
    video_cpu_s: float
    frames_per_cpu_s: float
    viewer_s: float
    video_MiB: float
    load_1min: float



def run(capture: Path, results: Path, out: Path, scale: float | None, label: str | None = None,
        number: int = 0) -> ViewRun:
    """Write ``capture``'s labelled videos and 3D viewer of ``results`` into ``out`` (``scale``:
    as ``spinemocap view --scale``) and time them; ``label``: the capture's name in the result
    (default its folder), ``number``: the run's."""
    cpu = cpu_seconds()
    video = write_videos(capture, results, out, scale=scale, progress=False)
    video_cpu = cpu_seconds() - cpu
    start = time.perf_counter()
    write_viewer(capture, results, out / "tape3d.html")
    html_s = time.perf_counter() - start
    return ViewRun(capture=label or str(capture), run=number, frames=len(video.frames), cameras=len(video.cameras),
                   sizes=sorted(set(video.sizes.values())), video_s=round(video.seconds, 2),
                   frames_per_s=round(video.frames_per_s, 2), video_cpu_s=round(video_cpu, 2),
                   frames_per_cpu_s=round(len(video.frames) / video_cpu, 2), viewer_s=round(html_s, 2),
                   video_MiB=round(sum(p.stat().st_size for p in [*video.cameras.values(), video.grid]
                                       if p is not None) / 2**20, 2),
                   load_1min=round(os.getloadavg()[0], 2))


def run_benchmark(capture: Path | None, results: Path | None, made: str | None, frames: int,
                  scale: float | None, repeat: int) -> list[ViewRun]:
    """``repeat`` runs on ``capture``/``results``, or on a capture ``made`` = "WIDTHxHEIGHTxCAMERAS"
    of ``frames`` frames (see the module docstring)."""
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        if made:
            width, height, cameras = (int(v) for v in made.split("x"))
            capture, results = made_capture(Path(tmp), width, height, cameras, frames)
        assert capture is not None and results is not None
        for k in range(repeat):
            runs.append(run(capture, results, Path(tmp) / f"v{k}", scale, made or str(capture), k))
    return runs
