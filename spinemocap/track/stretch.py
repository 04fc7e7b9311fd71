"""The tape's actual dot spacing, estimated from the data (beyond the paper).

Kinesiology tape is laid with tension (often 10-25 %) and stretches with the skin (the modified
Schober test: the lumbar skin lengthens by a third at full flexion), so the dots on the body sit
up to ~60 % farther apart along the tape than the roll's spec, and up to ~15 % across it, unevenly
and changing over time. A tracker that believes the spec then fits a template that is too short:
the chamfer match slides it by one or two rows and every residual still looks perfect. This
module measures the spacing from the frame's own points before any labelling:

- **along** (row pitch): the candidate points' arc length along a cubic fitted through them is
  periodic with the row pitch (every row, 2- or 3-dot, sits at one arc position). A Rayleigh
  periodogram ``R(p) = |sum exp(2 pi i s / p)| / N`` over pitches from ``along_range`` of the spec
  peaks at the true pitch and at its integer fractions (p/2, p/3 are periodic too); the largest
  pitch among the near-best local maxima is taken. Where the rows can be told apart in the arc
  positions (:func:`row_gaps`), the pitch is instead the rows' arc span over the rows it spans,
  the mean pitch, and their gaps are the local pitches (at full flexion the lumbar rows are
  20-30 % longer than the thoracic ones and the periodogram peaks at both). Otherwise the rows' arc positions, assigned
  by the period, give the pitch between neighbouring rows (how the stretch varies along the tape).
- **across** (column spacing): the median nearest-neighbour distance in the range of a row's
  dot spacing (the nearest other dot of every tape dot is its row neighbour: 15 mm across vs
  >= 23 mm to the next row for any along stretch >= 0.9).

:func:`stretched_spec` turns the estimate into the tape the frame is solved with (pitch, column
spacing and width scaled; labels unchanged), so the edge windows (th3, th4), the LP's tape, the
MRF1 template and target lengths and MRF2's target lengths all follow it.
:func:`dot_stretch` measures the stretch of a labelled solution per dot (reported per dot in
``markers.csv``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..tape import TapeGraph, TapeSpec
from .config import StretchConfig


@dataclass
class StretchEstimate:
    """Stretch of the tape on the body relative to the roll's spec (dimensionless, 1 = spec).

    ``along``: mean row-pitch ratio; ``across``: column-spacing ratio; ``along_min`` /
    ``along_max``: smallest/largest local row pitch ratio seen between neighbouring rows;
    ``coherence``: periodogram peak height (0..1, how periodic the points were);
    ``source``: ``data`` (this frame), ``carried`` (an earlier frame's, this one too
    ambiguous), ``nominal`` (the spec)."""

    along: float = 1.0
    across: float = 1.0
    along_min: float = 1.0
    along_max: float = 1.0
    coherence: float = 0.0
    source: str = "nominal"

    @classmethod
    def nominal(cls) -> "StretchEstimate":
        return cls()


def _rayleigh(arc: np.ndarray, pitches: np.ndarray) -> np.ndarray:
    """(P,) periodogram height |mean exp(2 pi i arc / p)| for each pitch p (mm)."""
    phase = 2 * np.pi * arc[None, :] / pitches[:, None]
    return np.abs(np.exp(1j * phase).mean(axis=1))


def _arc_coordinates(points: np.ndarray) -> np.ndarray:
    """Arc length (mm) of each point's nearest sample on a cubic fitted through the points."""
    from .template import SpineCurve

    return SpineCurve(points).arc_of(points)


def along_pitch(arc: np.ndarray, spec_pitch: float, along_range: tuple[float, float],
                resolution: float = 0.0025) -> tuple[float, float]:
    """(pitch mm, coherence): the largest near-best local maximum of the arc periodogram."""
    ratios = np.arange(along_range[0], along_range[1] + resolution, resolution)
    pitches = spec_pitch * ratios
    height = _rayleigh(arc, pitches)
    padded = np.concatenate([[-1.0], height, [-1.0]])
    peaks = np.flatnonzero((height >= padded[:-2]) & (height >= padded[2:]))
    best = float(height.max())
    strong = peaks[height[peaks] >= 0.8 * best]
    k = int(strong.max()) if len(strong) else int(np.argmax(height))
    return float(pitches[k]), float(height[k])


def local_pitches(arc: np.ndarray, pitch: float, min_per_row: int = 1) -> np.ndarray:
    """Pitch (mm) between neighbouring occupied rows, from the points' arc positions grouped
    into rows by the period ``pitch``: (n_row_pairs,), empty with fewer than two rows."""
    phase = np.angle(np.exp(2j * np.pi * arc / pitch).mean()) * pitch / (2 * np.pi)
    rows = np.round((arc - phase) / pitch).astype(np.int64)
    centres = []
    for r in np.unique(rows):
        members = arc[rows == r]
        if len(members) >= min_per_row:
            centres.append((r, float(np.median(members))))
    out = [(b[1] - a[1]) / (b[0] - a[0]) for a, b in zip(centres[:-1], centres[1:]) if b[0] - a[0] == 1]
    return np.asarray(out, float)


def row_gaps(arc: np.ndarray, min_pitch_mm: float, min_per_row: int = 2, min_rows: int = 4,
             max_gap_rows: int = 2) -> tuple[np.ndarray, float] | None:
    """Rows told apart in the points' arc positions (N,) mm, whatever the stretch along the tape:
    ``(local pitches (K,) mm between neighbouring rows, mean pitch mm over the rows seen)``, or
    None when the rows are not clear.

    A row's dots share one arc position (within a few mm: the tape's twist and the fitted curve's
    error), neighbouring rows lie >= ``min_pitch_mm`` apart: sorted arc positions split into
    groups at gaps over 0.4 x ``min_pitch_mm``; groups of >= ``min_per_row`` points are rows (a
    lone point may be a ghost). The gap between two neighbouring rows' median arcs spans one row,
    or a whole number of rows where rows were not seen (``round(gap / median gap)``, up to
    ``max_gap_rows``; more, or a gap of less than 0.6 x the median, and the rows are not clear).
    The mean pitch is the rows' arc span over the number of rows it spans: the uniform pitch
    that lays a template of the right length over a tape stretched unevenly (the lumbar rows of a
    flexed back are 20-30 % longer than the thoracic rows; the periodogram then has two peaks)."""
    order = np.sort(np.asarray(arc, float))
    if len(order) < min_per_row * min_rows:
        return None
    breaks = np.flatnonzero(np.diff(order) > 0.4 * min_pitch_mm) + 1
    starts = np.concatenate([[0], breaks])
    sizes = np.diff(np.concatenate([starts, [len(order)]]))
    starts, sizes = starts[sizes >= min_per_row], sizes[sizes >= min_per_row]
    if len(starts) < min_rows:
        return None
    # each group's median (the groups are runs of the sorted arcs): its middle value, or the mean
    # of its two middle values, as np.median computes them
    mid = starts + sizes // 2
    centres = np.where(sizes % 2 == 1, order[mid], (order[mid - 1] + order[mid]) / 2.0)
    gaps = np.diff(centres)
    unit = float(np.median(gaps))
    spans = np.round(gaps / unit).astype(np.int64)
    if (gaps < 0.6 * unit).any() or (spans > max_gap_rows).any() or (spans < 1).any():
        return None
    return gaps[spans == 1], float(gaps.sum() / spans.sum())


def across_spacing(points: np.ndarray, spec_spacing: float, across_range: tuple[float, float]) -> float | None:
    """Median nearest-neighbour distance (mm) within the plausible row-neighbour range, or None."""
    if len(points) < 2:
        return None
    dist = cKDTree(points).query(points, k=2)[0][:, 1]
    lo, hi = spec_spacing * across_range[0] * 0.9, spec_spacing * across_range[1] * 1.1
    inside = dist[(dist > lo) & (dist < hi)]
    return float(np.median(inside)) if len(inside) >= 3 else None


def estimate_stretch(points: np.ndarray, spec: TapeSpec, config: StretchConfig | None = None,
                     fallback: StretchEstimate | None = None) -> StretchEstimate:
    """Stretch of the tape seen in candidate points (N, 3) mm against ``spec`` (see module).

    Returns ``fallback`` (default: nominal) relabelled ``carried`` when the points are too few or
    not periodic enough to trust."""
    return read_stretch(points, spec, config).estimate(fallback)


@dataclass(frozen=True)
class StretchReading:
    """What one frame's points tell of the stretch, before the last frame's estimate (the
    fallback) is known: :meth:`estimate` completes it. ``measured``: this frame's estimate
    (``source`` ``data``), None when the points are too few, not periodic enough (``coherence``:
    their periodogram peak, None when none was taken) or adaptive stretch is off (``adaptive``);
    ``across_measured``: False when the estimate's across ratio is to come from the fallback."""

    measured: StretchEstimate | None
    coherence: float | None = None
    across_measured: bool = True
    adaptive: bool = True

    def estimate(self, fallback: StretchEstimate | None = None) -> StretchEstimate:
        """The frame's :class:`StretchEstimate` given the last one (``fallback``; default nominal)."""
        if not self.adaptive:
            return StretchEstimate.nominal()
        fallback = fallback or StretchEstimate.nominal()
        if self.measured is not None:
            return self.measured if self.across_measured else dataclasses.replace(self.measured, across=fallback.across)
        carried = dataclasses.replace(fallback, source="carried" if fallback.source != "nominal" else "nominal")
        return carried if self.coherence is None else dataclasses.replace(carried, coherence=self.coherence)


def read_stretch(points: np.ndarray, spec: TapeSpec, config: StretchConfig | None = None) -> StretchReading:
    """The :class:`StretchReading` of candidate points (N, 3) mm against ``spec`` (see module)."""
    config = config or StretchConfig()
    points = np.asarray(points, float).reshape(-1, 3)
    if not config.adaptive:
        return StretchReading(None, adaptive=False)
    if len(points) < config.min_points:
        return StretchReading(None)
    try:
        arc = _arc_coordinates(points)
    except (ValueError, np.linalg.LinAlgError):
        return StretchReading(None)
    pitch, coherence = along_pitch(arc, spec.row_pitch_mm, config.along_range)
    if coherence < config.min_coherence:
        return StretchReading(None, coherence=coherence)
    across = across_spacing(points, spec.column_spacing_mm, config.across_range)
    across_ratio = float(np.clip(across / spec.column_spacing_mm, *config.across_range)) if across else 1.0
    rows = row_gaps(arc, spec.row_pitch_mm * config.along_range[0])
    if rows is not None:  # rows told apart: the mean pitch over the tape, and its local pitches
        local, along = rows[0] / spec.row_pitch_mm, rows[1] / spec.row_pitch_mm
    else:  # the periodogram's period (uneven stretch biases it toward the longest local pitch)
        local, along = local_pitches(arc, pitch) / spec.row_pitch_mm, pitch / spec.row_pitch_mm
    local = local[(local > config.along_range[0] * 0.8) & (local < config.along_range[1] * 1.2)]
    along = float(np.clip(along, *config.along_range))
    measured = StretchEstimate(
        along=along, across=across_ratio,
        along_min=float(min(local.min(), along)) if len(local) else along,
        along_max=float(max(local.max(), along)) if len(local) else along,
        coherence=coherence, source="data",
    )
    return StretchReading(measured, across_measured=bool(across))


def stretched_spec(spec: TapeSpec, estimate: StretchEstimate, quantum: float = 0.005) -> TapeSpec:
    """The tape as laid on the body: row pitch and end margins times ``along``, column spacing
    and width times ``across`` (both rounded to ``quantum`` so frames share cached graphs); the
    stretch tolerance grows to cover the local pitches between ``along_min`` and ``along_max``."""
    along = max(round(estimate.along / quantum) * quantum, quantum)
    across = max(round(estimate.across / quantum) * quantum, quantum)
    spread = max(along / max(estimate.along_min, 1e-6) - 1, estimate.along_max / along - 1, 0.0)
    tolerance = min(max(spec.stretch_tolerance, round((spec.stretch_tolerance + spread) / quantum) * quantum), 0.5)
    if along == 1.0 and across == 1.0 and tolerance == spec.stretch_tolerance:
        return spec
    return _spec_cache(spec, along, across, tolerance)


_SPECS: dict[tuple, TapeSpec] = {}


def _spec_cache(spec: TapeSpec, along: float, across: float, tolerance: float) -> TapeSpec:
    key = (spec, along, across, tolerance)
    if key not in _SPECS:
        if len(_SPECS) > 256:
            _SPECS.clear()
        _SPECS[key] = dataclasses.replace(
            spec, row_pitch_mm=spec.row_pitch_mm * along, end_margin_mm=spec.end_margin_mm * along,
            column_spacing_mm=spec.column_spacing_mm * across, width_mm=spec.width_mm * across,
            stretch_tolerance=tolerance)
    return _SPECS[key]


def row_stretch(positions: np.ndarray, graph: TapeGraph) -> tuple[np.ndarray, np.ndarray]:
    """Measured stretch of a labelled solution (D, 3) mm against ``graph``'s spec, per dot:
    (along, across), each (D,). Along: distance between the centres of the dot's row and its
    neighbouring rows over the spec's pitch (mean of both sides); across: mean distance to the
    dot's row neighbours over the column spacing. NaN where the needed dots are missing."""
    pos = np.asarray(positions, float)
    spec = graph.spec
    n_rows = spec.n_rows
    rows = graph.row_index
    centre = np.full((n_rows, 3), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        found = rows.sums(pos) / rows.count[:, None]  # each row's mean (members added in order) ...
    three = rows.count == 3
    found[three] = pos[rows.members[three, 1]]  # ... but of a 3-dot row its C dot, on the midline
    found[rows.count == 0] = np.nan
    centre[:len(found)] = found[:n_rows]
    gaps = np.linalg.norm(np.diff(centre, axis=0), axis=1) / spec.row_pitch_mm  # (n_rows - 1,)
    sides = np.stack([np.concatenate([[np.nan], gaps]), np.concatenate([gaps, [np.nan]])])  # below, above
    count_rows = np.isfinite(sides).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        along_row = np.where(count_rows > 0, np.nansum(sides, axis=0) / count_rows, np.nan)
    along = along_row[graph.row]
    transverse = graph.edges[graph.solid & graph.transverse]
    lengths = np.linalg.norm(pos[transverse[:, 0]] - pos[transverse[:, 1]], axis=1)
    rest = graph.rest_length_mm[graph.solid & graph.transverse]
    ratio = lengths / rest
    total = np.zeros(len(pos))
    count = np.zeros(len(pos))
    for k in range(2):
        ok = np.isfinite(ratio)
        np.add.at(total, transverse[ok, k], ratio[ok])
        np.add.at(count, transverse[ok, k], 1)
    with np.errstate(invalid="ignore"):
        across = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return along, across
