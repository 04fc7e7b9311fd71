"""The perforated kinesiology tape: its dot layout (:class:`TapeSpec`) and graph (:class:`TapeGraph`).

Tape frame (2D, millimetres, on the flattened tape): ``v`` runs along the tape from the sacral
end (row 1 at ``v = 0``), ``u`` runs across it, positive toward the subject's right. Columns are
named from the subject's point of view: ``L`` (u < 0), ``C`` (u = 0), ``R`` (u > 0). Rows
alternate 2 and 3 dots, starting and ending with a 2-dot row, so the row count is odd.

Labels: ``R{row:02d}{column}``, rows counted from the sacral end: ``R01L``, ``R01R``, ``R02L``,
``R02C``, ``R02R``, ...

Graph (paper Fig. 2):
- solid transverse edges: neighbouring dots within a row (L-C, C-R; L-R in a 2-dot row);
- solid longitudinal edges: every dot to every dot of the adjacent rows (2 x 3 = 6 per row pair).
  The paper's target edge count (Eq. 1) counts exactly these six per row pair and its neighbour
  bounds 6..12 (Eq. 4-5) hold only for this graph, so "nearest dots of the adjacent rows" is read
  as the whole adjacent row (the two far diagonals are ~30 % longer than the near ones);
- dashed (long, anti-folding) edges: same column two rows apart, and L-R across the centre of a
  3-dot row.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property

import numpy as np

from .fileio import InputError, read_toml, write_toml

MAX_ROWS = 99  # labels carry two row digits (R01 ... R99)


@dataclass(frozen=True)
class TapeSpec:
    """Physical layout of a perforated tape strip. Lengths in millimetres.

    Defaults follow the paper: 50 mm wide tape, ~10 mm dots, 9 rows (22 dots on 20 x 5 cm).
    ``stretch_tolerance`` is the relative skin stretch accepted when matching dot distances.
    ``thickness_mm``: the cameras see the holes' rims on the tape's top surface; the tracker
    reports the skin point one thickness further in (kinesiology tape: about 0.5-1 mm; 0 reports
    the tape surface).
    """

    n_rows: int = 9
    width_mm: float = 50.0
    dot_diameter_mm: float = 10.0
    row_pitch_mm: float = 25.0
    column_spacing_mm: float = 15.0
    end_margin_mm: float = 12.5
    stretch_tolerance: float = 0.15
    thickness_mm: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.n_rows, (int, np.integer)) or isinstance(self.n_rows, bool) or self.n_rows > MAX_ROWS:
            raise ValueError(f"n_rows must be a whole number up to {MAX_ROWS}; got {self.n_rows!r}")
        for f in fields(self)[1:]:
            value = getattr(self, f.name)
            if not isinstance(value, (int, float, np.number)) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f"{f.name} must be a finite number; got {value!r}")
        if self.n_rows < 1 or self.n_rows % 2 == 0:
            raise ValueError(
                f"n_rows must be odd and >= 1 (rows alternate 2/3 dots and start and end with a "
                f"2-dot row); got {self.n_rows}"
            )
        for name in ("width_mm", "dot_diameter_mm", "row_pitch_mm", "column_spacing_mm"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive; got {getattr(self, name)}")
        if 2 * self.column_spacing_mm + self.dot_diameter_mm > self.width_mm:
            raise ValueError("the three dots of a row do not fit across the tape width")
        if self.dot_diameter_mm >= self.column_spacing_mm:
            raise ValueError("dot_diameter_mm must be smaller than column_spacing_mm")
        if self.thickness_mm < 0:
            raise ValueError(f"thickness_mm must be >= 0; got {self.thickness_mm}")
        if not 0 <= self.stretch_tolerance < 1:
            raise ValueError("stretch_tolerance must lie in [0, 1)")

    # ------------------------------------------------------------------ construction / IO
    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "TapeSpec":
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise InputError(source, f"unknown tape settings {sorted(unknown)}; known: {sorted(known)}")
        try:
            return cls(**data)
        except (TypeError, ValueError) as exc:
            raise InputError(source, f"invalid tape spec: {exc}") from exc

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "TapeSpec":
        """Load from a TOML file holding the fields at top level or under ``[tape]``."""
        data = read_toml(path)
        return cls.from_dict(data.get("tape", data), source=str(path))

    def to_dict(self) -> dict:
        return asdict(self)

    def to_toml(self, path: str | os.PathLike) -> None:
        write_toml(path, {"tape": self.to_dict()})

    # ------------------------------------------------------------------ derived quantities
    @property
    def row_sizes(self) -> list[int]:
        """Dots per row from the sacral end: 2, 3, 2, ..., 2."""
        return [2 if r % 2 == 0 else 3 for r in range(self.n_rows)]

    @property
    def n_dots(self) -> int:
        return sum(self.row_sizes)

    @property
    def length_mm(self) -> float:
        return (self.n_rows - 1) * self.row_pitch_mm + 2 * self.end_margin_mm

    @property
    def n_target_edges(self) -> int:
        """Paper Eq. 1: floor(n/2)*2 + ceil(n/2) + (n-1)*6 solid edges."""
        n = self.n_rows
        return (n // 2) * 2 + math.ceil(n / 2) + (n - 1) * 6

    @cached_property
    def graph(self) -> "TapeGraph":
        return TapeGraph.build(self)

    @property
    def labels(self) -> list[str]:
        return list(self.graph.labels)


def _row_columns(size: int) -> list[tuple[str, float]]:
    return [("L", -0.5), ("R", 0.5)] if size == 2 else [("L", -1.0), ("C", 0.0), ("R", 1.0)]


@dataclass(frozen=True)
class TapeGraph:
    """Dots and edges of a tape. Arrays are indexed by dot (D) or edge (E).

    ``edges``: (E, 2) dot indices, solid edges first; ``solid``/``transverse``: (E,) bool;
    ``rest_length_mm``: (E,) distances on the unstretched tape.
    """

    labels: tuple[str, ...]
    row: np.ndarray  # (D,) 0-based row index from the sacral end
    column: tuple[str, ...]  # (D,) 'L' | 'C' | 'R'
    uv_mm: np.ndarray  # (D, 2) (u across, v along) in the flat tape frame
    edges: np.ndarray  # (E, 2)
    solid: np.ndarray  # (E,) bool
    transverse: np.ndarray  # (E,) bool
    rest_length_mm: np.ndarray  # (E,)
    spec: TapeSpec = field(repr=False)

    @classmethod
    def build(cls, spec: TapeSpec) -> "TapeGraph":
        labels: list[str] = []
        rows: list[int] = []
        cols: list[str] = []
        uv: list[tuple[float, float]] = []
        row_members: list[list[int]] = []
        for r, size in enumerate(spec.row_sizes):
            members = []
            for name, offset in _row_columns(size):
                members.append(len(labels))
                labels.append(f"R{r + 1:02d}{name}")
                rows.append(r)
                cols.append(name)
                uv.append((offset * spec.column_spacing_mm, r * spec.row_pitch_mm))
            row_members.append(members)

        solid: list[tuple[int, int, bool]] = []  # (i, j, transverse)
        for members in row_members:  # neighbouring dots within a row
            solid += [(a, b, True) for a, b in zip(members[:-1], members[1:])]
        for lower, upper in zip(row_members[:-1], row_members[1:]):  # adjacent rows, all pairs
            solid += [(a, b, False) for a in lower for b in upper]
        dashed: list[tuple[int, int, bool]] = []
        for members in row_members:  # across the centre of a 3-dot row
            if len(members) == 3:
                dashed.append((members[0], members[2], True))
        for lower, upper in zip(row_members[:-2], row_members[2:]):  # same column two rows apart
            for a in lower:
                for b in upper:
                    if cols[a] == cols[b]:
                        dashed.append((a, b, False))

        all_edges = solid + dashed
        edges = np.array([(i, j) for i, j, _ in all_edges], dtype=np.int64).reshape(-1, 2)
        uv_arr = np.array(uv, dtype=float)
        return cls(
            labels=tuple(labels),
            row=np.array(rows, dtype=np.int64),
            column=tuple(cols),
            uv_mm=uv_arr,
            edges=edges,
            solid=np.array([True] * len(solid) + [False] * len(dashed)),
            transverse=np.array([t for _, _, t in all_edges], dtype=bool),
            rest_length_mm=np.linalg.norm(uv_arr[edges[:, 0]] - uv_arr[edges[:, 1]], axis=1),
            spec=spec,
        )

    @property
    def n_dots(self) -> int:
        return len(self.labels)

    @property
    def solid_edges(self) -> np.ndarray:
        return self.edges[self.solid]

    @property
    def dashed_edges(self) -> np.ndarray:
        return self.edges[~self.solid]

    def index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise KeyError(f"no dot labelled {label!r} on a {self.spec.n_rows}-row tape") from None

    @property
    def min_spacing_mm(self) -> float:
        """The tape's closest two dots (mm, unstretched): the shortest edge's rest length."""
        return float(self.rest_length_mm.min())

    def solid_length_bounds_mm(self) -> tuple[float, float]:
        """(th3, th4): the range of solid-edge lengths widened by the stretch tolerance."""
        lengths = self.rest_length_mm[self.solid]
        tol = self.spec.stretch_tolerance
        return float(lengths.min() * (1 - tol)), float(lengths.max() * (1 + tol))

    def edge_neighbours(self, edges: np.ndarray | None = None) -> list[np.ndarray]:
        """Omega_e for each edge: indices of the other edges sharing an endpoint with it."""
        return edge_neighbour_sets(self.solid_edges if edges is None else edges)

    def positions_on_plane_mm(self) -> np.ndarray:
        """(D, 3) rest positions in a tape-local 3D frame: x = u, y = v, z = 0."""
        return np.column_stack([self.uv_mm, np.zeros(self.n_dots)])

    @cached_property
    def row_index(self) -> "RowIndex":
        """The rows as index arrays (:class:`RowIndex`), built when first asked for."""
        return RowIndex(self)


class RowIndex:
    """A tape graph's rows as index arrays (:attr:`TapeGraph.row_index`, built once per graph):
    ``members`` (n_rows, k_max) dot indices of each row in label order, padded with 0, ``valid``
    (n_rows, k_max) which entries are dots, ``count`` (n_rows,), ``left`` / ``right`` (n_rows,) the first
    L / R dot of each row (-1: none)."""

    def __init__(self, graph: "TapeGraph"):
        rows = np.asarray(graph.row)
        n_rows = int(rows.max()) + 1
        groups = [np.flatnonzero(rows == r) for r in range(n_rows)]
        k_max = max(len(g) for g in groups)
        self.members = np.zeros((n_rows, k_max), np.int64)
        self.valid = np.zeros((n_rows, k_max), bool)
        for r, g in enumerate(groups):
            self.members[r, :len(g)] = g
            self.valid[r, :len(g)] = True
        self.count = self.valid.sum(axis=1)
        column = np.array(graph.column)
        self.left = np.array([next((i for i in g if column[i] == "L"), -1) for g in groups], np.int64)
        self.right = np.array([next((i for i in g if column[i] == "R"), -1) for g in groups], np.int64)

    def sums(self, values: np.ndarray) -> np.ndarray:
        """(n_rows, ...) sum of each row's entries of ``values`` (D, ...), added in label order
        (as summing each row's members alone adds them; padding adds exact zeros)."""
        gathered = values[self.members]
        mask = self.valid.reshape(self.valid.shape + (1,) * (values.ndim - 1))
        return np.where(mask, gathered, 0.0).sum(axis=1)


def edge_neighbour_sets(edges: np.ndarray) -> list[np.ndarray]:
    """For each edge (row of ``edges``), the indices of the other edges sharing an endpoint."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    by_node: dict[int, list[int]] = {}
    for e, (i, j) in enumerate(edges):
        by_node.setdefault(int(i), []).append(e)
        by_node.setdefault(int(j), []).append(e)
    out = []
    for e, (i, j) in enumerate(edges):
        members = set(by_node[int(i)]) | set(by_node[int(j)])
        members.discard(e)
        out.append(np.array(sorted(members), dtype=np.int64))
    return out


#: The tightest curvature across the tape (radius, mm) a taut strip on a back can take: the
#: cross-sagitta of a 3-dot row (+-``column_spacing_mm``, 15 mm by default) is then at most
#: 15^2 / (2 x 40) = 2.8 mm; a longer one comes from mislabelled dots, not from the back.
MIN_CROSS_RADIUS_MM = 40.0


def row_rest_positions_mm(tape: TapeSpec) -> np.ndarray:
    """(R,) each row's rest position ``v`` along the tape, mm from row 1 (tape frame)."""
    graph = tape.graph
    return graph.uv_mm[[graph.labels.index(f"R{r + 1:02d}L") for r in range(tape.n_rows)], 1]


def row_midline_points(midpoint: np.ndarray, middle: np.ndarray, tape: TapeSpec) -> np.ndarray:
    """The tape's midline point (u = 0) of every row, (F, R, 3) in the frame and unit of the inputs
    (mm), from the rows' ``L``-``R`` midpoints ``midpoint`` (F, R, 3) and ``C`` dots ``middle``
    (F, R, 3; NaN in 2-dot rows or where unseen).

    Why: the rows alternate ``L``/``R`` dots 7.5 mm off the midline (2-dot rows) and
    ``L``/``C``/``R`` at -15/0/+15 mm (3-dot rows), so the plain ``L``-``R`` midpoint lies on a
    chord of the cross-section that is 4x deeper in 3-dot rows than in 2-dot rows: any curvature
    across the tape (the back's, or a reconstruction's depth error growing toward the midline)
    zig-zags the midpoints between neighbouring rows. The cross-section is taken as a parabola:
    per frame the cross-sagitta ``C - midpoint`` measured on 3-dot rows is interpolated linearly
    in ``v`` to every row (held constant beyond the outermost measured rows) and added, scaled to
    each row's dot offsets (x 1 for 3-dot rows, x 1/4 for 2-dot rows), to the midpoint. A sagitta
    longer than allowed by :data:`MIN_CROSS_RADIUS_MM` is a mislabelled row (a column shift puts
    ``C`` 7.5-15 mm off the midpoint) and is not used; a frame without a usable sagitta keeps the
    midpoints; a row without ``L`` or ``R`` falls back to its ``C`` dot.
    """
    v = row_rest_positions_mm(tape)
    depth_factor = _chord_depth_factors(tape)
    max_sagitta_mm = tape.column_spacing_mm**2 / (2 * MIN_CROSS_RADIUS_MM)
    sagitta = middle - midpoint
    measured = np.isfinite(sagitta).all(axis=2) & (np.linalg.norm(sagitta, axis=2) <= max_sagitta_mm)
    out = midpoint.copy()
    for f in np.flatnonzero(measured.any(axis=1)):
        at = measured[f]
        for k in range(3):
            out[f, :, k] += depth_factor * np.interp(v, v[at], sagitta[f, at, k])
    fallback = ~np.isfinite(out).all(axis=2) & np.isfinite(middle).all(axis=2)
    out[fallback] = middle[fallback]
    return out


def _chord_depth_factors(tape: TapeSpec) -> np.ndarray:
    """Per row (R,): how deep its ``L``-``R`` midpoint lies below the midline for a parabolic
    cross-section, as a multiple of a 3-dot row's cross-sagitta ``(L + R) / 2 - C``: the mean
    squared ``L``/``R`` offset over a 3-dot row's (1 for 3-dot rows, 1/4 for 2-dot rows)."""
    graph = tape.graph
    u = {label: abs(float(uv[0])) for label, uv in zip(graph.labels, graph.uv_mm)}
    squared = np.array([0.5 * (u[f"R{r + 1:02d}L"] ** 2 + u[f"R{r + 1:02d}R"] ** 2) for r in range(tape.n_rows)])
    wide = [squared[r] for r in range(tape.n_rows) if tape.row_sizes[r] == 3]
    return squared / wide[0] if wide else np.zeros(tape.n_rows)
