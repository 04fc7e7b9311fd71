"""Studio cameras that are not synchronised: each records on its own clock and rate, may drop
frames, and may hear a hand clap on an audio track.

Clock convention as in :mod:`spinemocap.timebase`: camera ``c``'s frame ``k`` (timestamp ``k /
fps_c`` s on its clock) shows capture time ``k / fps_c - offset_c``; the camera starts recording at
capture time ``-offset_c`` and records until the capture's last frame. Audio samples follow the
same clock (sample ``n`` at ``n / AUDIO_RATE`` s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AUDIO_RATE = 48000  # samples/s of the studio's audio tracks
# the clap: a burst of a few tones (Hz), rising over CLAP_RISE_S and decaying with CLAP_DECAY_S
CLAP_TONES_HZ = (730.0, 1450.0, 2310.0, 3890.0)
CLAP_RISE_S = 0.0005
CLAP_DECAY_S = 0.012
CLAP_AMPLITUDE = 0.5       # of full scale
ROOM_NOISE = 0.004         # standard deviation of each camera's microphone noise, of full scale
CLAP_AFTER_START_S = 0.2   # the clap comes this long after the last camera started recording


@dataclass(frozen=True)
class CameraRecording:
    """One studio camera's recording: ``offset_s`` its clock minus the capture's, s; ``fps`` its
    rate, frames/s; ``n_slots`` frames on its grid from its start to the capture's end; ``dropped``
    the slots it failed to record (sorted)."""

    offset_s: float
    fps: float
    n_slots: int
    dropped: tuple[int, ...] = ()

    def capture_time(self, slot: int) -> float:
        """Capture time (s) its frame ``slot`` shows."""
        return slot / self.fps - self.offset_s

    @property
    def start_s(self) -> float:
        """Capture time (s) it starts recording."""
        return -self.offset_s

    @property
    def recorded(self) -> list[int]:
        dropped = set(self.dropped)
        return [k for k in range(self.n_slots) if k not in dropped]


def plan_recordings(offsets_s: np.ndarray, fps: np.ndarray, capture_end_s: float, drop_frames: int,
                    rng: np.random.Generator) -> list[CameraRecording]:
    """Each camera's recording (see :class:`CameraRecording`) from its ``offsets_s`` and ``fps`` (C,)
    until capture time ``capture_end_s``; ``drop_frames`` single frames dropped at seeded cameras and
    places (never the first or last frame, never two in a row). ValueError when a camera would
    start after the capture's end."""
    recordings = []
    for c, (offset, rate) in enumerate(zip(offsets_s, fps)):
        n_slots = int(np.floor((capture_end_s + offset) * rate + 1e-9)) + 1
        if n_slots < 2:
            raise ValueError(f"camera {c + 1} would start recording at {-offset:g} s, after the capture's end "
                             f"({capture_end_s:g} s): make the capture longer or the offset smaller")
        recordings.append(CameraRecording(float(offset), float(rate), n_slots))
    cameras = rng.integers(0, len(recordings), size=drop_frames)
    for c in range(len(recordings)):
        count = int((cameras == c).sum())
        rec = recordings[c]
        places = np.arange(2, rec.n_slots - 2, 3)  # spaced: every drop a gap of one frame
        if count > len(places):
            raise ValueError(f"camera {c + 1} records {rec.n_slots} frames: too few to drop {count}")
        dropped = tuple(sorted(int(x) for x in rng.choice(places, size=count, replace=False)))
        recordings[c] = CameraRecording(rec.offset_s, rec.fps, rec.n_slots, dropped)
    return recordings


def clap_time_s(recordings: list[CameraRecording], capture_end_s: float) -> float:
    """Capture time (s) of the clap: :data:`CLAP_AFTER_START_S` after the last camera started (and
    at least that after capture time 0), within every recording. ValueError when it does not fit."""
    t = max(0.0, max(r.start_s for r in recordings)) + CLAP_AFTER_START_S
    if t + 4 * CLAP_DECAY_S > capture_end_s:
        raise ValueError(f"the clap at {t:.3f} s does not fit before the capture's end ({capture_end_s:.3f} s)")
    return t


def clap_wave(t_s: np.ndarray) -> np.ndarray:
    """The clap's sound pressure (of full scale) at times ``t_s`` (s) after its onset: zero before,
    a smooth rise over :data:`CLAP_RISE_S`, then decaying tones. Continuous in time, so a
    microphone at any sub-sample delay samples it exactly."""
    t = np.asarray(t_s, float)
    rise = np.clip(t / CLAP_RISE_S, 0.0, 1.0)
    envelope = np.where(t >= 0, 0.5 * (1 - np.cos(np.pi * rise)) * np.exp(-np.maximum(t, 0) / CLAP_DECAY_S), 0.0)
    tones = sum(np.sin(2 * np.pi * f * t + k) for k, f in enumerate(CLAP_TONES_HZ)) / len(CLAP_TONES_HZ)
    return CLAP_AMPLITUDE * envelope * tones


def camera_audio(recording: CameraRecording, clap_at_s: float, gain: float, rng: np.random.Generator) -> np.ndarray:
    """(N,) int16 mono samples of a camera's microphone over its recording (:data:`AUDIO_RATE`):
    the clap at capture time ``clap_at_s`` (heard at ``clap_at_s + offset_s`` on the camera's clock),
    scaled by ``gain``, plus its own noise."""
    n = int(round(recording.n_slots / recording.fps * AUDIO_RATE))
    capture_t = np.arange(n) / AUDIO_RATE - recording.offset_s
    signal = gain * clap_wave(capture_t - clap_at_s) + rng.normal(0.0, ROOM_NOISE, n)
    return np.clip(np.round(signal * 32767), -32768, 32767).astype(np.int16)
