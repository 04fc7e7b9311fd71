"""Damaged media: a video with damaged bytes in the middle, a video cut short and an image missing
from a sequence. The tracker goes on with the other cameras for the affected frames, says which
camera was missing in which frames, and never shifts later frames or stops with a traceback."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from spinemocap.capture import Capture
from spinemocap.cli import main

pytest.importorskip("pyvista")
FRAMES = 5


def _render(root, video: bool):
    from spinemocap.synth import SynthConfig, write_capture

    config = SynthConfig.preset("tiny", frames=FRAMES, video=video)
    return write_capture(config, root, progress=False)


@pytest.fixture(scope="module")
def video_capture(tmp_path_factory):
    return _render(tmp_path_factory.mktemp("damaged") / "video", video=True)


@pytest.fixture(scope="module")
def image_capture(tmp_path_factory):
    return _render(tmp_path_factory.mktemp("damaged") / "images", video=False)


def _track(capture, out, capsys) -> tuple[pd.DataFrame, str]:
    assert main(["track", str(capture), "--out", str(out), "--detector", "mask", "--no-progress"]) == 0
    printed = capsys.readouterr()
    assert "Traceback" not in printed.out + printed.err
    return pd.read_csv(out / "markers.csv"), printed.out


def _check_unshifted(table: pd.DataFrame, capture, good_frames) -> None:
    """Every frame is there under its own number; where the damaged camera was fine the dots are
    where the ground truth has them (a shifted frame would be off by the motion)."""
    assert sorted(table["frame"].unique()) == list(range(FRAMES))
    truth = np.load(capture / "groundtruth.npz")
    labels = [str(x) for x in truth["labels"]]
    rows = table.set_index(["frame", "label"])
    for frame in good_frames:
        errors = [np.linalg.norm(rows.loc[(frame, label), ["x", "y", "z"]].to_numpy(float) - truth["dots"][frame, d])
                  for d, label in enumerate(labels)]
        assert np.nanmax(errors) < 3.0, frame


def test_a_video_cut_short_leaves_its_camera_out_of_the_frames_it_lacks(video_capture, tmp_path, capsys):
    capture = tmp_path / "capture"
    shutil.copytree(video_capture, capture)
    camera = Capture.open(capture).rig.names[1]
    video = capture / "videos" / f"{camera}.avi"
    data = video.read_bytes()
    video.write_bytes(data[: int(len(data) * 0.55)])
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert f"camera {camera} had no image in" in printed
    log = (tmp_path / "out" / "tracking.log").read_text()
    assert f"no image from camera {camera}" in log
    lacking = [int(line.split()[1].rstrip(":")) for line in log.splitlines() if f"no image from camera {camera}" in line]
    assert lacking and lacking == list(range(lacking[0], FRAMES))      # from the cut to the end
    _check_unshifted(table, capture, range(FRAMES))                   # the other two cameras carry them


def test_damaged_bytes_in_the_middle_of_a_video_cost_only_those_frames(video_capture, tmp_path, capsys):
    capture = tmp_path / "capture"
    shutil.copytree(video_capture, capture)
    camera = Capture.open(capture).rig.names[1]
    video = capture / "videos" / f"{camera}.avi"
    data = bytearray(video.read_bytes())
    middle = len(data) // 2
    data[middle: middle + 4096] = bytes(4096)                         # a damaged packet
    video.write_bytes(bytes(data))
    table, printed = _track(capture, tmp_path / "out", capsys)
    _check_unshifted(table, capture, range(FRAMES))


def test_an_image_missing_from_a_sequence_is_one_camera_out_of_one_frame(image_capture, tmp_path, capsys):
    capture = tmp_path / "capture"
    shutil.copytree(image_capture, capture)
    camera = Capture.open(capture).rig.names[1]
    (capture / "images" / camera / "000002.png").unlink()
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert f"camera {camera} had no image in 1 of {FRAMES} frames (frame 2)" in printed
    assert "frame 2:" in (tmp_path / "out" / "tracking.log").read_text()
    _check_unshifted(table, capture, range(FRAMES))
    observed = table[(table["frame"] == 2) & (table["status"] == "observed")]
    assert len(observed) and (observed["n_views"] <= 2).all()         # seen by the two cameras left
