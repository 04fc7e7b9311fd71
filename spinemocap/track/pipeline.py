"""The per-frame tracker: per-view dots -> candidates -> edges -> LP -> MRF1 -> MRF2 -> labelled dots.

:class:`FrameTracker` runs the paper's per-frame pipeline (sections 3-3.3) and assigns each dot a
status: ``observed`` when a candidate point triangulated from >= 2 views lies near the model dot
(its position is then that point), ``inferred`` when the model placed it without such a point,
``missing`` when the frame has no solution. Beyond the paper, every frame is solved with the tape
as laid on the body (its dot spacing measured from the frame's own points, :mod:`.stretch`)
and a candidate gate that follows the rig's measured residuals (:mod:`.rig_check`), and the
result carries quality flags (:mod:`.quality`). The sequence tracker (:mod:`spinemocap.track.sequence`)
wraps it; running a whole capture (detector choice, frames, outputs, sequence vs paper mode) is the
application layer's :mod:`spinemocap.app.run`.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from ..camera import Rig
from ..geometry import triangulate_rays
from ..markers import INFERRED, MISSING, OBSERVED
from ..tape import TapeSpec
from ..timing import StageTimer
from ..views import ViewDots
from .ahead import FrameCandidates, stretch_points
from .candidates import build_candidates
from .config import TrackerConfig
from .continuity import row_centres
from .edges import build_edges
from .evidence import build_evidence
from .lattice import (
    affine_from_neighbours,
    beyond_known_rows,
    crowded_labels,
    detached_groups,
    off_lattice,
    off_observed_lattice,
    rows_beyond,
)
from .lp import select_edges
from .mrf1 import fit_mrf1
from .mrf2 import TemplateEvidenceScore, refine_mrf2
from .quality import implausible_pitches, stretch_plausible, unlabelled_dots, unobserved_ends_beside
from .rig_check import RigMonitor
from .stretch import StretchEstimate, StretchReading, read_stretch, row_stretch, stretched_spec
from .template import tape_frames
from .types import CandidateCloud, FeasibleSet, FrameRoute, LpStatus

STAGES = ("detect", "candidates", "edges", "lp", "mrf1", "mrf2", "status")


@dataclass
class FrameResult:
    """One frame's labelled dots, in tape label order: ``positions`` (D, 3) mm (NaN = missing),
    ``status`` (D,) str, ``n_views`` (D,) int, ``residual`` (D,) px RMS reprojection error
    (NaN for inferred/missing); ``stage_ms`` per stage; ``route``: ``full`` (LP + MRFs),
    ``carried`` (sequence mode: the previous solution explained the frame), ``failed``;
    ``lp_time_limited``: the LP behind the frame stopped at its time limit (see
    :attr:`FeasibleSet.time_limited`); ``flags``: quality flags (:mod:`spinemocap.track.quality`); ``stretch``: the dot spacing the
    frame was solved with (ratio to the roll's spec); ``gate_px``: the candidate gate used; ``relocated``: dots the lattice check moved (see
    :meth:`FrameTracker.relocate_off_lattice`); ``unanchored``: inferred dots far beyond the
    observed rows (see :meth:`FrameTracker.assign_status`); ``unsupported``: observed dots whose
    label the other observed dots do not bear out (see :meth:`FrameTracker.assign_status`);
    ``end_misplaced``: unobserved end rows beside an implausible row pitch (see
    :meth:`FrameTracker.add_quality`)."""

    positions: np.ndarray
    status: np.ndarray
    n_views: np.ndarray
    residual: np.ndarray
    stage_ms: dict[str, float] = field(default_factory=dict)
    route: FrameRoute = "full"
    lp_status: LpStatus = ""
    lp_time_limited: bool = False
    note: str = ""
    flags: list[str] = field(default_factory=list)
    stretch: StretchEstimate | None = None
    gate_px: float = float("nan")
    pixels: np.ndarray | None = None  # (D, C, 2) distorted px of the blobs of observed dots
    relocated: np.ndarray | None = None  # (D,) bool: moved back onto the tape's lattice (quality)
    extrapolated: np.ndarray | None = None  # (D,) bool: relocated, no candidate, beyond the rows of observed dots kept in place
    unanchored: np.ndarray | None = None  # (D,) bool: inferred, >= unanchored_rows beyond the observed rows
    unsupported: np.ndarray | None = None  # (D,) bool: observed, its label not borne out by the other observed dots
    end_misplaced: np.ndarray | None = None  # (D,) bool: in an unobserved end row beside an implausible row pitch

    @property
    def solved(self) -> bool:
        return self.route != "failed"

    def dot_flags(self) -> dict[str, np.ndarray]:
        """Per-dot quality flags (name -> (D,) bool), see :mod:`spinemocap.track.quality`."""
        out = {}
        if self.relocated is not None and self.relocated.any():
            out["dot_relocated"] = self.relocated
        if self.extrapolated is not None and self.extrapolated.any():
            out["dot_extrapolated"] = self.extrapolated
        if self.unanchored is not None and self.unanchored.any():
            out["dot_unanchored"] = self.unanchored
        if self.unsupported is not None and self.unsupported.any():
            out["dot_unsupported"] = self.unsupported
        if self.end_misplaced is not None and self.end_misplaced.any():
            out["dot_end_misplaced"] = self.end_misplaced
        return out

    @classmethod
    def missing(cls, n_dots: int, stage_ms: dict, note: str) -> "FrameResult":
        return cls(np.full((n_dots, 3), np.nan), np.full(n_dots, MISSING, dtype=object),
                   np.zeros(n_dots, np.int64), np.full(n_dots, np.nan), stage_ms, "failed", "", note=note)


def match_points(model: np.ndarray, points: np.ndarray, radius_mm: float) -> np.ndarray:
    """(D,) index of the candidate point assigned to each model dot (-1: none within radius).

    One-to-one (Hungarian) on the distances; pairs farther than ``radius_mm`` never match."""
    out = np.full(len(model), -1, dtype=np.int64)
    ok = np.isfinite(model).all(axis=1)
    if not len(points) or not ok.any():
        return out
    dist = np.linalg.norm(model[ok][:, None, :] - points[None, :, :], axis=2)
    big = 1e6
    rows, cols = linear_sum_assignment(np.where(dist < radius_mm, dist, big))
    good = dist[rows, cols] < radius_mm
    out[np.nonzero(ok)[0][rows[good]]] = cols[good]
    return out


class FrameTracker:
    """The per-frame pipeline for one rig and tape. Lengths mm, images px."""

    def __init__(self, rig: Rig, tape: TapeSpec, config: TrackerConfig | None = None,
                 up: npt.ArrayLike = (0.0, 0.0, 1.0)):
        self.rig, self.tape = rig, tape
        self.graph = tape.graph
        self.config = config or TrackerConfig()
        self.up = np.asarray(up, float) / np.linalg.norm(up)
        self.rng = np.random.default_rng(self.config.seed)
        self.monitor = RigMonitor(rig, self.config.candidates, self.config.rig)
        self.stretch = StretchEstimate.nominal()  # the last spacing measured on a frame
        self._pool: tuple[int, ThreadPoolExecutor] | None = None  # the evidence threads, started when first needed
        self.ahead_used = 0  # frames whose candidate stage was built ahead (:meth:`candidates`)

    @property
    def n_dots(self) -> int:
        return self.graph.n_dots

    # ------------------------------------------------------------------ stages
    def candidates(self, views: Sequence[ViewDots], ahead: FrameCandidates | None = None) -> CandidateCloud:
        """The candidate cloud with the rig-derived gate (the first frame probes the residuals
        with a loose gate first); each frame's well-supported points update the residuals.
        ``ahead``: the frame's candidate stage built ahead (:mod:`.ahead`), taken when it serves
        this frame's gate (counted in :attr:`ahead_used`), else the cloud is built here."""
        gate_ready = not self.config.rig.adaptive_gate or self.monitor.measured
        if ahead is not None and gate_ready and ahead.serves(self.monitor.gate_px()):
            self.ahead_used += 1
            if self.config.rig.adaptive_gate:
                self.monitor.add(ahead.residuals)
            return ahead.cloud
        if not gate_ready:
            self.monitor.probe(views)
        cloud = build_candidates(self.rig, views, self.monitor.candidate_config())
        if self.config.rig.adaptive_gate:
            self.monitor.update(views, cloud)
        return cloud

    def measure_stretch(self, cloud: CandidateCloud, reading: StretchReading | None = None) -> StretchEstimate:
        """The tape's dot spacing in this frame's points (>= 3-view points when there are enough,
        ghosts rarely reach three views), falling back to the last measured one. ``reading``:
        the same points' reading made ahead (:class:`~.ahead.FrameCandidates`)."""
        if reading is None:
            reading = read_stretch(stretch_points(cloud, self.config.stretch.min_points), self.tape, self.config.stretch)
        estimate = reading.estimate(self.stretch)
        if estimate.source == "data":
            self.stretch = estimate
        return estimate

    def frame_tape(self, stretch: StretchEstimate) -> TapeSpec:
        """The tape as laid on the body for a spacing estimate (labels as the spec's)."""
        return stretched_spec(self.tape, stretch)

    def feasible_set(self, cloud: CandidateCloud, timer: StageTimer, tape: TapeSpec | None = None) -> FeasibleSet | None:
        tape = tape or self.tape
        with timer("edges"):
            edge_cloud = build_edges(cloud, tape, self.config.edges)
        with timer("lp"):
            return select_edges(cloud, edge_cloud, tape, self.config.lp)

    def evidence(self, views: Sequence[ViewDots]) -> list | None:
        """MRF2's per-camera cost images (None when no view has an image). A view that holds its
        colour image is read as it is: the evidence converts only its window to grey (the same
        pixels), not the whole frame."""
        images = [v.held_image for v in views]
        jobs = [(image, v.mask) for image, v in zip(images, views) if image is not None]
        if not jobs:
            return None
        build = functools.partial(build_evidence, downscale=self.config.evidence.downscale)
        threads = self.config.evidence.threads
        if threads > 1 and len(jobs) > 1:
            # while the tracker works the camera threads wait for it: a core may be free
            built = iter(list(self._evidence_pool(threads).map(lambda job: build(*job), jobs)))
        else:
            built = iter([build(*job) for job in jobs])
        return [next(built) if image is not None else None for image in images]

    def _evidence_pool(self, threads: int) -> ThreadPoolExecutor:
        """The tracker's evidence threads (shut down when the tracker goes)."""
        if self._pool is None or self._pool[0] != threads:
            if self._pool is not None:
                self._pool[1].shutdown(wait=False)
            pool = ThreadPoolExecutor(threads, thread_name_prefix="evidence")
            weakref.finalize(self, pool.shutdown, wait=False)
            self._pool = (threads, pool)
        return self._pool[1]

    def refine(self, positions: np.ndarray, views: Sequence[ViewDots],
               feasible_points: np.ndarray | None = None, evidence: list | None = None,
               tape: TapeSpec | None = None) -> np.ndarray:
        """MRF2 on the camera images (target lengths of ``tape``, default the spec); returns
        ``positions`` unchanged when no view has an image."""
        evidence = evidence if evidence is not None else self.evidence(views)
        if evidence is None:
            return positions
        result = refine_mrf2(positions, (tape or self.tape).graph, self.rig, evidence, self.config.mrf2,
                             rng=self.rng, feasible_points=feasible_points)
        return result.positions

    def assign_status(self, model: np.ndarray, cloud: CandidateCloud) -> FrameResult:
        """Observed where a >= min_views candidate lies within the radius, else inferred; then
        the lattice check (``status.lattice_check``): dots off their neighbours' lattice are
        moved to it (:meth:`relocate_off_lattice`). Inferred dots ``status.unanchored_rows`` or
        more rows beyond the outermost observed rows (the tape's end seen by no camera pair, so
        placed and labelled by the model's extrapolation alone) are marked ``unanchored``, after
        :meth:`anchor_tape_ends` (``status.anchor_ends``) looked for their points. Observed dots
        off the other observed dots' lattice or in a small group detached from them are marked
        ``unsupported`` (:meth:`_unsupported`)."""
        cfg = self.config.status
        usable = np.nonzero(cloud.n_views >= cfg.min_views)[0] if len(cloud) else np.zeros(0, np.int64)
        match = match_points(model, cloud.points[usable] if len(usable) else np.zeros((0, 3)),
                             cfg.observe_radius_mm)
        source = np.full(self.n_dots, -1, np.int64)
        source[match >= 0] = usable[match[match >= 0]]
        normals: list[np.ndarray] = []  # the model's tape normals, made once (the same model each time)
        positions = self._placed(model, cloud, source, normals=normals)
        relocated = np.zeros(self.n_dots, bool)
        if cfg.lattice_check:
            source, relocated = self.relocate_off_lattice(positions, model, cloud, source)
            positions = self._placed(model, cloud, source, np.where(relocated[:, None], positions, model), normals)
        if cfg.anchor_ends:
            source, anchored = self.anchor_tape_ends(positions, cloud, source)
            if anchored.any():
                positions = self._placed(model, cloud, source, positions, normals)
                relocated |= anchored
        seen = source >= 0
        status = np.where(seen, OBSERVED, INFERRED).astype(object)
        status[~np.isfinite(positions).all(axis=1)] = MISSING
        n_views = np.zeros(self.n_dots, np.int64)
        n_views[seen] = cloud.n_views[source[seen]]
        residual = np.full(self.n_dots, np.nan)
        residual[seen] = cloud.residual[source[seen]]
        pixels = np.full((self.n_dots, len(self.rig), 2), np.nan)
        if cloud.pixels is not None:
            pixels[seen] = cloud.pixels[source[seen]]
        result = FrameResult(positions, status, n_views, residual, pixels=pixels, relocated=relocated,
                             extrapolated=relocated & ~seen & beyond_known_rows(relocated | ~seen, positions, self.graph),
                             unanchored=self._unanchored(status), unsupported=self._unsupported(positions, status))
        result.flags.extend(result.dot_flags())
        self.mark_crowded(result)
        return result

    def mark_crowded(self, result: FrameResult, positions: np.ndarray | None = None,
                     status: np.ndarray | None = None) -> None:
        """Mark unsupported (``result.unsupported``, flag ``dot_unsupported``) every dot of a row
        where an observed dot lies within ``status.crowded_limit`` x the smallest dot spacing of
        another labelled dot (:func:`.lattice.crowded_labels`), judged on ``positions`` (D, 3) mm
        and ``status`` (D,) as they are reported (default ``result``'s own: a sequence fills and
        smooths its unobserved dots after each frame's solve)."""
        limit = self.config.status.crowded_limit * self.graph.min_spacing_mm
        positions = result.positions if positions is None else positions
        observed = (result.status if status is None else status) == OBSERVED
        crowded = crowded_labels(positions, observed, self.graph.row, limit)
        if not crowded.any():
            return
        result.unsupported = crowded if result.unsupported is None else result.unsupported | crowded
        if "dot_unsupported" not in result.flags:
            result.flags.append("dot_unsupported")

    def anchor_tape_ends(self, positions: np.ndarray, cloud: CandidateCloud,
                         source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inferred dots just beyond the outermost observed rows (``positions`` (D, 3) mm, candidate
        index ``source`` (D,), -1 = none) take the unclaimed candidate point of >= 3 cameras
        nearest to where the observed dots' lattice extrapolates them one row out
        (:func:`.lattice.affine_from_neighbours`, weights of ``status.lattice_sigma_mm``), when it
        lies within ``status.observe_radius_mm``; row by row outward while dots are found.
        Returns the new ``source`` and the (D,) mask of dots so anchored.

        The model (MRF1/MRF2) can leave a tape end it saw no points for 8-20 mm off, beyond the
        observe radius of the points that are there (under strong taping tension or a 3 px rig); one row out the lattice of the observed dots
        lands 3-5 mm from the truth (see :mod:`.lattice`), and >= 3-camera points are rarely ghosts."""
        cfg = self.config.status
        source, positions = source.copy(), positions.copy()
        anchored = np.zeros(self.n_dots, bool)
        finite = np.isfinite(positions).all(axis=1)
        strong = set(np.flatnonzero(cloud.n_views >= 3).tolist()) if len(cloud) else set()
        free = strong - set(source[source >= 0].tolist())
        while free:
            observed = source >= 0
            front = np.flatnonzero(finite & ~observed & (rows_beyond(observed, self.graph) == 1))
            if not len(front) or observed.sum() < 3:
                break
            predicted = affine_from_neighbours(self.graph.uv_mm, positions, observed, front, cfg.lattice_sigma_mm)
            found = False
            for d, p in zip(front, predicted):
                if not free or not np.isfinite(p).all():
                    continue
                options = np.fromiter(free, np.int64)
                dist = np.linalg.norm(cloud.points[options] - p, axis=1)
                if dist.min() < cfg.observe_radius_mm:
                    source[d] = options[int(np.argmin(dist))]
                    positions[d] = cloud.points[source[d]]  # the next row out extrapolates from it
                    free.discard(int(source[d]))
                    anchored[d] = found = True
            if not found:
                break
        return source, anchored

    def _unanchored(self, status: np.ndarray) -> np.ndarray:
        """(D,) bool: inferred dots >= ``status.unanchored_rows`` rows beyond the outermost rows
        holding an observed dot (none when the setting is 0)."""
        rows = self.config.status.unanchored_rows
        if rows <= 0:
            return np.zeros(len(status), bool)
        return (status == INFERRED) & (rows_beyond(status == OBSERVED, self.graph) >= rows)

    def _unsupported(self, positions: np.ndarray, status: np.ndarray) -> np.ndarray:
        """(D,) bool: observed dots whose label the other observed dots do not bear out: off
        their lattice (``status.observed_lattice_limit``) or in a small detached group
        (``status.detached_max_dots``), see :class:`~spinemocap.track.config.StatusConfig`;
        and the inferred dots joined to such a dot by a solid tape edge."""
        cfg = self.config.status
        observed = status == OBSERVED
        edges = self.graph.solid_edges
        out = detached_groups(observed, edges, cfg.detached_max_dots)
        if cfg.observed_lattice_limit > 0:
            limit = cfg.observed_lattice_limit * self.graph.min_spacing_mm
            out |= off_observed_lattice(self.graph.uv_mm, positions, observed, limit, cfg.lattice_sigma_mm)
        # the inferred dots beside such a dot were laid by the same model, around the same point
        beside = np.zeros_like(out)
        beside[edges[out[edges[:, 0]], 1]] = True
        beside[edges[out[edges[:, 1]], 0]] = True
        return out | (beside & (status == INFERRED))

    def _placed(self, model: np.ndarray, cloud: CandidateCloud, source: np.ndarray,
                fallback: np.ndarray | None = None, normals: list[np.ndarray] | None = None) -> np.ndarray:
        """(D, 3) mm: dots with a candidate (``source`` >= 0) at its triangulated point (its blobs'
        rays' point, ``status.ray_points``; moved in by the tape thickness, ``use_triangulated``),
        the others at ``fallback`` (default the model). ``normals``: a list holding the model's
        tape normals once made (empty: not yet)."""
        positions = (model if fallback is None else fallback).copy()
        seen = source >= 0
        if self.config.status.use_triangulated and seen.any():
            positions[seen] = self._ray_points(cloud, source[seen]) if self.config.status.ray_points else cloud.points[source[seen]]
            thickness = self.graph.spec.thickness_mm
            if thickness and np.isfinite(model).all():
                # triangulated points lie on the tape's top surface (the holes' rims), MRF2 reports
                # the skin underneath: move them in by the same tape thickness
                if normals is None:
                    normals = []
                if not normals:
                    normals.append(tape_frames(model, self.graph)[0])
                positions[seen] -= thickness * normals[0][seen]
        return positions

    def _ray_points(self, cloud: CandidateCloud, rows: np.ndarray) -> np.ndarray:
        """(N, 3) mm: the least-squares points of the rays of the candidates ``rows``' (N,) blobs
        (:func:`~spinemocap.geometry.triangulate_rays`, equal weights). A candidate without its
        blobs' pixels, or without a finite point, keeps its DLT point."""
        points = cloud.points[rows]
        if cloud.pixels is None:
            return points
        pixels = cloud.pixels[rows]  # (N, C, 2) distorted px, NaN where a camera is not used
        used = np.isfinite(pixels).all(axis=2)
        directions = np.zeros(pixels.shape[:2] + (3,))
        for c, camera in enumerate(self.rig):
            if used[:, c].any():
                directions[used[:, c], c] = camera.rays(pixels[used[:, c], c])[1]
        centers = np.array([camera.center for camera in self.rig])
        out = triangulate_rays(centers, directions, used.astype(float))
        keep = ~np.isfinite(out).all(axis=1)
        out[keep] = points[keep]
        return out

    def relocate_off_lattice(self, positions: np.ndarray, model: np.ndarray, cloud: CandidateCloud,
                             source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Dots (``positions`` (D, 3) mm, candidate index ``source`` (D,), -1 = none) farther
        than the lattice limit from their tape neighbours' prediction (:func:`.lattice.off_lattice`)
        take the nearest unclaimed candidate of >= min_views cameras within that limit of the
        prediction, else no candidate (inferred) and the prediction as position (``positions``
        is updated in place for those). Returns the new ``source`` and the (D,) relocated mask.

        A ghost point or a neighbour's point a few px from a dot's blobs matches within the
        observe radius when the model or the sequence's prediction strayed; the tape around it
        says where the dot must be (see :mod:`spinemocap.track.lattice`)."""
        cfg = self.config.status
        limit = cfg.lattice_limit * self.graph.min_spacing_mm
        outlier, prediction = off_lattice(self.graph.uv_mm, positions, limit, cfg.lattice_sigma_mm)
        outlier &= np.isfinite(prediction).all(axis=1)
        source = source.copy()
        if not outlier.any():
            return source, outlier
        claimed = set(source[(source >= 0) & ~outlier].tolist())
        free = np.array([i for i in np.flatnonzero(cloud.n_views >= cfg.min_views) if i not in claimed], np.int64) \
            if len(cloud) else np.zeros(0, np.int64)
        for d in np.flatnonzero(outlier):
            source[d] = -1
            # the model's own place (MRF2 on the images) when it agrees with the lattice
            consistent = np.isfinite(model[d]).all() and np.linalg.norm(model[d] - prediction[d]) < limit
            positions[d] = model[d] if consistent else prediction[d]
            if not len(free):
                continue
            dist = np.linalg.norm(cloud.points[free] - prediction[d], axis=1)
            best = int(np.argmin(dist))
            if dist[best] < limit:
                source[d] = free[best]
                free = np.delete(free, best)
        return source, outlier

    def add_quality(self, result: FrameResult, cloud: CandidateCloud, stretch: StretchEstimate) -> FrameResult:
        """Flags of a solved frame (see :mod:`spinemocap.track.quality`) and its spacing/gate. A
        solved row pitch outside the plausible range flags the frame ``stretch_implausible``,
        unless every such pitch lies beside an unobserved end row
        (:func:`~spinemocap.track.quality.unobserved_ends_beside`): then the dots of those end
        rows are marked ``end_misplaced`` (flag ``dot_end_misplaced``)."""
        result.stretch, result.gate_px = stretch, self.monitor.gate_px()
        if not result.solved:
            return result
        flags = result.flags
        if self.config.stretch.adaptive and stretch.source != "data":
            flags.append("stretch_carried")
        if result.lp_status == "relaxed":
            flags.append("lp_relaxed")
        if result.lp_time_limited:
            flags.append("lp_time_limited")
        if unlabelled_dots(result.positions, cloud.points, cloud.n_views, self.frame_tape(stretch).graph,
                           self.config.status.observe_radius_mm) >= 2:
            flags.append("unlabelled_dots")
        lo, hi = self.config.stretch.along_range
        tape_range = (lo * 0.85, hi * 1.15)
        measured = (stretch.along_min * 0.85, stretch.along_max * 1.15) if stretch.source == "data" else None
        pitches = self._solved_row_pitches(result.positions)
        if not stretch_plausible(row_stretch(result.positions, self.graph)[0], tape_range) or (
                measured is not None and not stretch_plausible(pitches, measured)):
            misplaced = unobserved_ends_beside(implausible_pitches(pitches, tape_range, measured),
                                               result.status == OBSERVED, self.graph)
            if misplaced is None:
                flags.append("stretch_implausible")  # a pitch that bears on the observed rows' labels
            else:
                result.end_misplaced = misplaced
                flags.append("dot_end_misplaced")
        return result

    def _solved_row_pitches(self, positions: np.ndarray) -> np.ndarray:
        """(n_rows - 1,) distance between neighbouring rows' centres over the spec's pitch: a
        row carrying its neighbour's label sits a fraction of a pitch from it (NaN: row missing)."""
        centres = row_centres(positions, self.graph)
        return np.linalg.norm(np.diff(centres, axis=0), axis=1) / self.tape.row_pitch_mm

    # ------------------------------------------------------------------ whole frame
    def solve(self, views: Sequence[ViewDots], previous: np.ndarray | None = None,
              cloud: CandidateCloud | None = None, stage_ms: dict | None = None,
              warm_start: bool = False, stretch: StretchEstimate | None = None) -> FrameResult:
        """The paper's pipeline on one frame. ``previous`` (D, 3): last frame's dots (NaN rows
        allowed), which carries orientation/identity into MRF1 (sequence mode); without it the
        capture's ``up`` direction orients the tape (row 1 lowest). ``warm_start``: MRF1 starts
        from ``previous`` whatever ``config.mrf1.warm_start`` says (the sequence tracker's option).
        ``stretch``: the frame's dot spacing (default: measured from the frame's points)."""
        stage_ms = {} if stage_ms is None else stage_ms
        timer = StageTimer(stage_ms)
        if cloud is None:
            with timer("candidates"):
                cloud = self.candidates(views)
        if stretch is None:
            with timer("candidates"):
                stretch = self.measure_stretch(cloud)
        result = self._solve(views, previous, cloud, stage_ms, warm_start, self.frame_tape(stretch))
        return self.add_quality(result, cloud, stretch)

    def _solve(self, views: Sequence[ViewDots], previous: np.ndarray | None, cloud: CandidateCloud,
               stage_ms: dict, warm_start: bool, tape: TapeSpec) -> FrameResult:
        timer = StageTimer(stage_ms)
        graph = tape.graph
        feasible = self.feasible_set(cloud, timer, tape)
        if feasible is None or len(feasible) < 4:
            return FrameResult.missing(self.n_dots, stage_ms, "no tape-like edge set")
        with timer("mrf1"):
            evidence = self.evidence(views)
            # the images break the two-row offset tie of a partial feasible set
            score = TemplateEvidenceScore(self.rig, evidence, graph) if evidence is not None else None
            try:
                mrf1_config = self.config.mrf1
                if warm_start:
                    mrf1_config = dataclasses.replace(mrf1_config, warm_start=True)
                mrf1 = fit_mrf1(feasible, graph, mrf1_config, up=self.up, previous=previous,
                                rng=self.rng, template_score=score)
            except ValueError as exc:
                return FrameResult.missing(self.n_dots, stage_ms, f"MRF1 failed: {exc}")
        with timer("mrf2"):
            model = self.refine(mrf1.positions, views, feasible.points, evidence=evidence, tape=tape)
        with timer("status"):
            result = self.assign_status(model, cloud)
        result.stage_ms, result.lp_status, result.lp_time_limited = stage_ms, feasible.status, feasible.time_limited
        return result
