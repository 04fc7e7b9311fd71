"""Unsynchronised studio cameras: each recording's frame grid on its own clock, dropped frames
never at the ends nor two in a row, the clap within every recording, and each camera's
microphone hearing it at the capture time shifted by that camera's clock offset."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.synth.clocks import (
    AUDIO_RATE,
    CLAP_AFTER_START_S,
    CameraRecording,
    camera_audio,
    clap_time_s,
    clap_wave,
    plan_recordings,
)


def test_recordings_cover_the_capture_on_their_own_clocks():
    offsets, fps = np.array([0.0, 0.013, -0.021]), np.array([30.0, 29.97, 25.0])
    recordings = plan_recordings(offsets, fps, capture_end_s=2.0, drop_frames=6, rng=np.random.default_rng(3))
    assert [r.offset_s for r in recordings] == list(offsets) and [r.fps for r in recordings] == list(fps)
    for rec in recordings:
        assert rec.capture_time(0) == pytest.approx(rec.start_s) and rec.start_s == -rec.offset_s
        assert rec.capture_time(rec.n_slots - 1) <= 2.0 + 1e-9 < rec.capture_time(rec.n_slots)
        gaps = np.diff(rec.dropped)
        assert all(0 < k < rec.n_slots - 1 for k in rec.dropped) and (gaps > 1).all()
        assert rec.recorded == [k for k in range(rec.n_slots) if k not in rec.dropped]
    assert sum(len(r.dropped) for r in recordings) == 6


def test_a_camera_starting_after_the_end_is_refused():
    with pytest.raises(ValueError, match="camera 2 would start recording"):
        plan_recordings(np.array([0.0, -3.0]), np.array([30.0, 30.0]), 1.0, 0, np.random.default_rng(0))


def test_the_clap_comes_after_every_camera_started():
    recordings = [CameraRecording(0.0, 30.0, 61), CameraRecording(-0.05, 30.0, 60)]
    assert clap_time_s(recordings, 2.0) == pytest.approx(0.05 + CLAP_AFTER_START_S)
    with pytest.raises(ValueError, match="does not fit"):
        clap_time_s(recordings, 0.26)


def test_the_clap_is_silent_before_its_onset_and_fades():
    t = np.linspace(-0.01, 0.1, 5000)
    wave = clap_wave(t)
    assert (wave[t < 0] == 0).all()
    assert np.abs(clap_wave(np.array([1e-7]))).max() < 1e-6  # the rise starts from silence
    assert np.abs(wave[(t > 0.08)]).max() < 0.05 * np.abs(wave).max()


def test_each_microphone_hears_the_clap_on_its_own_clock():
    clap_at = 0.4
    for offset in (0.0, 0.0123, -0.0071):
        rec = CameraRecording(offset, 30.0, 31)
        audio = camera_audio(rec, clap_at, gain=1.0, rng=np.random.default_rng(1))
        assert audio.dtype == np.int16 and len(audio) == round(31 / 30.0 * AUDIO_RATE)
        onset = np.flatnonzero(np.abs(audio) > 0.05 * 32767)[0] / AUDIO_RATE  # camera clock, s
        assert onset - (clap_at + offset) == pytest.approx(0.0, abs=0.002)
