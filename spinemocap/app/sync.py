"""Estimating the clock offsets of cameras that were not synchronised, before tracking.

Two estimators, both giving each camera's ``offset_s`` (its clock minus the capture's, the
convention of :mod:`spinemocap.timebase`) with camera 0 as the reference (offset 0):

- ``motion``: the tape's dots seen by two cameras at the same instant lie on each other's epipolar
  lines; seen at different instants, the moving dots leave them. Each camera's dots are detected
  over a window of its own frames; for every camera pair a coarse search over trial offsets (one
  frame of the faster camera apart, the nearest frames paired) finds the offset whose pairing has
  the smallest epipolar error, then a sub-frame search (the second camera's dots linearly
  interpolated between its frames, linked frame to frame by mutual nearest neighbours) refines it.
  The pairwise offsets are combined by weighted least squares on the camera graph.
- ``audio``: a clap or beep heard by every camera's microphone: the onset envelopes of the
  cameras' audio tracks are cross-correlated against camera 0's, the peak located to a fraction of
  a sample by a parabola.

Each offset comes with a standard error (s): from the curvature of the epipolar cost at its minimum
and the residual noise (motion), or from the width of the correlation peak (audio).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..camera import Rig
from ..capture import Capture, set_camera_offsets
from ..fileio import InputError
from ..media import VideoDecoder, read_image
from ..timebase import MediaTimes
from ..track.candidates import epipolar_distance, fundamental_matrix

Method = Literal["motion", "audio", "auto"]
METHODS: tuple[str, ...] = ("motion", "audio", "auto")
# epipolar residuals beyond this many px count as this many: a dot the other camera does not see
# costs the same at every trial offset
EPIPOLAR_CAP_PX = 3.0
# two dots of consecutive frames are one dot moving when they are each other's nearest and closer
# than this share of the frame's typical spacing between dots
LINK_SHARE = 0.45
# the coarse search pairs frames at most this many of the first camera's frames (spread over its window)
COARSE_FRAMES = 80
# a pairwise offset is trusted when at least this many frames overlap at it
MIN_OVERLAP_FRAMES = 15
# a pairwise coarse minimum must stand out: its cost at most this share of the median trial's
MAX_COST_SHARE = 0.6
AUDIO_ENVELOPE_S = 0.001  # smoothing of the audio envelope, s
# an offset whose standard error exceeds this is reported as uncertain (s)
UNCERTAIN_S = 0.001
# a clap's correlation peak must stand this many times above the highest value farther than
# AUDIO_ISOLATION_S from it (a clap rings for tens of ms: nearer values belong to the same clap)
AUDIO_PROMINENCE = 1.5
AUDIO_ISOLATION_S = 0.05


@dataclass
class CameraDots:
    """One camera's detected dots over a window of its own frames: ``times_s`` (N,) media
    timestamps, s (its clock); ``uv`` N arrays (M_k, 2) of undistorted pixels; ``fps`` its rate."""

    times_s: np.ndarray
    uv: list[np.ndarray]
    fps: float
    _tracks: list[tuple[np.ndarray, np.ndarray]] | None = field(default=None, repr=False)

    def tracks(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The dots linked into 2D tracks: (times (L,) s, uv (L, 2) px) each, at least 3 frames
        long. Dots of consecutive frames (no drop between) are one dot moving when they are each
        other's nearest and closer than :data:`LINK_SHARE` of the frame's typical spacing."""
        if self._tracks is None:
            self._tracks = []
            open_tracks: dict[int, list[int]] = {}  # dot index in the last frame -> its track's samples
            samples: list[list[tuple[int, int]]] = []
            for k in range(len(self.uv)):
                following = (k > 0 and self.times_s[k] - self.times_s[k - 1] < 1.5 / self.fps)
                link = _link(self.uv[k - 1], self.uv[k]) if following else np.full(len(self.uv[k - 1]) if k else 0, -1)
                now: dict[int, list[int]] = {}
                for i, j in enumerate(link):
                    if j >= 0 and i in open_tracks:
                        now[int(j)] = open_tracks[i]
                for j in range(len(self.uv[k])):
                    if j not in now:
                        now[j] = [len(samples)]
                        samples.append([])
                    samples[now[j][0]].append((k, j))
                open_tracks = now
            for track in samples:
                if len(track) >= 3:
                    frames = np.array([k for k, _ in track])
                    self._tracks.append((self.times_s[frames], np.array([self.uv[k][j] for k, j in track])))
        return self._tracks

    def nearest_frames(self, t: np.ndarray) -> np.ndarray:
        """(T,) index of the frame nearest each time in ``t`` (s) within half a frame, else -1."""
        t = np.asarray(t, float)
        right = np.clip(np.searchsorted(self.times_s, t), 1, len(self.times_s) - 1)
        left = right - 1
        k = np.where(np.abs(self.times_s[left] - t) <= np.abs(self.times_s[right] - t), left, right)
        return np.where(np.abs(self.times_s[k] - t) <= 0.5 / self.fps + 1e-9, k, -1)


def _link(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if not len(a) or not len(b):
        return np.full(len(a), -1)
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    ab, ba = d.argmin(axis=1), d.argmin(axis=0)
    mutual = ba[ab] == np.arange(len(a))
    spacing = np.median(np.sort(np.linalg.norm(a[:, None] - a[None], axis=2), axis=1)[:, 1]) if len(a) > 1 else np.inf
    close = d[np.arange(len(a)), ab] < LINK_SHARE * spacing
    return np.where(mutual & close, ab, -1)


def _track_at(track: tuple[np.ndarray, np.ndarray], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) a track's position linearly interpolated at times ``t`` (NaN outside its life), and
    (T,) the variance of that position's noise relative to one sample's: ``(1 - w)^2 + w^2`` for
    the weight ``w`` of the later sample (1 on a sample, 1/2 halfway)."""
    times, uv = track
    out = np.column_stack([np.interp(t, times, uv[:, 0]), np.interp(t, times, uv[:, 1])])
    out[(t < times[0]) | (t > times[-1])] = np.nan
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    w = np.clip((t - times[k]) / (times[k + 1] - times[k]), 0.0, 1.0)
    return out, (1 - w) ** 2 + w**2


def _weighted_squares(F: np.ndarray, xa: np.ndarray, xb: np.ndarray, variance_b: np.ndarray) -> np.ndarray:
    """(N,) capped squared epipolar residuals (px^2) of matched points, each divided by its relative
    noise variance (one sample of ``a`` plus ``b``'s interpolated ``variance_b``) over 2: without it
    the cost would fall wherever ``b`` is interpolated halfway (its noise averaged) and pull the
    offset toward half frames."""
    r = _pair_residuals(F, xa, xb)
    return np.minimum(r**2 * 2.0 / (1.0 + variance_b), EPIPOLAR_CAP_PX**2)


def _pair_residuals(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) symmetric epipolar distance (px) of matched undistorted pixels ``xa``, ``xb`` (N, 2)."""
    ha = np.column_stack([xa, np.ones(len(xa))])
    hb = np.column_stack([xb, np.ones(len(xb))])
    lines_b, lines_a = ha @ F.T, hb @ F
    algebraic = np.abs(np.sum(lines_b * hb, axis=1))
    return np.maximum(algebraic / np.linalg.norm(lines_b[:, :2], axis=1),
                      algebraic / np.linalg.norm(lines_a[:, :2], axis=1))


# ---------------------------------------------------------------------- pairwise motion estimate
@dataclass(frozen=True)
class PairOffset:
    """The offset between cameras ``a`` and ``b``: ``offset_s`` = offset_b - offset_a (s);
    ``stderr_s`` its standard error (inf: not found); ``samples`` the matched dot samples the
    sub-frame search used; ``cost_px`` their RMS epipolar residual there (capped at
    :data:`EPIPOLAR_CAP_PX`)."""

    a: int
    b: int
    offset_s: float
    stderr_s: float
    samples: int
    cost_px: float


def coarse_costs(F: np.ndarray, dots_a: CameraDots, dots_b: CameraDots, trials: np.ndarray
                 ) -> np.ndarray:
    """(T,) the mean capped squared epipolar residual (px^2) of each trial offset (s): frames of
    ``a`` (at most :data:`COARSE_FRAMES`, spread over its window) each against ``b``'s frame nearest
    ``t_a + d``, every dot of ``a`` against its nearest epipolar match there; inf where fewer than
    :data:`MIN_OVERLAP_FRAMES` frames pair."""
    n_a = len(dots_a.times_s)
    frames = np.unique(np.linspace(0, n_a - 1, min(COARSE_FRAMES, n_a)).round().astype(int))
    counts_b = np.array([len(x) for x in dots_b.uv])
    all_b = np.concatenate([x for x in dots_b.uv if len(x)] or [np.zeros((0, 2))])
    starts = np.concatenate([[0], np.cumsum(counts_b)[:-1]])
    # S[j, k]: frame j of a against frame k of b (sum of capped squares, residual count)
    S = np.zeros((len(frames), len(counts_b)))
    N = np.zeros((len(frames), len(counts_b)))
    has_b = counts_b > 0
    for row, j in enumerate(frames):
        xa = dots_a.uv[j]
        if not len(xa) or not len(all_b):
            continue
        d = np.minimum(epipolar_distance(F, xa, all_b), EPIPOLAR_CAP_PX)  # (M_a, all b dots)
        nearest = np.minimum.reduceat(d, starts[has_b], axis=1)           # (M_a, frames of b with dots)
        S[row, has_b] = (nearest**2).sum(axis=0)
        N[row, has_b] = len(xa)
    costs = np.full(len(trials), np.inf)
    need = min(MIN_OVERLAP_FRAMES, len(frames))
    for i, d in enumerate(trials):
        k = dots_b.nearest_frames(dots_a.times_s[frames] + d)
        ok = k >= 0
        n = N[ok, k[ok]]
        if (n > 0).sum() >= need:
            costs[i] = S[ok, k[ok]].sum() / n.sum()
    return costs


def match_tracks(F: np.ndarray, dots_a: CameraDots, dots_b: CameraDots, d: float
                 ) -> list[tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]]:
    """The tracks of ``a`` matched to tracks of ``b`` at offset ``d`` (s): each a-track to the
    b-track with the smallest mean epipolar residual over their common life, when that is below
    half :data:`EPIPOLAR_CAP_PX` and the next best b-track's is at least four times larger (a dot
    of the same row lying along the epipolar line is not taken for it). Returns (times_a, uv_a,
    b-track) per match, times on ``a``'s clock."""
    tracks_b = dots_b.tracks()
    matches = []
    for times, uv in dots_a.tracks():
        scores = []
        for track in tracks_b:
            xb, variance = _track_at(track, times + d)
            ok = np.isfinite(xb[:, 0])
            if ok.sum() < 3:
                scores.append(np.inf)
                continue
            scores.append(float(np.mean(_weighted_squares(F, uv[ok], xb[ok], variance[ok]))))
        if len(scores) < 1:
            continue
        order = np.argsort(scores)
        best = scores[order[0]]
        second = scores[order[1]] if len(order) > 1 else np.inf
        if best < (0.5 * EPIPOLAR_CAP_PX) ** 2 and second >= 4 * best:
            matches.append((times, uv, tracks_b[order[0]]))
    return matches


def _signed_residuals(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(N,) signed distance (px) of each ``xb`` from the epipolar line of its ``xa`` in image b."""
    lines = np.column_stack([xa, np.ones(len(xa))]) @ F.T
    return (np.sum(lines[:, :2] * xb, axis=1) + lines[:, 2]) / np.linalg.norm(lines[:, :2], axis=1)


def _matched_cost(F: np.ndarray, matches, d: float, per_track_bias: bool = True) -> tuple[float, int]:
    """Mean capped squared residual (px^2) of the matched tracks at offset ``d`` and the samples
    used. Each matched pair's signed epipolar residuals are taken about their own (variance-
    weighted) mean: an inexact calibration shifts a dot's epipolar line by a nearly constant amount
    while the dot stays in its part of the image, whereas a wrong offset moves it with the dot's
    speed; without this the offset would absorb the calibration error (milliseconds where the dots
    move slowly across the epipolar lines). ``per_track_bias`` False: about zero (the peer in
    ``spinemocap bench sync``)."""
    total, count = 0.0, 0
    for times, uv, track in matches:
        xb, variance = _track_at(track, times + d)
        ok = np.isfinite(xb[:, 0])
        if ok.sum() < 3:
            continue
        r, weight = _signed_residuals(F, uv[ok], xb[ok]), 2.0 / (1.0 + variance[ok])
        if per_track_bias:
            r = r - float(weight @ r) / float(weight.sum())
        total += float(np.minimum(r**2 * weight, EPIPOLAR_CAP_PX**2).sum())
        count += int(ok.sum())
    return (total / count if count else np.inf), count


def pair_offset(F: np.ndarray, dots_a: CameraDots, dots_b: CameraDots, a: int, b: int,
                search_s: float, per_track_bias: bool = True) -> PairOffset:
    """The offset of camera ``b`` relative to ``a`` (see :class:`PairOffset`) within
    +-``search_s`` s; ``F`` the fundamental matrix with ``x_b^T F x_a = 0`` on undistorted pixels.
    Coarse: :func:`coarse_costs` over trial offsets one frame of the faster camera apart; fine: the
    tracks matched there (:func:`match_tracks`), ``b``'s interpolated, by golden-section search of
    the matched residual within a frame and a half of the coarse minimum."""
    step = 1.0 / max(dots_a.fps, dots_b.fps)
    trials = np.arange(-np.ceil(search_s / step), np.ceil(search_s / step) + 1) * step
    costs = coarse_costs(F, dots_a, dots_b, trials)
    finite = np.isfinite(costs)
    if not finite.any():
        return PairOffset(a, b, float("nan"), float("inf"), 0, float("nan"))
    best = int(np.argmin(costs))
    d0 = float(trials[best])
    if costs[best] > MAX_COST_SHARE * float(np.median(costs[finite])):
        return PairOffset(a, b, d0, float("inf"), 0, float(np.sqrt(costs[best])))
    matches = match_tracks(F, dots_a, dots_b, d0)
    if not matches:
        return PairOffset(a, b, d0, float("inf"), 0, float(np.sqrt(costs[best])))

    def fine(d: float) -> float:
        return _matched_cost(F, matches, d, per_track_bias)[0]

    d_best = _golden_min(fine, d0 - 1.5 * step, d0 + 1.5 * step, tol=1e-6)
    cost, count = _matched_cost(F, matches, d_best, per_track_bias)
    h = 0.25 * step  # the cost's curvature from a parabola through d_best +- h
    curvature = (fine(d_best - h) - 2 * cost + fine(d_best + h)) / h**2
    stderr = float(np.sqrt(2 * cost / (count * curvature))) if curvature > 0 and count else float("inf")
    return PairOffset(a, b, d_best, stderr, count, float(np.sqrt(cost)))


def _golden_min(f: Callable[[float], float], lo: float, hi: float, tol: float) -> float:
    """The minimiser of ``f`` on [lo, hi] by golden-section search (to ``tol``), after a grid of 13
    points picks the bracket (the cost need not be unimodal over a whole frame)."""
    grid = np.linspace(lo, hi, 13)
    values = [f(float(x)) for x in grid]
    i = int(np.argmin(values))
    lo, hi = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])
    ratio = (np.sqrt(5) - 1) / 2
    x1, x2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    f1, f2 = f(x1), f(x2)
    while hi - lo > tol:
        if f1 <= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - ratio * (hi - lo)
            f1 = f(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + ratio * (hi - lo)
            f2 = f(x2)
    return 0.5 * (lo + hi)


# ---------------------------------------------------------------------- combining pairs
@dataclass(frozen=True)
class SyncEstimate:
    """Per-camera clock offsets (rig order): ``offsets_s`` (C,) s, camera 0 = 0 (NaN: not found);
    ``stderr_s`` (C,) standard errors, s (camera 0: 0; inf: not found); ``method`` that made them;
    ``pairs``: the pairwise offsets they came from (motion), empty for audio."""

    camera_names: tuple[str, ...]
    offsets_s: np.ndarray
    stderr_s: np.ndarray
    method: str
    pairs: tuple[PairOffset, ...] = ()

    @property
    def found(self) -> np.ndarray:
        """(C,) bool: cameras with an offset."""
        return np.isfinite(self.offsets_s) & np.isfinite(self.stderr_s)


def combine_pairs(pairs: Sequence[PairOffset], n_cameras: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera offsets (C,) and standard errors (C,) from pairwise ones by weighted least squares
    (weights 1 / stderr^2) with camera 0 fixed at 0; cameras not connected to camera 0 by trusted
    pairs get NaN and inf."""
    good = [p for p in pairs if np.isfinite(p.stderr_s) and p.stderr_s > 0 and np.isfinite(p.offset_s)]
    connected = {0}
    grew = True
    while grew:
        grew = False
        for p in good:
            if (p.a in connected) != (p.b in connected):
                connected |= {p.a, p.b}
                grew = True
    unknown = sorted(connected - {0})
    offsets, stderr = np.full(n_cameras, np.nan), np.full(n_cameras, np.inf)
    offsets[0], stderr[0] = 0.0, 0.0
    if not unknown:
        return offsets, stderr
    column = {c: i for i, c in enumerate(unknown)}
    rows, rhs, weights = [], [], []
    for p in good:
        if p.a not in connected or p.b not in connected:
            continue
        row = np.zeros(len(unknown))
        if p.b in column:
            row[column[p.b]] += 1.0
        if p.a in column:
            row[column[p.a]] -= 1.0
        rows.append(row)
        rhs.append(p.offset_s)
        weights.append(1.0 / p.stderr_s)
    A, y, w = np.array(rows), np.array(rhs), np.array(weights)
    solution, *_ = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)
    covariance = np.linalg.pinv((A * w[:, None]).T @ (A * w[:, None]))
    for c, i in column.items():
        offsets[c], stderr[c] = solution[i], np.sqrt(covariance[i, i])
    return offsets, stderr


# ---------------------------------------------------------------------- reading a capture
def _frame_reader(capture: Capture, camera: int, times: MediaTimes) -> tuple[Callable[[int], np.ndarray], Callable[[], None]]:
    """(read(slot) -> BGR image, close) for camera ``camera``'s own frames."""
    name = capture.camera_names[camera]
    path = capture.media_path(name)
    if capture.media == "video":
        decoder = VideoDecoder(path, times.fps)
        return decoder.read, decoder.close
    if capture.clocks[camera].media is not None:
        files = sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
        return (lambda slot: read_image(files[slot])), (lambda: None)
    return (lambda slot: read_image(capture.root / capture.image_pattern.format(camera=name, frame=slot))), (lambda: None)


def detect_camera_dots(capture: Capture, detector: str = "net", seconds: float = 6.0,
                       progress: bool = True) -> list[CameraDots]:
    """Each camera's dots (undistorted px) over the first ``seconds`` s of its recording, detected
    by the project's detector (:func:`spinemocap.app.run.make_detector`, no prediction: the
    cameras' frames are not paired yet)."""
    from tqdm import tqdm

    from .run import make_detector
    from .streaming import SpeedOptions

    times = capture.media_times()
    chosen = [np.flatnonzero(t.timestamps_s < seconds) for t in times]
    detect = make_detector(detector, None, SpeedOptions(predict=False, workers=1, prefetch=0))
    bar = tqdm(total=sum(len(k) for k in chosen), desc="detecting dots for the sync estimate", unit="image",
               disable=not progress)
    out = []
    try:
        with bar:
            for c, (t, keep) in enumerate(zip(times, chosen)):
                read, close = _frame_reader(capture, c, t)
                try:
                    uv = []
                    for slot in t.slots[keep]:
                        view = detect(int(slot), [read(int(slot))], None)[0]
                        uv.append(capture.rig[c].undistort_points(view.uv) if len(view) else np.zeros((0, 2)))
                        bar.update()
                finally:
                    close()
                out.append(CameraDots(t.timestamps_s[keep], uv, t.fps))
    finally:
        detect.close()
    return out


def estimate_motion(rig: Rig, dots: Sequence[CameraDots], max_offset_s: float = 2.0,
                    per_track_bias: bool = True) -> SyncEstimate:
    """Per-camera offsets from the dots' motion (module docstring): every camera pair searched
    within +-2 ``max_offset_s`` (two cameras may each be ``max_offset_s`` off camera 0);
    ``per_track_bias``: see :func:`_matched_cost`."""
    P = [cam.projection_matrix for cam in rig]
    pairs = []
    for a in range(len(rig)):
        for b in range(a + 1, len(rig)):
            search = max_offset_s if a == 0 else 2 * max_offset_s
            pairs.append(pair_offset(fundamental_matrix(P[a], P[b]), dots[a], dots[b], a, b, search, per_track_bias))
    offsets, stderr = combine_pairs(pairs, len(rig))
    return SyncEstimate(tuple(rig.names), offsets, stderr, "motion", tuple(pairs))


# ---------------------------------------------------------------------- audio
def read_audio(path: str | os.PathLike) -> tuple[np.ndarray, int, float] | None:
    """A video's first audio track as mono float samples (N,), its rate (samples/s) and its first
    sample's time on the video's clock (s after the first video frame); None without audio."""
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.audio:
                return None
            video = container.streams.video[0]
            video_start = float((video.start_time or 0) * video.time_base) if video.time_base else 0.0
            stream = container.streams.audio[0]
            chunks, first = [], None
            for frame in container.decode(stream):
                if first is None:
                    first = float(frame.pts * frame.time_base) if frame.pts is not None else 0.0
                samples = frame.to_ndarray().astype(np.float64)
                if frame.format.is_packed and len(frame.layout.channels) > 1:
                    samples = samples.reshape(-1, len(frame.layout.channels)).T
                chunks.append(samples.mean(axis=0))
            rate = int(stream.rate)
    except (av.error.FFmpegError, IndexError, ValueError) as exc:
        raise InputError(path, f"audio cannot be read ({exc})") from None
    if not chunks:
        return None
    return np.concatenate(chunks), rate, (first or 0.0) - video_start


def onset_envelope(samples: np.ndarray, rate: int) -> np.ndarray:
    """(N,) onset strength: the rise of the smoothed magnitude (a clap's or beep's start)."""
    width = max(1, int(round(AUDIO_ENVELOPE_S * rate)))
    magnitude = np.convolve(np.abs(samples - samples.mean()), np.ones(width) / width, mode="same")
    return np.maximum(np.diff(magnitude, prepend=magnitude[0]), 0.0)


def audio_lag(reference: np.ndarray, other: np.ndarray, rate: int, max_lag_s: float) -> tuple[float, float]:
    """The delay (s) of ``other`` relative to ``reference`` (onset envelopes at ``rate``) that
    maximises their cross-correlation within +-``max_lag_s``, to a fraction of a sample (parabola
    through the peak); and the peak's prominence (its height over the highest value more than
    :data:`AUDIO_ISOLATION_S` away; > 1 means a single clear peak)."""
    from scipy.signal import correlate, correlation_lags

    corr = correlate(other, reference, mode="full", method="fft")
    lags = correlation_lags(len(other), len(reference), mode="full")
    window = np.abs(lags) <= max_lag_s * rate
    corr, lags = corr[window], lags[window]
    i = int(np.argmax(corr))
    shift = 0.0
    if 0 < i < len(corr) - 1:
        y0, y1, y2 = corr[i - 1], corr[i], corr[i + 1]
        denominator = y0 - 2 * y1 + y2
        shift = 0.5 * (y0 - y2) / denominator if denominator < 0 else 0.0
    away = np.abs(lags - lags[i]) > AUDIO_ISOLATION_S * rate
    second = float(corr[away].max()) if away.any() else 0.0
    prominence = float(corr[i] / second) if second > 0 else float("inf")
    return (lags[i] + shift) / rate, prominence


def estimate_audio(capture: Capture, max_offset_s: float = 2.0) -> SyncEstimate | None:
    """Per-camera offsets from a clap or beep on the videos' audio tracks (module docstring); None
    when the capture has no videos or a camera's video has no audio. A camera whose correlation
    peak does not stand out (prominence below :data:`AUDIO_PROMINENCE`) gets NaN."""
    if capture.media != "video":
        return None
    tracks = []
    for name in capture.camera_names:
        audio = read_audio(capture.media_path(name))
        if audio is None:
            return None
        tracks.append(audio)
    rate = max(t[1] for t in tracks)
    envelopes = []
    for samples, own_rate, start in tracks:
        if own_rate != rate:  # onto the common rate's sample grid
            t = np.arange(int(len(samples) * rate / own_rate)) / rate
            samples = np.interp(t, np.arange(len(samples)) / own_rate, samples)
        envelopes.append((onset_envelope(samples, rate), start))
    offsets, stderr = np.zeros(len(tracks)), np.zeros(len(tracks))
    reference, start0 = envelopes[0]
    for c in range(1, len(tracks)):
        envelope, start = envelopes[c]
        lag, prominence = audio_lag(reference, envelope, rate, 2 * max_offset_s)
        offsets[c] = lag + start - start0
        # the peak's position is good to a fraction of a sample; a weak peak is not trusted
        stderr[c] = 0.25 / rate if prominence >= AUDIO_PROMINENCE else np.inf
        if prominence < AUDIO_PROMINENCE:
            offsets[c] = np.nan
    return SyncEstimate(tuple(capture.camera_names), offsets, stderr, "audio")


# ---------------------------------------------------------------------- the command's work
def estimate_offsets(capture: Capture, method: Method = "auto", detector: str = "net", seconds: float = 6.0,
                     max_offset_s: float = 2.0, progress: bool = True) -> SyncEstimate:
    """The capture's camera offsets by ``method``: ``audio``, ``motion`` or ``auto`` (audio where
    every video carries it and it finds every camera, else motion). :class:`InputError` when
    ``audio`` is asked of a capture without audio."""
    if method not in METHODS:
        raise InputError(None, f"unknown sync method {method!r} (choose {', '.join(METHODS)})")
    if method in ("audio", "auto"):
        estimate = estimate_audio(capture, max_offset_s)
        if estimate is None and method == "audio":
            raise InputError(capture.root, "the capture has no audio on every camera's video: use `method='motion'`")
        if estimate is not None and (method == "audio" or estimate.found.all()):
            return estimate
    dots = detect_camera_dots(capture, detector, seconds, progress)
    return estimate_motion(capture.rig, dots, max_offset_s)


def write_offsets(capture: Capture, estimate: SyncEstimate) -> Path:
    """Store the found offsets as ``[camera.<name>] offset_s`` in the capture's ``capture.toml``
    (:func:`spinemocap.capture.set_camera_offsets`; other keys kept); cameras without an offset keep
    theirs. Returns the manifest's path."""
    values = {name: float(x) for name, x, ok in zip(estimate.camera_names, estimate.offsets_s, estimate.found) if ok}
    return set_camera_offsets(capture.root, values)


def format_estimate(estimate: SyncEstimate) -> str:
    """The offsets as a table: camera, offset (ms), standard error (ms), and warning lines for
    cameras not found and for offsets less certain than :data:`UNCERTAIN_S`."""
    lines = [f"clock offsets by {estimate.method} (camera clock minus {estimate.camera_names[0]}'s):",
             f"  {'camera':<12} {'offset ms':>11} {'+- ms':>8}"]
    for name, offset, error, ok in zip(estimate.camera_names, estimate.offsets_s, estimate.stderr_s, estimate.found):
        if ok:
            lines.append(f"  {name:<12} {1000 * offset:11.3f} {1000 * error:8.3f}")
        else:
            lines.append(f"  {name:<12} {'not found':>11}")
    uncertain = [n for n, e, ok in zip(estimate.camera_names, estimate.stderr_s, estimate.found) if ok and e > UNCERTAIN_S]
    if uncertain:
        lines.append(f"WARNING: the offsets of {', '.join(uncertain)} are uncertain by more than "
                     f"{1000 * UNCERTAIN_S:g} ms (little motion across the views in the frames read: try more "
                     "`seconds`, or `method='audio'` with a clap)")
    missing = [n for n, ok in zip(estimate.camera_names, estimate.found) if not ok]
    if missing:
        lines.append(f"WARNING: no trustworthy offset for {', '.join(missing)} (too little shared motion or sound); "
                     "their offsets are left as they were")
    return "\n".join(lines)
