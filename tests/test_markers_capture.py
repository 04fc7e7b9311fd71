import numpy as np
import pytest

from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture, read_image
from spinemocap.fileio import InputError, atomic_write
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec


def test_marker_table_array_round_trip():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(4, 3, 3)) * 100
    pos[1, 2] = np.nan
    status = np.full((4, 3), "observed", dtype=object)
    status[2, 0] = "inferred"
    table = MarkerTable.from_arrays(["R01L", "R01R", "R02L"], pos, fps=100, status=status,
                                    n_views=np.full((4, 3), 3))
    arr = table.to_arrays()
    assert list(arr.labels) == ["R01L", "R01R", "R02L"]
    assert np.allclose(arr.positions, pos, equal_nan=True)
    assert arr.status[1, 2] == "missing" and arr.status[2, 0] == "inferred"
    assert np.allclose(arr.time, np.arange(4) / 100)
    assert table.completeness()["missing"] == pytest.approx(1 / 12)


def test_marker_table_rejects_duplicates_and_bad_status():
    t = MarkerTable.from_arrays(["A"], np.zeros((2, 1, 3)), fps=10)
    df = t.data.copy()
    df.loc[1, "frame"] = 0
    with pytest.raises(InputError, match="duplicate"):
        MarkerTable(df, {"source": "x.csv"})
    df = t.data.copy()
    df["status"] = df["status"].astype(str)
    df.loc[0, "status"] = "seen"
    with pytest.raises(InputError, match="x.csv.*unknown marker status"):
        MarkerTable(df, {"source": "x.csv"})


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_write(target) as f:
            f.write("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def _write_capture(root, n_frames=2):
    rig = Rig([Camera.look_at(f"cam{i}", (i * 500.0, -2000, 1200), (0, 0, 1100), (32, 24), 40) for i in range(2)])
    cap = Capture(root=root, name="t", fps=50.0, n_frames=n_frames, rig=rig, tape=TapeSpec(n_rows=5),
                  subject={"id": "S1", "up": [0, 0, 1]})
    cap.save()
    import cv2

    for cam in rig.names:
        for f in range(n_frames):
            p = root / cap.image_pattern.format(camera=cam, frame=f)
            p.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(p), np.full((24, 32, 3), f * 10, np.uint8))
    return cap


def test_capture_open_and_read(tmp_path):
    _write_capture(tmp_path)
    cap = Capture.open(tmp_path)
    assert cap.camera_names == ["cam0", "cam1"] and cap.tape.n_rows == 5 and cap.fps == 50
    frames = cap.frame_source().read(1)
    assert len(frames) == 2 and frames[0].shape == (24, 32, 3) and frames[0].max() == 10


def test_capture_errors_name_the_problem(tmp_path):
    with pytest.raises(InputError, match="not a capture folder"):
        Capture.open(tmp_path)
    _write_capture(tmp_path)
    (tmp_path / "images/cam1/000001.png").unlink()      # cam1's recording ends early: the others go on
    assert Capture.open(tmp_path).frame_source().read(1)[1] is None
    (tmp_path / "images/cam0/000001.png").unlink()      # no camera recorded frame 1
    with pytest.raises(InputError, match=r"n_frames = 2 but no camera recorded that many frames.*set n_frames = 1"):
        Capture.open(tmp_path)
    (tmp_path / "images/cam0/000001.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="000001.png.*corrupt"):
        read_image(tmp_path / "images/cam0/000001.png")


@pytest.mark.parametrize("codec", ["utvideo", "rawvideo"])
def test_videos_round_trip_losslessly_and_older_ffv1_videos_stay_readable(tmp_path, codec):
    import cv2

    from spinemocap.capture import VideoSource, VideoWriter

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(3)]
    new = VideoWriter(tmp_path / "videos" / "a.avi", 100.0, (64, 48), codec=codec)
    old = cv2.VideoWriter(str(tmp_path / "videos" / "b.mkv"), cv2.VideoWriter_fourcc(*"FFV1"), 100.0, (64, 48))
    for image in frames:
        new.write(image)
        old.write(image)
    new.close()
    old.release()
    for pattern in ("videos/a.avi", "videos/b.mkv"):  # a name without {camera}: one camera
        source = VideoSource(tmp_path, ["cam"], 3, pattern)
        for f in (0, 2, 1):  # a jump back seeks
            np.testing.assert_array_equal(source.read(f)[0], frames[f])
    # an aborted video leaves no file behind
    broken = VideoWriter(tmp_path / "videos" / "c.avi", 100.0, (64, 48), codec=codec)
    broken.write(frames[0])
    broken.abort()
    assert sorted(p.name for p in (tmp_path / "videos").iterdir()) == ["a.avi", "b.mkv"]
    with pytest.raises(InputError, match=r"d\.avi.*unknown video codec 'huffyuv'"):
        VideoWriter(tmp_path / "videos" / "d.avi", 100.0, (64, 48), codec="huffyuv")


def test_video_images_held_by_the_caller_are_never_overwritten(tmp_path):
    """The decoder interleaves each UT Video frame into an array it handed out before only once
    nothing else holds that array: images (or views of them) kept by the caller keep their pixels,
    a dropped one is reused, and a prefetching reader in another thread gets every frame right."""
    from spinemocap.app.streaming import prefetched_frames
    from spinemocap.capture import REUSED_BUFFERS, VideoDecoder, VideoSource, VideoWriter

    n = 2 * REUSED_BUFFERS + 3
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(n)]
    writer = VideoWriter(tmp_path / "a.avi", 100.0, (64, 48))
    for image in frames:
        writer.write(image)
    writer.close()
    decoder = VideoDecoder(tmp_path / "a.avi")
    first = decoder.read(0)
    view = decoder.read(1)[10:20, 5:9, 1]  # only a view of frame 1 kept
    held = [decoder.read(f) for f in range(2, n)]  # more than the decoder keeps for reuse
    np.testing.assert_array_equal(first, frames[0])
    np.testing.assert_array_equal(view, frames[1][10:20, 5:9, 1])
    for f, image in enumerate(held, start=2):
        np.testing.assert_array_equal(image, frames[f])
    decoder.close()
    decoder = VideoDecoder(tmp_path / "a.avi")
    addresses = set()
    for f in range(n):  # each image dropped before the next read: one array serves them all
        image = decoder.read(f)
        np.testing.assert_array_equal(image, frames[f])
        addresses.add(image.ctypes.data)
        del image
    decoder.close()
    assert len(addresses) == 1
    source = VideoSource(tmp_path, ["cam", "cam2"], n, "a.avi")  # two cameras: reader threads
    kept: list = []
    for frame, images, _ in prefetched_frames(source, range(n), workers=2, prefetch=2):
        kept = (kept + [images])[-2:]  # the consumer holds the last two frames, as the tracker does
        for earlier, images_then in zip(range(frame - len(kept) + 1, frame + 1), kept):
            for image in images_then:
                np.testing.assert_array_equal(image, frames[earlier])
    source.close()


def test_damaged_videos_name_the_file_and_leave_the_camera_out_of_the_frames_it_lacks(tmp_path):
    from spinemocap.capture import VideoSource, VideoWriter

    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(6)]
    writer = VideoWriter(tmp_path / "videos" / "a.avi", 100.0, (64, 48))
    for image in frames:
        writer.write(image)
    writer.close()
    whole = (tmp_path / "videos" / "a.avi").read_bytes()
    with pytest.raises(InputError, match=r"a\.avi.*6 frames, capture.toml says n_frames = 4"):
        VideoSource(tmp_path, ["cam"], 4, "videos/a.avi")           # more frames than the capture: a mistake
    short = VideoSource(tmp_path, ["cam"], 9, "videos/a.avi")       # a recording that ends early
    np.testing.assert_array_equal(short.read(5)[0], frames[5])
    assert short.read(6) == [None] and short.unreadable["cam"] == {6: "the video ends at frame 6"}
    (tmp_path / "videos" / "a.avi").write_bytes(b"RIFF" + bytes(200))
    with pytest.raises(InputError, match=r"a\.avi.*cannot be opened"):
        VideoSource(tmp_path, ["cam"], 6, "videos/a.avi")
    # cut after the first frames: the frames before the cut decode, a later one is None with the reason
    (tmp_path / "videos" / "a.avi").write_bytes(whole[: len(whole) // 2])
    source = VideoSource(tmp_path, ["cam"], 6, "videos/a.avi")
    np.testing.assert_array_equal(source.read(0)[0], frames[0])
    assert source.read(5) == [None]
    assert "cannot decode frame 5" in source.unreadable["cam"][5]


def test_videos_without_pyav_give_an_error_naming_the_file(tmp_path, monkeypatch):
    import sys

    from spinemocap.capture import VideoDecoder, VideoWriter

    monkeypatch.setitem(sys.modules, "av", None)  # as in an installation that lacks PyAV
    with pytest.raises(InputError, match=r"a\.avi.*PyAV"):
        VideoDecoder(tmp_path / "a.avi")
    with pytest.raises(InputError, match=r"b\.avi.*PyAV"):
        VideoWriter(tmp_path / "b.avi", 100.0, (64, 48))
    assert not list(tmp_path.iterdir())
