"""The tracker pipeline: per-view dots -> candidates -> edges -> LP -> MRF1 -> MRF2 -> labelled dots.

:class:`FrameTracker` runs the paper's per-frame pipeline (sections 3-3.3) and assigns each dot a
status: ``observed`` when a candidate point triangulated from >= 2 views lies near the model dot
(its position is then that point), ``inferred`` when the model placed it without such a point,
``missing`` when the frame has no solution. :func:`run_tracking` drives it over a sequence, in
``paper`` mode (every frame independent, as the paper) or ``sequence`` mode (identities and
states carried from frame to frame, see :mod:`spinemocap.track.sequence`).
:func:`track_capture` is the entry point for a capture folder (``spinemocap track``, batch).
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..camera import Rig
from ..capture import Capture, read_image
from ..fileio import InputError
from ..markers import MarkerTable
from ..tape import TapeSpec
from .candidates import build_candidates
from .config import TrackerConfig
from .edges import build_edges
from .evidence import build_evidence
from .lp import select_edges
from .mrf1 import fit_mrf1
from .mrf2 import TemplateEvidenceScore, refine_mrf2
from .template import tape_frames
from .types import CandidateCloud, FeasibleSet, ViewDots

log = logging.getLogger(__name__)

STAGES = ("detect", "candidates", "edges", "lp", "mrf1", "mrf2", "status")
MODES = ("sequence", "paper")


class TrackingWarning(UserWarning):
    """A frame could not be solved (its dots are reported missing)."""


@dataclass
class FrameResult:
    """One frame's labelled dots, in tape label order: ``positions`` (D, 3) mm (NaN = missing),
    ``status`` (D,) str, ``n_views`` (D,) int, ``residual`` (D,) px RMS reprojection error
    (NaN for inferred/missing); ``stage_ms`` per stage; ``route``: ``full`` (LP + MRFs),
    ``carried`` (sequence mode: the previous solution explained the frame), ``failed``."""

    positions: np.ndarray
    status: np.ndarray
    n_views: np.ndarray
    residual: np.ndarray
    stage_ms: dict[str, float] = field(default_factory=dict)
    route: str = "full"
    lp_status: str = ""
    note: str = ""

    @property
    def solved(self) -> bool:
        return self.route != "failed"

    @classmethod
    def missing(cls, n_dots: int, stage_ms: dict, note: str) -> "FrameResult":
        return cls(np.full((n_dots, 3), np.nan), np.full(n_dots, "missing", dtype=object),
                   np.zeros(n_dots, np.int64), np.full(n_dots, np.nan), stage_ms, "failed", "", note)


class _Timer:
    """Accumulates wall time per stage (ms)."""

    def __init__(self, into: dict[str, float]):
        self.into = into

    def __call__(self, stage: str):
        timer = self

        class _Ctx:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.into[stage] = timer.into.get(stage, 0.0) + 1000 * (time.perf_counter() - self.t0)

        return _Ctx()


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
                 up: Sequence[float] = (0.0, 0.0, 1.0)):
        self.rig, self.tape = rig, tape
        self.graph = tape.graph
        self.config = config or TrackerConfig()
        self.up = np.asarray(up, float) / np.linalg.norm(up)
        self.rng = np.random.default_rng(self.config.seed)

    @property
    def n_dots(self) -> int:
        return self.graph.n_dots

    # ------------------------------------------------------------------ stages
    def candidates(self, views: Sequence[ViewDots]) -> CandidateCloud:
        return build_candidates(self.rig, views, self.config.candidates)

    def feasible_set(self, cloud: CandidateCloud, timer: _Timer) -> FeasibleSet | None:
        with timer("edges"):
            edge_cloud = build_edges(cloud, self.tape, self.config.edges)
        with timer("lp"):
            return select_edges(cloud, edge_cloud, self.tape, self.config.lp)

    def evidence(self, views: Sequence[ViewDots]) -> list | None:
        """MRF2's per-camera cost images (None when no view has an image)."""
        if not any(v.image is not None for v in views):
            return None
        return [build_evidence(v.image, v.mask, downscale=self.config.evidence.downscale)
                if v.image is not None else None for v in views]

    def refine(self, positions: np.ndarray, views: Sequence[ViewDots],
               feasible_points: np.ndarray | None = None, evidence: list | None = None) -> np.ndarray:
        """MRF2 on the camera images; returns ``positions`` unchanged when no view has an image."""
        evidence = evidence if evidence is not None else self.evidence(views)
        if evidence is None:
            return positions
        result = refine_mrf2(positions, self.graph, self.rig, evidence, self.config.mrf2,
                             rng=self.rng, feasible_points=feasible_points)
        return result.positions

    def assign_status(self, model: np.ndarray, cloud: CandidateCloud) -> FrameResult:
        """Observed where a >= min_views candidate lies within the radius, else inferred."""
        cfg = self.config.status
        usable = np.nonzero(cloud.n_views >= cfg.min_views)[0] if len(cloud) else np.zeros(0, np.int64)
        match = match_points(model, cloud.points[usable] if len(usable) else np.zeros((0, 3)),
                             cfg.observe_radius_mm)
        seen = match >= 0
        src = usable[match[seen]]
        positions = model.copy()
        if cfg.use_triangulated:
            positions[seen] = cloud.points[src]
            thickness = self.graph.spec.thickness_mm
            if thickness and np.isfinite(model).all():
                # triangulated points lie on the tape's top surface (the holes' rims), MRF2 reports
                # the skin underneath: move them in by the same tape thickness
                positions[seen] -= thickness * tape_frames(model, self.graph)[0][seen]
        status = np.where(seen, "observed", "inferred").astype(object)
        status[~np.isfinite(positions).all(axis=1)] = "missing"
        n_views = np.zeros(self.n_dots, np.int64)
        n_views[seen] = cloud.n_views[src]
        residual = np.full(self.n_dots, np.nan)
        residual[seen] = cloud.residual[src]
        return FrameResult(positions, status, n_views, residual)

    # ------------------------------------------------------------------ whole frame
    def solve(self, views: Sequence[ViewDots], previous: np.ndarray | None = None,
              cloud: CandidateCloud | None = None, stage_ms: dict | None = None) -> FrameResult:
        """The paper's pipeline on one frame. ``previous`` (D, 3): last frame's dots (NaN rows
        allowed), which carries orientation/identity into MRF1 (sequence mode); without it the
        capture's ``up`` direction orients the tape (row 1 lowest)."""
        stage_ms = {} if stage_ms is None else stage_ms
        timer = _Timer(stage_ms)
        if cloud is None:
            with timer("candidates"):
                cloud = self.candidates(views)
        feasible = self.feasible_set(cloud, timer)
        if feasible is None or len(feasible) < 4:
            return FrameResult.missing(self.n_dots, stage_ms, "no tape-like edge set")
        with timer("mrf1"):
            evidence = self.evidence(views)
            # the images break the two-row offset tie of a partial feasible set
            score = TemplateEvidenceScore(self.rig, evidence, self.graph) if evidence is not None else None
            try:
                mrf1 = fit_mrf1(feasible, self.graph, self.config.mrf1, up=self.up, previous=previous,
                                rng=self.rng, template_score=score)
            except ValueError as exc:
                return FrameResult.missing(self.n_dots, stage_ms, f"MRF1 failed: {exc}")
        with timer("mrf2"):
            model = self.refine(mrf1.positions, views, feasible.points, evidence=evidence)
        with timer("status"):
            result = self.assign_status(model, cloud)
        result.stage_ms, result.lp_status = stage_ms, feasible.status
        return result


# ---------------------------------------------------------------------- dot detection
DotDetector = Callable[[int, list[np.ndarray], list[np.ndarray] | None], list[ViewDots]]


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def make_detector(name: str) -> DotDetector:
    """A function ``(frame, images, masks) -> [ViewDots per camera]``.

    ``net`` / ``classical``: :class:`spinemocap.detect.Detector` (tape mask + dots from the image);
    ``mask``: dots found inside given tape masks (synthetic captures ship exact masks; this
    isolates the tracker from tape-segmentation errors)."""
    if name == "mask":
        from ..detect.blobs import find_dots

        def detect_in_masks(frame, images, masks):
            if masks is None:
                raise InputError(None, "detector 'mask' needs tape masks (synthetic captures have masks/)")
            out = []
            for c, (image, mask) in enumerate(zip(images, masks)):
                uv, conf = find_dots(image, mask)
                out.append(ViewDots(c, uv, conf, mask=mask, image=_grey(image)))
            return out

        return detect_in_masks
    if name in ("net", "classical"):
        try:
            from ..detect import Detector
        except ImportError as exc:
            raise InputError(None, f"detector {name!r} is not available in this installation ({exc})") from exc
        detector = Detector(name=name)

        def detect_images(frame, images, masks):
            out = []
            for c, image in enumerate(images):
                dots = detector.detect(image, camera=c)
                if dots.image is None:
                    dots.image = _grey(image)
                out.append(dots)
            return out

        return detect_images
    raise InputError(None, f"unknown detector {name!r} (choose net, classical or mask)")


# ---------------------------------------------------------------------- sequences
@dataclass
class TrackResult:
    """A tracked sequence: the marker table plus per-frame diagnostics."""

    table: MarkerTable
    frames: list[FrameResult]

    def stage_ms(self) -> dict[str, float]:
        """Mean time per stage per frame (ms), over all frames."""
        n = max(len(self.frames), 1)
        return {s: sum(f.stage_ms.get(s, 0.0) for f in self.frames) / n for s in STAGES}

    def routes(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.frames:
            out[f.route] = out.get(f.route, 0) + 1
        return out


def run_tracking(
    views_per_frame: Iterable[tuple[int, list[ViewDots], float]],
    rig: Rig,
    tape: TapeSpec,
    fps: float,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    progress: bool = True,
    n_frames: int | None = None,
    meta: dict | None = None,
) -> TrackResult:
    """Track a sequence. ``views_per_frame`` yields ``(frame, views, detect_ms)``.

    Returns the table (frames numbered as yielded) and the per-frame results. A frame without a
    solution gives ``missing`` rows and a :class:`TrackingWarning`, never an exception."""
    from tqdm import tqdm

    from .sequence import SequenceTracker, fill_and_smooth

    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; choose from {MODES}")
    config = config or TrackerConfig()
    tracker = FrameTracker(rig, tape, config, up)
    carry = SequenceTracker(tracker) if mode == "sequence" else None
    results, frame_ids = [], []
    bar = tqdm(views_per_frame, total=n_frames, desc=f"tracking ({mode})", unit="frame", disable=not progress)
    for frame, views, detect_ms in bar:
        stage_ms = {"detect": detect_ms}
        try:
            result = carry.step(views, stage_ms) if carry else tracker.solve(views, stage_ms=stage_ms)
        except InputError:
            raise
        except Exception as exc:  # one unsolvable frame must not end the sequence: report it missing
            log.debug("frame %d failed", frame, exc_info=True)
            result = FrameResult.missing(tracker.n_dots, stage_ms, f"{type(exc).__name__}: {exc}")
        if not result.solved:
            warnings.warn(f"frame {frame}: tape not found ({result.note}); dots reported missing",
                          TrackingWarning, stacklevel=2)
        results.append(result)
        frame_ids.append(frame)
    positions = np.stack([r.positions for r in results]) if results else np.zeros((0, tracker.n_dots, 3))
    status = np.stack([r.status for r in results]) if results else np.zeros((0, tracker.n_dots), object)
    n_views = np.stack([r.n_views for r in results]) if results else np.zeros((0, tracker.n_dots), int)
    residual = np.stack([r.residual for r in results]) if results else np.zeros((0, tracker.n_dots))
    if carry is not None and len(results):
        positions, status = fill_and_smooth(positions, status, config.sequence)
    first = frame_ids[0] if frame_ids else 0
    if frame_ids and frame_ids != list(range(first, first + len(frame_ids))):
        raise ValueError("frames must be consecutive")
    table = MarkerTable.from_arrays(tape.labels, positions, fps, status=status, n_views=n_views,
                                    residual=residual, first_frame=first,
                                    meta={"mode": mode, **(meta or {})})
    return TrackResult(table, results)


def parse_frames(spec: str | None, n_frames: int, source: str = "--frames") -> range:
    """``A:B`` (Python slice, B exclusive, either side optional) -> frame range within the capture."""
    if not spec:
        return range(n_frames)
    try:
        a, _, b = spec.partition(":")
        start = int(a) if a else 0
        stop = int(b) if b else n_frames
    except ValueError:
        raise InputError(source, f"frame range {spec!r} is not of the form A:B") from None
    start, stop = max(start, 0), min(stop, n_frames)
    if start >= stop:
        raise InputError(source, f"frame range {spec!r} selects no frame of the {n_frames} in the capture")
    return range(start, stop)


def _capture_views(capture: Capture, frames: range, detect: DotDetector):
    source = capture.frame_source()
    mask_dir = capture.root / "masks"
    for frame in frames:
        t0 = time.perf_counter()
        images = source.read(frame)
        masks = None
        if mask_dir.is_dir():
            masks = [read_image(mask_dir / cam / f"{frame:06d}.png")[:, :, 0] > 127 for cam in capture.camera_names]
        views = detect(frame, images, masks)
        yield frame, views, 1000 * (time.perf_counter() - t0)


def track_capture(
    capture_dir: str | Path,
    out_dir: str | Path,
    mode: str = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | range | None = None,
    progress: bool = True,
) -> MarkerTable:
    """Track a capture folder and write ``out_dir/markers.csv`` plus ``.trc`` and ``.c3d``.

    ``frames``: ``"A:B"`` or a range (default: all). Returns the marker table (mm, world Z up)."""
    capture = Capture.open(capture_dir)
    if mode not in MODES:
        raise InputError(capture_dir, f"unknown tracking mode {mode!r}; choose from {MODES}")
    frame_range = frames if isinstance(frames, range) else parse_frames(frames, capture.n_frames)
    detect = make_detector(detector)
    result = run_tracking(
        _capture_views(capture, frame_range, detect), capture.rig, capture.tape, capture.fps,
        up=capture.up, mode=mode, config=config, progress=progress, n_frames=len(frame_range),
        meta={"subject": capture.subject.get("id", ""), "source": str(capture.root), "detector": detector},
    )
    write_markers(result.table, out_dir)
    return result.table


def write_markers(table: MarkerTable, out_dir: str | Path) -> list[Path]:
    """``markers.csv``, ``markers.trc`` and ``markers.c3d`` in ``out_dir`` (atomic writes)."""
    import exporters

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for ext in ("csv", "trc", "c3d"):
        path = out / f"markers.{ext}"
        exporters.write(table, path)
        paths.append(path)
    return paths
