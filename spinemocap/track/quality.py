"""Quality flags: what the tracker cannot vouch for, per frame and per dot (beyond the paper).

A two-row label shift reprojects perfectly (every dot sits on a real dot, just the wrong one), so
residuals alone never reveal it. Each frame therefore carries flags for the situations where the
labels may be wrong, and each dot a label confidence in [0, 1]:

``confidence = status factor x product of the frame's flag factors x the dot's own flag factors``

- status factor: ``observed`` 1.0 (a triangulated point of >= 2 views is at the dot), ``inferred``
  0.6 (placed by the tape model only), ``missing`` 0;
- flags (factor): ``identity_kept`` 0.5 (the re-solve wanted another labelling, the previous
  frame's was kept, see :mod:`spinemocap.track.continuity`); ``relabelled`` 0.5 (the labels moved
  by whole rows against the previous frame because the evidence demanded it); ``identity_unsure``
  0.5 (sequence mode: no frame so far saw enough rows to rule out a labelling shifted by whole
  rows, e.g. a capture that starts with one end of the tape unseen: every label may be rows off,
  see :func:`spinemocap.track.continuity.other_shifts`); ``unlabelled_dots``
  0.5 (dots seen by >= 3 cameras just beyond an end of the labelled tape were left without a
  label: the template may sit a row or two off); ``stretch_implausible`` 0.5 (the solved tape's row pitch leaves the
  range a kinesiology tape can take, or two neighbouring rows lie more than 15 % closer or
  farther than any row pitch measured in the frame's points); ``unsolved`` 0.5 (the frame had no solution: its dots,
  where given, were interpolated in time between solved frames); ``stretch_carried`` 0.9 (this frame's spacing could not be
  measured, an earlier frame's was used); ``lp_relaxed`` 0.9 (the LP had to drop edges);
  ``lp_time_limited`` 0.95 (the LP stopped at its time limit: its edges, or the count it settled
  on, are the best found in that time and may differ on a slower or busier machine; raise
  ``[lp] time_limit_s`` to search longer);
- per-dot flags (factor on the dots concerned only; the frame lists the flag): ``dot_relocated``
  0.8 (the dot sat off its tape neighbours' lattice, matched to a ghost or a neighbour's point
  under a poor rig, and was moved back onto it: :mod:`spinemocap.track.lattice`);
  ``dot_extrapolated`` 0.5 (such a dot found no candidate point and its observed neighbours
  (kept in place) lie on one side only: its place is an extrapolation along the tape, possibly a
  dot spacing off; the inferred dots beyond it are the model's, no evidence of its place);
  ``dot_unanchored`` 0.5 (an inferred dot two or more rows beyond the last row with an observed
  dot: the tape's end seen by no camera pair, placed and labelled by the model alone, which
  misses there by half a dot spacing or more, see :func:`spinemocap.track.lattice.rows_beyond`;
  also an unseen dot beyond the observed rows that the sequence moved with the last frames'
  motion more than half a dot spacing from the re-solve's place: the two disagree on which dot
  lies there, see :meth:`spinemocap.track.sequence.SequenceTracker._hidden_rows_follow`);
  ``dot_unsupported`` 0.5 (an observed dot whose label the other observed dots do not bear out:
  more than half a dot spacing from where their lattice puts it (judged again without each dot
  found off, the worst first, so that two wrong dots do not bear each other out), or in a group
  of a few observed dots that no solid edge joins to the rest of the observed tape, or within
  half the smallest dot spacing of another labelled dot (with that dot: a row labelled a
  column aside, beside the model's own dot for the column it took); also the inferred dots beside
  such a dot, laid by the same model around the same point; a triangulated point with a low
  residual is no proof of its label: matched to its row neighbour's point, a dot reprojects
  perfectly, and the dots the model infers around it follow it, see
  :func:`spinemocap.track.lattice.off_observed_lattice` and :func:`~spinemocap.track.lattice.detached_groups`).
  ``dot_end_misplaced`` 0.5 (the dots of the rows beyond the outermost observed rows, the tape's
  end seen by no camera pair, on a side where the solved row pitch leaves the plausible range
  (as ``stretch_implausible`` judges it) while every pitch between rows with an observed dot
  stays within it: the model misplaced the unseen end, and only its dots are in doubt; a
  pitch beside an observed row's or a hidden middle row's is the frame's ``stretch_implausible``,
  since a row carrying its neighbour's label shows there, see :func:`unobserved_ends_beside`).

A frame is *flagged* when it holds any flag but the mild ``stretch_carried``, ``lp_relaxed``,
``lp_time_limited`` and ``dot_relocated`` (frequent under occlusion or a poor rig, the relocated
dots land within ~2 mm of their truth, and the later stages check the LP's labels as they check
any). In ``markers.csv`` a flagged frame shows as a dot whose confidence is below 0.6 x its status
factor (mild factors multiply to >= 0.61, doubting ones give <= 0.5).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..markers import INFERRED, MISSING, OBSERVED
from ..tape import TapeGraph
from .continuity import row_centres

FLAG_FACTORS = {
    "identity_kept": 0.5,
    "relabelled": 0.5,
    "identity_unsure": 0.5,
    "unlabelled_dots": 0.5,
    "stretch_implausible": 0.5,
    "unsolved": 0.5,
    "stretch_carried": 0.9,
    "lp_relaxed": 0.9,
    "lp_time_limited": 0.95,
}
DOT_FLAG_FACTORS = {
    "dot_relocated": 0.8,
    "dot_extrapolated": 0.5,
    "dot_unanchored": 0.5,
    "dot_unsupported": 0.5,
    "dot_end_misplaced": 0.5,
}
MILD_FLAGS = frozenset({"stretch_carried", "lp_relaxed", "lp_time_limited", "dot_relocated"})
STATUS_FACTORS: dict[str, float] = {OBSERVED: 1.0, INFERRED: 0.6, MISSING: 0.0}


def label_confidence(status: np.ndarray, flags: list[str], dot_flags: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """(D,) confidence in [0, 1] from the dots' status (D,), the frame's flags and the per-dot
    flags ``dot_flags`` (name -> (D,) bool; see module)."""
    frame = float(np.prod([FLAG_FACTORS.get(f, 1.0) for f in set(flags)])) if flags else 1.0
    out = np.array([STATUS_FACTORS.get(str(s), 0.0) for s in status]) * frame
    for name, mask in (dot_flags or {}).items():
        if mask is not None:
            out[np.asarray(mask, bool)] *= DOT_FLAG_FACTORS[name]
    return out


def is_flagged(flags: list[str]) -> bool:
    """True when the frame holds a flag that puts its labels in doubt (see module)."""
    return bool(set(flags) - MILD_FLAGS)


def unlabelled_dots(model: np.ndarray, points: np.ndarray, n_views: np.ndarray, graph: TapeGraph,
                    radius_mm: float, min_views: int = 3, reach: float = 1.5) -> int:
    """Candidate points of >= ``min_views`` cameras beyond either end row of the labelled tape
    (model (D, 3) mm in label order; ``graph`` the frame's stretched tape): nearest to an end
    row, farther out along the tape than that row by 0.4-``reach`` row pitches and claimed by
    no dot (none within ``radius_mm``). Real dots there are the mark of a template one or two
    rows off; ghosts of a poor rig scatter around the whole tape instead."""
    model = np.asarray(model, float)
    strong = np.asarray(points, float).reshape(-1, 3)[np.asarray(n_views) >= min_views]
    if not len(strong) or not np.isfinite(model).all():
        return 0
    centres = row_centres(model, graph)  # model is finite here: every row has its dots
    n_rows = len(centres)
    if n_rows < 3:
        return 0
    pitch = graph.spec.row_pitch_mm
    dist, nearest = cKDTree(model).query(strong)
    nearest_row = graph.row[nearest]
    count = 0
    for end, inner in ((0, 1), (n_rows - 1, n_rows - 2)):
        outward = centres[end] - centres[inner]
        outward /= max(np.linalg.norm(outward), 1e-9)
        beyond = (strong - centres[end]) @ outward
        count += int(((nearest_row == end) & (dist > radius_mm) & (beyond > 0.4 * pitch) & (beyond < reach * pitch)).sum())
    return count


def stretch_plausible(along: np.ndarray, bounds: tuple[float, float]) -> bool:
    """False when a measured row stretch (D,) leaves ``bounds`` (ratio to the spec)."""
    finite = np.asarray(along, float)
    finite = finite[np.isfinite(finite)]
    return bool(not len(finite) or ((finite >= bounds[0]) & (finite <= bounds[1])).all())


def implausible_pitches(pitches: np.ndarray, tape_range: tuple[float, float],
                        measured_range: tuple[float, float] | None = None) -> np.ndarray:
    """(n_rows - 1,) bool: the solved row pitches (``pitches``, ratio to the spec's, NaN where a
    row is missing) outside ``tape_range`` (what a kinesiology tape can take) or outside
    ``measured_range`` (the pitches the frame's points show, when measured)."""
    pitches = np.asarray(pitches, float)
    with np.errstate(invalid="ignore"):
        out = (pitches < tape_range[0]) | (pitches > tape_range[1])
        if measured_range is not None:
            out |= (pitches < measured_range[0]) | (pitches > measured_range[1])
    return out


def unobserved_ends_beside(implausible: np.ndarray, observed: np.ndarray, graph: TapeGraph) -> np.ndarray | None:
    """(D,) bool: the dots of the end rows beyond the outermost rows holding an ``observed`` (D,)
    bool dot, on each side where an ``implausible`` (n_rows - 1,) bool pitch (between rows ``k``
    and ``k + 1``) lies, when every implausible pitch touches such a row; None when some
    implausible pitch lies between rows within the observed span (a row carrying its
    neighbour's label, or a hidden row between observed ones whose pitches tell a skipped row:
    the observed labels are in doubt) or when no pitch is implausible.

    Beyond the outermost observed rows every row is placed by the model alone: a pitch there,
    or between the last observed row and the first unseen one, says where the model laid the
    unseen end, not which label an observed dot carries."""
    implausible = np.asarray(implausible, bool)
    observed = np.asarray(observed, bool)
    if not implausible.any() or not observed.any():
        return None
    rows = np.asarray(graph.row)
    lo, hi = int(rows[observed].min()), int(rows[observed].max())
    gaps = np.flatnonzero(implausible)  # gap k joins rows k and k + 1
    if ((gaps >= lo) & (gaps < hi)).any():
        return None
    below, above = bool((gaps < lo).any()), bool((gaps >= hi).any())
    return (below & (rows < lo)) | (above & (rows > hi))


def flagged_from_confidence(status: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """(F,) bool from a marker table's (F, D) status and confidence columns: frames where some
    dot's confidence sits below 0.6 x its status factor, i.e. a label-doubting flag was set
    (see module). Unknown confidences (NaN, older files) never flag."""
    factor = np.vectorize(lambda s: STATUS_FACTORS.get(str(s), 0.0))(status) if status.size else np.zeros(status.shape)
    with np.errstate(invalid="ignore"):
        low = (factor > 0) & np.isfinite(confidence) & (confidence < 0.6 * factor)
    return low.any(axis=1)
