"""The speed benchmark (``spinemocap bench speed``): end-to-end frames per second of
tracking the synthetic studio, from frames held in memory, from PNG images and from lossless
video, with the serial pipeline (:data:`spinemocap.app.streaming.SERIAL`) as the peer in the
same run.

The scene is rendered once into a capture folder of PNG images (``write_capture``) and copied
into lossless videos (UT Video by default, ``video_codec``: any of the writer's codecs, e.g.
uncompressed ``rawvideo``; and its first frames into FFV1, the previous format, whose decoding
alone is the video peer); rendering and encoding are not timed. Each run tracks the same frames with the
shipped network detector and reports frames/s (wall time of detection + tracking, reading
included, writing the outputs excluded), the mean time per stage per frame, the peak resident
memory during the run above the memory before it (sampled every 20 ms), the detector's routes
(predicted box / full search) and the accuracy against the ground truth, so a faster run that got
worse shows it. ``speedup_vs_serial`` is the pipeline's fps over the serial one's on the
same frames and source (PNG, the capture's own format); ``speedup_vs_serial_in_memory`` the
same from memory, where at most ``memory_frames`` decoded frames are held and replayed. The
numbers are the dataclasses of :mod:`spinemocap.bench.speed_results`.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from tqdm import tqdm

from ..app.run import TrackingMode, TrackingWarning, TrackResult, track_source
from ..app.streaming import SERIAL, SpeedOptions, resolve_parallel
from ..capture import VIDEO_CODEC, VIDEO_CODECS, VIDEO_PATTERN, Capture, FrameSource, VideoWriter
from ..fileio import InputError, atomic_write, read_toml, write_toml
from ..track.evaluate import evaluate_tracking
from .speed_results import (
    DecodeSpeed,
    DeviceDots,
    LookaheadComparison,
    MachineInfo,
    RenderedSpeed,
    ReplayedSpeed,
    SameAccuracy,
    SpeedNumbers,
    SpeedRun,
)

# "Not worse": mean error within this of the peer's (sub-pixel differences of the predicted
# boxes' masks move a few dot centres by ~0.01 px), and no more swaps or unsolved frames.
ACCURACY_TOLERANCE_MM = 0.01
SAME_ACCURACY_MM = 0.02  # the GPU path's mean and p95 error within this of the CPU path's
GOALS_FPS = {"in_memory_cpu2": 10.0, "video_cpu2": 5.0, "gpu": 100.0}
REPLAYED = ("dots", "visible", "dot_normals", "keypoints")  # per-frame ground truth (replayed alike)
FFV1_FRAMES = 10  # frames of the previous video format decoded as the decoding peer


class MemorySource:
    """A :class:`~spinemocap.capture.FrameSource` over frames already decoded in memory
    (``frames[i]``: one BGR uint8 image per camera)."""

    def __init__(self, frames: list[list[np.ndarray]], camera_names: list[str]):
        self.frames = frames
        self.camera_names = list(camera_names)
        self.n_frames = len(frames)

    def read(self, frame: int) -> list[np.ndarray | None]:
        return list(self.frames[frame])

    def read_camera(self, camera: int, frame: int) -> np.ndarray:
        return self.frames[frame][camera]


class PeakMemory:
    """Peak resident memory (MiB) of this process while in the ``with`` block, above the
    resident memory at its start; sampled every ``interval_s`` from /proc (Linux; NaN elsewhere)."""

    def __init__(self, interval_s: float = 0.02):
        self.interval_s = interval_s
        self.peak_mib = float("nan")

    @staticmethod
    def rss_mib() -> float:
        try:
            with open("/proc/self/statm") as fh:
                return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
        except (OSError, ValueError, IndexError):
            return float("nan")

    def __enter__(self) -> "PeakMemory":
        self._start = self.rss_mib()
        self._peak = self._start
        self._stop = threading.Event()

        def sample() -> None:
            while not self._stop.wait(self.interval_s):
                self._peak = max(self._peak, self.rss_mib())

        self._thread = threading.Thread(target=sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self._peak = max(self._peak, self.rss_mib())
        self.peak_mib = self._peak - self._start


def video_copy(png_capture: Path, out: Path, codec: str = VIDEO_CODEC, frames: int | None = None,
               progress: bool = True, source: FrameSource | None = None, groundtruth: dict | None = None) -> Path:
    """The PNG capture ``png_capture`` as a capture of lossless videos (one per camera) in ``out``,
    with the same rig, manifest and ground truth. ``codec``: one of
    :data:`~spinemocap.capture.VIDEO_CODECS` (:class:`~spinemocap.capture.VideoWriter`: UT Video,
    what captures are written in by default, or uncompressed ``rawvideo``) or ``ffv1`` (the
    previous format, through OpenCV: the decoding peer); ``frames``: only the first so many; ``source`` and
    ``groundtruth``: other frames of the same rig and their ground truth (a replayed capture)."""
    capture = Capture.open(png_capture)
    source = source or capture.frame_source()
    n_frames = source.n_frames if frames is None else min(frames, source.n_frames)
    pattern = VIDEO_PATTERN if codec in VIDEO_CODECS else "videos/{camera}.mkv"
    writers = [_video_writer(out / pattern.format(camera=cam.name), codec, capture.fps, cam.size) for cam in capture.rig]
    try:
        for frame in tqdm(range(n_frames), desc=f"encoding {codec}", unit="frame", leave=False,
                           disable=not progress):
            for writer, image in zip(writers, source.read(frame)):
                writer.write(image)
    finally:
        for writer in writers:
            if isinstance(writer, VideoWriter):
                writer.close()
            else:
                writer.release()
    shutil.copy2(png_capture / capture.rig_file, out / capture.rig_file)
    if groundtruth is None:
        shutil.copy2(png_capture / "groundtruth.npz", out / "groundtruth.npz")
    else:
        np.savez(out / "groundtruth.npz", allow_pickle=False, **{k: np.asarray(v)[:n_frames] if k in REPLAYED else v
                                             for k, v in groundtruth.items()})
    manifest = read_toml(png_capture / "capture.toml")
    manifest["capture"].update(media="video", video_pattern=pattern, n_frames=n_frames)
    write_toml(out / "capture.toml", manifest)
    return out


def _video_writer(path: Path, codec: str, fps: float, size: tuple[int, int]):
    path.parent.mkdir(parents=True, exist_ok=True)
    if codec in VIDEO_CODECS:
        return VideoWriter(path, fps, size, codec)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, size)  # type: ignore[attr-defined]
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write FFV1 video to {path}")
    return writer


def replay_order(n_source: int, n_frames: int) -> list[int]:
    """Source frame indices that play ``n_source`` frames forward, backward, forward ... for
    ``n_frames`` frames (0 1 2 1 0 1 2 ...): a long, continuous sequence from a few frames."""
    if n_source < 2:
        return [0] * n_frames
    period = 2 * (n_source - 1)
    return [k if k < n_source else period - k for k in (f % period for f in range(n_frames))]


def every_camera(source: FrameSource, frame: int) -> list[np.ndarray]:
    """Frame ``frame`` of ``source``, one image per camera; InputError when a camera has none
    (a replayed benchmark needs every camera in every frame)."""
    images = source.read(frame)
    present = [image for image in images if image is not None]
    if len(present) < len(images):
        raise InputError(None, f"frame {frame} lacks the images of {len(images) - len(present)} cameras; "
                         "the speed benchmark replays complete frames only")
    return present


def with_sensor_noise(images: list[np.ndarray], sigma: float, seed: int) -> list[np.ndarray]:
    """Images plus Gaussian sensor noise (``sigma`` grey levels, seeded), as the studio's sensor
    adds it: for captures rendered without noise to keep them small (``--sensor-noise``)."""
    if sigma <= 0:
        return images
    out = []
    for c, image in enumerate(images):
        # float32 draws, in place: ~3x less time than float64 normals (6 x 11.75 M values a frame)
        noisy = np.random.default_rng([seed, 2, c]).standard_normal(image.shape, dtype=np.float32)
        noisy *= sigma
        noisy += image
        noisy += 0.5
        out.append(np.clip(noisy, 0, 255, out=noisy).astype(np.uint8))
    return out


def run_replay_benchmark(capture_dir: Path, frames: int, mode: TrackingMode = "sequence", detector: str = "net",
                         serial_peer: bool = True, speed: SpeedOptions | None = None, sensor_noise: float = 0.0,
                         progress: bool = True, say: Callable[[str], None] = print, cpu_peer: bool = True,
                         parallel_peer: bool = True, video_frames: int = 0, workdir: Path | None = None,
                         lookahead_peer: bool = False, default_peer: bool = True, budget: bool = True) -> ReplayedSpeed:
    """In-memory speed of an existing synthetic capture (e.g. a few frames carried to a machine
    that cannot render): its frames played forward and backward (:func:`replay_order`) for
    ``frames`` frames, the ground truth replayed alike; the new pipeline and the serial peer.
    When the network runs on a GPU, ``cpu_peer`` also runs the same pipeline on the CPU in the
    same run (``speedup_vs_cpu``) and every source frame is detected on both to compare the dots
    (``device_check``). ``parallel_peer``: the cameras also in the other parallel mode (processes
    or threads; ``speedup_processes_vs_threads``, ``same_output_processes_threads``).
    ``video_frames`` > 0: the first so many replayed frames (noise included) are also written as
    lossless UT Video into ``workdir`` (reused when there) and tracked from it, in both modes.
    ``lookahead_peer``: also the same pipeline with the other ``lookahead`` (0 when ``speed``
    looks ahead, else 1; :func:`lookahead_numbers`). ``default_peer``: when ``speed`` detects
    several frames at once, also the pipeline's default options on the same device
    (``in_memory_default``: one frame at a time, predicted boxes). ``budget``: the detection's
    time per camera image by step, one image after the other (:func:`detection_budget`).
    Ground-truth masks are not replayed (the serial peer reads none here)."""
    from ..detect.detector import resolve_device

    speed = speed or SpeedOptions()
    device = resolve_device(speed.device) if detector == "net" else "cpu"
    capture = Capture.open(capture_dir)
    source = capture.frame_source()
    decoded = [with_sensor_noise(every_camera(source, f), sensor_noise, f) for f in range(capture.n_frames)]
    order = replay_order(capture.n_frames, frames)
    replayed = MemorySource([decoded[i] for i in order], capture.camera_names)
    gt = replayed_groundtruth(capture, order)
    parallel = resolve_parallel(speed.parallel)
    other = "threads" if parallel == "processes" else "processes"
    speed = replace(speed, parallel=parallel)
    configs = [("in_memory", speed)]
    if parallel_peer and speed.n_workers(len(capture.rig)) > 1:
        configs.append((f"in_memory_{other}", replace(speed, parallel=other)))
    if lookahead_peer:
        configs.append((f"in_memory_lookahead{_peer_lookahead(speed)}", replace(speed, lookahead=_peer_lookahead(speed))))
    if default_peer and speed.frames_at_once > 1:
        configs.append(("in_memory_default", SpeedOptions(device=speed.device)))
    if speed.candidate_workers > 0:
        configs.append(("in_memory_candidates_in_tracker", replace(speed, candidate_workers=0)))
    if device != "cpu" and cpu_peer:
        configs.append(("in_memory_cpu", replace(speed, device="cpu")))
    if serial_peer:
        configs.append(("in_memory_serial", SERIAL))
    say(f"warming up (2 frames per run, not timed; network on {device}) ...")
    for _, options in configs:
        _timed_run(replayed, capture, options, mode, detector, False, range(2), masks=False)
    runs, positions = [], {}
    for name, options in configs:
        say(f"tracking: {name} ...")
        timed = _timed_run(replayed, capture, options, mode, detector, progress, masks=False)
        runs.append(_summary(name, timed, capture, gt, options))
        positions[name] = timed.result.table.to_arrays().positions
        say(f"  {runs[-1].fps:.2f} frames/s, {runs[-1].cpu_s_per_frame:.3f} CPU s/frame, "
            f"mean error {runs[-1].mean_error_mm:.3f} mm")
    fps_video = None
    if video_frames > 0:
        fps_video = _replayed_video_runs(capture, replayed, gt, video_frames, workdir, speed, mode, detector,
                                         progress, say, runs, parallel_peer)
    by_name = {r.run: r for r in runs}
    new, peer, cpu = by_name["in_memory"], by_name.get("in_memory_serial"), by_name.get("in_memory_cpu")
    by_mode = {parallel: by_name["in_memory"], other: by_name.get(f"in_memory_{other}")}
    in_processes, in_threads = by_mode["processes"], by_mode["threads"]
    check = None
    if cpu is not None:
        say("detecting every source frame on the CPU and on the GPU (same dots?) ...")
        check = dots_on_devices(decoded, device)
        say(f"  {check.to_dict()}")
    steps = None
    if budget and detector == "net":
        say(f"detection's time per camera image by step (network on {device}, one image at a time) ...")
        steps = detection_budget(decoded, device, speed.precision)
        say(f"  {steps}")
    default = by_name.get("in_memory_default")
    in_tracker = by_name.get("in_memory_candidates_in_tracker")
    return ReplayedSpeed(
        preset=f"capture {capture.name} replayed", source_frames=capture.n_frames, frames=frames,
        sensor_noise=sensor_noise, cameras=len(capture.rig), image_size=list(capture.rig[0].size),
        mode=mode, detector=detector, device=device, machine=machine_info(),
        speed_options=speed, fps_in_memory=new.fps, fps_png=None, fps_video=fps_video,
        speedup_vs_serial=new.fps / peer.fps if peer else None,
        accuracy_not_worse=_not_worse(new, peer) if peer else None,
        speedup_vs_cpu=new.fps / cpu.fps if cpu else None,
        accuracy_not_worse_vs_cpu=_not_worse(new, cpu) if cpu else None,
        same_accuracy_as_cpu=same_accuracy(new, cpu) if cpu else None,
        speedup_vs_default=new.fps / default.fps if default else None,
        speedup_candidates_ahead=new.fps / in_tracker.fps if in_tracker else None,
        same_output_candidates_ahead=(bool(np.array_equal(positions["in_memory"], positions[in_tracker.run],
                                                          equal_nan=True)) if in_tracker else None),
        detection_budget_ms=steps,
        parallel=parallel,
        speedup_processes_vs_threads=(in_processes.fps / in_threads.fps if in_processes and in_threads else None),
        # bit for bit the same tracked positions with the cameras in processes as in threads
        same_output_processes_threads=(bool(np.array_equal(positions["in_memory"], positions[f"in_memory_{other}"],
                                                           equal_nan=True)) if by_mode[other] else None),
        device_check=check,
        lookahead_comparison=lookahead_numbers(runs, speed, positions),
        accuracy_tolerance_mm=ACCURACY_TOLERANCE_MM, runs=runs, goals_fps=GOALS_FPS,
    )


def _peer_lookahead(speed: SpeedOptions) -> int:
    """The lookahead of the peer run: the exact serial order (0) when ``speed`` looks ahead, else 1."""
    return 0 if speed.lookahead > 0 else 1


def lookahead_numbers(runs: list[SpeedRun], speed: SpeedOptions,
                      positions: dict[str, np.ndarray]) -> LookaheadComparison | None:
    """The in-memory run against its peer with the other lookahead (None when that did not run):
    the frames/s ratio of detection ahead (lookahead > 0) over the exact serial order (0), the CPU
    per frame of each, accuracy not worse, and the largest distance (mm) between the two runs'
    tracked dots (:class:`LookaheadComparison`)."""
    peer_name = f"in_memory_lookahead{_peer_lookahead(speed)}"
    by_name = {r.run: r for r in runs}
    if peer_name not in by_name or "in_memory" not in by_name:
        return None
    ahead, exact = (by_name["in_memory"], by_name[peer_name]) if speed.lookahead > 0 else (by_name[peer_name], by_name["in_memory"])
    a, b = positions.get("in_memory"), positions.get(peer_name)
    differ = share = same_missing = None
    if a is not None and b is not None and a.shape == b.shape:
        both = np.isfinite(a).all(axis=-1) & np.isfinite(b).all(axis=-1)
        distance = np.linalg.norm(a - b, axis=-1)[both]
        differ = float(distance.max()) if both.any() else 0.0
        share = float(np.mean(distance > 0.1)) if both.any() else 0.0
        same_missing = bool(np.array_equal(np.isnan(a), np.isnan(b)))
    return LookaheadComparison(
        speedup_lookahead_in_memory=ahead.fps / exact.fps,
        cpu_s_per_frame_lookahead=ahead.cpu_s_per_frame, cpu_s_per_frame_exact=exact.cpu_s_per_frame,
        lookahead_accuracy_not_worse=_not_worse(ahead, exact),
        lookahead_max_difference_mm=differ,
        # share of the (frame, dot) positions tracked in both that moved by more than 0.1 mm
        lookahead_share_over_0p1mm=share,
        lookahead_same_missing=same_missing)


def _replayed_video_runs(capture: Capture, replayed: MemorySource, gt: dict, n_frames: int, workdir: Path | None,
                         speed: SpeedOptions, mode: TrackingMode, detector: str, progress: bool, say: Callable[[str], None],
                         runs: list[SpeedRun], parallel_peer: bool) -> float:
    """Track the first ``n_frames`` replayed frames from a lossless UT Video copy (``video`` with
    ``speed``, and ``video_<other mode>`` with the cameras in the other parallel mode); returns the fps."""
    video_dir = Path(workdir or tempfile.mkdtemp(prefix="spinemocap-speed-")) / f"video_replayed{n_frames}"
    if not (video_dir / "capture.toml").is_file():
        say(f"encoding {n_frames} replayed frames as lossless UT Video (not timed) ...")
        video_copy(capture.root, video_dir, frames=n_frames, progress=progress, source=replayed, groundtruth=gt)
    video = Capture.open(video_dir)
    configs = [("video", speed)]
    other = "threads" if speed.parallel == "processes" else "processes"
    if parallel_peer and speed.n_workers(len(video.rig)) > 1:
        configs.append((f"video_{other}", replace(speed, parallel=other)))
    for name, options in configs:
        say(f"tracking: {name} ...")
        runs.append(_summary(name, _timed_run(video.frame_source(), video, options, mode, detector, progress,
                                              masks=False), video))
        say(f"  {runs[-1].fps:.2f} frames/s, {runs[-1].cpu_s_per_frame:.3f} CPU s/frame")
    return runs[-len(configs)].fps


def machine_info() -> MachineInfo:
    """CPU cores and model, whether the CPU has VNNI and the network arithmetic ``precision="auto"``
    resolves to on it (int8 on VNNI CPUs: the CPU numbers of two machines compare only with the same
    arithmetic), load, torch's version and threads, and the GPU torch sees (or None)."""
    import platform

    import torch

    from ..detect.detector import auto_precision
    from ..detect.segnet import cpu_has_vnni

    cuda = torch.cuda.is_available()
    model = platform.processor()
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), model)
    except OSError:
        pass
    return MachineInfo(cpu_cores=os.cpu_count(), cpu_model=model, cpu_vnni=cpu_has_vnni(),
                       auto_precision=auto_precision(), load_average_1min=os.getloadavg()[0],
                       torch=torch.__version__, torch_threads=torch.get_num_threads(),
                       gpu=torch.cuda.get_device_name(0) if cuda else None,
                       cuda=torch.version.cuda if cuda else None,
                       cudnn_allow_tf32=bool(torch.backends.cudnn.allow_tf32) if cuda else None)


def dots_on_devices(frames: list[list[np.ndarray]], device: str, match_px: float = 1.0) -> DeviceDots:
    """Full two-stage detection of every image of ``frames`` (per frame, one BGR image per camera)
    with the network on the CPU and on ``device``: dots per side, dots of one side with no dot of
    the other within ``match_px``, the largest distance (px) between matched dots, and the number
    of mask pixels that differ."""
    from ..detect import Detector

    on_cpu, on_device = Detector("net", device="cpu"), Detector("net", device=device)
    counts = {"images": 0, "dots_cpu": 0, "dots_device": 0, "unmatched_cpu": 0, "unmatched_device": 0,
              "mask_pixels_differing": 0, "images_identical": 0}
    max_px = 0.0
    for images in frames:
        for camera, image in enumerate(images):
            a, b = on_cpu.detect(image, camera=camera), on_device.detect(image, camera=camera)
            dist = (np.linalg.norm(a.uv[:, None] - b.uv[None], axis=2) if len(a) and len(b)
                    else np.full((len(a), len(b)), np.inf))
            near_a = dist.min(axis=1) if len(b) else np.full(len(a), np.inf)
            near_b = dist.min(axis=0) if len(a) else np.full(len(b), np.inf)
            differing = int(np.count_nonzero(a.mask != b.mask))
            counts["images"] += 1
            counts["dots_cpu"] += len(a)
            counts["dots_device"] += len(b)
            counts["unmatched_cpu"] += int(np.count_nonzero(near_a > match_px))
            counts["unmatched_device"] += int(np.count_nonzero(near_b > match_px))
            matched = near_a[near_a <= match_px]
            max_px = max(max_px, float(matched.max()) if len(matched) else 0.0)
            counts["mask_pixels_differing"] += differing
            counts["images_identical"] += int(len(a) == len(b) and not differing
                                              and (not len(a) or float(near_a.max()) == 0.0))
    return DeviceDots(max_px=max_px, **counts)


def same_accuracy(run: SpeedRun, reference: SpeedRun, tolerance_mm: float = SAME_ACCURACY_MM) -> SameAccuracy:
    """``run``'s accuracy against ``reference``'s (e.g. the GPU path against the CPU path): the
    differences of the mean and 95th-percentile errors (mm) and of the label swaps, and
    ``same``: both within ``tolerance_mm`` and no more swaps or unsolved frames."""
    mean = run.mean_error_mm - reference.mean_error_mm
    p95 = run.p95_error_mm - reference.p95_error_mm
    return SameAccuracy(mean_difference_mm=mean, p95_difference_mm=p95,
                        label_swaps=run.label_swaps, reference_label_swaps=reference.label_swaps,
                        same=bool(abs(mean) <= tolerance_mm and abs(p95) <= tolerance_mm
                                  and run.label_swaps <= reference.label_swaps
                                  and run.frames_without_solution <= reference.frames_without_solution))


BUDGET_STEPS = ("network_stage1", "boxes", "network_stage2", "cleanup_and_dots", "instances_and_lattice", "grey_and_rest")


def detection_budget(frames: list[list[np.ndarray]], device: str, precision: str = "auto") -> dict[str, float]:
    """Mean wall ms per camera image of each step of the full two-stage search (one image after
    the other, one thread, after one image of warm-up), keyed by :data:`BUDGET_STEPS`, plus
    ``total``: stage 1's network pass and its boxes, stage 2's network passes, the
    full-resolution clean-up that finds the dots, the kept instances and the lattice test, and
    the grey conversion. ``frames``: per frame one BGR image per camera; ``device``: where the
    network runs."""
    from ..detect import Detector

    detector = Detector("net", device=device, precision=precision)
    images = [image for frame in frames for image in frame]
    detector.detect(images[0], camera=0)  # warm-up: first-call set-up on the device
    sums = dict.fromkeys(BUDGET_STEPS, 0.0)
    for image in images:
        n0, t0 = detector.network_s, time.perf_counter()
        boxes = detector.tape_boxes([image])[0]
        n1, t1 = detector.network_s, time.perf_counter()
        detector.detect(image, camera=0, boxes=boxes)
        n2, t2 = detector.network_s, time.perf_counter()
        timings = detector.last_timings
        sums["network_stage1"] += n1 - n0
        sums["boxes"] += (t1 - t0) - (n1 - n0)
        sums["network_stage2"] += n2 - n1
        sums["cleanup_and_dots"] += timings["cleanup_s"] - (n2 - n1)
        sums["instances_and_lattice"] += timings["segment_s"] - timings["cleanup_s"]
        sums["grey_and_rest"] += (t2 - t1) - timings["segment_s"]
    out = {step: 1000 * total / len(images) for step, total in sums.items()}
    out["total"] = sum(out.values())
    return out


def _not_worse(new: SpeedRun, peer: SpeedRun) -> bool:
    return (new.mean_error_mm <= peer.mean_error_mm + ACCURACY_TOLERANCE_MM
            and new.label_swaps <= peer.label_swaps
            and new.frames_without_solution <= peer.frames_without_solution)


@dataclass
class TimedRun:
    """A tracked run and what it cost: ``wall_s`` (the camera workers' start-up excluded),
    ``peak_mib`` (peak memory), ``cpu_s`` (CPU seconds of this process and of its camera workers
    after their start-up) and ``main_thread_cpu_s`` (of the thread that ran the tracker)."""

    result: TrackResult
    wall_s: float
    peak_mib: float
    cpu_s: float
    main_thread_cpu_s: float


def _timed_run(source: FrameSource, capture: Capture, speed: SpeedOptions, mode: TrackingMode, detector: str,
               progress: bool, frames: range | None = None, masks: bool = True) -> TimedRun:
    """Track ``frames`` of ``source`` (all when None) and measure it (:class:`TimedRun`).
    ``masks``: the capture's ground-truth ``masks/`` may be read (False for a replayed source)."""
    with warnings.catch_warnings(), PeakMemory() as memory:
        warnings.simplefilter("ignore", TrackingWarning)
        cpu_start, thread_start = time.process_time(), time.thread_time()
        start = time.perf_counter()
        result = track_source(source, capture.rig, capture.tape, capture.fps, frames, up=capture.up, mode=mode,
                              detector=detector, progress=progress, speed=speed,
                              mask_dir=capture.root / "masks" if masks else None)
        wall = time.perf_counter() - start
        cpu_s = time.process_time() - cpu_start
        main_thread_cpu_s = time.thread_time() - thread_start
    # camera worker processes: their start-up (importing torch, loading the network: seconds, once
    # per run, not per frame) is not timed; the CPU they used after it is added to this process's
    info = result.detector_info
    if info is not None and info.startup_s is not None and np.isfinite(info.startup_s):
        wall -= info.startup_s
    if info is not None and info.workers_cpu_s is not None and np.isfinite(info.workers_cpu_s):
        cpu_s += info.workers_cpu_s
    ahead = result.candidates_ahead  # the candidate workers likewise
    if ahead is not None:
        wall -= ahead.startup_s
        cpu_s += ahead.workers_cpu_s if np.isfinite(ahead.workers_cpu_s) else 0.0
    return TimedRun(result, wall, memory.peak_mib, cpu_s, main_thread_cpu_s)


def decode_speed(source: FrameSource, n_frames: int, workers: int) -> DecodeSpeed:
    """Decoding alone (every camera's image of each of the first ``n_frames`` frames, cameras in
    ``workers`` threads, no detection): ``fps`` (wall) and ``cpu_s_per_frame`` (this process, all
    threads): the ceiling the source sets on tracking speed."""
    from ..app.streaming import prefetched_frames

    cpu, start = time.process_time(), time.perf_counter()
    for _ in prefetched_frames(source, range(n_frames), workers=workers, prefetch=0):
        pass
    wall = time.perf_counter() - start
    return DecodeSpeed(frames=n_frames, fps=n_frames / wall, cpu_s_per_frame=(time.process_time() - cpu) / n_frames)


def replayed_groundtruth(capture: Capture, order: list[int]) -> dict:
    """The capture's ground truth for the frames ``order`` (source frame indices) in that order."""
    gt = dict(capture.groundtruth())
    for key in REPLAYED:
        if key in gt:
            gt[key] = np.asarray(gt[key])[order]
    return gt


def _summary(name: str, timed: TimedRun, capture: Capture, gt: dict | None = None,
             options: SpeedOptions | None = None) -> SpeedRun:
    result, wall, peak_mib = timed.result, timed.wall_s, timed.peak_mib
    info = result.detector_info
    gt = gt if gt is not None else capture.groundtruth()
    acc = evaluate_tracking(result.table, gt, float(capture.tape.graph.rest_length_mm.min()), result.stage_ms())
    n = len(result.frames)
    return SpeedRun(
        run=name, frames=n, wall_s=wall, fps=n / wall if wall > 0 else float("nan"),
        # CPU seconds of this process (all threads) per frame: less sensitive than wall time to
        # other programs on a shared machine; cores / this = fps on an idle machine at best
        cpu_s_per_frame=timed.cpu_s / max(n, 1),
        # cores busy on average = CPU s per frame x frames/s
        cores_used=timed.cpu_s / wall if wall > 0 else float("nan"),
        # CPU s per frame of the thread that runs the tracker (with lookahead 0 it also drives
        # detection), and of the camera worker processes: where the CPU goes
        main_thread_cpu_s_per_frame=timed.main_thread_cpu_s / max(n, 1),
        workers_cpu_s_per_frame=(info.workers_cpu_s or 0.0) / max(n, 1) if info is not None else 0.0,
        parallel=info.parallel if info is not None else None, workers=info.workers if info is not None else None,
        lookahead=options.lookahead if options is not None else None,
        workers_startup_s=info.startup_s if info is not None else None,
        slowest_camera_ms=info.slowest_camera_ms if info is not None else None,
        stage_ms=result.stage_ms(), peak_memory_mib=peak_mib, routes=result.routes(),
        detector_searches=dict(result.detector_searches),
        mean_error_mm=acc.mean_error_mm, p95_error_mm=acc.p95_error_mm,
        label_swaps=acc.label_swaps, frames_without_solution=acc.frames_without_solution,
        candidates_built_ahead=result.candidates_ahead.built if result.candidates_ahead else 0,
        candidates_taken_ahead=result.candidates_taken_ahead,
    )


def run_speed_benchmark(preset: str = "studio", frames: int = 100, occlusion: str = "none",
                        mode: TrackingMode = "sequence", detector: str = "net", seed: int = 0,
                        workdir: Path | None = None, serial_peer: bool = True, video: bool = True,
                        in_memory: bool = True, speed: SpeedOptions | None = None, progress: bool = True,
                        say: Callable[[str], None] = print, realism: str = "lab", memory_frames: int = 30,
                        parallel_peer: bool = False, lookahead_peer: bool = False,
                        video_codec: str = VIDEO_CODEC) -> RenderedSpeed:
    """Render ``frames`` frames of the synthetic ``preset`` and time tracking them (see the module
    docstring). ``serial_peer``: also run the serial pipeline (the peer); ``workdir``: where the
    capture folders go (a temporary folder, removed afterwards, when None); ``realism``: the
    studio's level (``lab``: tension, skin strain, the lab's inexact rig, sync error, noise);
    ``memory_frames``: decoded frames held for the in-memory runs (replayed forward and backward);
    ``parallel_peer`` / ``lookahead_peer``: the in-memory run also with the cameras in the other
    parallel mode / with the other lookahead (:func:`lookahead_numbers`; the video run too);
    ``video_codec``: the lossless codec the video run reads (:data:`~spinemocap.capture.VIDEO_CODECS`;
    its copy goes to ``video`` for UT Video, else ``video_<codec>``)."""
    from ..synth import SynthConfig, write_capture

    if video_codec not in VIDEO_CODECS:
        raise InputError(None, f"unknown video codec {video_codec!r} (choose {', '.join(VIDEO_CODECS)})")

    speed = speed or SpeedOptions()
    config = SynthConfig.preset(preset, frames=frames, occlusion=occlusion, seed=seed, realism=realism)
    tmp: str | None = None
    if workdir is not None:
        root = Path(workdir)
    else:
        tmp = tempfile.mkdtemp(prefix="spinemocap-speed-")
        root = Path(tmp)
    try:
        png_dir = root / "png"
        if not (png_dir / "capture.toml").is_file():
            say(f"rendering the {preset} scene ({frames} frames, {config.cameras} cameras {config.size[0]}x{config.size[1]}) "
                f"to PNG (not timed) ...")
            write_capture(config, png_dir, progress=progress)
        capture = Capture.open(png_dir)
        runs: list[SpeedRun] = []

        positions: dict[str, np.ndarray] = {}

        def run(name: str, source: FrameSource, options: SpeedOptions, gt: dict | None = None) -> SpeedRun:
            say(f"tracking: {name} ...")
            timed = _timed_run(source, capture, options, mode, detector, progress)
            summary = _summary(name, timed, capture, gt, options)
            positions[name] = timed.result.table.to_arrays().positions
            runs.append(summary)
            say(f"  {summary.fps:.2f} frames/s, {summary.cpu_s_per_frame:.2f} CPU s/frame, "
                f"mean error {summary.mean_error_mm:.3f} mm")
            return summary

        say("warming up (2 frames, not timed: model loading, first-call set-up) ...")
        for options in (speed, SERIAL):
            _timed_run(capture.frame_source(), capture, options, mode, detector, False, range(min(2, frames)))
        mem = mem_peer = None
        if in_memory:
            # at most memory_frames decoded frames held (six 2448x1600 images are 70 MB a frame),
            # played forward and backward for all frames, the ground truth alike
            source = capture.frame_source()
            held = [every_camera(source, f) for f in range(min(capture.n_frames, memory_frames))]
            order = replay_order(len(held), capture.n_frames)
            gt = replayed_groundtruth(capture, order)
            frames_in_memory = MemorySource([held[i] for i in order], capture.camera_names)
            mem = run("in_memory", frames_in_memory, speed, gt)
            other = "threads" if speed.parallel == "processes" else "processes"
            if parallel_peer:
                run(f"in_memory_{other}", frames_in_memory, replace(speed, parallel=other), gt)
            if lookahead_peer:
                peer_speed = replace(speed, lookahead=_peer_lookahead(speed))
                run(f"in_memory_lookahead{peer_speed.lookahead}", frames_in_memory, peer_speed, gt)
                if parallel_peer:
                    run(f"in_memory_{other}_lookahead{peer_speed.lookahead}", frames_in_memory,
                        replace(peer_speed, parallel=other), gt)
            if serial_peer:
                mem_peer = run("in_memory_serial", frames_in_memory, SERIAL, gt)
            del held, frames_in_memory
        workers = speed.n_workers(len(capture.camera_names))
        decoding = {"png": decode_speed(capture.frame_source(), capture.n_frames, workers)}
        vid = None
        if video:
            video_dir = root / ("video" if video_codec == "utvideo" else f"video_{video_codec}")
            ffv1_dir = root / "video_ffv1"
            if not (video_dir / "capture.toml").is_file():
                say(f"encoding the frames as lossless video ({video_codec}, not timed) ...")
                video_copy(png_dir, video_dir, codec=video_codec, progress=progress)
            decoding["video"] = decode_speed(Capture.open(video_dir).frame_source(), capture.n_frames, workers)
            n_ffv1 = min(capture.n_frames, FFV1_FRAMES)  # the previous format's decoding: the peer
            if not (ffv1_dir / "capture.toml").is_file():
                say(f"encoding {n_ffv1} frames as FFV1, the previous video format (not timed) ...")
                video_copy(png_dir, ffv1_dir, codec="ffv1", frames=n_ffv1, progress=progress)
            decoding["video_ffv1_previous"] = decode_speed(Capture.open(ffv1_dir).frame_source(), n_ffv1, workers)
            vid = run("video", Capture.open(video_dir).frame_source(), speed)
            if lookahead_peer:
                peer_speed = replace(speed, lookahead=_peer_lookahead(speed))
                run(f"video_lookahead{peer_speed.lookahead}", Capture.open(video_dir).frame_source(), peer_speed)
        alone = {name: decoded.to_dict() for name, decoded in decoding.items()}
        say(f"  decoding alone: {alone}")
        png = run("png", capture.frame_source(), speed)
        peer = run("png_serial", capture.frame_source(), SERIAL) if serial_peer else None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return RenderedSpeed(
        preset=preset, realism=realism, frames=frames, cameras=config.cameras, image_size=list(config.size),
        occlusion=occlusion, mode=mode, detector=detector, machine=machine_info(),
        speed_options=speed,
        fps_png=png.fps,
        fps_video=vid.fps if vid else None,
        video_codec=video_codec if vid else None,
        fps_in_memory=mem.fps if mem else None,
        speedup_vs_serial=png.fps / peer.fps if peer else None,
        speedup_vs_serial_in_memory=mem.fps / mem_peer.fps if mem and mem_peer else None,
        cpu_ratio_vs_serial_in_memory=mem_peer.cpu_s_per_frame / mem.cpu_s_per_frame if mem and mem_peer else None,
        accuracy_not_worse=_not_worse(png, peer) if peer else None,
        accuracy_not_worse_in_memory=_not_worse(mem, mem_peer) if mem and mem_peer else None,
        accuracy_tolerance_mm=ACCURACY_TOLERANCE_MM,
        memory_frames=memory_frames,
        lookahead_comparison=lookahead_numbers(runs, speed, positions),
        decode_only=decoding,
        runs=runs,
        goals_fps=GOALS_FPS,
    )


def save(numbers: SpeedNumbers, path: Path) -> None:
    """Write ``numbers`` to ``path`` as JSON (their :meth:`to_dict`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as fh:
        json.dump(numbers.to_dict(), fh, indent=2, default=float)


def plot_stages(numbers: SpeedNumbers, path: Path) -> Path:
    """Stacked bars of each run's time per stage (ms per frame, wall) with the frame budget of
    the goal that applies (100 frames/s on a GPU, else 10 on two cores) as a line; a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = numbers.runs
    stages = list(runs[0].stage_ms) if runs else []
    on_gpu = isinstance(numbers, ReplayedSpeed) and numbers.device != "cpu"
    budget_ms = 1000.0 / GOALS_FPS["gpu" if on_gpu else "in_memory_cpu2"]
    fig, ax = plt.subplots(figsize=(9, 1.6 + 0.5 * len(runs)))
    left = np.zeros(len(runs))
    for stage in stages:
        ms = np.array([r.stage_ms[stage] for r in runs])
        ax.barh([r.run for r in runs], ms, left=left, label=stage)
        left += ms
    ax.axvline(budget_ms, color="k", linestyle="--", label=f"goal: {1000 / budget_ms:.0f} frames/s")
    ax.set_xlabel("ms per frame (wall)")
    machine = numbers.machine
    ax.set_title(f"{numbers.preset}: {numbers.cameras} cameras, {machine.cpu_cores} cores, "
                 f"GPU {machine.gpu or 'none'}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
    return path


def format_report(numbers: SpeedNumbers) -> str:
    """A table of the runs: fps, per-stage ms, peak memory, accuracy; then the comparisons."""
    runs, machine = numbers.runs, numbers.machine
    rendered = numbers if isinstance(numbers, RenderedSpeed) else None
    replayed = numbers if isinstance(numbers, ReplayedSpeed) else None
    stages = list(runs[0].stage_ms) if runs else []
    head = f"  {'run':<18}{'fps':>7}{'cpu s/f':>8}{'cores':>6}{'peak MiB':>10}{'err mm':>8}{'swaps':>6}  " + " ".join(f"{s:>10}" for s in stages)
    lines = [f"\nspeed: {numbers.preset} x {numbers.frames} frames, {numbers.cameras} cameras "
             f"{numbers.image_size[0]}x{numbers.image_size[1]}, mode {numbers.mode}, detector "
             f"{numbers.detector}; {machine.cpu_cores} CPU cores (load {machine.load_average_1min:.1f}), "
             f"GPU {machine.gpu or 'none'}", head]
    for r in runs:
        lines.append(f"  {r.run:<18}{r.fps:>7.2f}{r.cpu_s_per_frame:>8.2f}{r.cores_used:>6.2f}{r.peak_memory_mib:>10.0f}{r.mean_error_mm:>8.3f}"
                     f"{r.label_swaps:>6}  " + " ".join(f"{r.stage_ms[s]:>10.0f}" for s in stages))
    if rendered is not None and rendered.decode_only:
        lines.append("  decoding alone (no detection): "
                     + ", ".join(f"{k} {v.fps:.2f} fps / {v.cpu_s_per_frame:.2f} CPU s per frame"
                                 for k, v in rendered.decode_only.items()))
    if numbers.speedup_vs_serial is not None:
        source = "PNG" if numbers.fps_png is not None else "in memory"
        lines.append(f"  speedup vs the serial pipeline ({source}): {numbers.speedup_vs_serial:.2f}x; "
                     f"accuracy not worse: {numbers.accuracy_not_worse}")
    if replayed is not None and replayed.speedup_processes_vs_threads is not None:
        lines.append(f"  cameras in processes: {replayed.speedup_processes_vs_threads:.2f}x the frames/s of cameras in "
                     f"threads (in memory; default here: {replayed.parallel}); same tracked positions: "
                     f"{replayed.same_output_processes_threads}")
    ahead = numbers.lookahead_comparison
    if ahead is not None:
        lines.append(f"  detection ahead of the tracker: {ahead.speedup_lookahead_in_memory:.2f}x the frames/s of the "
                     f"exact serial order (in memory; CPU s per frame {ahead.cpu_s_per_frame_lookahead:.3f} vs "
                     f"{ahead.cpu_s_per_frame_exact:.3f}); accuracy not worse: {ahead.lookahead_accuracy_not_worse}; "
                     + _differences(ahead))
    if replayed is not None:
        lines += _device_lines(replayed)
    if rendered is not None and rendered.speedup_vs_serial_in_memory is not None:
        lines.append(f"  in memory: {rendered.speedup_vs_serial_in_memory:.2f}x the serial pipeline's frames/s, "
                     f"{rendered.cpu_ratio_vs_serial_in_memory:.2f}x less CPU per frame; "
                     f"accuracy not worse: {rendered.accuracy_not_worse_in_memory}")
    return "\n".join(lines)


def _differences(ahead: LookaheadComparison) -> str:
    differ, share = ahead.lookahead_max_difference_mm, ahead.lookahead_share_over_0p1mm
    if differ is None or share is None:
        return "the two runs' tracked dots differ in shape"
    return f"largest difference {differ:.4f} mm, {100 * share:.2f} % of dots > 0.1 mm"


def _device_lines(numbers: ReplayedSpeed) -> list[str]:
    """The replayed capture's comparisons with the CPU and the pipeline's defaults, the detection's
    time per step and the dots on both devices."""
    lines = []
    if numbers.speedup_vs_cpu is not None:
        lines.append(f"  network on {numbers.device}: {numbers.speedup_vs_cpu:.2f}x the same pipeline's frames/s "
                     f"on the CPU; accuracy not worse: {numbers.accuracy_not_worse_vs_cpu}")
    same = numbers.same_accuracy_as_cpu
    if same is not None:
        lines.append(f"  accuracy against the CPU path: mean {same.mean_difference_mm:+.4f} mm, p95 "
                     f"{same.p95_difference_mm:+.4f} mm, swaps {same.label_swaps} vs {same.reference_label_swaps}: "
                     f"{'same' if same.same else 'NOT the same'} (within {SAME_ACCURACY_MM} mm)")
    if numbers.speedup_vs_default is not None:
        lines.append(f"  {numbers.speed_options.frames_at_once} frames at once: {numbers.speedup_vs_default:.2f}x the "
                     f"frames/s of the pipeline's defaults on the same device")
    if numbers.speedup_candidates_ahead is not None:
        run = next(r for r in numbers.runs if r.run == "in_memory")
        lines.append(f"  candidates built ahead in {numbers.speed_options.candidate_workers} processes: "
                     f"{numbers.speedup_candidates_ahead:.2f}x the frames/s of the tracker building them "
                     f"({run.candidates_taken_ahead} of {run.frames} frames served); same dots: "
                     f"{numbers.same_output_candidates_ahead}")
    if numbers.detection_budget_ms:
        lines.append("  detection per camera image, one at a time (ms): "
                     + ", ".join(f"{k} {v:.1f}" for k, v in numbers.detection_budget_ms.items()))
    if numbers.device_check is not None:
        lines.append(f"  dots, GPU vs CPU (full search of every source image): {numbers.device_check.to_dict()}")
    return lines
