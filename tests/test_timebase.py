"""Per-camera clocks: timestamps, dropped frames, pairing capture frames to each camera's frames,
and the frame sources reading by them (the default reading unchanged)."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.media import ImageFolderSource, VideoSource, VideoWriter
from spinemocap.timebase import CameraClock, image_times, media_times, pair_cameras, pair_frames, video_times


def _nearest_slot(t: float, fps: float, n: int) -> int:
    """Brute force: the slot of the frame nearest ``t`` within half a frame, else -1."""
    stamps = np.arange(n) / fps
    k = int(np.argmin(np.abs(stamps - t)))
    return k if abs(stamps[k] - t) <= 0.5 / fps + 1e-9 else -1


@pytest.mark.parametrize("camera_fps, offset_s", [(60.0, 0.1), (50.0, -0.2345), (100.0, 1.93), (100.0, 0.0)])
def test_pairing_by_time_with_offsets_and_rates(camera_fps, offset_s):
    times = image_times(150, camera_fps)
    slots = pair_frames(times, offset_s, capture_fps=100.0, n_frames=200)
    expected = [_nearest_slot(i / 100.0 + offset_s, camera_fps, 150) for i in range(200)]
    assert slots.tolist() == expected
    assert (slots == -1).any() == any(e == -1 for e in expected)
    if offset_s == 0.0 and camera_fps == 100.0:
        assert slots[:150].tolist() == list(range(150))


def test_late_camera_has_no_frames_before_it_starts():
    times = image_times(100, 100.0)
    slots = pair_frames(times, -0.5, capture_fps=100.0, n_frames=120)  # starts at capture time 0.5 s
    assert (slots[:50] == -1).all() and slots[50] == 0 and slots[119] == 69


def test_dropped_frames_found_and_later_frames_not_shifted():
    stamps = np.delete(np.arange(40) / 60.0, [10, 25, 26])
    times = media_times(stamps + 3.25, 60.0, "cam2")  # any origin
    assert [(d.camera, d.after_slot, d.missing) for d in times.dropped] == [("cam2", 9, 1), ("cam2", 24, 2)]
    assert times.slots.tolist() == [k for k in range(40) if k not in (10, 25, 26)]
    slots = pair_frames(times, 0.0, capture_fps=60.0, n_frames=40)
    assert slots[10] == -1 and slots[25] == slots[26] == -1
    assert slots[11] == 11 and slots[39] == 39  # the frames after a drop keep their own time


def test_two_frames_on_one_slot_is_an_error():
    with pytest.raises(ValueError, match="closer than one frame"):
        media_times([0.0, 0.01, 0.0125], 100.0, "cam1")


def _write_video(path, fps, slots, size=(32, 24)):
    writer = VideoWriter(path, fps, size)
    for k in slots:
        writer.write(np.full((size[1], size[0], 3), k % 250, np.uint8), slot=k)
    writer.close()


def test_video_timestamps_drops_and_paired_reading(tmp_path):
    (tmp_path / "videos").mkdir()
    _write_video(tmp_path / "videos" / "cam1.avi", 100.0, range(60))
    kept = [k for k in range(36) if k != 12]
    _write_video(tmp_path / "videos" / "cam2.avi", 60.0, kept)
    times = video_times(tmp_path / "videos" / "cam2.avi", None, "cam2")
    assert times.fps == 60.0 and times.slots.tolist() == kept
    assert [(d.after_slot, d.missing) for d in times.dropped] == [(11, 1)]

    clocks = [CameraClock(), CameraClock(offset_s=0.05, fps=60.0)]
    source = VideoSource(tmp_path, ["cam1", "cam2"], 60, "videos/{camera}.avi", clocks=clocks, fps=100.0)
    try:
        assert [(d.camera, d.after_slot) for d in source.dropped] == [("cam2", 11)]
        missing = source.pairing.missing()["cam2"]
        for i in range(60):
            images = source.read(i)
            assert images[0][0, 0, 0] == i
            expected = _nearest_slot(i / 100 + 0.05, 60.0, 36)
            if expected in (12, -1):
                assert images[1] is None and i in missing
            else:
                assert images[1][0, 0, 0] == expected
        # reading back and forth over the drop (seeks land by time, not by packet)
        assert source.read_camera(1, 30)[0, 0, 0] == _nearest_slot(0.30 + 0.05, 60.0, 36)
        assert source.read_camera(1, 3)[0, 0, 0] == _nearest_slot(0.03 + 0.05, 60.0, 36)
    finally:
        source.close()


def test_default_clocks_read_exactly_the_frames_read_without_clocks(tmp_path):
    (tmp_path / "videos").mkdir()
    for cam in ("cam1", "cam2"):
        _write_video(tmp_path / "videos" / f"{cam}.avi", 100.0, range(20))
    for cam in ("cam1", "cam2"):
        folder = tmp_path / "images" / cam
        folder.mkdir(parents=True)
        import cv2

        for k in range(20):
            cv2.imwrite(str(folder / f"{k:06d}.png"), np.full((8, 8, 3), 10 * k, np.uint8))
    defaults = [CameraClock(), CameraClock(fps=100.0)]
    plain = VideoSource(tmp_path, ["cam1", "cam2"], 20, "videos/{camera}.avi")
    clocked = VideoSource(tmp_path, ["cam1", "cam2"], 20, "videos/{camera}.avi", clocks=defaults, fps=100.0)
    try:
        assert clocked.pairing is None
        for i in (0, 1, 7, 19, 3):
            assert all(np.array_equal(a, b) for a, b in zip(plain.read(i), clocked.read(i)))
    finally:
        plain.close()
        clocked.close()
    plain_images = ImageFolderSource(tmp_path, ["cam1", "cam2"], 20, "images/{camera}/{frame:06d}.png")
    clocked_images = ImageFolderSource(tmp_path, ["cam1", "cam2"], 20, "images/{camera}/{frame:06d}.png",
                                       clocks=defaults, fps=100.0)
    assert clocked_images.pairing is None
    for i in (0, 5, 19):
        assert all(np.array_equal(a, b) for a, b in zip(plain_images.read(i), clocked_images.read(i)))
    # an image folder on its own clock: a 50 fps camera's images paired by time
    slow = ImageFolderSource(tmp_path, ["cam1", "cam2"], 30, "images/{camera}/{frame:06d}.png",
                             clocks=[CameraClock(), CameraClock(offset_s=0.0, fps=50.0)], fps=100.0)
    assert slow.read(0)[1][0, 0, 0] == 0 and slow.read(4)[1][0, 0, 0] == 20  # capture 0.04 s = its frame 2
    assert slow.read(25)[0] is None  # camera 1 has 20 frames at 100 fps


def test_common_span_default_frame_count():
    times = [image_times(100, 100.0), image_times(50, 50.0)]
    pairing = pair_cameras(["a", "b"], times, [CameraClock(), CameraClock(offset_s=0.3)], 100.0)
    assert pairing.n_frames == 69  # camera b's last frame (0.98 s on its clock) shows capture time 0.68 s: frame 68
    assert pairing.missing() == {}


def test_detector_gives_a_camera_without_an_image_an_empty_view():
    from spinemocap.app.run import make_detector
    from spinemocap.app.streaming import SpeedOptions

    detect = make_detector("mask", None, SpeedOptions(predict=False, workers=2))
    image = np.zeros((40, 40, 3), np.uint8)
    image[18:22, 18:22] = 255
    mask = np.zeros((40, 40), bool)
    mask[10:30, 10:30] = True
    try:
        views = detect(7, [image, None], [mask, None])
    finally:
        detect.close()
    assert len(views) == 2 and len(views[1]) == 0 and views[1].camera == 1
    assert detect.missing == {1: [7]} and detect.info.missing_frames == {"1": [7]}
