"""The tape's local lattice: where a dot should be, given its neighbours on the tape (beyond the
paper).

Over a few centimetres the tape on the skin is close to an affine image of the flat tape: its
local stretch, shear and orientation change slowly along the back. A dot's 3D position is
therefore predicted well by a weighted affine map from the flat tape's (u, v) (mm) to 3D, fitted
to the other dots with Gaussian weights on their distance on the tape (:func:`affine_from_neighbours`).
On a curved back this prediction is off by the tape's sagitta over the fit's reach, about 1-2 mm;
a dot carrying a neighbour's label, or matched to a ghost point, is off by a dot spacing (15-40
mm). :func:`off_lattice` finds such dots one at a time (the worst first, so that one wrong dot
does not make its correct neighbours look wrong).

Beyond the last row that holds an observed dot the lattice can only be extrapolated, and that
fails fast: one row out a hidden end row lands ~4-5 mm off, two rows out ~8-11 mm, i.e. beyond
half the smallest dot spacing, where a dot is nearer its neighbour's place than its own.
:func:`rows_beyond` counts how far a dot lies out there.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..tape import TapeGraph


def affine_from_neighbours(uv: np.ndarray, positions: np.ndarray, known: np.ndarray, targets: np.ndarray,
                           sigma_mm: float = 30.0) -> np.ndarray:
    """(T, 3) mm: each target dot (indices ``targets``) predicted from the ``known`` (D,) bool dots
    other than itself: a weighted affine map flat tape ``uv`` (D, 2) mm -> ``positions`` (D, 3) mm
    with weights ``exp(-d^2 / 2 sigma^2)`` on the tape distance ``d``; when fewer than 3 known
    dots carry weight, a global affine fit. NaN where fewer than 3 known dots remain.

    All targets at once: each target's weighted least-squares fit in coordinates centred on it
    (the prediction is then the fit's constant term), by its 3 x 3 normal equations refined with
    residuals taken from the data (so the least-squares solution to rounding, as
    ``np.linalg.lstsq`` per target gives it); targets whose known dots do not span the tape's
    plane (a rank-deficient fit) take ``lstsq`` itself."""
    targets = np.asarray(targets, np.int64)
    out = np.full((len(targets), 3), np.nan)
    if not len(targets):
        return out
    T = len(targets)
    use = np.repeat(np.asarray(known, bool)[None, :], T, axis=0)
    use[np.arange(T), targets] = False
    active = use.sum(axis=1) >= 3
    gap = uv[None, :, :] - uv[targets][:, None, :]  # (T, D, 2): the design, centred on the target
    w = np.where(use, np.exp(-0.5 * ((uv[None, :, :] - uv[targets][:, None, :]) ** 2).sum(axis=2) / sigma_mm**2), 0.0)
    few = ((w > 1e-3) & use).sum(axis=1) < 3
    w[few] = use[few]  # far from every known dot: a global affine fit
    design = np.concatenate([gap, np.ones(gap.shape[:2] + (1,))], axis=2)  # (T, D, 3)
    Y = np.where(use[:, :, None], positions[None, :, :], 0.0)  # (T, D, 3)
    Dw = design.transpose(0, 2, 1) * w[:, None, :]  # (T, 3, D)
    M = Dw @ design
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = inverse_sym3(M)
        A = inv @ (Dw @ Y)
        for _ in range(3):  # iterative refinement: residuals from the data, not the normal equations
            A = A + inv @ (Dw @ (Y - design @ A))
        scale = np.sqrt(np.abs(M[:, 0, 0] * M[:, 1, 1] * M[:, 2, 2]))
        solid = active & np.isfinite(A).all(axis=(1, 2)) & (np.abs(np.linalg.det(M)) > 1e-9 * scale)
    out[solid] = A[solid, 2, :]
    for k in np.flatnonzero(active & ~solid):  # the known dots on a line: lstsq's minimum-norm fit
        out[k] = _affine_lstsq(uv, positions, use[k], w[k][use[k]], targets[k])
    return out


def _affine_lstsq(uv: np.ndarray, positions: np.ndarray, use: np.ndarray, w: np.ndarray, i: int) -> np.ndarray:
    """One target's weighted affine fit by ``np.linalg.lstsq`` (uncentred: the reference form)."""
    design = np.column_stack([uv[use], np.ones(use.sum())])
    sw = np.sqrt(w)[:, None]
    A, *_ = np.linalg.lstsq(design * sw, positions[use] * sw, rcond=None)
    return np.append(uv[i], 1.0) @ A


def inverse_sym3(M: np.ndarray) -> np.ndarray:
    """(N, 3, 3) inverses of symmetric (N, 3, 3) matrices by their cofactors (inf/NaN where singular)."""
    a, b, c, d, e, f = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2], M[:, 1, 1], M[:, 1, 2], M[:, 2, 2]
    i00, i01, i02 = d * f - e * e, c * e - b * f, b * e - c * d
    i11, i12, i22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * i00 + b * i01 + c * i02
    return np.stack([i00, i01, i02, i01, i11, i12, i02, i12, i22], axis=1).reshape(-1, 3, 3) / det[:, None, None]


def off_lattice(uv: np.ndarray, positions: np.ndarray, limit_mm: float, sigma_mm: float = 30.0,
                min_support: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Dots whose position (D, 3) mm sits farther than ``limit_mm`` from the prediction of their
    tape neighbours (:func:`affine_from_neighbours`), found one at a time: the worst is set aside
    and the rest checked again without it. Returns ``(outlier (D,) bool, prediction (D, 3))``,
    the prediction of every finite dot from the dots that passed (NaN where it cannot be made).
    Needs ``min_support`` finite dots (else nothing is judged).

    Limits: a single wrong dot (a ghost, a neighbour's point) is found exactly; a block of wrong
    dots that agree with one another (the last two rows both a row pitch off along the tape) can
    look like a stretched tape to a local affine map and is not always told apart."""
    finite = np.isfinite(positions).all(axis=1)
    outlier = np.zeros(len(positions), bool)
    prediction = np.full_like(positions, np.nan, dtype=float)
    if finite.sum() < min_support:
        return outlier, prediction
    idx = np.flatnonzero(finite)
    while True:
        known = finite & ~outlier
        prediction[idx] = affine_from_neighbours(uv, positions, known, idx, sigma_mm)
        residual = np.linalg.norm(positions - prediction, axis=1)
        residual[~known | ~np.isfinite(residual)] = -np.inf
        worst = int(np.argmax(residual))
        if residual[worst] <= limit_mm or known.sum() - 1 < min_support:
            return outlier, prediction
        outlier[worst] = True


def beyond_known_rows(excluded: np.ndarray, positions: np.ndarray, graph: TapeGraph) -> np.ndarray:
    """(D,) bool: dots whose row has no other known dot (finite and not ``excluded``) both at or
    below and at or above it on the tape, i.e. whose lattice prediction extrapolates along the
    tape (1-2 dot spacings off on a poor frame) instead of interpolating between neighbours."""
    known = np.isfinite(positions).all(axis=1) & ~excluded
    rows = np.asarray(graph.row)
    below = (known[None, :] & (rows[None, :] <= rows[:, None])).sum(axis=1) - known  # other known dots at or below
    above = (known[None, :] & (rows[None, :] >= rows[:, None])).sum(axis=1) - known  # ... at or above
    return ~((below > 0) & (above > 0))


def rows_beyond(anchored: np.ndarray, graph: TapeGraph) -> np.ndarray:
    """(D,) int: how many rows each dot lies beyond the outermost rows that hold an ``anchored``
    (D,) bool dot (an observed one), toward either end of the tape; 0 for dots between them.
    Without any anchored dot every dot counts as the whole tape's length beyond."""
    rows = np.asarray(graph.row)
    n_rows = int(rows.max()) + 1
    if not np.any(anchored):
        return np.full(len(rows), n_rows, np.int64)
    lo, hi = int(rows[anchored].min()), int(rows[anchored].max())
    return np.maximum(lo - rows, 0) + np.maximum(rows - hi, 0)


def off_observed_lattice(uv: np.ndarray, positions: np.ndarray, observed: np.ndarray, limit_mm: float,
                         sigma_mm: float = 20.0) -> np.ndarray:
    """(D,) bool: ``observed`` (D,) bool dots farther than ``limit_mm`` from where the *other
    observed* dots' lattice puts them (:func:`affine_from_neighbours` on the flat tape ``uv``
    (D, 2) mm, ``positions`` (D, 3) mm), judged in passes: each pass judges the observed dots not
    yet set aside against one another and sets the worst one beyond the limit aside, the next
    pass judges the rest without it; a dot beyond the limit in any pass is returned. Inferred
    dots take no part: the model places them together with a dot matched to its neighbour's
    point, and the block then agrees with itself. Dots that cannot be predicted (fewer than 3
    other observed dots) are not judged.

    The passes: two wrong dots side by side (the end rows' only observed dots, both a column
    aside) bear each other out; the worse of them is found, and without it the other lies a dot
    spacing off the rest of the tape's lattice. The first pass alone is the all-at-once check,
    so a dot it finds is always returned."""
    observed = np.asarray(observed, bool) & np.isfinite(positions).all(axis=1)
    out = np.zeros(len(positions), bool)
    support = observed.copy()
    while support.sum() >= 4:
        idx = np.flatnonzero(support)
        prediction = affine_from_neighbours(uv, positions, support, idx, sigma_mm)
        residual = np.linalg.norm(positions[idx] - prediction, axis=1)
        residual[~np.isfinite(residual)] = -np.inf
        off = residual > limit_mm
        if not off.any():
            break
        out[idx[off]] = True
        support[idx[int(np.argmax(residual))]] = False  # the worst bears out no other dot
    return out


def crowded_labels(positions: np.ndarray, observed: np.ndarray, rows: np.ndarray, limit_mm: float) -> np.ndarray:
    """(D,) bool: every dot of a row (``rows`` (D,) int) where an ``observed`` (D,) bool dot has
    another labelled dot (any finite row of ``positions`` (D, 3) mm, observed or inferred) nearer
    than ``limit_mm``, or is that other dot. Two dots of a tape never lie within half its smallest
    spacing of each other; labels that do were put a column aside (on a staggered tape, rows
    shifted by a column keep every edge length to the rows beside them) next to the model's own
    dot for the column they took, and the rest of their row moved with them."""
    finite = np.isfinite(positions).all(axis=1)
    if limit_mm <= 0 or not (observed & finite).any() or finite.sum() < 2:
        return np.zeros(len(positions), bool)
    idx = np.flatnonzero(finite)
    dist = np.linalg.norm(positions[idx][:, None, :] - positions[idx][None, :, :], axis=2)
    np.fill_diagonal(dist, np.inf)
    close = (dist < limit_mm) & (observed[idx][:, None] | observed[idx][None, :])  # one of the pair observed
    return np.isin(rows, rows[idx[close.any(axis=1)]])


def detached_groups(observed: np.ndarray, solid_edges: np.ndarray, max_dots: int) -> np.ndarray:
    """(D,) bool: ``observed`` (D,) bool dots in a group of at most ``max_dots`` observed dots that
    the tape's ``solid_edges`` (E, 2) join to each other but to no observed dot of the largest
    group (a row of unseen dots lies between). Such a group's labels come from the model's
    placement across the gap alone: a group smaller than two whole rows fits a column or a row
    beside its own as well as its own."""
    observed = np.asarray(observed, bool)
    out = np.zeros(len(observed), bool)
    if max_dots <= 0 or observed.sum() < 2:
        return out
    both = solid_edges[observed[solid_edges[:, 0]] & observed[solid_edges[:, 1]]]
    n = len(observed)
    adjacency = coo_matrix((np.ones(len(both)), (both[:, 0], both[:, 1])), shape=(n, n))
    _, group = connected_components(adjacency, directed=False)
    sizes = np.bincount(group[observed], minlength=n)
    largest = int(np.argmax(sizes))
    small = sizes <= max_dots
    out[observed] = (group[observed] != largest) & small[group[observed]]
    return out
