"""The tape's lattice: which found dots, and which tape regions, are perforated tape.

The holes of the tape lie on a two-dimensional lattice: rows of 2 and 3 dots across the tape
(in-row spacing ``a``) stacked along it (the next row shifted by ``b``: half a spacing across
and a row pitch along); every dot is ``i a + j b`` for whole ``i``, ``j``. A camera sees the
lattice through a smooth map (perspective, the back's curvature, uneven stretch) that is nearly
affine over a few neighbouring dots, and an affine map keeps parallelograms and equally spaced
collinear dots. So on the tape, seen from any side:

- every dot is a corner of a *parallelogram* of dots (``p``, ``p + a``, ``p + b``,
  ``p + a + b``) whose sides lead to nearby dots in two directions;
- some dot is the middle of a row of exactly three equally spaced dots on a line (a 3-dot row:
  no fourth dot continues it);
- the rows are *staggered*: a row of three lies beside a row of exactly two with the same step,
  and the stagger continues over a third row (the other row of two mirrored through the row of
  three's middle, or the next row of three mirrored through the row of two), wherever three
  neighbouring rows are in view.

Bright spots that are not tape lack one or the other: an isolated spot has no neighbours; screw
heads on a rail, the gaps of blinds or a line of lights lie on one line (no parallelogram), and
two such lines side by side have rows of two across and longer lines along (no row of three); the
LED ring round a motion-capture camera's lens lies on an ellipse, where no three points are
collinear (its inscribed parallelograms span the ring, and count only while that is within
reach); a grid whose rows all hold three (wall bars with three gaps per rung, a pegboard's
corner) has rows of three but none of two beside them, and a gap missing here and there makes a
row of two only on one side of a row of three.

:func:`lattice_dots` marks all three; :func:`tape_regions` keeps the tape mask's components that
hold at least :data:`MIN_LATTICE_DOTS` parallelogram corners and a staggered row of three, with
all their dots, and the pieces too small to test (1-3 dots, e.g. cut off by an occluder) that
lie beside them; every other component and dot goes. What passes and is not tape: a grid with
the tape's stagger over three rows (a grid with gaps missing in the right places, a
checkerboard three squares wide), and two staggered LED rings seen obliquely: lattices too, over
a few dots. What is lost: a piece of tape showing fewer than three whole rows, and not beside a
kept piece.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from .blobs import labelled_components

NEIGHBOURS = 8            # displacements tested per dot (to its nearest dots)
MAX_REACH = 6.0           # ... up to this x the median nearest-neighbour distance (the next row of a
                          # tape seen 70 deg from face-on across it: ~5x the in-row spacing)
TOLERANCE = 0.2           # a parallelogram's fourth corner matches a dot within this x its shorter side
BETWEEN_NEAREST = 8       # dots tested for lying between two neighbouring rows (nearest the parallelogram's centre)
ROW_TOLERANCE = 0.35      # a dot of the rows beside a row of three matches within this x its step (the tape
                          # curves and stretches unevenly; a grid's dots lie half a step off)
LINE_TOLERANCE = 0.1      # a triple's end matches a dot within this x the spacing (a row is straight)
MIN_ANGLE_DEG = 25.0      # a parallelogram's sides differ in direction by this at least
MIN_LATTICE_DOTS = 4      # a tape region holds at least this many parallelogram corners (one parallelogram)
_MIN_LATTICE = 4


class Lattice(NamedTuple):
    """Per dot (N,) bool: ``corner`` of a parallelogram of dots, ``middle`` of a row of exactly
    three equally spaced collinear dots, ``staggered``: one of the five dots of a row of three
    beside a row of exactly two (:func:`staggered_rows`)."""

    corner: np.ndarray
    middle: np.ndarray
    staggered: np.ndarray


def lattice_dots(uv: np.ndarray) -> Lattice:
    """The lattice structure of the dots ``uv`` ((N, 2) px, x y): see the module docstring.
    Fewer than four dots: none."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    n = len(uv)
    corner, middle, staggered = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    if n < _MIN_LATTICE:
        return Lattice(corner, middle, staggered)
    tree = cKDTree(uv)
    k = min(NEIGHBOURS, n - 1)
    dist, idx = tree.query(uv, k=k + 1)
    dist, idx = dist[:, 1:], idx[:, 1:]  # the first is the dot itself
    nearest = float(np.median(dist[:, 0]))
    if not nearest > 0:
        return Lattice(corner, middle, staggered)
    valid = dist <= MAX_REACH * nearest
    vectors = uv[idx] - uv[:, None]  # (n, k, 2) each dot's displacements to its neighbours
    # the middle of a row of three: the opposite displacement leads to a dot too, and neither
    # doubled displacement does (a tape's rows hold 2 or 3 dots; a longer line is not a row)
    def dot_at(offset: float) -> np.ndarray:
        found, _ = tree.query((uv[:, None] + offset * vectors).reshape(-1, 2))
        return found.reshape(n, k) <= LINE_TOLERANCE * dist

    row_step = valid & dot_at(-1.0) & ~dot_at(2.0) & ~dot_at(-2.0)  # (n, k): p is a middle, step vectors[p, k]
    middle = row_step.any(axis=1)
    staggered = staggered_rows(uv, tree, idx, vectors, dist, valid, row_step)
    # parallelograms: two non-parallel displacements of a dot, and a dot at their sum
    i, j = np.triu_indices(k, 1)
    v1, v2 = vectors[:, i], vectors[:, j]  # (n, pairs, 2)
    l1, l2 = dist[:, i], dist[:, j]
    sin = np.abs(v1[..., 0] * v2[..., 1] - v1[..., 1] * v2[..., 0]) / np.maximum(l1 * l2, 1e-12)
    pairs = valid[:, i] & valid[:, j] & (sin >= math.sin(math.radians(MIN_ANGLE_DEG)))
    dot, pair = np.nonzero(pairs)
    if len(dot):
        found, fourth = tree.query(uv[dot] + v1[dot, pair] + v2[dot, pair])
        ok = found <= TOLERANCE * np.minimum(l1[dot, pair], l2[dot, pair])
        for members in (dot[ok], idx[dot[ok], i[pair[ok]]], idx[dot[ok], j[pair[ok]]], fourth[ok]):
            corner[members] = True
    return Lattice(corner, middle, staggered)


def staggered_rows(uv: np.ndarray, tree: cKDTree, idx: np.ndarray, vectors: np.ndarray, dist: np.ndarray,
                   valid: np.ndarray, row_step: np.ndarray) -> np.ndarray:
    """Per dot (N,) bool: one of the five dots of a row of three (middle ``p``, step ``v``)
    beside a row of exactly two with the same step (dots ``q`` and ``q - v``, ``q`` a neighbour
    of ``p`` off the row's line, no dot at ``q + v`` or ``q - 2 v``), where a third row continues
    the stagger: a row of exactly two at ``2 p - q`` and ``2 p - q + v``, or a row of exactly
    three around ``2 q - v - p``. Dots match within :data:`ROW_TOLERANCE` x the step.

    The tape's rows alternate three and two dots, each row of two half a step across from the
    rows of three beside it; a grid whose rows all hold three (wall bars with three gaps per
    rung, a pegboard's corner) has no row of two beside a row of three, and where a missing gap
    makes one, the row mirrored through it holds three. ``idx``, ``vectors``,
    ``dist`` and ``valid`` (N, K): each dot's nearest neighbours, displacements to them (px),
    distances and whether within reach; ``row_step`` (N, K): ``p`` is the middle of a row of
    three whose step is that displacement."""
    n, k = row_step.shape
    out = np.zeros(n, bool)
    p, kv = np.nonzero(row_step)
    if not len(p):
        return out
    step = vectors[p, kv]                                       # (m, 2) the row's step v
    length = dist[p, kv]
    q_index = idx[p]                                            # (m, k) the candidate q: p's neighbours
    u = vectors[p]                                              # (m, k, 2) p -> q
    sin = np.abs(step[:, None, 0] * u[..., 1] - step[:, None, 1] * u[..., 0]) / np.maximum(length[:, None] * dist[p], 1e-12)
    off_line = valid[p] & (sin >= math.sin(math.radians(MIN_ANGLE_DEG)))
    q = uv[q_index]                                             # (m, k, 2)
    radius = (ROW_TOLERANCE * length)[:, None]

    def dot_near(offset: float) -> tuple[np.ndarray, np.ndarray]:
        found, which = tree.query((q + offset * step[:, None]).reshape(-1, 2))
        return found.reshape(q.shape[:2]) <= radius, which.reshape(q.shape[:2])

    partner, _ = dot_near(-1.0)
    beyond_q, _ = dot_near(1.0)
    beyond_partner, _ = dot_near(-2.0)
    rows, cols = np.nonzero(off_line & partner & ~beyond_q & ~beyond_partner)  # rows of three beside a row of two
    if not len(rows):
        return out
    middle, v, two = uv[p[rows]], step[rows], q[rows, cols]
    r = radius[rows, 0]
    # ... and a third row continuing the stagger: the other row of two, the first mirrored through
    # the middle of the row of three, or the next row of three, mirrored through the row of two
    other_two = 2 * middle - two
    next_three = 2 * two - v - middle
    mirrored = _row_at(tree, other_two, v, r, (0, 1), (-1, 2))
    onward = _row_at(tree, next_three, v, r, (-1, 0, 1), (-2, 2))
    # neighbouring rows: no dot between them or between their dots (a grid's oblique lines of three
    # and two, or its every other column, have dots between)
    continued = mirrored | onward
    continued[continued] = _nothing_between(uv, tree, (middle - v)[continued], v[continued], (two - middle)[continued])
    for third, origin, side2 in ((mirrored, other_two, middle - other_two), (onward, two - v, next_three - two + v)):
        third &= continued
        third[third] = _nothing_between(uv, tree, origin[third], v[third], side2[third], corner=ROW_TOLERANCE)
    continued = mirrored | onward
    if continued.any():
        members = [middle[continued][:, None] + np.array([-1.0, 0.0, 1.0])[:, None] * v[continued][:, None]]
        members += [two[continued][:, None] - np.array([0.0, 1.0])[:, None] * v[continued][:, None]]
        _, which = tree.query(np.concatenate([m.reshape(-1, 2) for m in members]))
        out[which] = True
    return out


def _nothing_between(uv: np.ndarray, tree: cKDTree, origin: np.ndarray, side1: np.ndarray, side2: np.ndarray,
                     margin: float = 0.15, corner: float = 0.15) -> np.ndarray:
    """Per parallelogram (M,): none of the :data:`BETWEEN_NEAREST` dots of ``uv`` nearest its
    centre on ``origin + s side1 + t side2`` (all (M, 2) px) with ``s``, ``t`` in ``[-margin,
    1 + margin]`` (inside or on an edge) but within ``corner`` of its corners (in ``s`` and ``t``:
    predicted corners match dots that far off)."""
    if not len(origin):
        return np.zeros(0, bool)
    k = min(BETWEEN_NEAREST, len(uv))
    _, near = tree.query(origin + 0.5 * (side1 + side2), k=k)
    near = near.reshape(len(origin), k)
    det = side1[:, 0] * side2[:, 1] - side1[:, 1] * side2[:, 0]
    det = np.where(np.abs(det) > 1e-9, det, np.nan)
    d = uv[near] - origin[:, None]                               # (M, k, 2)
    s_ = (d[..., 0] * side2[:, None, 1] - d[..., 1] * side2[:, None, 0]) / det[:, None]
    t_ = (side1[:, None, 0] * d[..., 1] - side1[:, None, 1] * d[..., 0]) / det[:, None]
    st = np.stack([s_, t_])                                      # (2, M, k)
    on = np.all((st > -margin) & (st < 1 + margin), axis=0)
    at_corner = np.all(np.minimum(np.abs(st), np.abs(1 - st)) < corner, axis=0)
    return ~np.any(on & ~at_corner, axis=1) & np.isfinite(det)


def _row_at(tree: cKDTree, start: np.ndarray, step: np.ndarray, radius: np.ndarray,
            present: tuple[int, ...], absent: tuple[int, ...]) -> np.ndarray:
    """Per row (M,): dots within ``radius`` (M,) of ``start + i step`` ((M, 2) px each) for every
    ``i`` in ``present`` and none for every ``i`` in ``absent``."""
    ok = np.ones(len(start), bool)
    for i, want in [(i, True) for i in present] + [(i, False) for i in absent]:
        found, _ = tree.query(start + i * step)
        ok &= (found <= radius) == want
    return ok


def tape_regions(mask: np.ndarray, uv: np.ndarray, box: tuple[slice, slice] | None = None,
                 reach_px: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The tape: ``mask`` ((H, W) bool) less its 8-connected components that hold fewer than
    :data:`MIN_LATTICE_DOTS` parallelogram corners or no middle of a collinear triple
    (:func:`lattice_dots` of ``uv``, (N, 2) px x y), and which dots to keep ((N,) bool: those on
    a kept component, a dot within ``reach_px`` of it counting as on it). ``box``: a box holding
    every pixel of ``mask`` (else the whole mask is labelled). Returns ``mask`` itself when every
    component is kept, else a new mask (``mask`` is never changed)."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    h, w = mask.shape
    if box is None:
        box = (slice(0, h), slice(0, w))
    y0, x0 = box[0].start or 0, box[1].start or 0
    region = np.ascontiguousarray(mask[box])
    if not len(uv) or not region.any():
        return np.zeros((h, w), bool), np.zeros(len(uv), bool)
    n_labels, labels, _ = labelled_components(region)
    dot_label = _dot_labels(labels, np.round(uv).astype(np.int64) - [x0, y0], reach_px)
    lattice = lattice_dots(uv)
    corners = np.bincount(dot_label[lattice.corner], minlength=n_labels)
    staggered = np.bincount(dot_label[lattice.staggered], minlength=n_labels)
    accepted = (corners >= MIN_LATTICE_DOTS) & (staggered >= 1)
    accepted[0] = False
    if accepted.any():  # pieces too small to test, beside the tape (cut off by an occluder), stay
        accepted |= _pieces_beside(uv, dot_label, accepted, n_labels)
        accepted[0] = False
    keep_dots = accepted[dot_label]
    if accepted[1:].all():
        return mask, keep_dots
    kept = np.zeros((h, w), bool)
    if accepted.any():
        kept[box] = accepted[labels]
    return kept, keep_dots


def _pieces_beside(uv: np.ndarray, dot_label: np.ndarray, accepted: np.ndarray, n_labels: int) -> np.ndarray:
    """Per label: a component with 1-3 dots (too few for a parallelogram) whose dots all lie
    within the accepted dots' bounding box grown by half its larger side."""
    on_tape = accepted[dot_label]
    lo, hi = uv[on_tape].min(axis=0), uv[on_tape].max(axis=0)
    pad = 0.5 * float((hi - lo).max())
    beside = np.all((uv >= lo - pad) & (uv <= hi + pad), axis=1)
    dots = np.bincount(dot_label, minlength=n_labels)
    away = np.bincount(dot_label[~beside], minlength=n_labels)
    return (dots >= 1) & (dots < _MIN_LATTICE) & (away == 0)


def _dot_labels(labels: np.ndarray, ij: np.ndarray, reach: int) -> np.ndarray:
    """Each dot's component (``ij`` (N, 2) x y px in ``labels``' frame): the label at its pixel,
    else the highest within ``reach`` px (a dot on the tape's edge), 0 for none."""
    hh, ww = labels.shape
    out = np.zeros(len(ij), np.int64)
    for k, (x, y) in enumerate(ij.tolist()):
        if 0 <= x < ww and 0 <= y < hh and labels[y, x]:
            out[k] = labels[y, x]
        else:
            near = labels[max(0, y - reach):max(0, y + reach + 1), max(0, x - reach):max(0, x + reach + 1)]
            out[k] = int(near.max()) if near.size else 0
    return out
