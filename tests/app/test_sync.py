"""Clock-offset estimates: the dots' motion across views and a clap on the audio tracks."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.app.sync import (
    CameraDots,
    PairOffset,
    audio_lag,
    combine_pairs,
    estimate_motion,
    onset_envelope,
    read_audio,
    write_offsets,
)
from spinemocap.media import VideoWriter
from spinemocap.synth.clocks import AUDIO_RATE, CameraRecording, camera_audio
from spinemocap.synth.rigs import LAYOUTS, arc_rig

GOAL_S = 0.001  # |error| on 100 fps cameras


def _tape(t: float) -> np.ndarray:
    """(33, 3) mm: a 3 x 11 grid of dots on a back that sways, bends and twists, at capture time t (s)."""
    u, v = np.meshgrid(np.linspace(-30, 30, 3), np.linspace(0, 400, 11))
    local = np.column_stack([u.ravel(), np.zeros(u.size), v.ravel()])
    a, b = 0.35 * np.sin(2 * np.pi * t / 2.2), 0.25 * np.sin(2 * np.pi * t / 3.1 + 1)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return local @ (rz @ rx).T + [40 * np.sin(2 * t), 0, 900]


def _camera_dots(camera, offset_s: float, fps: float, seconds: float, rng, noise_px: float = 0.15) -> CameraDots:
    """What a camera whose clock is ``offset_s`` ahead records over ``seconds`` s: the grid's
    projections with detection noise, undistorted."""
    stamps = np.arange(int(seconds * fps)) / fps
    uv = []
    for tau in stamps:
        pixels = camera.project(_tape(tau - offset_s + 1.0))
        uv.append(camera.undistort_points(pixels + rng.normal(0, noise_px, pixels.shape)))
    return CameraDots(stamps, uv, fps)


def test_motion_estimate_finds_whole_and_fractional_offsets_and_mixed_rates():
    rng = np.random.default_rng(3)
    rig = arc_rig(LAYOUTS["tiny"], 3, (480, 360), np.array([0.0, 0.0, 1100.0]), 0.0, rng)
    offsets = np.array([0.0, 0.27, -0.1234])  # 27 whole frames; 12.34 frames at 100 fps (7.4 at 60)
    fps = np.array([100.0, 100.0, 60.0])
    dots = [_camera_dots(cam, o, f, 1.2, rng) for cam, o, f in zip(rig, offsets, fps)]
    estimate = estimate_motion(rig, dots, max_offset_s=0.4)
    assert estimate.found.all()
    error = estimate.offsets_s - offsets
    assert abs(error[1]) <= GOAL_S  # 100 fps
    assert abs(error[2]) <= 2 * GOAL_S  # 60 fps: within a tenth of its frame
    assert (estimate.stderr_s[1:] < GOAL_S).all()


def test_motion_estimate_rejects_a_camera_without_shared_motion():
    rng = np.random.default_rng(4)
    rig = arc_rig(LAYOUTS["tiny"], 2, (480, 360), np.array([0.0, 0.0, 1100.0]), 0.0, rng)
    still = CameraDots(np.arange(60) / 100, [rig[1].project(_tape(0.0)) + rng.normal(0, 0.15, (33, 2))
                                            for _ in range(60)], 100.0)
    estimate = estimate_motion(rig, [_camera_dots(rig[0], 0.0, 100.0, 0.6, rng), still], max_offset_s=0.2)
    assert not estimate.found[1] and np.isinf(estimate.stderr_s[1])


def test_pairwise_offsets_combined_on_the_camera_graph():
    pairs = [PairOffset(0, 1, 0.100, 1e-4, 100, 0.2), PairOffset(0, 2, -0.300, 1e-4, 100, 0.2),
             PairOffset(1, 2, -0.4006, 1e-4, 100, 0.2), PairOffset(0, 3, 5.0, float("inf"), 0, 3.0)]
    offsets, stderr = combine_pairs(pairs, 4)
    assert offsets[0] == 0 and stderr[0] == 0
    np.testing.assert_allclose(offsets[1:3], [0.1002, -0.3002], atol=1e-6)  # the loop's misfit shared
    assert np.isnan(offsets[3]) and np.isinf(stderr[3])  # only an untrusted pair reaches camera 3


def test_audio_estimate_finds_a_clap_to_a_fraction_of_a_sample(tmp_path):
    rng = np.random.default_rng(5)
    offsets = [0.0, 0.73712345, -0.41230007]  # fractions of a 48 kHz sample
    clap_at = 0.9
    tracks = []
    for c, offset in enumerate(offsets):
        recording = CameraRecording(offset, 50.0, int((2.0 + offset) * 50))
        audio = camera_audio(recording, clap_at, gain=0.6 + 0.2 * c, rng=rng)
        path = tmp_path / f"cam{c}.avi"
        writer = VideoWriter(path, 50.0, (16, 16), audio_rate=AUDIO_RATE)  # read back from a real file
        per_frame = AUDIO_RATE // 50
        for k in range(recording.n_slots):
            writer.write(np.zeros((16, 16, 3), np.uint8), k)
            writer.write_audio(audio[k * per_frame:(k + 1) * per_frame])
        writer.close()
        samples, rate, start = read_audio(path)
        assert rate == AUDIO_RATE and start == 0.0
        np.testing.assert_array_equal(samples, audio[: len(samples)].astype(float))
        tracks.append(onset_envelope(samples, rate))
    for c in (1, 2):
        lag, prominence = audio_lag(tracks[0], tracks[c], AUDIO_RATE, 2.0)
        assert abs(lag - offsets[c]) < 0.05e-3 and prominence > 1.5


def test_audio_lag_of_noise_alone_is_not_prominent():
    rng = np.random.default_rng(6)
    a, b = (onset_envelope(rng.normal(0, 0.01, AUDIO_RATE), AUDIO_RATE) for _ in range(2))
    assert audio_lag(a, b, AUDIO_RATE, 0.5)[1] < 1.5


def test_written_offsets_read_back_as_the_cameras_clocks(tmp_path):
    from spinemocap.app.sync import SyncEstimate
    from spinemocap.camera import Rig
    from spinemocap.capture import Capture
    from spinemocap.tape import TapeSpec

    rig = arc_rig(LAYOUTS["tiny"], 3, (64, 48), np.array([0.0, 0.0, 1100.0]), 0.0, np.random.default_rng(0))
    capture = Capture(root=tmp_path, name="t", fps=100.0, n_frames=10, rig=Rig(list(rig)), tape=TapeSpec(n_rows=3))
    capture.save()
    estimate = SyncEstimate(tuple(capture.camera_names), np.array([0.0, 0.0123, np.nan]),
                            np.array([0.0, 1e-4, np.inf]), "motion")
    write_offsets(capture, estimate)
    clocks = Capture.open(tmp_path).clocks
    assert [c.offset_s for c in clocks] == pytest.approx([0.0, 0.0123, 0.0])


@pytest.mark.slow
def test_studio_capture_with_offsets_and_a_drop_is_synced_within_the_goal(tmp_path):
    from spinemocap.app.sync import estimate_offsets
    from spinemocap.capture import Capture
    from spinemocap.synth import SynthConfig, write_capture

    config = SynthConfig.preset("tiny", frames=100, fps=100.0, cameras=3, realism="skin", video=True, clap=True,
                                camera_offsets_s=(0.0, 0.1831, -0.0967), drop_frames=1)
    capture = Capture.open(write_capture(config, tmp_path / "unsynced", progress=False))
    truth = capture.groundtruth()
    offsets = truth["clock_offsets_s"] - truth["clock_offsets_s"][0]
    (camera, slot), = truth["dropped_slots"]
    dropped = capture.media_times()[camera].dropped
    assert [(d.after_slot, d.missing) for d in dropped] == [(slot - 1, 1)]
    motion = estimate_offsets(capture, "motion", detector="classical", progress=False)
    assert motion.found.all() and np.abs(motion.offsets_s - offsets).max() <= GOAL_S
    audio = estimate_offsets(capture, "audio")
    assert np.abs(audio.offsets_s - offsets).max() <= 0.05e-3
    write_offsets(capture, motion)
    source = Capture.open(capture.root).frame_source()
    try:
        missing = source.pairing.missing()
        late = int(np.ceil(0.0967 * 100 - 0.5))  # camera 3 starts 96.7 ms into the capture
        assert missing[capture.camera_names[2]][:late] == list(range(late))
    finally:
        source.close()
