"""Sequence mode's full searches: the schedule of the periodic refreshes
(all cameras in one frame, or each camera on its own, spread over the period; settled cameras
less often) and a tape coming into a camera's view found within the refresh period."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spinemocap.app.streaming import SETTLED_EDGE_PX, CaptureDetector, SpeedOptions
from spinemocap.fileio import InputError
from spinemocap.views import ViewDots

pytest.importorskip("pyvista")


def _recording_detector(monkeypatch, options: SpeedOptions, shape=(400, 600), box=(slice(100, 200), slice(200, 300))):
    """A CaptureDetector on the tiny rig (two camera threads: each camera's search reaches ``_detect``, a full
    search with no box) whose camera detection is a recorder: every search finds
    the same five dots in the tape box ``box`` of an image of ``shape``; returns the detector and
    the log of (frame, cameras searched in full)."""
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("tiny", frames=1))
    detect = CaptureDetector("net", scene.rig, options)
    mask = np.zeros(shape, bool)
    mask[box] = True
    full: list = []

    def one_camera(camera, image, boxes):
        if boxes is None:
            full.append([camera])
        return ViewDots(camera, np.zeros((5, 2)), np.ones(5), mask=mask)

    monkeypatch.setattr(detect, "_detect", one_camera)
    return detect, scene, full


def _schedule(monkeypatch, frames: int, **options) -> tuple[list[set], int]:
    """Which cameras each frame searched in full (the first frame: all), and the rig's size."""
    detect, scene, runs = _recording_detector(monkeypatch, SpeedOptions(workers=2, **options))
    n = len(scene.rig)
    dots = scene.groundtruth["dots"][0]
    images = [np.zeros((400, 600, 3), np.uint8)] * n
    per_frame = []
    try:
        for f in range(frames):
            runs.clear()
            detect(f, images, None)
            per_frame.append({c for cameras in runs for c in cameras})
            detect.observe(f, dots)
    finally:
        detect.close()
    return per_frame, n


def test_frame_refresh_searches_every_camera_in_the_same_frame(monkeypatch):
    per_frame, n = _schedule(monkeypatch, 25, refresh_every=10)
    assert [f for f, cams in enumerate(per_frame) if cams] == [0, 10, 20]
    assert all(len(per_frame[f]) == n for f in (0, 10, 20))


def test_camera_refresh_spreads_each_cameras_full_search_over_the_period(monkeypatch):
    every = 4
    per_frame, n = _schedule(monkeypatch, 1 + 3 * every, refresh="camera", refresh_every=every)
    assert per_frame[0] == set(range(n))                  # the first frame: every camera in full
    for camera in range(n):                               # then each camera once per period
        frames = [f for f, cams in enumerate(per_frame) if camera in cams][1:]
        assert len(frames) == 3 and np.all(np.diff(frames) == every)
    # no later frame pays more than its share of the cameras' full searches
    assert max(len(cams) for cams in per_frame[1:]) == math.ceil(n / every)


def test_settled_cameras_refresh_less_often_and_cameras_at_the_edge_keep_the_period(monkeypatch):
    # a tape box well inside the image, all dots found every frame: settled
    per_frame, n = _schedule(monkeypatch, 13, refresh="camera", refresh_every=3, refresh_settled_every=6)
    assert all(np.all(np.diff([f for f, cams in enumerate(per_frame) if c in cams][1:]) == 6) for c in range(n))
    # the same tape box touching the image edge: not settled, the base period
    detect, scene, runs = _recording_detector(monkeypatch, SpeedOptions(workers=2, refresh="camera", refresh_every=3,
                                                                          refresh_settled_every=6),
                                              box=(slice(100, 200), slice(0, SETTLED_EDGE_PX - 1)))
    images = [np.zeros((400, 600, 3), np.uint8)] * len(scene.rig)
    full_at = []
    try:
        for f in range(13):
            runs.clear()
            detect(f, images, None)
            if 0 in {c for cameras in runs for c in cameras}:
                full_at.append(f)
            detect.observe(f, scene.groundtruth["dots"][0])
    finally:
        detect.close()
    assert np.all(np.diff(full_at) == 3)


def test_unknown_refresh_schedules_and_periods_are_refused_by_the_options_and_both_commands(tmp_path, capsys):
    from spinemocap.cli import main

    with pytest.raises(InputError, match="refresh"):
        SpeedOptions(refresh="sometimes")
    with pytest.raises(InputError, match="refresh_every"):
        SpeedOptions(refresh_every=0)
    for argv in (["track", str(tmp_path), "--out", str(tmp_path / "o"), "--refresh", "camera", "--refresh-every", "0"],
                 ["bench", "speed", "--preset", "tiny", "--refresh", "camera", "--refresh-every", "0"]):
        assert main(argv) == 2
        assert "--refresh-every: must be 1 or more" in capsys.readouterr().err


@pytest.fixture(scope="module")
def small_studio():
    """The studio's six cameras at a quarter of the pixels, one frame."""
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset("studio", frames=1, size=(1224, 800)))
    return scene, scene.render(0, with_masks=False).images


@pytest.mark.parametrize("refresh", ["frame", "camera"])
def test_a_tape_coming_into_view_is_found_within_the_refresh_period(small_studio, refresh):
    # the camera that sees most of the tape sees nothing for the first frames (a black image),
    # then the tape: with no tape box to predict, it finds the tape at its next full search, at
    # most refresh_every frames on
    scene, images = small_studio
    cam = int(np.argmax(scene.groundtruth["visible"][0].sum(axis=1)))
    every, appears = 4, 1  # the worst case: the tape appears just after a full search
    detect = CaptureDetector("net", scene.rig, SpeedOptions(workers=1, refresh=refresh, refresh_every=every,
                                                            refresh_settled_every=1000))
    dots = scene.groundtruth["dots"][0]
    found = None
    try:
        for f in range(appears + every):
            frame_images = list(images)
            if f < appears:
                frame_images[cam] = np.zeros_like(images[cam])
            views = detect(f, frame_images, None)
            assert f >= appears or len(views[cam]) == 0
            if f >= appears and len(views[cam]) > 0:
                found = f
                break
            detect.observe(f, dots)
    finally:
        detect.close()
    assert found is not None and found - appears < every
