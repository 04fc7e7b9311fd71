"""One tracker configuration, composed of one section per pipeline stage, loadable from TOML.

Every stage's settings dataclass is defined here and imported by its stage, so reading, checking
and writing a configuration loads no solver (no torch, Pyomo or SciPy).

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

``TrackerConfig.nominal_unchecked()`` is the tracker without stretch adaptation, the rig-derived
gate, label continuity, the lattice check and the unanchored-end check (nominal spacing, fixed
th1): the peer in ``bench realism``.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

from ..fileio import InputError, read_toml
from ..tape import MAX_ROWS
from .pbp import PBPConfig, pbp_config


@dataclass
class CandidateConfig:
    """``th1_px``: max reprojection error (undistorted px) of a candidate in each of its views;
    ``th2_mm``: merge distance; ``epipolar_px``: max symmetric epipolar distance of a blob pair
    before triangulation (a cheap pre-filter; ``None`` = 2 * th1); ``max_merge_rounds`` caps the
    merge loop (it normally stops far earlier, when nothing merges); ``suppress_dominated``: drop a
    point when one of its blobs also belongs to a point seen by more cameras (see
    :func:`~spinemocap.track.candidates.suppress_dominated`)."""

    th1_px: float = 2.0
    th2_mm: float = 6.0
    epipolar_px: float | None = None
    max_merge_rounds: int = 20
    suppress_dominated: bool = True


@dataclass
class EdgeConfig:
    """``th3_mm``/``th4_mm``: override the bounds from the tape (``None``: use the tape's);
    ``drop_shared_blob``: drop pairs of points triangulated from the same blob of one camera —
    one blob images one dot, so such a pair is a point and its own ghost, never a tape edge."""

    th3_mm: float | None = None
    th4_mm: float | None = None
    drop_shared_blob: bool = True


@dataclass
class LPConfig:
    """``solver``: Pyomo solver name (``appsi_highs`` or ``highs``); ``time_limit_s`` per solve;
    ``min_neighbours``/``max_neighbours``: Eq. 4-5 bounds (``None``: from the tape graph);
    ``mip_rel_gap``: HiGHS optimality gap; ``min_point_degree``: selected edges a used point
    needs (0 = the paper's model, see :mod:`spinemocap.track.lp`); ``max_step_relaxations``: unit decrements of n before one cardinality solve finds the largest
    feasible n; ``min_target``: give up below this many edges (no tape in the frame)."""

    solver: str = "appsi_highs"
    time_limit_s: float = 10.0
    min_neighbours: int | None = None
    max_neighbours: int | None = None
    max_step_relaxations: int = 3
    min_target: int = 6
    mip_rel_gap: float = 1e-4
    min_point_degree: int = 3
    limit_points: bool = True


@dataclass
class MRF1Config:
    """MRF1 weights and particle-BP settings. Lengths in mm; ``d`` is dimensionless."""

    theta1_longitudinal: float = 0.05  # |p| vs the local stretch d
    theta1_transverse: float = 0.1
    theta2: float = 0.005  # orthogonality to the normal field (camera-biased normals: 0.02 is worse)
    theta3: float = 1.0  # minimum-distance barrier
    theta4_longitudinal: float = 0.02  # |p| vs the rest length
    theta4_transverse: float = 0.05
    dashed_weight: float = 0.5  # dashed (anti-folding) edges relative to solid ones
    d_min_mm: float = 8.0
    unary_cap_mm: float = 12.0
    d_bounds: tuple[float, float] = (0.7, 1.4)  # plausible local stretch
    particles: int = 8
    slice_particles: int = 6
    iterations: int = 8
    slice_steps: int = 5  # shrink steps of the slice sampler per iteration
    sweeps: int = 6
    damping: float = 0.3
    knn: int = 3
    mobility: bool = True  # P_mobility: neighbours' positions as proposals (Eq. 9)
    slice_width_mm: float = 4.0
    slice_width_d: float = 0.05
    width_decay: float = 0.9
    temperature: float = 1.0
    normal_radius_mm: float = 30.0
    warm_start: bool = False  # start from `previous` (its finite rows) instead of the cubic template

    def pbp(self) -> PBPConfig:
        return pbp_config(self, slice_width=(self.slice_width_mm,) * 3 + (self.slice_width_d,), init_spread=(self.slice_width_mm / 2,) * 3 + (self.slice_width_d / 2,))


@dataclass
class MRF2Config:
    """MRF2 weights and solver settings. Image costs are in [0, ~1] per camera; lengths in mm."""

    theta5: float = 0.25  # bright dots vs dark midpoint
    theta6: float = 0.002  # edge orthogonal to the tape normal
    theta7: float = 0.002  # edge along its expected in-plane direction
    theta8: float = 0.002  # edge length vs rest length
    facing_cos: float = 0.05  # a camera sees a dot when cos(normal, dot->camera) exceeds this
    # beyond the paper: per-view image cost capped here (None: uncapped, the paper's growing
    # distance transform). An occluder in front of a dot makes its view look "off the tape"; a cap
    # keeps that view from dragging the dot to the nearest visible tape.
    cost_cap: float | None = 1.0
    image_margin_px: float = 2.0
    particles: int = 4
    slice_particles: int = 4
    iterations: int = 4
    slice_steps: int = 5  # shrink steps of the slice sampler per iteration
    sweeps: int = 5
    damping: float = 0.3
    slice_width_mm: float = 3.0
    width_decay: float = 0.8
    temperature: float = 0.05
    # Eq. 9 P_mobility. Off: in MRF2 a neighbour's spot is itself a bright dot, so with it dots
    # jump onto their neighbours, most of all under heavy occlusion
    mobility: bool = False
    knn: int = 2  # nearest feasible points as proposals, when feasible points are given
    # beyond the paper: L-BFGS on the same energy after particle BP. Off by default: it moves dots
    # from the (sub-pixel blob) feasible points toward slightly biased evidence minima; useful
    # without knn proposals.
    polish: bool = False
    polish_steps: int = 3
    polish_max_step_mm: float = 3.0  # per-dot move limit of the polish from the PBP result
    # beyond the paper: a dot no camera sees (no facing view below the cost cap) has no image
    # term, and the weak Eq. 11 shape terms let the sampler wander (unseen dots' error
    # grows). Such dots are held to their start (MRF1, which keeps the dashed
    # anti-folding edges) by anchor_unseen * |x - x_start|^2.
    anchor_unseen: float = 0.1

    def pbp(self) -> PBPConfig:
        return pbp_config(self, slice_width=(self.slice_width_mm,) * 3, init_spread=(self.slice_width_mm / 3,) * 3)


@dataclass
class StretchConfig:
    """``adaptive``: estimate the spacing from the data (False = the roll's nominal spec);
    ``along_range`` / ``across_range``: searched stretch relative to
    the spec (kinesiology tape gives out at ~1.6; 0.8 covers a spec longer than the tape);
    ``min_points``: fewer candidate points than this keep the previous/nominal estimate;
    ``min_coherence``: periodogram peak below this is not trusted (occluded or ghost-ridden
    frame); ``window_margin``: th3/th4 are widened by this beyond the smallest/largest local row
    pitch (on top of the spec's ``stretch_tolerance`` for the solid-edge set)."""

    adaptive: bool = True
    along_range: tuple[float, float] = (0.8, 1.75)
    across_range: tuple[float, float] = (0.85, 1.3)
    min_points: int = 8
    min_coherence: float = 0.45
    window_margin: float = 0.05


@dataclass
class RigCheckConfig:
    """``adaptive_gate``: derive th1 from the measured residuals (False: the fixed
    ``candidates.th1_px``); ``probe_gate_px``: the loose gate used
    to find the dots the residuals are measured on; ``min_views``: cameras a dot needs to count;
    ``gate_factor`` x the worst camera's robust RMS + ``gate_margin_px`` = the gate, clamped to
    [th1_px, ``max_gate_px``]; ``warn_px``:
    per-camera RMS above which the camera is named in a warning; ``window``: frames the running
    per-camera RMS is the median over."""

    adaptive_gate: bool = True
    probe_gate_px: float = 8.0
    min_views: int = 3
    gate_factor: float = 1.5
    gate_margin_px: float = 1.0
    max_gate_px: float = 6.0
    warn_px: float = 1.0
    window: int = 25



@dataclass
class EvidenceConfig:
    """MRF2's image evidence: ``downscale`` of the cost images (1 = full resolution); ``threads``:
    the cameras' cost images are built by this many threads of the tracker's own (1, the default:
    one after another in the calling thread). Each image is built alone (OpenCV and numpy release
    the GIL for most of the work), so the same images either way. More threads spend the same CPU
    and shorten the wall time only where a core is free."""

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
    origin lies rather than by their errors, so a camera seeing the tape at a grazing angle pulls
    the DLT points most (docs/decisions/0001-ray-points-for-observed-dots.md).
    False: the candidate's point. Two checks of an observed dot's label against the other
    observed dots alone (beyond the paper; 0 = off; the dot is marked and its frame flagged, see
    :mod:`spinemocap.track.quality`): ``observed_lattice_limit`` x the smallest dot spacing, the
    farthest an observed dot may lie from where the other observed dots' lattice puts it
    (:func:`spinemocap.track.lattice.off_observed_lattice`; a dot matched to its row
    neighbour's point lies a dot spacing off; the worst dot found off is set aside and the rest
    judged again without it); ``detached_max_dots``, the largest group of
    observed dots joined to the rest of the observed tape by no solid edge whose labels are
    doubted (:func:`spinemocap.track.lattice.detached_groups`: fewer dots than two whole rows
    fit a column or row beside their own as well); ``crowded_limit`` x the smallest dot spacing,
    the nearest another labelled dot (observed or inferred) may lie to an observed one
    (:func:`spinemocap.track.lattice.crowded_labels`: labels a column off beside the model's
    own dot there, where a staggered tape's rows fit a column aside as well as their own);
    the inferred dots beside such a dot are marked with it."""

    observe_radius_mm: float = 7.0
    min_views: int = 2
    use_triangulated: bool = True
    lattice_check: bool = True
    lattice_limit: float = 0.3
    lattice_sigma_mm: float = 20.0
    unanchored_rows: int = 2
    anchor_ends: bool = True
    ray_points: bool = True
    observed_lattice_limit: float = 0.5
    detached_max_dots: int = 4
    crowded_limit: float = 0.5


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
    two rows (4 rows with the last 4 of 13 hidden), and a narrower search would leave every label
    off by the rows it cannot reach; ``follow_hidden_rows``: after
    a full re-solve, unobserved rows beyond the observed ones move with their observed tape
    neighbours from the prediction instead of the re-solve's mean-stretch placement (a dot so
    moved more than half a dot spacing from the re-solve's place is marked ``dot_unanchored``);
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
    def nominal_unchecked(cls) -> "TrackerConfig":
        """The tracker on the roll's nominal dot spacing and the fixed th1 gate, without the
        label-continuity, lattice and unanchored-end checks (the realism benchmark's peer)."""
        config = cls()
        return dataclasses.replace(
            config, stretch=dataclasses.replace(config.stretch, adaptive=False),
            rig=dataclasses.replace(config.rig, adaptive_gate=False),
            status=dataclasses.replace(config.status, lattice_check=False, unanchored_rows=0, anchor_ends=False,
                                      observed_lattice_limit=0.0, detached_max_dots=0, crowded_limit=0.0),
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
