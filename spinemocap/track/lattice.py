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
fails fast: on the studio's exact dots (``lab``, ``tension 30 % + skin``, ``flexion (lab)``,
``forehand (lab)``, 30-60 frames each) the end rows hidden and predicted from the rest land
3.8-5.3 mm off (median) one row out, 8-11 mm two rows out and 13-17 mm three rows out (the
weighted affine map with 30 mm weights; 20 mm weights give 15-41 mm two rows out; a weighted
quadratic map does no better: 7-9 mm two rows out), i.e. from two
rows out beyond half the smallest dot spacing, where a dot is nearer its neighbour's place than
its own. :func:`rows_beyond` counts how far a dot lies out there.
"""

from __future__ import annotations

import numpy as np

from ..tape import TapeGraph


def affine_from_neighbours(uv: np.ndarray, positions: np.ndarray, known: np.ndarray, targets: np.ndarray,
                           sigma_mm: float = 30.0) -> np.ndarray:
    """(T, 3) mm: each target dot (indices ``targets``) predicted from the ``known`` (D,) bool dots
    other than itself: a weighted affine map flat tape ``uv`` (D, 2) mm -> ``positions`` (D, 3) mm
    with weights ``exp(-d^2 / 2 sigma^2)`` on the tape distance ``d``; when fewer than 3 known
    dots carry weight, a global affine fit. NaN where fewer than 3 known dots remain."""
    targets = np.asarray(targets, np.int64)
    out = np.full((len(targets), 3), np.nan)
    for k, i in enumerate(targets):
        use = known.copy()
        use[i] = False
        if use.sum() < 3:
            continue
        design = np.column_stack([uv[use], np.ones(use.sum())])
        w = np.exp(-0.5 * ((uv[use] - uv[i]) ** 2).sum(axis=1) / sigma_mm**2)
        if (w > 1e-3).sum() < 3:
            w = np.ones_like(w)  # far from every known dot: a global affine fit
        sw = np.sqrt(w)[:, None]
        A, *_ = np.linalg.lstsq(design * sw, positions[use] * sw, rcond=None)
        out[k] = np.append(uv[i], 1.0) @ A
    return out


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
    out = np.zeros(len(positions), bool)
    for d in range(len(positions)):
        others = known.copy()
        others[d] = False
        rows = graph.row[others]
        out[d] = not ((rows <= graph.row[d]).any() and (rows >= graph.row[d]).any())
    return out


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
