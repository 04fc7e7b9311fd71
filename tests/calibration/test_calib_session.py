"""Board sessions as labs record them: videos of any codec and rate paired by their timestamps,
the pose-graph consensus that keeps the right one of a planar view's two poses, and the
comparison with a calibration the lab already has."""

from fractions import Fraction

import av
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.check import compare_rigs
from calibration.extrinsics import _relative_pose
from spinemocap.app.calibrate import open_recording, pair_frames
from spinemocap.bench.calibration_scenes import make_ring_rig
from spinemocap.camera import Camera, Rig
from spinemocap.fileio import InputError


def write_video(path, fps: int, n_frames: int, start_s: float, codec: str = "mpeg4") -> None:
    """A small video whose frames are stamped from ``start_s`` on the container's clock."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=fps)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        stream.time_base = Fraction(1, 1000)
        for k in range(n_frames):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 8 * k, np.uint8), format="rgb24")
            frame.pts = int(round(1000 * (start_s + k / fps)))
            frame.time_base = Fraction(1, 1000)
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))


def test_videos_of_other_rates_and_start_times_pair_by_timestamp(tmp_path):
    write_video(tmp_path / "a.mp4", 6, 12, 10.0)              # 6 fps from t = 10 s
    write_video(tmp_path / "b.avi", 12, 30, 9.5)              # 12 fps, started half a second earlier
    write_video(tmp_path / "c.mkv", 6, 12, 10.5, "libx264" if "libx264" in av.codecs_available else "mpeg4")
    recordings = [open_recording(tmp_path / n) for n in ("a.mp4", "b.avi", "c.mkv")]
    assert [r.n_frames for r in recordings] == [12, 30, 12]
    assert recordings[1].size == (64, 48)
    a, b, c = pair_frames(recordings, "time", max_frames=100)
    assert a == {k: k for k in range(12)}
    # b's frame i is at 9.5 + i / 12 s: a's frame k (10 + k / 6 s) is b's frame 6 + 2k
    assert b == {6 + 2 * k: k for k in range(12)}
    # c started 0.5 s (3 frames) after a
    assert c == {k - 3: k for k in range(3, 12)}
    by_index = pair_frames(recordings, "index", max_frames=4)
    assert sorted(by_index[0]) == [0, 3, 6, 9] and by_index[1] == {k: k for k in (0, 3, 6, 9)}
    # decoding gives the frames asked for
    frames = dict(recordings[1].frames({6, 8}))
    assert sorted(frames) == [6, 8]
    # frame k is grey 8 k (the lossy codec within 4; the neighbours are 8 away)
    assert abs(frames[6].mean() - 48) < 4 and abs(frames[8].mean() - 64) < 4


def test_image_folders_cannot_pair_by_time(tmp_path):
    import cv2

    folder = tmp_path / "cam_0"
    folder.mkdir()
    cv2.imwrite(str(folder / "0000.png"), np.zeros((48, 64), np.uint8))
    rec = open_recording(folder)
    assert (rec.name, rec.n_frames, rec.size) == ("cam_0", 1, (64, 48))
    with pytest.raises(InputError, match="no timestamps; pair frames by index"):
        pair_frames([rec, rec], "time", 10)
    with pytest.raises(InputError, match="no such video or image folder"):
        open_recording(tmp_path / "missing.mp4")


def test_pair_pose_from_consensus_of_both_planar_solutions():
    """Half the frames' best PnP solution is the wrong one of the planar pair: the consensus
    over both candidates recovers the true relative pose; averaging the best ones would not."""
    rng = np.random.default_rng(0)
    true_R = Rotation.from_euler("xyz", [5, -40, 3], degrees=True).as_matrix()
    true_t = np.array([900.0, -40.0, 350.0])
    parent, child = {}, {}
    for f in range(12):
        Rp = Rotation.from_rotvec(rng.normal(0, 0.4, 3)).as_matrix()
        tp = np.array([0, 0, 1500.0]) + rng.normal(0, 200, 3)
        Rc, tc = true_R @ Rp, true_R @ tp + true_t
        flip = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()  # the other solution
        wrong = (flip @ Rc, tc + rng.normal(0, 30, 3))
        parent[f] = [(Rp, tp)]
        child[f] = [wrong, (Rc, tc)] if f % 2 else [(Rc, tc), wrong]
    (R, t), agree = _relative_pose(parent, child, list(range(12)))
    assert agree == 12
    assert np.degrees(Rotation.from_matrix(R @ true_R.T).magnitude()) < 1e-6
    assert np.linalg.norm(t - true_t) < 1e-6


def test_compare_rigs_reports_baseline_ratio_and_rotation_difference():
    truth = make_ring_rig(4, size=(800, 600), seed=1)
    # the same rig in another world frame: agrees exactly
    moved = truth.transformed(Rotation.from_euler("z", 33, degrees=True).as_matrix(), np.array([100.0, 5, -7]))
    same = compare_rigs(moved, truth)
    assert same.agrees and same.matched_by == "name"
    assert same.worst_baseline_error < 1e-9 and same.worst_rotation_deg < 1e-6
    # one camera moved 3 % farther from the others along its baseline to cam1 and turned 1.5 deg
    cams = list(truth)
    c = cams[2]
    centre = cams[0].center + 1.03 * (c.center - cams[0].center)
    R = Rotation.from_euler("y", 1.5, degrees=True).as_matrix() @ c.R
    cams[2] = Camera(c.name, c.K, c.dist, R, -R @ centre, c.size)
    off = compare_rigs(Rig(cams), truth)
    pair = next(p for p in off.pairs if (p.a, p.b) == (cams[0].name, c.name))
    assert pair.baseline_ratio == pytest.approx(1.03, abs=1e-9)
    assert pair.rotation_diff_deg == pytest.approx(1.5, abs=1e-6)
    assert not off.agrees and "DISAGREE" in off.summary()
    renamed = Rig([Camera(f"x{k}", c.K, c.dist, c.R, c.t, c.size) for k, c in enumerate(truth)])
    assert compare_rigs(renamed, truth).matched_by == "order"
    with pytest.raises(InputError, match="different cameras"):
        compare_rigs(truth.subset(truth.names[:3]), truth)
