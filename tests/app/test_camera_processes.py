"""Cameras detected in worker processes give what the detector gives in this process, dot for
dot; the pool stops its workers when closed."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spinemocap.app.camera_processes import CameraProcesses, ProcessesUnavailable, shared_memory_free
from spinemocap.app.worker_processes import join_or_kill
from spinemocap.detect import Detector


def _images() -> list[np.ndarray]:
    """Two views of a dark tape on skin with its holes (skin seen through) in staggered rows."""
    images = []
    for shift in (0, 12):
        image = np.full((480, 400, 3), (150, 170, 210), np.uint8)
        cv2.rectangle(image, (120 + shift, 40), (280 + shift, 440), (35, 35, 35), -1)
        for row in range(9):
            for u in ((165, 235) if row % 2 else (145, 200, 255)):
                cv2.circle(image, (u + shift, 70 + 44 * row), 8, (150, 170, 210), -1)
        images.append(image)
    return images


def test_workers_detect_as_this_process_does():
    free = shared_memory_free()
    if free is not None and free < 10_000_000:
        pytest.skip("too little shared memory here")
    images = _images()
    local = [Detector("classical").detect(image, camera=k) for k, image in enumerate(images)]
    try:
        pool = CameraProcesses("classical", 1)
    except ProcessesUnavailable as exc:
        pytest.skip(f"worker processes cannot start here: {exc}")
    try:
        remote = pool.detect(images, [0, 1], [None, None])
    finally:
        pool.close()
    for a, b in zip(local, remote):
        assert a.camera == b.camera and len(a) == len(b) >= 20
        np.testing.assert_array_equal(a.uv, b.uv)
        np.testing.assert_array_equal(a.tape_mask, b.tape_mask)
    assert pool.calls == 1


def test_join_or_kill_stops_a_process_that_does_not_leave():
    import multiprocessing as mp
    import time

    context = mp.get_context("fork")
    stubborn = context.Process(target=time.sleep, args=(60,))
    stubborn.start()
    started = time.monotonic()
    join_or_kill([stubborn], grace_s=0.2)
    assert not stubborn.is_alive() and time.monotonic() - started < 5
