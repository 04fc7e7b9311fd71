"""One tracker configuration, composed of one section per pipeline stage, loadable from TOML.

Example ``tracker.toml`` (every key optional; unknown keys are an error)::

    [candidates]
    th1_px = 2.0
    th2_mm = 6.0
    [edges]
    drop_shared_blob = true
    [lp]
    time_limit_s = 10.0
    [mrf1]
    iterations = 12
    [mrf2]
    polish = true
    [status]
    observe_radius_mm = 7.0
    [sequence]
    skip_lp = true
    [stretch]
    adaptive = true
    [rig]
    adaptive_gate = true

``TrackerConfig.before_issue_11()`` is the tracker as it was before stretch adaptation, the
rig-derived gate, label continuity, the lattice check and the unanchored-end check (nominal spacing, fixed th1): the peer in ``bench realism``.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

from ..fileio import InputError, read_toml
from ..tape import MAX_ROWS
from .candidates import CandidateConfig
from .edges import EdgeConfig
from .lp import LPConfig
from .mrf1 import MRF1Config
from .mrf2 import MRF2Config
from .rig_check import RigCheckConfig
from .stretch import StretchConfig


@dataclass
class EvidenceConfig:
    """MRF2's image evidence: ``downscale`` of the cost images (1 = full resolution); ``threads``:
    the cameras' cost images are built by this many threads of the tracker's own (1, the default:
    one after another in the calling thread). Each image is built alone (OpenCV and numpy release
    the GIL for most of the work), so the same images either way. Two threads did not pay on a
    loaded 2-core machine: the same CPU, and the evidence alone built in half the wall time when a
    core was free, but a whole run's wall time was not
    lower under load."""

    downscale: float = 1.0
    threads: int = 1


@dataclass
class StatusConfig:
    """Per-dot status: a model dot is ``observed`` when a candidate point of >= ``min_views``
    cameras lies within ``observe_radius_mm``; its output position is that triangulated point when
    ``use_triangulated`` (the blobs are the most direct measurement), else the model's.
    ``lattice_check`` (beyond the paper): a dot farther than ``lattice_limit`` x the tape's
    smallest dot spacing from where its tape neighbours put it (:mod:`spinemocap.track.lattice`,
    Gaussian weights of ``lattice_sigma_mm`` on the tape) was matched to a ghost or a
    neighbour's point, or placed wrong by the model: it is moved to the unclaimed candidate point
    at that prediction (or, without one, inferred there) and marked relocated (its label
    confidence lowered, see :mod:`spinemocap.track.quality`). ``unanchored_rows`` (beyond the
    paper; 0 = off): an inferred dot this many rows or more beyond the last row holding an
    observed dot, toward the tape's end, has a place and label from the model alone, an
    extrapolation that misses by about half a dot spacing from two rows out
    (:func:`spinemocap.track.lattice.rows_beyond`): it is marked unanchored and its frame flagged.
    Before that, ``anchor_ends`` looks for such dots' points one row out at a time where the
    observed dots' lattice extrapolates them (:meth:`~spinemocap.track.pipeline.FrameTracker.anchor_tape_ends`;
    dots so found count as relocated). ``ray_points`` (beyond the paper): an observed dot's
    output point is the least-squares point of its blobs' rays (the sum of its squared distances
    from them, mm; :func:`spinemocap.geometry.triangulate_rays`), not its candidate's DLT point:
    the DLT's rows, normalised as 4-vectors in world mm, weight the cameras by where the world's
    origin lies rather than by their errors (on the studio's ``lab`` capture the DLT points of
    the same blobs were 0.86 mm off on average, the ray points 0.35 mm, as the points of least
    reprojection error; a camera seeing the tape at a grazing angle pulled the DLT points most).
    False: the candidate's point."""

    observe_radius_mm: float = 7.0
    min_views: int = 2
    use_triangulated: bool = True
    lattice_check: bool = True
    lattice_limit: float = 0.3
    lattice_sigma_mm: float = 20.0
    unanchored_rows: int = 2
    anchor_ends: bool = True
    ray_points: bool = True


@dataclass
class SequenceConfig:
    """Beyond the paper: frame-to-frame tracking (``mode = "sequence"``).

    ``skip_lp``: when the previous frame's dots, moved by their velocity, find candidate points
    within ``match_radius_mm`` for at least ``min_explained`` of the dots, the LP and MRF1 are
    skipped for that frame; ``refine_skipped`` runs MRF2 on such frames when dots are occluded;
    ``warm_start``: MRF1 starts from the previous frame instead of the cubic template (off by
    default: after a fast move the previous dots are too far for particle BP to travel); ``gap_fill_frames``: frames without a
    solution between solved ones are interpolated in time up to this gap length;
    ``smooth_inferred``: window (frames, odd) of a moving average over inferred stretches
    (``smooth_trusted_only``: flagged frames' samples enter no other frame's average);
    ``keep_identity``: a full re-solve that relabels the tape by up to ``max_row_shift`` rows
    against the previous frame is overruled (previous identity kept, frame flagged) unless the
    evidence is unambiguous (see :mod:`spinemocap.track.continuity`). By default every shift
    is searched: with one end of the tape unseen a re-solve can slide the template by more than
    two rows (the last 4 rows of 13 hidden: 4 rows, and a search up to 2 then relabelled it
    by 2 only, leaving every label 2 rows off); ``follow_hidden_rows``: after
    a full re-solve, unobserved rows beyond the observed ones move with their observed tape
    neighbours from the prediction instead of the re-solve's mean-stretch placement;
    ``pin_identity``: until a frame's observed rows admit no other whole-row labelling (the
    first frame's labels are its own guess when an end of the tape is unseen), every frame is
    flagged ``identity_unsure`` and a carried frame leaving strong points unlabelled beyond an
    end of the tape is re-solved (see :mod:`spinemocap.track.sequence`)."""

    skip_lp: bool = True
    match_radius_mm: float = 8.0
    min_explained: float = 0.75
    refine_skipped: bool = True
    warm_start: bool = False
    gap_fill_frames: int = 10
    smooth_inferred: int = 3
    smooth_trusted_only: bool = True
    keep_identity: bool = True
    max_row_shift: int = MAX_ROWS - 1
    follow_hidden_rows: bool = True
    pin_identity: bool = True


_SECTIONS = {
    "candidates": CandidateConfig,
    "edges": EdgeConfig,
    "lp": LPConfig,
    "mrf1": MRF1Config,
    "mrf2": MRF2Config,
    "evidence": EvidenceConfig,
    "status": StatusConfig,
    "sequence": SequenceConfig,
    "stretch": StretchConfig,
    "rig": RigCheckConfig,
}


@dataclass
class TrackerConfig:
    """All tracker thresholds and weights, one section per stage (see module docstring)."""

    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    edges: EdgeConfig = field(default_factory=EdgeConfig)
    lp: LPConfig = field(default_factory=LPConfig)
    mrf1: MRF1Config = field(default_factory=MRF1Config)
    mrf2: MRF2Config = field(default_factory=MRF2Config)
    evidence: EvidenceConfig = field(default_factory=EvidenceConfig)
    status: StatusConfig = field(default_factory=StatusConfig)
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    stretch: StretchConfig = field(default_factory=StretchConfig)
    rig: RigCheckConfig = field(default_factory=RigCheckConfig)
    seed: int = 0

    @classmethod
    def before_issue_11(cls) -> "TrackerConfig":
        """The tracker before issue 11: the roll's nominal dot spacing, the fixed th1 gate, no
        label-continuity, lattice or unanchored-end check (kept as the benchmark's peer)."""
        config = cls()
        return dataclasses.replace(
            config, stretch=dataclasses.replace(config.stretch, adaptive=False),
            rig=dataclasses.replace(config.rig, adaptive_gate=False),
            status=dataclasses.replace(config.status, lattice_check=False, unanchored_rows=0, anchor_ends=False),
            sequence=dataclasses.replace(config.sequence, keep_identity=False, smooth_trusted_only=False,
                                         follow_hidden_rows=False, pin_identity=False))

    @classmethod
    def from_dict(cls, data: dict, source: str | None = None) -> "TrackerConfig":
        unknown = set(data) - set(_SECTIONS) - {"seed"}
        if unknown:
            raise InputError(source, f"unknown tracker config sections {sorted(unknown)}; known: {sorted(_SECTIONS)}")
        sections = {}
        for name, kind in _SECTIONS.items():
            values = data.get(name, {})
            if not isinstance(values, dict):
                raise InputError(source, f"[{name}] must be a table")
            known = {f.name for f in dataclasses.fields(kind)}
            bad = set(values) - known
            if bad:
                raise InputError(source, f"unknown keys {sorted(bad)} in [{name}]; known: {sorted(known)}")
            values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
            try:
                sections[name] = kind(**values)
            except (TypeError, ValueError) as exc:
                raise InputError(source, f"invalid [{name}] settings: {exc}") from exc
        return cls(**sections, seed=int(data.get("seed", 0)))

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> "TrackerConfig":
        return cls.from_dict(read_toml(path), source=str(path))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
