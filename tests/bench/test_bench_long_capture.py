"""The long-capture benchmark's input: a capture played forward and back from a short one's
images, frame for frame."""

from __future__ import annotations

import numpy as np

from spinemocap.bench.long_capture import looped_capture, pingpong
from spinemocap.bench.view import made_capture
from spinemocap.capture import Capture


def test_pingpong_plays_forward_then_back():
    assert [pingpong(f, 4) for f in range(9)] == [0, 1, 2, 3, 2, 1, 0, 1, 2]
    assert pingpong(5, 1) == 0


def test_a_looped_capture_shows_the_base_frames_in_pingpong_order(tmp_path):
    base, _ = made_capture(tmp_path, 64, 48, 2, 3)
    for camera in Capture.open(base).camera_names:  # the made capture has no masks: give it the images'
        (base / "masks" / camera).mkdir(parents=True)
        for image in (base / "images" / camera).iterdir():
            (base / "masks" / camera / image.name).write_bytes(image.read_bytes())
    looped = Capture.open(looped_capture(base, tmp_path / "long", 7))
    assert looped.n_frames == 7 and not looped.has_groundtruth
    original, long = Capture.open(base).frame_source(), looped.frame_source()
    for frame in range(7):
        for a, b in zip(long.read(frame), original.read(pingpong(frame, 3))):
            np.testing.assert_array_equal(a, b)
