"""capture.toml as documented in docs/CAPTURE.md: unknown keys refused in every table, the rate
checked against the videos', n_frames optional, partial ranges, paths outside the folder, a
foreign calibration named as the rig, camera offsets written back; `capture init`'s name
matching and size fixes on small videos (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest
from lab_recordings import write_mp4
from repo_paths import SHARED

from spinemocap.app.capture_init import fixed_camera, init_capture, match_cameras, size_mismatch
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture, set_camera_offsets
from spinemocap.cli import main
from spinemocap.fileio import InputError, read_toml, write_toml
from spinemocap.tape import TapeSpec

pytest.importorskip("av")
SIZE = (64, 48)
FPS = 25.0


def small_rig(size=SIZE) -> Rig:
    return Rig([Camera.look_at(f"cam{i + 1}", (i * 600.0 - 600, -2500, 1200), (0, 0, 1100), size, 60)
                for i in range(3)])


def frames(n: int, seed: int) -> list[np.ndarray]:
    """Frames whose mean grey level is their index x 20 (which frame a reader returned)."""
    rng = np.random.default_rng(seed)
    return [np.clip(rng.integers(-3, 4, (SIZE[1], SIZE[0], 3)) + 20 * k + 20, 0, 255).astype(np.uint8)
            for k in range(n)]


@pytest.fixture
def lab(tmp_path):
    """Three cameras' MP4s of 6, 5 and 6 frames at 25 frames/s, and their rig TOML."""
    folder = tmp_path / "lab"
    videos = [write_mp4(folder / f"take3_cam{k + 1}.mp4", frames(5 if k == 1 else 6, k), FPS) for k in range(3)]
    small_rig().to_toml(folder / "rig.toml")
    return folder, videos


def test_init_reads_counts_and_rates_from_the_files_and_spans_what_two_cameras_recorded(lab, tmp_path):
    folder, videos = lab
    result = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos)
    capture = result.capture
    assert capture.fps == FPS and capture.n_frames == 6 and capture.external_media
    assert [result.probes[n].n_frames for n in capture.camera_names] == [6, 5, 6]
    source = capture.frame_source()
    means = [float(image.mean()) for image in source.read(4)]
    np.testing.assert_allclose(means, 100.0, atol=3)  # every camera's fifth frame
    last = source.read(5)                             # cam2's recording ended: the others go on
    assert last[1] is None and [float(last[k].mean()) for k in (0, 2)] == pytest.approx([120.0, 120.0], abs=3)
    manifest = read_toml(tmp_path / "cap" / "capture.toml")
    assert manifest["camera"]["cam2"]["media"] == str(videos[1].resolve())


def test_init_start_and_end_choose_a_part_in_seconds_or_frames(lab, tmp_path):
    folder, videos = lab
    capture = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos, start="0.04s", end="4").capture
    assert capture.start_s == pytest.approx(0.04) and capture.n_frames == 3
    means = [float(image.mean()) for image in capture.frame_source().read(0)]
    np.testing.assert_allclose(means, 40.0, atol=3)  # capture frame 0 = the recordings' frame 1
    with pytest.raises(InputError, match="start: 0.2s lies after the end of camera 'cam2'"):
        init_capture(tmp_path / "late", folder / "rig.toml", media=videos, start="0.2s")
    with pytest.raises(InputError, match="end: 7 leaves 7 frames after `start`"):
        init_capture(tmp_path / "long", folder / "rig.toml", media=videos, end="7")


def test_init_offset_pairs_a_late_camera_by_time(lab, tmp_path):
    folder, videos = lab
    capture = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos, offsets={"cam3": 0.08}).capture
    means = [float(image.mean()) for image in capture.frame_source().read(1)]
    np.testing.assert_allclose(means, [40.0, 40.0, 80.0], atol=3)  # cam3 shows its frame 3


def test_name_matching_errors_list_both_sides_and_map_fixes_them(lab, tmp_path):
    folder, videos = lab
    renamed = [videos[0].rename(folder / "left.mp4"), videos[1], videos[2]]
    with pytest.raises(InputError) as error:
        init_capture(tmp_path / "cap", folder / "rig.toml", media=renamed)
    message = str(error.value)
    assert "left.mp4 names no camera" in message
    assert "The calibration's cameras: cam1, cam2, cam3" in message and "left.mp4, take3_cam2.mp4" in message
    assert "`mapping` (CAMERA=FILE)" in message and error.value.source == "camera names"
    capture = init_capture(tmp_path / "cap", folder / "rig.toml", media=renamed, mapping={"cam1": "left.mp4"}).capture
    assert capture.camera_names == ["cam1", "cam2", "cam3"]
    assert capture.camera_clocks["cam1"].media.endswith("left.mp4")
    with pytest.raises(InputError, match="'cam9' is not a camera of the calibration"):
        match_cameras(["cam1"], [], named={"cam9": renamed[0]})
    # a name inside a longer one is not a match: cam1 is not cam10's
    assert match_cameras(["cam1", "cam10"], [folder / "x_cam10.mp4", folder / "cam1.mp4"]) == {
        "cam1": folder / "cam1.mp4", "cam10": folder / "x_cam10.mp4"}


def test_size_fixes_crop_and_scale_adjust_the_intrinsics():
    camera = small_rig((640, 368))[0]
    crop = size_mismatch(camera, (640, 360))
    assert crop is not None and crop.kind == "crop" and "8 rows" in crop.explain()
    kept = fixed_camera(camera, crop, "crop")
    assert kept.size == (640, 360) and np.array_equal(kept.K, camera.K)
    centred = fixed_camera(camera, crop, "crop-centre")
    assert centred.K[1, 2] == pytest.approx(camera.K[1, 2] - 4.0) and centred.K[0, 2] == camera.K[0, 2]
    scale = size_mismatch(camera, (1280, 736))
    assert scale is not None and scale.kind == "scale" and scale.scale == 2.0
    doubled = fixed_camera(camera, scale, "scale")
    points = np.array([[10.0, 50.0, 1100.0], [-80.0, 20.0, 1250.0]])
    np.testing.assert_allclose(doubled.project(points), (camera.project(points) + 0.5) * 2 - 0.5, atol=1e-9)
    assert size_mismatch(camera, (500, 300)).kind is None
    with pytest.raises(InputError, match="does not fit"):
        fixed_camera(camera, scale, "crop")


def test_init_refuses_a_size_mismatch_with_the_fix_and_applies_it(lab, tmp_path, capsys):
    folder, videos = lab
    small_rig((SIZE[0], SIZE[1] + 8)).to_toml(folder / "tall.toml")
    args = ["capture", "init", str(tmp_path / "cap"), "--videos", *map(str, videos), "--calibration",
            str(folder / "tall.toml")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "camera 'cam1': its recording is 64x48 px but the calibration says 64x56 px" in err
    assert "--fix-size crop" in err and not (tmp_path / "cap" / "capture.toml").exists()
    assert main([*args, "--fix-size", "crop"]) == 0
    assert "calibration fixed: camera 'cam1': calibration 64x56 -> 64x48 px (--fix-size crop)" in capsys.readouterr().out
    assert Rig.from_toml(tmp_path / "cap" / "rig.toml")[0].size == SIZE
    assert main(args) == 2 and "already here" in capsys.readouterr().err  # never over a capture


def _manifest_with(cap, change):
    data = read_toml(cap / "capture.toml")
    change(data)
    write_toml(cap / "capture.toml", data)


@pytest.mark.parametrize("table, key, valid", [
    ("capture", "vidoe_pattern", "video_pattern"), ("subject", "hieght", "facing"),
    ("camera.cam2", "ofset_s", "offset_s"), ("tape", "n_row", "n_rows")])
def test_unknown_keys_are_refused_in_every_table_naming_the_valid_ones(lab, tmp_path, table, key, valid):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos).root

    def add(data):
        node = data
        for part in table.split("."):
            node = node.setdefault(part, {})
        node[key] = 1

    _manifest_with(cap, add)
    with pytest.raises(InputError, match=rf"{key}") as error:
        Capture.open(cap)
    assert valid in str(error.value)
    _manifest_with(cap, lambda d: d.__setitem__("cameras", {"x": 1}))
    with pytest.raises(InputError, match=r"unknown table \[cameras\] \(valid tables: capture, tape"):
        Capture.open(cap)


def test_a_rate_that_is_not_the_videos_is_refused_unless_forced(lab, tmp_path):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos).root
    _manifest_with(cap, lambda d: d["capture"].__setitem__("fps", 50.0))
    with pytest.raises(InputError, match=r"fps = 50 but camera 'cam1'.*runs at 25 frames/s.*force_fps = true"):
        Capture.open(cap)
    _manifest_with(cap, lambda d: d["capture"].__setitem__("force_fps", True))
    assert Capture.open(cap).fps == 50.0


def test_n_frames_is_optional_and_a_part_of_the_videos_may_be_used(lab, tmp_path):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos).root
    assert "n_frames" not in read_toml(cap / "capture.toml")["capture"]  # found on opening
    assert Capture.open(cap).n_frames == 6  # cam1 and cam3 recorded 6 frames, cam2 5
    set_camera_offsets(cap, {"cam1": 0.04})  # cam1 started a frame earlier: its last frame is sooner
    assert Capture.open(cap).n_frames == 5 and Capture.open(cap).clocks[0].offset_s == 0.04  # cam3 alone at 5
    set_camera_offsets(cap, {"cam3": 0.08})  # cam1 and cam2 still reach frame 4 together
    assert Capture.open(cap).n_frames == 5
    set_camera_offsets(cap, {"cam1": 0.08})  # now only cam2 does
    assert Capture.open(cap).n_frames == 4
    _manifest_with(cap, lambda d: d["capture"].__setitem__("n_frames", 2))
    capture = Capture.open(cap)
    assert capture.n_frames == 2 and len(capture.frame_source().read(1)) == 3


def test_paths_outside_the_folder_need_external_media(lab, tmp_path):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos).root
    _manifest_with(cap, lambda d: d["capture"].pop("external_media"))
    with pytest.raises(InputError, match=r"\[camera.cam1\] media .* leads outside the capture folder; set "
                                         r"external_media = true"):
        Capture.open(cap)
    copied = init_capture(tmp_path / "copied", folder / "rig.toml", media=videos, copy=True).capture
    assert not copied.external_media and copied.camera_clocks["cam1"].media == "videos/cam1.mp4"
    (copied.root / "videos").rename(tmp_path / "disk2")  # media on another disk, linked into the folder
    (copied.root / "videos").symlink_to(tmp_path / "disk2")
    assert Capture.open(copied.root).n_frames == 6


def test_a_foreign_calibration_as_the_rig_names_the_command_that_converts_it(lab, tmp_path):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos).root
    _manifest_with(cap, lambda d: d["capture"].__setitem__("rig", "Calib.qca.txt"))
    with pytest.raises(InputError, match=r"Qualisys calibration.*`spinemocap calibrate convert .*Calib.qca.txt "
                                         r".*rig.toml`"):
        Capture.open(cap)


def test_camera_offsets_are_written_back_keeping_the_rest(lab, tmp_path):
    folder, videos = lab
    cap = init_capture(tmp_path / "cap", folder / "rig.toml", media=videos, start="0.04s").root
    set_camera_offsets(cap, {"cam2": -0.0123})
    capture = Capture.open(cap)
    assert capture.camera_clocks["cam2"].offset_s == -0.0123 and capture.camera_clocks["cam2"].media
    assert capture.clocks[1].offset_s == pytest.approx(-0.0123 + 0.04)  # start_s folded into the clock
    with pytest.raises(InputError, match="no camera 'cam7'"):
        set_camera_offsets(cap, {"cam7": 0.0})


def test_a_tape_spec_and_images_need_their_own_values(tmp_path):
    import cv2

    for name in ("cam1", "cam2", "cam3"):
        (tmp_path / "imgs" / name).mkdir(parents=True)
        for k, image in enumerate(frames(3, 0)):
            cv2.imwrite(str(tmp_path / "imgs" / name / f"img_{k:03d}.png"), image)
    small_rig().to_toml(tmp_path / "rig.toml")
    media = sorted((tmp_path / "imgs").iterdir())
    with pytest.raises(InputError, match="give it with `fps`"):
        init_capture(tmp_path / "cap", tmp_path / "rig.toml", media=media)
    capture = init_capture(tmp_path / "cap", tmp_path / "rig.toml", media=media, fps=30,
                           tape=TapeSpec(n_rows=7)).capture
    assert capture.media == "images" and capture.n_frames == 3 and capture.tape.n_rows == 7
    assert float(capture.frame_source().read(2)[0].mean()) == pytest.approx(60.0, abs=3)


@pytest.mark.parametrize("name, fmt", [("calib.xcp", None), ("Calib.toml", "pose2sim")])
def test_init_converts_vicon_and_pose2sim_calibrations(lab, tmp_path, name, fmt):
    from calibration.formats import write_rig

    folder, videos = lab
    write_rig(small_rig(), folder / name, fmt)
    capture = init_capture(tmp_path / "cap", folder / name, media=videos).capture
    assert capture.camera_names == ["cam1", "cam2", "cam3"]
    np.testing.assert_allclose(capture.rig["cam2"].K, small_rig()["cam2"].K, rtol=1e-6)
    assert Rig.from_toml(tmp_path / "cap" / "rig.toml").names == capture.camera_names


def test_init_with_named_videos_and_an_offset_from_the_command_line(lab, tmp_path, capsys):
    folder, videos = lab
    renamed = [v.rename(folder / f"clip{k}.mp4") for k, v in enumerate(videos)]
    out = tmp_path / "cap"
    assert main(["capture", "init", str(out), *[f"--video=cam{k + 1}={p}" for k, p in enumerate(renamed)],
                 "--calibration", str(folder / "rig.toml"), "--offset", "cam2=-0.04", "--copy", "-q"]) == 0
    assert "capture written" in capsys.readouterr().out
    capture = Capture.open(out)
    assert capture.camera_clocks["cam2"].offset_s == -0.04 and capture.camera_clocks["cam2"].media == "videos/cam2.mp4"
    assert not capture.external_media and (out / "videos" / "cam3.mp4").is_file()
    assert main(["capture", "init", str(tmp_path / "x"), "--video", "cam1=" + str(renamed[0]), "--calibration",
                 str(folder / "rig.toml"), "--offset", "cam9=0.1"]) == 2
    assert "cam9: no camera of that name has a recording" in capsys.readouterr().err


def test_a_real_qualisys_calibration_of_1088_px_cameras_with_1080_px_videos(tmp_path):
    """The Pose2Sim demo studio's QTM export (four 1088x1920 portrait cameras) and videos of
    1080x1920, as its encoder wrote them: refused with the reason, fixed by --fix-size crop."""

    qca = SHARED / "data/calibration/pose2sim_demo/Calib.qca.txt"
    if not qca.is_file():
        pytest.skip("shared reference data not present")
    grey = [np.full((1920, 1080, 3), 90 + 10 * k, np.uint8) for k in range(2)]
    videos = [write_mp4(tmp_path / "takes" / f"walk_cam0{k}.mp4", grey, 30.0) for k in range(1, 5)]
    with pytest.raises(InputError) as error:
        init_capture(tmp_path / "cap", qca, media=videos)
    assert "camera 'cam01': its recording is 1080x1920 px but the calibration says 1088x1920 px: 8 columns" \
        in str(error.value)
    capture = init_capture(tmp_path / "cap", qca, media=videos, fix_size="crop").capture
    assert capture.camera_names == ["cam01", "cam02", "cam03", "cam04"] and capture.fps == 30.0
    assert all(camera.size == (1080, 1920) for camera in capture.rig)
    assert capture.frame_source().read(1)[3].shape == (1920, 1080, 3)
