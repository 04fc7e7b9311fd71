"""What ``spinemocap bench speed`` reports (:mod:`spinemocap.bench.speed`): one
:class:`SpeedRun` per timed run, decoding alone, accuracy and lookahead comparisons, the
machine, and the whole record of a rendered scene (:class:`RenderedSpeed`) or a replayed capture
(:class:`ReplayedSpeed`). ``to_dict`` gives the JSON object ``--json`` writes (keys in field
order, nested results as objects)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from ..app.run import TrackingMode
from ..app.streaming import DetectionRoute, SpeedOptions
from .records import JsonRecord


@dataclass(frozen=True)
class SpeedRun(JsonRecord):
    """One timed run of the benchmark (an entry of ``runs``): its name and frames, ``wall_s``
    (the camera workers' start-up excluded) and ``fps``; CPU seconds per frame of this process
    and its camera workers (``cpu_s_per_frame``), of the tracker's thread and of the workers
    alone, and ``cores_used`` (CPU over wall); the detector's parallel mode, workers, lookahead,
    workers' start-up (s) and slowest camera (ms per call; None when not in processes); mean ms
    per stage per frame; peak memory above the start (MiB); frames per tracker route and camera
    images per detection route; and the accuracy against the ground truth (mm, swaps, frames
    without a solution)."""

    run: str
    frames: int
    wall_s: float
    fps: float
    cpu_s_per_frame: float
    cores_used: float
    main_thread_cpu_s_per_frame: float
    workers_cpu_s_per_frame: float
    parallel: str | None
    workers: int | None
    lookahead: int | None
    workers_startup_s: float | None
    slowest_camera_ms: float | None
    stage_ms: dict[str, float]
    peak_memory_mib: float
    routes: dict[str, int]
    detector_searches: dict[DetectionRoute, int]
    mean_error_mm: float
    p95_error_mm: float
    label_swaps: int
    frames_without_solution: int
    candidates_built_ahead: int = 0
    candidates_taken_ahead: int = 0


@dataclass(frozen=True)
class DecodeSpeed(JsonRecord):
    """Decoding alone (:func:`decode_speed`): frames decoded, frames per second (wall) and CPU
    seconds per frame."""

    frames: int
    fps: float
    cpu_s_per_frame: float


@dataclass(frozen=True)
class SameAccuracy(JsonRecord):
    """A run's accuracy against a reference run's (:func:`same_accuracy`): the differences of
    the mean and 95th-percentile errors (mm), both runs' label swaps, and ``same``."""

    mean_difference_mm: float
    p95_difference_mm: float
    label_swaps: int
    reference_label_swaps: int
    same: bool


@dataclass(frozen=True)
class LookaheadComparison(JsonRecord):
    """The run detecting ahead of the tracker against the exact serial order
    (:func:`lookahead_numbers`): the frames/s ratio, CPU seconds per frame of each, accuracy not
    worse, the largest distance (mm) between their tracked dots, the share of dots tracked in
    both that moved more than 0.1 mm, and whether the same dots are missing (None: shapes differ)."""

    speedup_lookahead_in_memory: float
    cpu_s_per_frame_lookahead: float
    cpu_s_per_frame_exact: float
    lookahead_accuracy_not_worse: bool
    lookahead_max_difference_mm: float | None
    lookahead_share_over_0p1mm: float | None
    lookahead_same_missing: bool | None


@dataclass(frozen=True)
class MachineInfo(JsonRecord):
    """The machine a benchmark ran on (:func:`machine_info`)."""

    cpu_cores: int | None
    cpu_model: str
    cpu_vnni: bool
    auto_precision: str
    load_average_1min: float
    torch: str
    torch_threads: int
    gpu: str | None
    cuda: str | None
    cudnn_allow_tf32: bool | None


@dataclass(frozen=True)
class DeviceDots(JsonRecord):
    """Dots found with the network on the CPU and on another device (:func:`dots_on_devices`):
    camera images, dots per side, dots of one side with no dot of the other within the match
    distance, the largest distance (px) between matched dots, mask pixels that differ, and images
    whose dots and mask are identical."""

    images: int
    dots_cpu: int
    dots_device: int
    unmatched_cpu: int
    unmatched_device: int
    max_px: float
    mask_pixels_differing: int
    images_identical: int


def _flattened(record: JsonRecord, nested: str) -> dict[str, Any]:
    """``record``'s fields as a JSON object, the keys of its field ``nested`` (a result or None)
    in that field's place."""
    out: dict[str, Any] = {}
    for name, value in asdict(record).items():
        if name == nested:
            out.update(value or {})
        else:
            out[name] = value
    return out


@dataclass(frozen=True)
class RenderedSpeed(JsonRecord):
    """``bench speed`` on a rendered studio scene (:func:`run_speed_benchmark`): the scene and
    options, the frames/s from PNG, lossless video and memory, the speedups and CPU ratio over
    the serial pipeline with accuracy not worse, the lookahead comparison (when it ran),
    decoding alone per source, every run and the goals (frames/s)."""

    preset: str
    realism: str
    frames: int
    cameras: int
    image_size: list[int]
    occlusion: str
    mode: TrackingMode
    detector: str
    machine: MachineInfo
    speed_options: SpeedOptions
    fps_png: float
    fps_video: float | None
    video_codec: str | None
    fps_in_memory: float | None
    speedup_vs_serial: float | None
    speedup_vs_serial_in_memory: float | None
    cpu_ratio_vs_serial_in_memory: float | None
    accuracy_not_worse: bool | None
    accuracy_not_worse_in_memory: bool | None
    accuracy_tolerance_mm: float
    memory_frames: int
    lookahead_comparison: LookaheadComparison | None
    decode_only: dict[str, DecodeSpeed]
    runs: list[SpeedRun]
    goals_fps: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields in order, the lookahead comparison's keys in its place."""
        return _flattened(self, "lookahead_comparison")


@dataclass(frozen=True)
class ReplayedSpeed(JsonRecord):
    """``bench speed --capture`` (:func:`run_replay_benchmark`): the capture replayed and the
    options, the device, frames/s in memory (and from video), the speedups over the serial
    pipeline, the CPU and the pipeline's defaults with accuracy not worse or the same, the
    detection's time per step, the parallel mode and processes vs threads, the dots on both
    devices, the lookahead comparison (when it ran), every run and the goals (frames/s).
    ``speedup_candidates_ahead``: with candidate workers, the frames/s over the same options with
    the tracker building the candidates itself, and ``same_output_candidates_ahead`` whether the
    two tracked bit for bit the same dots (None when that peer did not run)."""

    preset: str
    source_frames: int
    frames: int
    sensor_noise: float
    cameras: int
    image_size: list[int]
    mode: TrackingMode
    detector: str
    device: str
    machine: MachineInfo
    speed_options: SpeedOptions
    fps_in_memory: float
    fps_png: None
    fps_video: float | None
    speedup_vs_serial: float | None
    accuracy_not_worse: bool | None
    speedup_vs_cpu: float | None
    accuracy_not_worse_vs_cpu: bool | None
    same_accuracy_as_cpu: SameAccuracy | None
    speedup_vs_default: float | None
    speedup_candidates_ahead: float | None
    same_output_candidates_ahead: bool | None
    detection_budget_ms: dict[str, float] | None
    parallel: str
    speedup_processes_vs_threads: float | None
    same_output_processes_threads: bool | None
    device_check: DeviceDots | None
    lookahead_comparison: LookaheadComparison | None
    accuracy_tolerance_mm: float
    runs: list[SpeedRun]
    goals_fps: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields in order, the lookahead comparison's keys in its place."""
        return _flattened(self, "lookahead_comparison")


#: What ``bench speed`` returns: a rendered scene's numbers or a replayed capture's.
SpeedNumbers = RenderedSpeed | ReplayedSpeed
