"""Label continuity in sequence mode (beyond the paper): a full re-solve must not silently
relabel the tape by whole rows against the previous frame.

The per-frame pipeline decides which end of the point cloud is row 1 and where along the curve
the template sits from the current frame alone. When only part of the tape is seen (occlusion,
a stretched tape, a poor rig) two offsets one or two rows apart can explain the points equally
well, and a re-solve then shifts every label by a row or two with perfect residuals. Between two
frames the body moves millimetres, a row is ~25-40 mm: comparing the re-solve's row centres with
the previous frame's prediction tells the shift exactly (:func:`row_shift`).

A shift is accepted only when the evidence is unambiguous (:func:`shift_is_unambiguous`): the
re-solve observes dots in the rows that keeping the previous identity would push off the tape's
end, i.e. the previous labelling cannot explain what the cameras see. Otherwise the re-solve's
geometry is relabelled with the previous identity (:func:`relabel_rows`) and the frame flagged.

A capture's first frame has no previous identity: when one end of the tape is unseen, labellings
two (or more) rows apart can explain the observed dots equally well (:func:`other_shifts`), and
nothing but a row beyond the other end coming into view tells them apart.
"""

from __future__ import annotations

import numpy as np

from ..tape import TapeGraph


def row_centres(positions: np.ndarray, graph: TapeGraph) -> np.ndarray:
    """(n_rows, 3) centre of each row's finite dots (NaN when none)."""
    rows = graph.row_index
    positions = np.asarray(positions, float)
    finite = np.isfinite(positions).all(axis=1)
    count = rows.sums(finite.astype(float))  # finite members per row
    with np.errstate(invalid="ignore", divide="ignore"):
        out = rows.sums(np.where(finite[:, None], positions, 0.0)) / count[:, None]  # members added in order
    out[count == 0] = np.nan
    return out


def row_shift(new: np.ndarray, reference: np.ndarray, graph: TapeGraph, max_shift: int = 2) -> tuple[int, dict[int, float]]:
    """The whole-row shift ``k`` with the re-solve's row ``r + k`` nearest the reference's row
    ``r`` (median distance of row centres, mm), and the cost of every ``k`` in
    ``-max_shift..max_shift``. Positions (D, 3) mm in label order, NaN rows allowed."""
    a, b = row_centres(new, graph), row_centres(reference, graph)
    n_rows = len(a)
    costs: dict[int, float] = {}
    for k in range(-max_shift, max_shift + 1):
        rows = np.arange(max(0, -k), min(n_rows, n_rows - k))
        if len(rows) < 2:
            continue
        d = np.linalg.norm(a[rows + k] - b[rows], axis=1)
        d = d[np.isfinite(d)]
        if len(d) >= 2:
            costs[k] = float(np.median(d))
    if not costs:
        return 0, costs
    return min(costs, key=lambda k: costs[k]), costs


def shift_is_unambiguous(observed: np.ndarray, graph: TapeGraph, shift: int) -> bool:
    """True when keeping the previous identity (new row ``r + shift`` becomes row ``r``) would
    drop observed dots of the re-solve: rows ``r + shift`` outside the tape then held real
    points that only the re-solve's labelling explains. ``observed`` (D,) bool."""
    n_rows = int(graph.row.max()) + 1
    dropped = np.arange(n_rows)[(np.arange(n_rows) - shift < 0) | (np.arange(n_rows) - shift >= n_rows)]
    return bool(observed[np.isin(graph.row, dropped)].sum() >= 2)


def other_shifts(observed: np.ndarray, graph: TapeGraph) -> list[int]:
    """Whole-row shifts ``k != 0`` under which every ``observed`` (D,) bool dot (row ``r``, column
    ``c``) lands on a dot of the tape (row ``r + k`` has a column ``c``): the other labellings of
    the same observed points, one per shift. Odd shifts need no observed C dot (2- and 3-dot
    rows alternate); with the tape's both end rows observed there is none. Empty without
    observed dots too (nothing to relabel)."""
    rows, columns = np.asarray(graph.row), np.asarray(graph.column)
    n_rows = int(rows.max()) + 1
    seen = {(int(r), str(c)) for r, c in zip(rows[observed], columns[observed])}
    if not seen:
        return []
    tape = {(int(r), str(c)) for r, c in zip(rows, columns)}
    lo, hi = min(r for r, _ in seen), max(r for r, _ in seen)
    return [k for k in range(-lo, n_rows - hi) if k and all((r + k, c) in tape for r, c in seen)]


def relabel_rows(new: np.ndarray, graph: TapeGraph, shift: int) -> np.ndarray:
    """The re-solve's positions (D, 3) under the previous identity: label of row ``r`` takes the
    re-solve's row ``r + shift`` dot by column; between 2- and 3-dot rows (odd shifts) the
    across positions are rescaled (L/R at +-7.5 vs +-15 mm on the spec tape, C in the middle);
    rows without a source stay NaN."""
    out = np.full_like(new, np.nan)
    column = np.asarray(graph.column)
    n_rows = int(graph.row.max()) + 1
    for r in range(n_rows):
        src = r + shift
        if not 0 <= src < n_rows:
            continue
        dst_idx = np.flatnonzero(graph.row == r)
        src_idx = np.flatnonzero(graph.row == src)
        src_pos = {column[i]: new[i] for i in src_idx}
        for i in dst_idx:
            col = column[i]
            if col in src_pos:
                out[i] = src_pos[col]
            elif col == "C":  # 3-dot row from a 2-dot row: the midpoint
                out[i] = 0.5 * (src_pos["L"] + src_pos["R"])
        if len(src_idx) == 2 and len(dst_idx) == 3:  # 3-dot row's L/R lie twice as far out
            for i in dst_idx:
                if column[i] != "C":
                    out[i] = 1.5 * src_pos[column[i]] - 0.5 * src_pos["R" if column[i] == "L" else "L"]
        if len(src_idx) == 3 and len(dst_idx) == 2:  # 2-dot row from a 3-dot row: L/R halfway in
            for i in dst_idx:
                out[i] = 0.5 * (src_pos[column[i]] + src_pos["C"])
    return out
