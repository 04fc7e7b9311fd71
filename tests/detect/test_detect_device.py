"""Where the network runs (the GPU path) on a machine without CUDA: ``auto`` falls back to
the CPU, ``cuda`` asked for where there is none is an InputError (not a torch traceback), the
pixels reach the network the same way whether converted as numpy or as a tensor (the GPU path
uploads uint8 and converts there), stage 1 batched over several images finds each image's own
boxes, and the benchmark's CPU-vs-device dot check counts identical dots as identical."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spinemocap.cli import main
from spinemocap.detect.detector import NetSegmenter, resolve_device
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.segnet import to_tensor
from spinemocap.fileio import InputError

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")


@no_cuda
def test_auto_device_falls_back_to_the_cpu():
    assert resolve_device("auto") == "cpu"
    assert NetSegmenter(device="auto").device.type == "cpu"


@no_cuda
def test_cuda_without_a_gpu_is_an_input_error(capsys):
    with pytest.raises(InputError, match="sees no CUDA GPU"):
        resolve_device("cuda")
    with pytest.raises(InputError, match="unknown device"):
        resolve_device("gpu")
    # on the command line: a message and exit code 2, before any capture is read
    assert main(["bench", "speed", "--capture", "/nonexistent", "--device", "cuda", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--device: device 'cuda' asked for" in err and "sees no CUDA GPU" in err  # the parameter shown as its flag


def test_uint8_tensor_converts_like_the_numpy_image():
    images = np.random.default_rng(0).integers(0, 256, (2, 24, 40, 3), dtype=np.uint8)
    from_numpy = to_tensor(images)
    from_tensor = to_tensor(torch.from_numpy(images))
    assert from_numpy.shape == (2, 3, 24, 40) and from_numpy.dtype == torch.float32
    assert torch.equal(from_numpy, from_tensor)
    assert torch.equal(to_tensor(images[0]), from_numpy[:1])


@pytest.fixture(scope="module")
def drawn_images():
    rng = np.random.default_rng(7)
    sizes = [(480, 360), (480, 360), (640, 400)]  # two share a stage-1 view size, one does not
    return [draw_sample(rng, size=size, px_per_mm=1.2, noise=2.0).image for size in sizes]


def test_batched_stage1_finds_each_images_own_boxes(drawn_images):
    seg = NetSegmenter(device="cpu")
    batched = seg.tape_boxes(drawn_images)
    one_by_one = [seg.tape_boxes([image])[0] for image in drawn_images]
    assert all(boxes for boxes in one_by_one)  # each image has tape
    assert batched == one_by_one


def test_device_check_counts_identical_dots_as_identical(drawn_images):
    from spinemocap.bench.speed import dots_on_devices

    check = dots_on_devices([drawn_images[:2], drawn_images[2:]], "cpu")
    assert check.images == 3 and check.images_identical == 3
    assert check.dots_cpu == check.dots_device > 0
    assert check.unmatched_cpu == check.unmatched_device == check.mask_pixels_differing == 0
    assert check.max_px == 0.0


def test_opencv_threads_apply_while_cameras_run_in_parallel_and_are_restored():
    import os

    import cv2

    from spinemocap.app.streaming import SERIAL, CaptureDetector, SpeedOptions

    before = cv2.getNumThreads()
    wanted = 1 if before != 1 else 2
    CaptureDetector("mask", None, SpeedOptions(opencv_threads=wanted, workers=1)).close()
    assert cv2.getNumThreads() == before  # cameras one after the other: OpenCV keeps its threads
    detect = CaptureDetector("mask", None, SERIAL)
    assert cv2.getNumThreads() == before  # the serial pipeline leaves OpenCV alone
    detect.close()
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: the cameras never run in parallel threads")
    detect = CaptureDetector("mask", None, SpeedOptions(opencv_threads=wanted, workers=2))
    try:
        assert cv2.getNumThreads() == wanted
    finally:
        detect.close()
    assert cv2.getNumThreads() == before


def test_fast_percentile_is_numpys_bit_for_bit():
    # the blob pass's per-dot percentile skips numpy's overhead; it must be numpy's number
    from spinemocap.detect.blobs import percentile

    rng = np.random.default_rng(1)
    for trial in range(1000):
        n = int(rng.integers(1, 300))
        values = (rng.normal(0, 30, n) if trial % 2 else rng.integers(0, 255, n)).astype(np.float32)
        for q in (0, 37.3, 50, 60, 98, 99.5, 100):
            assert percentile(values, q) == float(np.percentile(values, q)), (n, q)
