"""Speed machinery: detection by prediction finds the dots the full search finds, the
parallel path gives the serial path's output, masks are read only for the mask detector, and
the prefetching reader hands its errors to the consumer."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
from repo_paths import ROOT

from spinemocap.app.run import track_source
from spinemocap.app.streaming import CaptureDetector, SpeedOptions, prefetched_frames
from spinemocap.fileio import InputError

pytest.importorskip("pyvista")


def _rendered(preset: str, frames: int, **overrides):
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset(preset, frames=frames, **overrides))
    images = [scene.render(f, with_masks=False).images for f in range(frames)]
    return scene, images


def _speed_run(**fields):
    """A :class:`~spinemocap.bench.speed.SpeedRun` of 4 frames, error-free unless ``fields`` say otherwise."""
    from spinemocap.bench.speed_results import SpeedRun

    run = SpeedRun(run="in_memory", frames=4, wall_s=2.0, fps=2.0, cpu_s_per_frame=0.5, cores_used=1.0,
                   main_thread_cpu_s_per_frame=0.4, workers_cpu_s_per_frame=0.0, parallel="threads", workers=2,
                   lookahead=0, workers_startup_s=None, slowest_camera_ms=None, stage_ms={"detect": 100.0},
                   peak_memory_mib=40.0, routes={"full": 4}, detector_searches={"full": 12}, mean_error_mm=0.0,
                   p95_error_mm=0.0, label_swaps=0, frames_without_solution=0)
    return replace(run, **fields)


def _same_dots(a, b) -> float:
    """Largest distance (px) between matched dots of two ViewDots lists; inf when counts differ."""
    worst = 0.0
    for va, vb in zip(a, b):
        if len(va) != len(vb):
            return float("inf")
        if len(va):
            worst = max(worst, float(np.linalg.norm(va.uv[:, None] - vb.uv[None], axis=2).min(axis=1).max()))
    return worst


def _tracked_from_memory(scene, images, options, mode="sequence"):
    """``images`` (per frame, one image per camera) of ``scene`` tracked from memory with ``options``."""
    from spinemocap.bench.speed import MemorySource

    return track_source(MemorySource(images, scene.rig.names), scene.rig, scene.tape, scene.fps,
                        up=scene.subject()["up"], mode=mode, progress=False, speed=options)


def _prediction_vs_full(scene, images):
    gt = scene.groundtruth["dots"]
    full = CaptureDetector("net", scene.rig, SpeedOptions(predict=False, workers=1))
    predicted = CaptureDetector("net", scene.rig, SpeedOptions(predict=True, refresh_every=1000, workers=1))
    try:
        worst = 0.0
        for f, frame_images in enumerate(images):
            worst = max(worst, _same_dots(full(f, frame_images, None), predicted(f, frame_images, None)))
            predicted.observe(f, gt[f])
    finally:
        full.close()
        predicted.close()
    return worst, predicted.searches


@pytest.mark.slow
def test_prediction_finds_the_full_search_dots_on_the_studio():
    scene, images = _rendered("studio", 3)
    worst, searches = _prediction_vs_full(scene, images)
    assert searches["predicted"] == 2 * len(scene.rig) and searches["fallback"] == 0
    assert worst < 0.01


@pytest.fixture(scope="module")
def small_studio():
    """The studio's six cameras at a quarter of the pixels, two frames (rendered once per module)."""
    return _rendered("studio", 2, size=(1224, 800))


def test_prediction_finds_the_full_search_dots_on_a_small_studio(small_studio):
    # the default suite's version of the test above
    scene, images = small_studio
    worst, searches = _prediction_vs_full(scene, images)
    assert searches["full"] == len(scene.rig)            # only the first frame searched in full
    assert searches["predicted"] == len(scene.rig) and searches["fallback"] == 0
    assert worst < 0.01


@pytest.mark.parametrize("parallel", ["threads", "processes"])
def test_parallel_path_gives_the_serial_output(parallel):
    scene, images = _rendered("tiny", 3)
    serial = _tracked_from_memory(scene, images, SpeedOptions(workers=1, prefetch=0))
    parallel_run = _tracked_from_memory(scene, images, SpeedOptions(workers=3, prefetch=2, parallel=parallel))
    assert serial.detector_info.parallel == "serial"
    assert parallel_run.detector_info.parallel == parallel  # it did run in parallel (no fallback)
    a, b = serial.table.to_arrays(), parallel_run.table.to_arrays()
    np.testing.assert_array_equal(a.positions, b.positions)
    assert (a.status == b.status).all()
    assert serial.detector_searches == parallel_run.detector_searches


def _assert_same_views(a, b):
    assert len(a) == len(b)
    for va, vb in zip(a, b):
        assert va.camera == vb.camera
        np.testing.assert_array_equal(va.uv, vb.uv)
        np.testing.assert_array_equal(va.confidence, vb.confidence)
        np.testing.assert_array_equal(va.mask, vb.mask)
        np.testing.assert_array_equal(va.image, vb.image)


def test_camera_processes_give_the_serial_views_on_a_small_studio(small_studio):
    # full search (stage 1 batched over the cameras in this process, one image per pass in a
    # worker) and the predicted boxes: the same dots, masks and grey images bit for bit
    scene, images = small_studio
    gt = scene.groundtruth["dots"]
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1))
    processes = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, parallel="processes"))
    try:
        assert processes.parallel == "processes"
        assert processes._processes is not None and len(processes._processes.pids) == 2  # both workers' CPU counted
        for f, frame_images in enumerate(images):
            _assert_same_views(serial(f, frame_images, None), processes(f, frame_images, None))
            serial.observe(f, gt[f])
            processes.observe(f, gt[f])
        assert serial.searches == processes.searches and processes.searches["predicted"] == len(scene.rig)
        assert sum(len(v) for v in processes(9, images[1], None)) > 50  # the tape was in view
    finally:
        serial.close()
        processes.close()
    assert (processes.info.workers_cpu_s or 0) > 0  # the workers' CPU is measured (bench speed adds it)
    assert (processes.info.slowest_camera_ms or 0) > 0


def test_camera_threads_give_the_serial_views_on_a_small_studio(small_studio):
    import threading

    # threads (default options, network on the CPU): each camera's full search does its own stage 1
    # in the pool (serial: stage 1 batched over the cameras): the same dots, masks and grey images
    # bit for bit
    scene, images = small_studio
    gt = scene.groundtruth["dots"]
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1))
    threads = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, device="cpu"))
    stage1_threads: list = []
    tape_boxes = threads.detector.tape_boxes

    def recorded(batch):  # the real stage 1, noting the thread it ran in and the images per pass
        stage1_threads.append((threading.current_thread().name, len(batch)))
        return tape_boxes(batch)

    threads.detector.tape_boxes = recorded
    try:
        assert threads.parallel == "threads"
        for f, frame_images in enumerate(images):
            _assert_same_views(serial(f, frame_images, None), threads(f, frame_images, None))
            serial.observe(f, gt[f])
            threads.observe(f, gt[f])
        assert serial.searches == threads.searches and threads.searches["predicted"] == len(scene.rig)
        # the first frame's full search: one stage-1 pass per camera, all in the pool's threads
        assert len(stage1_threads) == len(scene.rig)
        assert all(name.startswith("detect") and n == 1 for name, n in stage1_threads)
    finally:
        serial.close()
        threads.close()
    # stage1_in_pool=False: one batched pass for all cameras in the calling thread, the same views
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1))  # anew: no frame observed
    batched = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, device="cpu", stage1_in_pool=False))
    stage1_threads.clear()
    tape_boxes = batched.detector.tape_boxes
    batched.detector.tape_boxes = recorded
    try:
        _assert_same_views(serial(0, images[0], None), batched(0, images[0], None))
        assert stage1_threads == [(threading.current_thread().name, len(scene.rig))]
    finally:
        serial.close()
        batched.close()


def test_a_dead_camera_process_falls_back_to_threads_with_the_same_views(small_studio):
    import os
    import signal
    import time

    from spinemocap.app.streaming import ParallelFallbackWarning

    scene, images = small_studio
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1, predict=False))
    processes = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, parallel="processes", predict=False))
    try:
        _assert_same_views(serial(0, images[0], None), processes(0, images[0], None))
        os.kill(processes._processes.pids[0], signal.SIGKILL)
        time.sleep(0.5)
        with pytest.warns(ParallelFallbackWarning, match="died"):
            views = processes(1, images[1], None)
        assert processes.parallel == "threads"
        _assert_same_views(serial(1, images[1], None), views)
    finally:
        serial.close()
        processes.close()


def test_processes_that_cannot_start_fall_back_to_threads(monkeypatch):
    from spinemocap.app import camera_processes, streaming

    def cannot_start(*args, **kwargs):
        raise camera_processes.ProcessesUnavailable("OSError: no processes here")

    monkeypatch.setattr(streaming, "CameraProcesses", cannot_start)
    scene, _ = _rendered("tiny", 1)
    with pytest.warns(streaming.ParallelFallbackWarning, match="could not start.*no processes here.*threads"):
        detector = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, parallel="processes"))
    try:
        assert detector.parallel == "threads"
    finally:
        detector.close()


@pytest.mark.slow  # ~45 s on the 2-core machine, most of it rendering the capture
@pytest.mark.parametrize("lookahead", ["0", "1"])  # 1: detection runs a frame ahead in its own thread
def test_ctrl_c_stops_tracking_with_camera_processes(tmp_path, lookahead):
    # a real `spinemocap track` with cameras in worker processes, Ctrl-C sent to its process
    # group as a terminal does: it exits within seconds and leaves no worker behind
    import os
    import signal
    import subprocess
    import sys
    import time

    import psutil

    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=60), tmp_path / "capture", progress=False)
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.Popen([sys.executable, "-m", "spinemocap", "track", str(root), "--out", str(tmp_path / "out"),
                             "--workers", "2", "--parallel", "processes", "--lookahead", lookahead, "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True,
                            # Ctrl-C's default action even when this test runs in a background job
                            # (whose children inherit SIGINT ignored, and Python keeps it so)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        parent = psutil.Process(proc.pid)
        end = time.monotonic() + 120
        workers: list = []
        while len(workers) < 2:  # both camera workers up (the resource tracker is a child too)
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < end, "the workers did not start"
            workers = [p for p in parent.children(recursive=True) if "resource_tracker" not in " ".join(p.cmdline())]
            time.sleep(0.2)
        time.sleep(3.0)  # tracking under way
        children = parent.children(recursive=True)
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=20)
        assert proc.returncode != 0
        _, still = psutil.wait_procs(children, timeout=5)
        assert not still, f"left behind: {still}"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()


def test_masks_are_read_only_for_the_mask_detector(tmp_path):
    from spinemocap.app.run import track_capture
    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=2), tmp_path / "capture", progress=False)

    # damaged ground-truth masks: the net detector never opens them ...
    for png in (root / "masks").rglob("*.png"):
        png.write_bytes(b"not a png")
    table = track_capture(root, tmp_path / "out", detector="net", progress=False)
    assert np.isfinite(table.to_arrays().positions).any()
    # ... the mask detector needs them and says which file is bad
    with pytest.raises(InputError, match="corrupt"):
        track_capture(root, tmp_path / "out", detector="mask", progress=False)
    shutil.rmtree(root / "masks")
    with pytest.raises(InputError, match="needs tape masks"):
        track_capture(root, tmp_path / "out", detector="mask", progress=False)


def test_prefetching_reader_raises_the_readers_error_and_stops():
    class Source:
        camera_names = ["a", "b"]
        n_frames = 5
        reads: list[int] = []

        def read(self, frame):
            self.reads.append(frame)
            if frame == 2:
                raise InputError(f"frame{frame}.png", "image file not found")
            return [np.zeros((4, 4, 3), np.uint8)] * 2

    source = Source()
    got = []
    with pytest.raises(InputError, match="frame2.png"):
        for frame, images, masks in prefetched_frames(source, range(5), prefetch=2):
            assert masks is None and len(images) == 2
            got.append(frame)
    assert got == [0, 1]
    assert max(source.reads) == 2  # the reader stopped at the error


def test_detector_dots_are_a_blob_pass_on_its_final_mask(small_studio):
    # The clean-up's blob pass is reused as the detector's dots (no second pass): they must be
    # the dots a separate pass over the detector's final mask finds (the pipeline before).
    from spinemocap.detect import Detector, find_dots

    _, images = small_studio
    detector = Detector("net")
    seen = 0
    for frame_images in images:
        for camera, image in enumerate(frame_images):
            view = detector.detect(image, camera=camera)
            uv, _ = find_dots(view.image, view.mask)
            assert len(view) == len(uv), f"camera {camera}"
            if len(uv):
                assert np.linalg.norm(view.uv[:, None] - uv[None], axis=2).min(axis=1).max() < 0.01
            seen += len(uv)
    assert seen > 100  # the tape was in view: the comparison was not empty


def test_too_little_shared_memory_falls_back_to_threads(small_studio, monkeypatch):
    # a block larger than /dev/shm's free space would kill the process when written (SIGBUS):
    # it is refused first and the frame detected in threads, with a warning naming the cause
    from spinemocap.app import camera_processes
    from spinemocap.app.streaming import ParallelFallbackWarning

    scene, images = small_studio
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1, predict=False))
    processes = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, parallel="processes", predict=False))
    try:
        monkeypatch.setattr(camera_processes, "shared_memory_free", lambda: 1024)
        with pytest.warns(ParallelFallbackWarning, match="/dev/shm.*MiB free"):
            views = processes(0, images[0], None)
        assert processes.parallel == "threads"
        _assert_same_views(serial(0, images[0], None), views)
    finally:
        serial.close()
        processes.close()


def test_parallel_mode_defaults_to_threads_and_unknown_modes_are_refused():
    from spinemocap.app.streaming import SpeedOptions, resolve_parallel

    assert SpeedOptions().parallel == "threads"  # as fast or faster on 2 and 16 cores
    assert resolve_parallel("threads") == "threads" and resolve_parallel("processes") == "processes"
    with pytest.raises(InputError, match="unknown parallel mode"):
        resolve_parallel("fibres")


@pytest.mark.slow  # ~45 s on the 2-core machine: six runs, three of them starting worker processes
def test_replay_benchmark_runs_both_parallel_modes_from_memory_and_video(tmp_path):
    from spinemocap.bench.speed import format_report, run_replay_benchmark
    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=3), tmp_path / "capture", progress=False)
    numbers = run_replay_benchmark(root, 5, serial_peer=False, speed=SpeedOptions(workers=2, parallel="threads"),
                                   sensor_noise=3.0, progress=False, say=lambda _: None, video_frames=3,
                                   workdir=tmp_path / "work")
    runs = {r.run: r for r in numbers.runs}
    assert set(runs) == {"in_memory", "in_memory_processes", "video", "video_processes"}
    assert runs["in_memory"].parallel == "threads" and runs["in_memory_processes"].parallel == "processes"
    assert (runs["in_memory_processes"].workers_startup_s or 0) > 0  # not timed, but reported
    assert numbers.same_output_processes_threads is True
    assert (numbers.speedup_processes_vs_threads or 0) > 0 and (numbers.fps_video or 0) > 0
    assert runs["video"].frames == 3 and runs["in_memory"].frames == 5
    assert "cameras in processes" in format_report(numbers)


# ---------------------------------------------------------------- detection ahead of the tracker
def test_detection_ahead_without_prediction_gives_the_serial_output():
    # lookahead 1: frame t+1 detected while the tracker solves frame t; without prediction
    # (per-frame mode) nothing depends on the tracker, so the output is the serial one exactly
    scene, images = _rendered("tiny", 3)
    for mode in ("paper", "sequence"):
        options = SpeedOptions(workers=2, predict=mode == "sequence")
        serial = _tracked_from_memory(scene, images, options, mode)
        ahead = _tracked_from_memory(scene, images, replace(options, lookahead=1), mode)
        a, b = serial.table.to_arrays(), ahead.table.to_arrays()
        if mode == "paper":
            np.testing.assert_array_equal(a.positions, b.positions)
            assert (a.status == b.status).all()
            assert serial.detector_searches == ahead.detector_searches
        else:  # predicted boxes from one frame earlier: same dots here, up to rounding of the crops
            np.testing.assert_allclose(a.positions, b.positions, atol=0.05)
            assert (a.status == b.status).all()


def test_prediction_from_two_frames_back_finds_the_full_search_dots_on_a_small_studio(small_studio):
    # lookahead 1: the box of a frame is predicted from the solved frame two before it (here the
    # first frame's dots, no velocity known) and the previous frame's mask, with the wider margin
    scene, images = small_studio
    gt = scene.groundtruth["dots"]
    full = CaptureDetector("net", scene.rig, SpeedOptions(predict=False, workers=1))
    ahead = CaptureDetector("net", scene.rig, SpeedOptions(refresh_every=1000, workers=1, lookahead=1))
    try:
        n = len(scene.rig)
        first = ahead(0, images[0], None)  # nothing solved yet: full search
        # frame 1 (the same image), detected before frame 0 is solved: frame 0's boxes alone,
        # as lookahead 0 would predict it (the same full-search schedule); the same dots
        assert _same_dots(first, ahead(1, images[0], None)) < 0.01
        assert ahead.searches == {"full": n, "predicted": n, "fallback": 0, "refresh": 0}
        ahead.observe(0, gt[0])
        views = ahead(2, images[1], None)  # predicted from frame 0 over two frames
        assert ahead.searches == {"full": n, "predicted": 2 * n, "fallback": 0, "refresh": 0}
        assert _same_dots(full(1, images[1], None), views) < 0.01
        assert sum(len(v) for v in views) > 50  # the tape was in view
    finally:
        full.close()
        ahead.close()


class _Recorder:
    """A detector for :func:`detected_ahead` that records how far the tracker had got when each
    frame was detected, and fails on frame ``fail``."""

    needs_masks = False

    def __init__(self, done: list, fail: int = -1):
        self.done, self.fail, self.seen = done, fail, []

    def __call__(self, frame, images, masks):
        if frame == self.fail:
            raise InputError(f"frame{frame}.png", "image file not found")
        self.seen.append((frame, len(self.done)))
        return [frame]


def test_detection_ahead_stays_at_most_lookahead_frames_ahead_and_overlaps():
    import time

    from spinemocap.app.streaming import detected_ahead

    frames = [(f, [np.zeros((2, 2, 3), np.uint8)], None) for f in range(8)]
    for lookahead in (1, 2):
        done: list = []
        detect = _Recorder(done)
        for frame, views, wait_ms in detected_ahead(iter(frames), detect, lookahead):
            assert views == [frame] and wait_ms >= 0
            time.sleep(0.03)  # the tracker's work: detection runs meanwhile
            done.append(frame)
        assert [f for f, _ in detect.seen] == list(range(8))
        # frame i was detected only once the tracker was done with frame i - 1 - lookahead ...
        assert all(n >= i - lookahead for i, n in detect.seen)
        # ... and while it was still on an earlier frame (the overlap)
        assert any(n < i for i, n in detect.seen)


def test_detection_ahead_raises_the_detectors_error_and_closing_stops_it():
    import threading

    from spinemocap.app.streaming import detected_ahead

    frames = [(f, [np.zeros((2, 2, 3), np.uint8)], None) for f in range(6)]
    got: list = []
    with pytest.raises(InputError, match="frame3.png"):
        for frame, _, _ in detected_ahead(iter(frames), _Recorder(got, fail=3), 1):
            got.append(frame)
    assert got == [0, 1, 2]
    assert not any(t.name == "detect-ahead" for t in threading.enumerate())
    # the tracker stops early (an error, Ctrl-C): closing the generator ends the thread
    ahead = detected_ahead(iter(frames), _Recorder([]), 1)
    next(ahead)
    ahead.close()
    assert not any(t.name == "detect-ahead" for t in threading.enumerate())


def test_stopping_the_tracker_ends_the_detection_running_ahead():
    # the tracker stops (Ctrl-C sets the stop flag of `spinemocap track`) while detection runs a
    # frame ahead in its thread: the run ends with TrackingStopped, no thread is left behind
    import threading

    from spinemocap.app.results import TrackingStopped
    from spinemocap.bench.speed import MemorySource

    scene, images = _rendered("tiny", 6)
    source = MemorySource(images, scene.rig.names)
    asked: list = []

    def stop() -> bool:
        asked.append(1)
        return len(asked) > 2

    with pytest.raises(TrackingStopped, match="before frame 2"):
        track_source(source, scene.rig, scene.tape, scene.fps, up=scene.subject()["up"], progress=False,
                     speed=SpeedOptions(workers=2, lookahead=1), stop=stop)
    assert not any(t.name in ("detect-ahead", "detect-stream") or t.name.startswith("detect_")
                   for t in threading.enumerate())


def test_lookahead_numbers_compare_the_run_ahead_with_the_exact_order():
    from spinemocap.bench.speed import lookahead_numbers

    def run(name, fps, cpu, error):
        return _speed_run(run=name, fps=fps, cpu_s_per_frame=cpu, mean_error_mm=error)

    exact = np.zeros((4, 2, 3))
    ahead = exact.copy()
    ahead[1, 0, 0] = 0.5          # one of 8 dot positions moved by 0.5 mm
    ahead[2, 1] = exact[2, 1] = np.nan
    runs = [run("in_memory", 3.0, 0.2, 0.50), run("in_memory_lookahead0", 2.0, 0.18, 0.50)]
    numbers = lookahead_numbers(runs, SpeedOptions(lookahead=1),
                                {"in_memory": ahead, "in_memory_lookahead0": exact})
    assert numbers is not None and numbers.speedup_lookahead_in_memory == pytest.approx(1.5)
    assert numbers.cpu_s_per_frame_lookahead == 0.2 and numbers.cpu_s_per_frame_exact == 0.18
    assert numbers.lookahead_max_difference_mm == pytest.approx(0.5)
    assert numbers.lookahead_share_over_0p1mm == pytest.approx(1 / 7)
    assert numbers.lookahead_accuracy_not_worse and numbers.lookahead_same_missing
    # the default (lookahead 0) with lookahead 1 as the peer: the ratio the other way round
    runs = [run("in_memory", 2.0, 0.18, 0.50), run("in_memory_lookahead1", 3.0, 0.2, 0.60)]
    numbers = lookahead_numbers(runs, SpeedOptions(), {"in_memory": exact, "in_memory_lookahead1": ahead})
    assert numbers is not None and numbers.speedup_lookahead_in_memory == pytest.approx(1.5)
    assert not numbers.lookahead_accuracy_not_worse  # 0.1 mm worse on average
    assert lookahead_numbers(runs[:1], SpeedOptions(), {}) is None  # no peer ran


def test_a_negative_lookahead_is_refused_by_the_options_and_both_commands(tmp_path, capsys):
    from spinemocap.cli import main

    with pytest.raises(InputError, match="lookahead: must be 0 or more"):
        SpeedOptions(lookahead=-1)
    for argv in (["track", str(tmp_path), "--out", str(tmp_path / "o"), "--lookahead", "-1"],
                 ["bench", "speed", "--preset", "tiny", "--lookahead", "-1"]):
        assert main(argv) == 2
        assert "--lookahead: must be 0 or more, got -1" in capsys.readouterr().err


def test_views_of_sequence_detection_make_the_grey_image_when_read(small_studio):
    # Prediction on (sequence tracking): the views hold the colour image and make the grey one
    # when MRF2 reads it: the same pixels as the detector's eager grey image, and the colour image
    # is let go then. Without prediction (benchmarks keep every frame's views) it is made at once.
    from spinemocap.capture import to_grey

    scene, images = small_studio
    gt = scene.groundtruth["dots"]
    eager = CaptureDetector("net", scene.rig, SpeedOptions(predict=False, workers=1))
    lazy = CaptureDetector("net", scene.rig, SpeedOptions(workers=1))
    try:
        for f, frame_images in enumerate(images):
            a, b = eager(f, frame_images, None), lazy(f, frame_images, None)
            assert all(v._colour is None and v._image is not None for v in a)
            assert all(v._colour is frame_images[v.camera] and v._image is None for v in b)
            for va, vb in zip(a, b):
                np.testing.assert_array_equal(vb.image, va.image)
                np.testing.assert_array_equal(vb.image, to_grey(frame_images[vb.camera]))
                assert vb._colour is None and vb.image is vb.image  # converted once, then kept
            lazy.observe(f, gt[f])
        assert lazy.searches["predicted"] == len(scene.rig)  # the second frame was predicted
    finally:
        eager.close()
        lazy.close()


def test_a_view_takes_the_grey_or_the_colour_image_not_both():
    from spinemocap.views import ViewDots

    colour = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    with pytest.raises(ValueError):
        ViewDots(0, np.zeros((0, 2)), np.zeros(0), image=colour[:, :, 0], colour=colour)
    view = ViewDots(0, np.zeros((0, 2)), np.zeros(0), colour=colour)
    view.image = None  # set: the colour image no longer stands for it
    assert view.image is None and ViewDots(1, np.zeros((0, 2)), np.zeros(0)).image is None


def test_kept_instances_within_the_searched_boxes_are_the_full_frame_ones(small_studio):
    # _segment_with_dots labels the mask's instances only inside the union of the final boxes:
    # the mask must be the full-frame labelling's, also where specks are dropped
    from spinemocap.detect import Detector
    from spinemocap.detect.instances import kept_instances

    _, images = small_studio
    detector = Detector("net")
    segmenter = detector._segment
    all_boxes = detector.tape_boxes(images[0])
    camera = max(range(len(all_boxes)), key=lambda c: len(all_boxes[c]))  # a camera that sees the tape
    image, boxes = images[0][camera], all_boxes[camera]
    found = segmenter.segment_boxes(image, boxes)
    assert found.box is not None and found.mask[found.box].sum() == found.mask.sum() > 0
    np.testing.assert_array_equal(detector._segment_with_dots(image, boxes).mask, kept_instances(found.mask))
    # a speck far from the tape (a false positive of another box) is dropped the same way
    h, w = found.mask.shape
    speck = (slice(h - 12, h - 9), slice(w - 12, w - 9))
    speckled = found.mask.copy()
    speckled[speck] = True
    union = (slice(min(found.box[0].start, speck[0].start), h), slice(min(found.box[1].start, speck[1].start), w))
    cropped = np.zeros_like(speckled)
    cropped[union] = kept_instances(speckled[union])
    np.testing.assert_array_equal(cropped, kept_instances(speckled))
    assert not cropped[speck].any()
    # no box searched: an empty mask
    assert not detector._segment_with_dots(image, []).mask.any()


# ---------------------------------------------------------------- cameras streamed through the frames
@pytest.mark.parametrize("mode", ["sequence", "paper"])
def test_streamed_cameras_give_the_frame_by_frame_output(monkeypatch, mode):
    # lookahead >= 1 with the cameras in threads: each camera runs through the frames on its own
    # (CaptureDetector.stream); the output is that of detecting frame by frame with the same
    # lookahead in one thread (detected_ahead), whatever the threads' timing
    import threading

    from spinemocap.bench.speed import MemorySource

    scene, images = _rendered("tiny", 6)
    source = MemorySource(images, scene.rig.names)
    where: set = set()
    inner = CaptureDetector._camera_view

    def spied(self, camera, image, plan):
        where.add(threading.current_thread().name)
        return inner(self, camera, image, plan)

    monkeypatch.setattr(CaptureDetector, "_camera_view", spied)

    def track(**options):
        return track_source(source, scene.rig, scene.tape, scene.fps, up=scene.subject()["up"], mode=mode,
                            progress=False, speed=SpeedOptions(refresh_every=4, **options))

    for lookahead in (1, 2):
        where.clear()
        frame_by_frame = track(workers=1, lookahead=lookahead)
        assert not where  # one camera after the other: frame by frame
        streamed = track(workers=3, lookahead=lookahead)
        assert where and all(name.startswith("detect_") for name in where)  # streamed, in the camera threads
        a, b = frame_by_frame.table.to_arrays(), streamed.table.to_arrays()
        np.testing.assert_array_equal(a.positions, b.positions)
        assert (a.status == b.status).all()
        assert frame_by_frame.detector_searches == streamed.detector_searches
        if mode == "sequence":
            assert streamed.detector_searches["predicted"] > 0
    assert not any(t.name == "detect-stream" for t in threading.enumerate())


def test_refresh_frames_start_while_the_tracker_solves_the_frame_before(monkeypatch):
    # lookahead 0, cameras in threads: a frame due for a full search (refresh_every) is detected in
    # a background thread while the tracker solves the frame before; every other frame after it,
    # each camera whole (box, search, fallback) in its camera thread. The output, routes and
    # searches are those of one camera after the other, frame by frame, bit for bit
    import threading
    import time

    from spinemocap.bench.speed import MemorySource
    from spinemocap.track.sequence import SequenceTracker

    scene, images = _rendered("tiny", 9)
    source = MemorySource(images, scene.rig.names)
    started: list = []  # (frame, thread, steps done, frame being solved) as each frame's detection starts
    steps: list = []
    solving: dict = {"frame": None}
    call, step = CaptureDetector.__call__, SequenceTracker.step

    def spied_call(self, frame, frame_images, masks):
        started.append((frame, threading.current_thread().name, len(steps), solving["frame"]))
        return call(self, frame, frame_images, masks)

    def spied_step(self, views, stage_ms, ahead=None):
        solving["frame"] = len(steps)
        out = step(self, views, stage_ms, ahead)
        if len(steps) + 1 in (4, 8):
            time.sleep(0.3)  # a step long enough for the refresh's thread to start within it
        solving["frame"] = None
        steps.append(len(steps))
        return out

    monkeypatch.setattr(CaptureDetector, "__call__", spied_call)
    monkeypatch.setattr(SequenceTracker, "step", spied_step)

    def track(workers: int):
        started.clear()
        steps.clear()
        return track_source(source, scene.rig, scene.tape, scene.fps, up=scene.subject()["up"], progress=False,
                            speed=SpeedOptions(refresh_every=4, workers=workers))

    serial = track(1)
    assert all(done == frame and now is None for frame, _, done, now in started)  # each after the step before it
    threads = track(3)
    a, b = serial.table.to_arrays(), threads.table.to_arrays()
    np.testing.assert_array_equal(a.positions, b.positions)
    assert (a.status == b.status).all()
    assert [f.route for f in serial.frames] == [f.route for f in threads.frames]
    assert serial.detector_searches == threads.detector_searches and threads.detector_searches["predicted"] > 0
    refreshed = {frame for frame, name, *_ in started if name.startswith("detect-refresh")}
    assert refreshed == {4, 8}  # the full searches after the first frame's
    for frame, _, done, now in started:  # a refresh started before the tracker is done with the frame before it
        if frame in refreshed:
            assert done == frame - 1 and now in (None, frame - 1)
        else:
            assert (done, now) == (frame, None)
    assert not any(t.name.startswith("detect-refresh") for t in threading.enumerate())


def test_camera_refresh_schedule_detects_no_frame_ahead_of_the_tracker(monkeypatch):
    # refresh="camera": no frame is searched in full as a whole by the schedule, so none may be
    # started before the tracker solved the frame before (its boxes need that frame's dots): the
    # threads' output is the serial one bit for bit and no detection runs in the refresh thread
    import threading

    from spinemocap.bench.speed import MemorySource

    scene, images = _rendered("tiny", 9)
    source = MemorySource(images, scene.rig.names)
    threads_seen: list = []
    call = CaptureDetector.__call__

    def spied_call(self, frame, frame_images, masks):
        threads_seen.append(threading.current_thread().name)
        return call(self, frame, frame_images, masks)

    monkeypatch.setattr(CaptureDetector, "__call__", spied_call)

    def track(workers: int):
        return track_source(source, scene.rig, scene.tape, scene.fps, up=scene.subject()["up"], progress=False,
                            speed=SpeedOptions(refresh="camera", refresh_every=4, workers=workers))

    serial, threads = track(1), track(3)
    a, b = serial.table.to_arrays(), threads.table.to_arrays()
    np.testing.assert_array_equal(a.positions, b.positions)
    assert serial.detector_searches == threads.detector_searches and threads.detector_searches["predicted"] > 0
    assert not any(name.startswith("detect-refresh") for name in threads_seen)


def _streaming_detector(monkeypatch, log: list, fail: int | None = None, cost_s: float = 0.0):
    """A CaptureDetector with two camera threads whose detection is a recorder: ``log`` gets
    (frame, camera, frames the tracker has solved so far) per detection; frame ``fail`` raises."""
    import time

    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("tiny", frames=1))
    detect = CaptureDetector("net", scene.rig, SpeedOptions(workers=2))
    solved: list = []

    def camera_view(camera, image, plan):
        if image == fail:
            raise InputError(f"frame{image}.png", "cannot be read")
        time.sleep(cost_s)
        log.append((image, camera, len(solved)))
        return (image, camera)

    monkeypatch.setattr(detect, "_camera_view", camera_view)
    monkeypatch.setattr(detect, "_plan", lambda frame: frame)
    return detect, solved


def test_streamed_cameras_wait_for_the_frame_their_boxes_come_from_and_overlap_the_tracker(monkeypatch):
    import time

    frames = [(f, [f, f], None) for f in range(8)]  # the "images" are the frame numbers
    for lookahead in (1, 2):
        log: list = []
        detect, solved = _streaming_detector(monkeypatch, log, cost_s=0.005)
        try:
            for frame, views, wait_ms in detect.stream(iter(frames), lookahead):
                assert views == [(frame, 0), (frame, 1)] and wait_ms >= 0
                time.sleep(0.03)  # the tracker's work: the cameras run meanwhile
                solved.append(frame)
        finally:
            detect.close()
        assert solved == list(range(8))
        for camera in (0, 1):  # each camera's frames in order, once
            assert [f for f, c, _ in log if c == camera] == list(range(8))
        # frame i started only once the tracker had solved frame i - 1 - lookahead ...
        assert all(n >= frame - lookahead for frame, _, n in log)
        # ... and while the tracker was still on an earlier frame (the overlap)
        assert any(n < frame for frame, _, n in log)


def test_streamed_cameras_raise_the_detectors_error_and_closing_stops_them(monkeypatch):
    import threading

    frames = [(f, [f, f], None) for f in range(6)]
    got: list = []
    detect, solved = _streaming_detector(monkeypatch, [], fail=3)
    try:
        with pytest.raises(InputError, match="frame3.png"):
            for frame, _, _ in detect.stream(iter(frames), 1):
                got.append(frame)
                solved.append(frame)
        assert got == [0, 1, 2]
        assert not any(t.name == "detect-stream" for t in threading.enumerate())
        # the tracker stops early (an error, Ctrl-C): closing the generator ends the reading thread
        stream = detect.stream(iter(frames), 1)
        next(stream)
        stream.close()
        assert not any(t.name == "detect-stream" for t in threading.enumerate())
    finally:
        detect.close()


def test_the_networks_precision_reaches_the_detector_and_unknown_ones_are_refused():
    import torch

    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("tiny", frames=1))
    detect = CaptureDetector("net", scene.rig, SpeedOptions(workers=1, precision="bfloat16"))
    try:
        assert detect.detector._segment.dtype == torch.bfloat16
    finally:
        detect.close()
    with pytest.raises(InputError, match="precision 'pixels'"):
        CaptureDetector("net", scene.rig, SpeedOptions(workers=1, precision="pixels"))


def test_the_automatic_precision_is_int8_only_on_a_cpu_with_vnni_and_falls_back_to_float32(monkeypatch):
    import warnings

    from spinemocap.detect import detector as detector_module
    from spinemocap.detect.detector import NetSegmenter, auto_precision

    monkeypatch.setattr(detector_module, "cpu_has_vnni", lambda: True)
    assert auto_precision("cpu") == "int8"
    assert auto_precision("cpu", runtime="torch") == "float32"
    monkeypatch.setattr(detector_module, "cpu_has_vnni", lambda: False)
    assert auto_precision("cpu") == "float32"
    # chosen automatically, an int8 model that cannot load gives float32 with a warning (asked
    # for, it is an InputError: test_detect_int8)
    monkeypatch.setattr(detector_module, "auto_precision", lambda device, runtime: "int8")

    def refuse(self, *args, precision="float32", **kwargs):
        if precision == "int8":
            raise RuntimeError("no int8 kernels here")
        return real_init(self, *args, precision=precision, **kwargs)

    real_init = detector_module.OnnxUNet.__init__
    monkeypatch.setattr(detector_module.OnnxUNet, "__init__", refuse)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        segmenter = NetSegmenter(device="cpu", precision="auto")
    assert segmenter.precision == "float32" and segmenter.runtime == "onnxruntime"
    assert any("int8" in str(w.message) for w in caught)


def test_the_benchmarks_machine_record_names_the_arithmetic_auto_resolves_to(monkeypatch):
    # two machines' CPU numbers compare only with the same arithmetic: the record says whether the
    # CPU has VNNI and what precision="auto" became there
    from spinemocap.bench import speed as speed_bench
    from spinemocap.detect import detector as detector_module

    monkeypatch.setattr(detector_module, "resolve_device", lambda device="auto": "cpu")  # as on a machine without a GPU
    for vnni, expected in ((True, "int8"), (False, "float32")):
        monkeypatch.setattr(detector_module, "cpu_has_vnni", lambda v=vnni: v)
        monkeypatch.setattr("spinemocap.detect.segnet.cpu_has_vnni", lambda v=vnni: v)
        info = speed_bench.machine_info()
        assert info.cpu_vnni is vnni and info.auto_precision == expected


# ---------------------------------------------------------------- several frames detected at once
class _SlowRecorder(_Recorder):
    """A :class:`_Recorder` whose detection takes ``seconds`` and that counts the frames being
    detected at the same time (the most at once in ``most``)."""

    predicts = False

    def __init__(self, done: list, seconds: float, fail: int = -1):
        import threading

        super().__init__(done, fail)
        self.seconds, self.now, self.most = seconds, 0, 0
        self._lock = threading.Lock()

    def __call__(self, frame, images, masks):
        import time

        with self._lock:
            self.now += 1
            self.most = max(self.most, self.now)
        try:
            time.sleep(self.seconds * (1 + (frame % 3 == 0)))  # some frames slower: out-of-order ends
            return super().__call__(frame, images, masks)
        finally:
            with self._lock:
                self.now -= 1


def test_frames_detected_at_once_come_in_order_with_at_most_that_many_under_way():
    import threading

    from spinemocap.app.streaming import detected_at_once

    frames = [(f, [np.zeros((2, 2, 3), np.uint8)], None) for f in range(10)]
    detect = _SlowRecorder([], 0.02)
    got = [frame for frame, views, wait_ms in detected_at_once(iter(frames), detect, 4) if views == [frame]]
    assert got == list(range(10))
    assert 2 <= detect.most <= 4  # frames overlapped, never more than asked
    with pytest.raises(InputError, match="frame5.png"):
        for _ in detected_at_once(iter(frames), _SlowRecorder([], 0.01, fail=5), 3):
            pass
    assert not any(t.name.startswith("detect-frame") for t in threading.enumerate())


@pytest.mark.parametrize("parallel", ["threads", "processes"])
def test_frames_detected_at_once_give_the_output_of_one_frame_at_a_time(parallel):
    # every frame searched in full: the tracked dots cannot depend on which frame ended first
    scene, images = _rendered("tiny", 5)
    one = _tracked_from_memory(scene, images, SpeedOptions(workers=2, predict=False, device="cpu"))
    at_once = _tracked_from_memory(scene, images, SpeedOptions(workers=3, predict=False, device="cpu",
                                                               frames_at_once=3, parallel=parallel))
    a, b = one.table.to_arrays(), at_once.table.to_arrays()
    np.testing.assert_array_equal(a.positions, b.positions)
    assert (a.status == b.status).all()
    assert one.detector_searches == at_once.detector_searches == {**one.detector_searches, "full": 5 * len(scene.rig)}
    assert at_once.detector_info.workers == 3  # workers not capped at one per camera
    assert at_once.detector_info.parallel == parallel


def test_images_staged_by_the_reader_are_detected_in_shared_memory_without_a_second_copy(small_studio):
    scene, images = small_studio
    detect = CaptureDetector("net", scene.rig, SpeedOptions(workers=2, parallel="processes", predict=False))
    serial = CaptureDetector("net", scene.rig, SpeedOptions(workers=1, predict=False))
    try:
        assert detect.parallel == "processes"
        staged = detect.stage(list(images[0]))
        views = detect(0, staged, None)
        processes = detect._processes
        assert processes is not None and processes._direct.memory is None  # the staged block served
        assert _same_dots(views, serial(0, list(images[0]), None)) == 0.0
    finally:
        detect.close()
        serial.close()


def test_frames_at_once_need_prediction_off_and_at_least_one_frame(tmp_path, capsys):
    with pytest.raises(InputError, match="`predict=False`"):
        SpeedOptions(frames_at_once=2)
    with pytest.raises(InputError, match="1 or more"):
        SpeedOptions(frames_at_once=0, predict=False)
    assert SpeedOptions(frames_at_once=4, predict=False, workers=5).n_workers(2) == 5  # not capped at the cameras
    assert SpeedOptions(workers=5).n_workers(2) == 2


def test_detection_budget_splits_a_camera_images_time_into_its_steps():
    from spinemocap.bench.speed import BUDGET_STEPS, detection_budget

    _, images = _rendered("tiny", 1)
    steps = detection_budget(images, "cpu", "float32")
    assert set(steps) == {*BUDGET_STEPS, "total"}
    assert steps["network_stage1"] > 0 and steps["network_stage2"] > 0 and steps["cleanup_and_dots"] > 0
    assert min(steps.values()) >= 0
    assert steps["total"] == pytest.approx(sum(steps[s] for s in BUDGET_STEPS))


def test_same_accuracy_holds_within_the_tolerance_and_fails_outside_it():
    from spinemocap.bench.speed import SAME_ACCURACY_MM, same_accuracy

    cpu = _speed_run(mean_error_mm=0.40, p95_error_mm=0.80)
    close = replace(cpu, mean_error_mm=0.40 + SAME_ACCURACY_MM / 2)
    assert same_accuracy(close, cpu).same
    assert not same_accuracy(replace(cpu, p95_error_mm=0.80 + 2 * SAME_ACCURACY_MM), cpu).same
    assert not same_accuracy(replace(cpu, label_swaps=1), cpu).same


def test_replay_benchmark_runs_the_pipelines_defaults_beside_frames_at_once(tmp_path):
    from spinemocap.bench.speed import format_report, run_replay_benchmark
    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=2), tmp_path / "capture", progress=False)
    numbers = run_replay_benchmark(root, 4, serial_peer=False, parallel_peer=False, progress=False, say=lambda _: None,
                                   speed=SpeedOptions(workers=2, predict=False, frames_at_once=2, device="cpu",
                                                      candidate_workers=1))
    runs = {r.run: r for r in numbers.runs}
    assert set(runs) == {"in_memory", "in_memory_default", "in_memory_candidates_in_tracker"}
    # the candidates built ahead: the same dots as the tracker building them, frames served
    assert numbers.same_output_candidates_ahead is True
    assert runs["in_memory"].candidates_taken_ahead >= 1 and runs["in_memory_candidates_in_tracker"].candidates_built_ahead == 0
    assert runs["in_memory_default"].detector_searches["predicted"] > 0  # the defaults predict boxes
    assert runs["in_memory"].detector_searches["predicted"] == 0
    assert numbers.speedup_vs_default == pytest.approx(runs["in_memory"].fps / runs["in_memory_default"].fps)
    assert set(numbers.detection_budget_ms or {}) >= {"network_stage1", "cleanup_and_dots", "total"}
    assert "2 frames at once" in format_report(numbers)


def test_speed_numbers_are_written_as_one_json_object_with_the_lookahead_keys_in_place(tmp_path):
    import json

    from spinemocap.bench.speed import GOALS_FPS, format_report, save
    from spinemocap.bench.speed_results import DecodeSpeed, LookaheadComparison, MachineInfo, RenderedSpeed

    machine = MachineInfo(cpu_cores=2, cpu_model="x", cpu_vnni=False, auto_precision="float32", load_average_1min=0.5,
                          torch="2", torch_threads=2, gpu=None, cuda=None, cudnn_allow_tf32=None)
    ahead = LookaheadComparison(speedup_lookahead_in_memory=1.5, cpu_s_per_frame_lookahead=0.5,
                                cpu_s_per_frame_exact=0.4, lookahead_accuracy_not_worse=True,
                                lookahead_max_difference_mm=0.0, lookahead_share_over_0p1mm=0.0,
                                lookahead_same_missing=True)
    numbers = RenderedSpeed(
        preset="tiny", realism="lab", frames=4, cameras=3, image_size=[480, 360], occlusion="none", mode="sequence",
        detector="net", machine=machine, speed_options=SpeedOptions(), fps_png=2.0, fps_video=None, video_codec=None,
        fps_in_memory=None, speedup_vs_serial=None, speedup_vs_serial_in_memory=None,
        cpu_ratio_vs_serial_in_memory=None, accuracy_not_worse=None, accuracy_not_worse_in_memory=None,
        accuracy_tolerance_mm=0.01, memory_frames=30, lookahead_comparison=ahead,
        decode_only={"png": DecodeSpeed(frames=4, fps=30.0, cpu_s_per_frame=0.01)}, runs=[_speed_run(run="png")],
        goals_fps=GOALS_FPS)
    save(numbers, tmp_path / "speed.json")
    saved = json.loads((tmp_path / "speed.json").read_text())
    assert list(saved)[20:26] == ["memory_frames", "speedup_lookahead_in_memory", "cpu_s_per_frame_lookahead",
                                  "cpu_s_per_frame_exact", "lookahead_accuracy_not_worse",
                                  "lookahead_max_difference_mm"]
    assert list(saved)[-3:] == ["decode_only", "runs", "goals_fps"] and "lookahead_comparison" not in saved
    assert saved["machine"]["cpu_cores"] == 2 and saved["speed_options"]["parallel"] == "threads"
    assert saved["decode_only"] == {"png": {"frames": 4, "fps": 30.0, "cpu_s_per_frame": 0.01}}
    assert saved["runs"][0]["run"] == "png" and saved["runs"][0]["stage_ms"] == {"detect": 100.0}
    assert "1.50x the frames/s of the exact serial order" in format_report(numbers)
    without = replace(numbers, lookahead_comparison=None)
    assert "speedup_lookahead_in_memory" not in without.to_dict()  # no peer ran: no keys


def test_a_replayed_run_on_a_gpu_reports_its_cpu_peer_and_the_dots_on_both_devices(tmp_path):
    import json

    from spinemocap.bench.speed import GOALS_FPS, format_report, same_accuracy, save
    from spinemocap.bench.speed_results import DeviceDots, MachineInfo, ReplayedSpeed

    machine = MachineInfo(cpu_cores=16, cpu_model="x", cpu_vnni=True, auto_precision="int8", load_average_1min=0.1,
                          torch="2", torch_threads=16, gpu="GPU", cuda="12", cudnn_allow_tf32=True)
    gpu = _speed_run(fps=40.0, mean_error_mm=0.41, candidates_built_ahead=4, candidates_taken_ahead=3)
    cpu = _speed_run(run="in_memory_cpu", fps=8.0, mean_error_mm=0.40)
    dots = DeviceDots(images=6, dots_cpu=300, dots_device=300, unmatched_cpu=0, unmatched_device=0, max_px=0.02,
                      mask_pixels_differing=5, images_identical=4)
    numbers = ReplayedSpeed(
        preset="capture c replayed", source_frames=3, frames=10, sensor_noise=0.0, cameras=6, image_size=[2448, 1600],
        mode="sequence", detector="net", device="cuda", machine=machine,
        speed_options=SpeedOptions(device="cuda", predict=False, frames_at_once=12, candidate_workers=3),
        fps_in_memory=40.0, fps_png=None, fps_video=None, speedup_vs_serial=None, accuracy_not_worse=None,
        speedup_vs_cpu=5.0, accuracy_not_worse_vs_cpu=True, same_accuracy_as_cpu=same_accuracy(gpu, cpu),
        speedup_vs_default=None, speedup_candidates_ahead=1.6, same_output_candidates_ahead=True,
        detection_budget_ms={"network_stage1": 1.5, "total": 3.0}, parallel="threads",
        speedup_processes_vs_threads=None, same_output_processes_threads=None, device_check=dots,
        lookahead_comparison=None, accuracy_tolerance_mm=0.01, runs=[gpu, cpu], goals_fps=GOALS_FPS)
    report = format_report(numbers)
    assert "network on cuda: 5.00x the same pipeline's frames/s on the CPU" in report
    assert "mean +0.0100 mm" in report and ": same (within" in report
    assert "network_stage1 1.5, total 3.0" in report and "'max_px': 0.02" in report
    assert "candidates built ahead in 3 processes: 1.60x" in report and "(3 of 4 frames served); same dots: True" in report
    save(numbers, tmp_path / "speed.json")
    saved = json.loads((tmp_path / "speed.json").read_text())
    assert saved["same_accuracy_as_cpu"] == {"mean_difference_mm": pytest.approx(0.01), "p95_difference_mm": 0.0,
                                             "label_swaps": 0, "reference_label_swaps": 0, "same": True}
    assert list(saved["device_check"]) == ["images", "dots_cpu", "dots_device", "unmatched_cpu", "unmatched_device",
                                           "max_px", "mask_pixels_differing", "images_identical"]
    assert list(saved)[:3] == ["preset", "source_frames", "frames"] and list(saved)[-2:] == ["runs", "goals_fps"]
