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
from spinemocap.fileio import InputError

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


def _missing_in_files(out, camera) -> dict[str, list[int]]:
    """The frames each marker file records ``camera`` missing in, read by our readers and checked
    against what ezc3d and OpenSim read from the same files."""
    import exporters

    found = {name: exporters.read(out / name).meta.get("missing_cameras", {}).get(camera, [])
             for name in ("markers.csv", "markers.trc", "markers.c3d")}
    ezc3d = pytest.importorskip("ezc3d")
    group = ezc3d.c3d(str(out / "markers.c3d"))["parameters"]["MISSING_CAMERAS"]
    spans = np.array(group["SPANS"]["value"]).reshape(3, -1, order="F") if np.ndim(group["SPANS"]["value"]) == 1 \
        else np.array(group["SPANS"]["value"])
    number = list(group["CAMERAS"]["value"]).index(camera) + 1
    found["ezc3d"] = sorted(f - 1 for n, a, b in spans.T if n == number for f in range(int(a), int(b) + 1))
    osim = pytest.importorskip("opensim")
    table = osim.TimeSeriesTableVec3(str(out / "markers.trc"))  # OpenSim still reads the file
    assert table.getNumRows() == FRAMES and "missing cameras: " in table.getTableMetaDataAsString("header")
    return found


def test_the_marker_files_record_which_camera_was_missing_in_which_frames(image_capture, tmp_path, capsys):
    capture = tmp_path / "capture"
    shutil.copytree(image_capture, capture)
    camera = Capture.open(capture).rig.names[2]
    for frame in (1, 2):
        (capture / "images" / camera / f"{frame:06d}.png").write_bytes(b"not a png")   # damaged images
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert set(table.loc[table["frame"].isin([1, 2]), "missing_cameras"]) == {camera}
    assert table.loc[~table["frame"].isin([1, 2]), "missing_cameras"].isna().all()
    assert _missing_in_files(tmp_path / "out", camera) == {name: [1, 2] for name in
                                                           ("markers.csv", "markers.trc", "markers.c3d", "ezc3d")}
    chunked = tmp_path / "chunked"   # a long capture tracked in chunks records them the same way
    assert main(["track", str(capture), "--out", str(chunked), "--detector", "mask", "--no-progress",
                 "--chunk-frames", "3", "--warmup-frames", "1"]) == 0
    assert f"camera {camera} had no image in 2 of {FRAMES} frames (frames 1-2)" in capsys.readouterr().out
    assert _missing_in_files(chunked, camera)["markers.c3d"] == [1, 2]


def test_a_camera_whose_images_end_early_is_left_out_of_the_frames_it_lacks(image_capture, tmp_path, capsys,
                                                                             caplog):
    capture = tmp_path / "capture"
    shutil.copytree(image_capture, capture)
    camera = Capture.open(capture).rig.names[1]
    for frame in (3, 4):
        (capture / "images" / camera / f"{frame:06d}.png").unlink()
    Capture.open(capture)          # n_frames = 5 is given: a warning, not a refusal
    assert f"camera {camera!r} has no images for capture frames 3-4 (its recording ends early)" in caplog.text
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert f"camera {camera} had no image in 2 of {FRAMES} frames (frames 3-4)" in printed
    _check_unshifted(table, capture, range(FRAMES))
    manifest = (capture / "capture.toml").read_text()
    (capture / "capture.toml").write_text(manifest.replace(f"n_frames = {FRAMES}", "n_frames = 9"))
    with pytest.raises(InputError, match=r"n_frames = 9 but no camera recorded that many frames .* set n_frames = 5"):
        Capture.open(capture)
    (capture / "capture.toml").write_text(manifest.replace(f"n_frames = {FRAMES}\n", ""))
    assert Capture.open(capture).n_frames == FRAMES   # left out: the frames two cameras recorded


def test_a_camera_whose_images_start_late_is_left_out_of_the_frames_before(image_capture, tmp_path, capsys, caplog):
    capture = tmp_path / "capture"
    shutil.copytree(image_capture, capture)
    camera = Capture.open(capture).rig.names[0]
    for frame in (0, 1):
        (capture / "images" / camera / f"{frame:06d}.png").unlink()
    manifest = (capture / "capture.toml").read_text()
    (capture / "capture.toml").write_text(manifest.replace(f"n_frames = {FRAMES}\n", ""))
    assert Capture.open(capture).n_frames == FRAMES    # its later images keep their numbers
    assert f"camera {camera!r} has no images for capture frames 0-1 (its recording starts late)" in caplog.text
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert f"camera {camera} had no image in 2 of {FRAMES} frames (frames 0-1)" in printed
    _check_unshifted(table, capture, range(FRAMES))


def test_a_video_that_starts_late_is_paired_by_time_and_nothing_shifts(video_capture, tmp_path, capsys, caplog):
    from spinemocap.capture import set_camera_offsets
    from spinemocap.media import VideoDecoder, VideoWriter

    capture = tmp_path / "capture"
    shutil.copytree(video_capture, capture)
    opened = Capture.open(capture)
    camera = opened.rig.names[1]
    video = capture / "videos" / f"{camera}.avi"
    decoder = VideoDecoder(video)
    images = [decoder.read(k).copy() for k in range(FRAMES)]
    decoder.close()
    writer = VideoWriter(video, opened.fps, opened.rig[1].size)
    for image in images[2:]:                          # the camera started two frames late
        writer.write(image)
    writer.close()
    set_camera_offsets(capture, {camera: -2 / opened.fps})
    table, printed = _track(capture, tmp_path / "out", capsys)
    assert f"camera {camera!r} has no images for capture frames 0-1 (its recording starts late)" in caplog.text
    assert f"camera {camera} had no image in 2 of {FRAMES} frames (frames 0-1)" in printed
    _check_unshifted(table, capture, range(FRAMES))
