"""Quality flags: what the tracker cannot vouch for, per frame and per dot (beyond the paper).

A two-row label shift reprojects perfectly (every dot sits on a real dot, just the wrong one), so
residuals alone never reveal it. Each frame therefore carries flags for the situations where the
labels may be wrong, and each dot a label confidence in [0, 1]:

``confidence = status factor x product of the frame's flag factors``

- status factor: ``observed`` 1.0 (a triangulated point of >= 2 views is at the dot), ``inferred``
  0.6 (placed by the tape model only), ``missing`` 0;
- flags (factor): ``identity_kept`` 0.5 (the re-solve wanted another labelling, the previous
  frame's was kept, see :mod:`spinemocap.track.continuity`); ``relabelled`` 0.5 (the labels moved
  by whole rows against the previous frame because the evidence demanded it); ``unlabelled_dots``
  0.5 (dots seen by >= 3 cameras right beside the tape were left without a label: the template
  may sit a row or two off); ``stretch_implausible`` 0.5 (the solved tape's row pitch leaves the
  range a kinesiology tape can take); ``stretch_carried`` 0.9 (this frame's spacing could not be
  measured, an earlier frame's was used); ``lp_relaxed`` 0.9 (the LP had to drop edges).

A frame is *flagged* when it holds any flag but ``stretch_carried``/``lp_relaxed`` (both mild and
frequent under occlusion).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..tape import TapeGraph

FLAG_FACTORS = {
    "identity_kept": 0.5,
    "relabelled": 0.5,
    "unlabelled_dots": 0.5,
    "stretch_implausible": 0.5,
    "stretch_carried": 0.9,
    "lp_relaxed": 0.9,
}
MILD_FLAGS = frozenset({"stretch_carried", "lp_relaxed"})
STATUS_FACTORS = {"observed": 1.0, "inferred": 0.6, "missing": 0.0}


def label_confidence(status: np.ndarray, flags: list[str]) -> np.ndarray:
    """(D,) confidence in [0, 1] from the dots' status (D,) and the frame's flags (see module)."""
    frame = float(np.prod([FLAG_FACTORS.get(f, 1.0) for f in set(flags)])) if flags else 1.0
    return np.array([STATUS_FACTORS.get(str(s), 0.0) for s in status]) * frame


def is_flagged(flags: list[str]) -> bool:
    """True when the frame holds a flag that puts its labels in doubt (see module)."""
    return bool(set(flags) - MILD_FLAGS)


def unlabelled_dots(model: np.ndarray, points: np.ndarray, n_views: np.ndarray, graph: TapeGraph,
                    radius_mm: float, min_views: int = 3, reach: float = 1.5) -> int:
    """Candidate points of >= ``min_views`` cameras that no model dot claims (none within
    ``radius_mm``) although they lie within ``reach`` row pitches of the model's dots (mm):
    real dots next to the labelled tape, the mark of a template one or two rows off."""
    model = np.asarray(model, float)
    finite = np.isfinite(model).all(axis=1)
    strong = np.asarray(points, float).reshape(-1, 3)[np.asarray(n_views) >= min_views]
    if not len(strong) or finite.sum() < 2:
        return 0
    dist = cKDTree(model[finite]).query(strong)[0]
    pitch = graph.spec.row_pitch_mm
    return int(((dist > radius_mm) & (dist < reach * pitch)).sum())


def stretch_plausible(along: np.ndarray, bounds: tuple[float, float]) -> bool:
    """False when a measured row stretch (D,) leaves ``bounds`` (ratio to the spec)."""
    finite = np.asarray(along, float)
    finite = finite[np.isfinite(finite)]
    return bool(not len(finite) or ((finite >= bounds[0]) & (finite <= bounds[1])).all())
