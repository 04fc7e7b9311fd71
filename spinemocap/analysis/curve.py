"""The tape's midline as a smooth 3D curve per frame.

Pipeline position: marker table -> **row centres -> midline curve** -> segment frames -> angles.

Row centres: the tape's midline point (u = 0) of every row, estimated the same way for both row
kinds. The rows alternate between ``L``/``R`` dots 7.5 mm off the midline (2-dot rows) and
``L``/``C``/``R`` dots at -15/0/+15 mm (3-dot rows), so the plain ``L``-``R`` midpoint lies on a
chord of the cross-section that is 4x deeper in 3-dot rows than in 2-dot rows: any curvature across
the tape -- the back's, or a reconstruction's depth error that grows toward the midline --
becomes a zig-zag between neighbouring rows, and an interpolating spline turns a
0.2-0.5 mm zig-zag into degrees at its end tangent (S1 sits on row 1). So the cross-section of
each row is taken as a parabola: 3-dot rows measure its depth ``C - (L + R) / 2`` (the
cross-sagitta), which is interpolated along the tape to every row, and each row's centre is its
``L``-``R`` midpoint plus the sagitta scaled to that row's dot offsets (x 1/4 for 2-dot rows; = the
``C`` dot for a 3-dot row). Without any ``C`` dot in a frame the ``L``-``R`` midpoints are used as
they are, and a sagitta over 2.8 mm (a mislabelled row) is not used; a 3-dot row whose ``L`` or ``R``
is missing falls back to its ``C`` dot (:func:`spinemocap.tape.row_midline_points`). Row transverse
axis: ``R - L`` (toward the subject's right), NaN when either is missing.

Curve: per frame a cubic spline of the row centres against the row's rest position ``v`` along
the tape (mm from row 1): by default interpolating with not-a-knot ends (exact for any cubic,
so the end tangents -- S1 sits on row 1 -- are not forced straight as a natural spline would
do), or a smoothing spline (``scipy.interpolate.make_smoothing_spline``) with a given penalty. ``v`` is known
from the labels, so missing rows simply leave a gap the spline bridges. The curve is then
re-parameterised by arc length ``s`` (mm from row 1's centre along the deformed curve); tangents
are unit vectors toward the head end of the tape.

Short gaps in time (<= ``max_gap_s``) are filled per row centre by linear interpolation before
fitting, longer gaps stay missing and surface as NaN angles with a reason (see ``angles``).
Row centres and transverse axes are low-pass filtered in time (zero-lag Butterworth, the usual
treatment of marker data in biomechanics) because tangents over a 25 mm row pitch amplify
millimetre noise: 1 mm of noise tilts a tangent by ~2 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline, make_smoothing_spline
from scipy.signal import butter, filtfilt

from ..tape import TapeSpec, row_midline_points, row_rest_positions_mm

#: Fewest observed rows a frame needs before a curve is fitted through them.
MIN_ROWS = 4


@dataclass
class RowTracks:
    """Per-row summaries of a marker sequence. Arrays are indexed (F frames, R rows).

    ``centre`` (F, R, 3) mm world; ``transverse`` (F, R, 3) unit vectors L -> R (subject's
    right), NaN where unknown; ``observed`` (F, R) bool: the centre came from measured dots (not
    from time gap-filling); ``v`` (R,) rest position of each row along the tape, mm.
    """

    centre: np.ndarray
    transverse: np.ndarray
    observed: np.ndarray
    v: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.centre.shape[0]


def row_tracks(positions: np.ndarray, labels: list[str], tape: TapeSpec, fps: float,
               max_gap_s: float = 0.1, lowpass_hz: float | None = 10.0) -> RowTracks:
    """Row centres and transverse axes from (F, D, 3) marker positions (mm, NaN = missing).

    Labels absent from ``labels`` count as missing. Gaps in a row centre's track up to
    ``max_gap_s`` seconds are filled by linear interpolation in time; then each unbroken run is
    low-pass filtered at ``lowpass_hz`` (None: no filtering).
    """
    index = {label: k for k, label in enumerate(labels)}
    F, R = positions.shape[0], tape.n_rows
    nan3 = np.full((F, 3), np.nan)

    def dot(row: int, column: str) -> np.ndarray:
        k = index.get(f"R{row + 1:02d}{column}")
        return positions[:, k] if k is not None else nan3

    midpoint = np.full((F, R, 3), np.nan)
    middle = np.full((F, R, 3), np.nan)  # C dots (3-dot rows)
    transverse = np.full((F, R, 3), np.nan)
    for r in range(R):
        left, right = dot(r, "L"), dot(r, "R")
        midpoint[:, r] = 0.5 * (left + right)
        if tape.row_sizes[r] == 3:
            middle[:, r] = dot(r, "C")
        across = right - left
        transverse[:, r] = across / np.linalg.norm(across, axis=1, keepdims=True)
    v = row_rest_positions_mm(tape)
    centre = row_midline_points(midpoint, middle, tape)
    observed = np.isfinite(centre).all(axis=2)
    max_gap = int(round(max_gap_s * fps))
    centre = _fill_short_gaps(centre, observed, max_gap)
    transverse = _fill_short_gaps(transverse, np.isfinite(transverse).all(axis=2), max_gap)
    if lowpass_hz is not None:
        centre = _lowpass(centre, lowpass_hz, fps)
        transverse = _lowpass(transverse, lowpass_hz, fps)
        transverse /= np.linalg.norm(transverse, axis=2, keepdims=True)
    return RowTracks(centre=centre, transverse=transverse, observed=observed, v=v)


def _fill_short_gaps(values: np.ndarray, valid: np.ndarray, max_gap: int) -> np.ndarray:
    """Linear interpolation in time over interior runs of invalid frames no longer than
    ``max_gap`` frames, per row. ``values`` (F, R, 3); leading/trailing gaps stay NaN."""
    out = values.copy()
    if max_gap < 1:
        return out
    F, R = valid.shape
    frames = np.arange(F)
    for r in range(R):
        ok = valid[:, r]
        if ok.sum() < 2 or ok.all():
            continue
        gap_len = _run_lengths(~ok)
        fill = ~ok & (gap_len <= max_gap) & (frames > frames[ok][0]) & (frames < frames[ok][-1])
        for c in range(3):
            out[fill, r, c] = np.interp(frames[fill], frames[ok], values[ok, r, c])
    return out


def _lowpass(values: np.ndarray, cutoff_hz: float, fps: float, order: int = 2) -> np.ndarray:
    """Zero-lag Butterworth (``order`` each way) over every unbroken finite run of (F, R, 3)
    tracks; runs too short for the filter's padding are left as they are."""
    if cutoff_hz >= 0.5 * fps:
        return values
    b, a = butter(order, cutoff_hz / (0.5 * fps))
    pad = 3 * max(len(a), len(b))
    out = values.copy()
    finite = np.isfinite(values).all(axis=2)
    for r in range(values.shape[1]):
        run = _run_lengths(finite[:, r])
        starts = np.flatnonzero(finite[:, r] & (np.r_[True, ~finite[:-1, r]]))
        for start in starts:
            stop = start + run[start]
            if stop - start > pad:
                out[start:stop, r] = filtfilt(b, a, values[start:stop, r], axis=0)
    return out


def _run_lengths(flags: np.ndarray) -> np.ndarray:
    """For each True element, the length of the run of Trues it belongs to (0 elsewhere)."""
    out = np.zeros(len(flags), dtype=int)
    start = None
    for i, f in enumerate(np.append(flags, False)):
        if f and start is None:
            start = i
        elif not f and start is not None:
            out[start:i] = i - start
            start = None
    return out


@dataclass
class MidlineCurve:
    """One frame's midline: a smoothing spline ``v -> xyz`` plus an arc-length table.

    ``v`` is the rest position along the tape (mm from row 1), ``s`` the arc length along the
    deformed curve (mm from row 1). ``support`` holds the ``v`` of the rows the fit used.
    """

    spline: Any  # scipy spline: callable, with .derivative()
    v_grid: np.ndarray
    s_grid: np.ndarray
    support: np.ndarray

    def point(self, v: np.ndarray | float) -> np.ndarray:
        """Curve point(s) at rest position ``v`` (mm), world mm."""
        return self.spline(np.asarray(v, float))

    def tangent(self, v: np.ndarray | float) -> np.ndarray:
        """Unit tangent(s) at ``v``, pointing toward the head end of the tape."""
        d = self.spline.derivative()(np.asarray(v, float))
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def arc_length(self, v: np.ndarray | float) -> np.ndarray:
        """Arc length (mm) from row 1 to rest position ``v``."""
        return np.interp(v, self.v_grid, self.s_grid)

    def v_at_arc_length(self, s: np.ndarray | float) -> np.ndarray:
        """Inverse of :meth:`arc_length`."""
        return np.interp(s, self.s_grid, self.v_grid)

    def resample(self, step_mm: float = 5.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points evenly spaced in arc length: (s (n,), points (n, 3), tangents (n, 3))."""
        s = np.arange(0.0, self.s_grid[-1] + 1e-9, step_mm)
        v = self.v_at_arc_length(s)
        return s, self.point(v), self.tangent(v)

    @property
    def length_mm(self) -> float:
        return float(self.s_grid[-1])


def fit_midline(v: np.ndarray, centres: np.ndarray, v_end: float, lam: float | None = None,
                grid_step_mm: float = 1.0) -> MidlineCurve | None:
    """Fit one frame's midline through row ``centres`` (R, 3) at rest positions ``v`` (R,).

    Rows with non-finite centres are skipped; returns None with fewer than :data:`MIN_ROWS`.
    ``lam`` is a smoothing spline's roughness penalty (None: interpolating not-a-knot cubic).
    ``v_end`` is the rest position of the last row (the arc-length table spans 0..v_end).
    """
    ok = np.isfinite(centres).all(axis=1)
    if ok.sum() < MIN_ROWS:
        return None
    if lam is None:
        spline = CubicSpline(v[ok], centres[ok], bc_type="not-a-knot", axis=0)
    elif ok.sum() >= 5:
        spline = make_smoothing_spline(v[ok], centres[ok], lam=lam, axis=0)
    else:
        return None
    v_grid = np.linspace(0.0, v_end, max(2, int(np.ceil(v_end / grid_step_mm)) + 1))
    pts = spline(v_grid)
    s_grid = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return MidlineCurve(spline=spline, v_grid=v_grid, s_grid=s_grid, support=v[ok])
