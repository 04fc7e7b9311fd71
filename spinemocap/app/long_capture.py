"""Long captures tracked in chunks: memory bounded by the chunk, and a run that is stopped or
killed resumes from its last completed chunk with the output of an uninterrupted run.

The frames are tracked ``chunk_frames`` at a time. Every chunk after the first starts
``warmup_frames`` earlier, so that the tracker's identities, tape stretch and rig statistics have
settled when its own frames begin; only its own frames are kept. On the warm-up frames both the
previous chunk and this one have labels: this chunk's labels are checked against the previous
chunk's there (:func:`continuity`), relabelled when a shift or reversal of the rows fits them
(with a warning), and flagged (confidence 0) when nothing does.

Each completed chunk is saved as ``OUT/.chunks/chunk_NNNNN.npz`` (plain arrays, no pickle),
written atomically, beside ``plan.json`` naming what the chunks were tracked from (capture files'
sizes and times, frames, chunking, mode, detector, settings). A rerun with the same plan loads
the saved chunks and tracks the rest; a different plan starts over. When every chunk is done the
marker set is written (:func:`~spinemocap.app.results.write_markers`) and ``.chunks`` removed.
A chunk is a deterministic function of its frames, so the output does not depend on where a run
was interrupted. One chunk is held in memory at a time, while tracking and while writing the
marker files from the saved chunks, so memory does not grow with the capture's length.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm import tqdm

from ..capture import MANIFEST, Capture
from ..fileio import InputError, atomic_path, atomic_write, check_writable
from ..markers import MISSING, MISSING_CAMERAS, MarkerTable, missing_from_frames, missing_per_frame
from ..track.config import TrackerConfig
from ..track.quality import is_flagged
from .results import write_marker_parts
from .run import (
    NO_TAPE_SHARE,
    NoTapeFound,
    TrackingMode,
    detector_example,
    frame_ranges,
    select_frames,
    track_source,
)
from .streaming import SpeedOptions

log = logging.getLogger(__name__)

CHUNK_DIR = ".chunks"
PLAN = "plan.json"
#: arrays a saved chunk holds, (F, ...) over its own frames
CHUNK_ARRAYS = ("frames", "positions", "status", "n_views", "residual", "confidence", "stretch", "flags",
                "missing_cameras")
#: median distance (mm) between two chunks' positions of a label on their shared frames above
#: which the two labellings disagree (the tape's dots are >= ~15 mm apart)
CONTINUITY_TOLERANCE_MM = 5.0


@dataclass(frozen=True)
class Chunking:
    """How a long capture is cut: ``chunk_frames`` frames per chunk (>= 1) and ``warmup_frames``
    tracked before each chunk after the first and then dropped (>= 0).

    Raises:
        InputError: a chunk of fewer than 1 frame or a negative warm-up.
    """

    chunk_frames: int = 1000
    warmup_frames: int = 25

    def __post_init__(self) -> None:
        if self.chunk_frames < 1:
            raise InputError("chunk_frames", f"must be at least 1, got {self.chunk_frames}")
        if self.warmup_frames < 0:
            raise InputError("warmup_frames", f"must be at least 0, got {self.warmup_frames}")

    def spans(self, frames: range) -> list[tuple[int, int, int]]:
        """``(tracked_from, first, stop)`` per chunk: frames ``first..stop-1`` are kept, tracking
        starts at ``tracked_from`` (``first`` minus the warm-up, not before the range)."""
        out = []
        for first in range(frames.start, frames.stop, self.chunk_frames):
            stop = min(first + self.chunk_frames, frames.stop)
            out.append((max(frames.start, first - self.warmup_frames) if first > frames.start else first, first, stop))
        return out


@dataclass
class ChunkedResult:
    """A capture tracked in chunks (its markers are in the output folder): how many frames, the
    marker statuses counted, the cameras missing in frames, and what the tracker could not vouch for."""

    n_frames: int = 0
    status_counts: dict[str, int] = field(default_factory=dict)
    missing_cameras: dict[str, list[int]] = field(default_factory=dict)
    flagged_frames: list[int] = field(default_factory=list)
    flags: dict[str, int] = field(default_factory=dict)
    relabelled_chunks: list[int] = field(default_factory=list)
    discontinuous_chunks: list[int] = field(default_factory=list)
    resumed_chunks: int = 0
    n_chunks: int = 0

    def summary(self) -> str:
        """A few lines for the end of ``spinemocap track``."""
        lines = [f"{self.n_chunks} chunks" + (f", {self.resumed_chunks} taken from an interrupted run"
                                              if self.resumed_chunks else "")]
        if self.relabelled_chunks:
            lines.append(f"labels of chunks {self.relabelled_chunks} re-aligned to the chunk before them")
        if self.discontinuous_chunks:
            lines.append(f"WARNING chunks {self.discontinuous_chunks}: labels do not continue the chunk before; "
                         "their frames are flagged (confidence 0)")
        for camera, frames in sorted(self.missing_cameras.items()):
            lines.append(f"camera {camera} had no image in {len(frames)} of {self.n_frames} frames "
                         f"({frame_ranges(frames)}); the other cameras were used there")
        if self.flagged_frames:
            kinds = ", ".join(f"{k} {v}" for k, v in sorted(self.flags.items()))
            lines.append(f"WARNING {len(self.flagged_frames)} of {self.n_frames} frames flagged (labels not "
                         f"vouched for: {kinds}); see the confidence column of markers.csv")
        else:
            lines.append(f"no frame flagged ({self.n_frames} frames)")
        return "\n".join(lines)


def track_in_chunks(
    capture_dir: str | Path,
    out_dir: str | Path,
    chunking: Chunking,
    mode: TrackingMode = "sequence",
    config: TrackerConfig | None = None,
    detector: str = "net",
    frames: str | Sequence[int] | None = None,
    progress: bool = True,
    speed: SpeedOptions | None = None,
) -> ChunkedResult:
    """Track a capture folder chunk by chunk into ``out_dir`` (see the module docstring): the
    same outputs as :func:`spinemocap.app.run.track_capture`, resumable after a stop or a kill.
    Memory does not grow with the capture's length: one chunk is held at a time, in tracking
    and in writing the marker files (:func:`~spinemocap.app.results.write_marker_parts`).

    Raises:
        InputError: a bad capture or frame selection, an output folder that cannot be written.
        NoTapeFound: the tape was not found in most frames (no markers are written).
    """
    capture = Capture.open(capture_dir)
    out = check_writable(out_dir)
    frame_range = select_frames(frames, capture.n_frames)
    config = config or TrackerConfig()
    plan = _plan(capture, frame_range, chunking, mode, detector, config)
    chunk_dir = _chunk_dir(out, plan)
    spans = chunking.spans(frame_range)
    result = ChunkedResult(n_frames=len(frame_range), n_chunks=len(spans))
    paths = [chunk_dir / f"chunk_{k:05d}.npz" for k in range(len(spans))]
    previous: dict[str, np.ndarray] | None = None
    bar = tqdm(total=len(frame_range), desc="long capture", unit="frame", disable=not progress)
    try:
        for k, (tracked_from, first, stop) in enumerate(spans):
            chunk = _load_chunk(paths[k])
            if chunk is not None:
                result.resumed_chunks += 1
            else:
                chunk = _track_chunk(capture, range(tracked_from, stop), first, mode, config, detector, speed)
                if previous is not None:
                    _continue_labels(k, chunk, previous, capture.tape.labels, result)
                _save_chunk(paths[k], {name: chunk[name] for name in CHUNK_ARRAYS})
            previous = {name: chunk[name] for name in CHUNK_ARRAYS}
            bar.update(stop - first)
    finally:
        bar.close()
    unsolved = _tally(paths, result)
    if unsolved > NO_TAPE_SHARE * len(frame_range):  # a lost tape is not a result: nothing written over one
        raise NoTapeFound(capture.root, f"no tape found in {unsolved} of {len(frame_range)} frames: check the "
                                        f"detector with `spinemocap detector run "
                                        f"{detector_example(capture, frame_range[0])}`")
    write_marker_parts(lambda: (_table(_saved_chunk(path), capture, result.missing_cameras) for path in paths),
                       len(frame_range), out)
    shutil.rmtree(chunk_dir, ignore_errors=True)
    return result


def _saved_chunk(path: Path) -> dict[str, np.ndarray]:
    chunk = _load_chunk(path)
    if chunk is None:
        raise InputError(path, "a saved chunk went missing or was damaged while the marker files were written; "
                               "run the same command again")
    return chunk


def _tally(paths: Sequence[Path], result: ChunkedResult) -> int:
    """Statuses, missing cameras, flagged frames and flags of the saved chunks into ``result``,
    one chunk at a time; returns the frames without a solution."""
    unsolved = 0
    missing: dict[str, list[int]] = {}
    for path in paths:
        chunk = _saved_chunk(path)
        for status, count in zip(*np.unique(chunk["status"], return_counts=True)):
            result.status_counts[str(status)] = result.status_counts.get(str(status), 0) + int(count)
        for camera, frames in missing_from_frames(chunk["frames"].tolist(), chunk["missing_cameras"].tolist()).items():
            missing.setdefault(camera, []).extend(frames)
        for frame, flags in zip(chunk["frames"], chunk["flags"]):
            names = [f for f in str(flags).split(";") if f]
            unsolved += "unsolved" in names
            if is_flagged(names) or "unsolved" in names:
                result.flagged_frames.append(int(frame))
            for name in set(names):
                result.flags[name] = result.flags.get(name, 0) + 1
    result.missing_cameras = missing
    return unsolved


def _plan(capture: Capture, frames: range, chunking: Chunking, mode: TrackingMode, detector: str,
          config: TrackerConfig) -> dict:
    """What the chunks are tracked from: a rerun reuses saved chunks only for the same plan."""
    files = sorted(p for p in capture.root.rglob("*") if p.is_file() and CHUNK_DIR not in p.parts)
    stamp = hashlib.sha256()
    for path in files:
        stat = path.stat()
        stamp.update(f"{path.relative_to(capture.root)}:{stat.st_size}:{stat.st_mtime_ns}\n".encode())
    return {"capture": str(capture.root.resolve()), "files": stamp.hexdigest(),
            "manifest": (capture.root / MANIFEST).read_text(), "frames": [frames.start, frames.stop],
            "chunking": asdict(chunking), "mode": mode, "detector": detector, "config": repr(config)}


def _chunk_dir(out: Path, plan: dict) -> Path:
    """``out/.chunks`` holding chunks of ``plan`` (saved chunks of another plan are removed)."""
    chunk_dir = out / CHUNK_DIR
    plan_path = chunk_dir / PLAN
    if plan_path.is_file():
        try:
            same = json.loads(plan_path.read_text()) == plan
        except ValueError:
            same = False
        if not same:
            log.info("%s: saved chunks are of another capture or other settings; starting over", chunk_dir)
            shutil.rmtree(chunk_dir)
    chunk_dir.mkdir(parents=True, exist_ok=True)
    if not plan_path.is_file():
        with atomic_write(plan_path) as handle:
            json.dump(plan, handle, indent=1)
    return chunk_dir


def _track_chunk(capture: Capture, tracked: range, first: int, mode: TrackingMode, config: TrackerConfig,
                 detector: str, speed: SpeedOptions | None) -> dict[str, np.ndarray]:
    """Track frames ``tracked`` and keep those from ``first`` on; the warm-up's positions are
    returned too (``warmup_positions``, for :func:`_continue_labels`)."""
    tracked_result = track_source(capture.frame_source(), capture.rig, capture.tape, capture.fps, tracked,
                                  up=capture.up, mode=mode, config=config, detector=detector, progress=False,
                                  speed=speed, mask_dir=capture.root / "masks",
                                  meta={"subject": capture.subject.get("id", ""), "source": str(capture.root)},
                                  weights=capture.detector_weights_path if detector == "net" else None)
    arrays = tracked_result.table.to_arrays()
    keep = slice(first - tracked.start, None)
    flags = np.array([";".join(f.flags if f.solved else [*f.flags, "unsolved"]) for f in tracked_result.frames])
    chunk = {name: getattr(arrays, name)[keep] for name in CHUNK_ARRAYS if hasattr(arrays, name)}
    chunk["status"] = chunk["status"].astype(str)
    chunk["flags"] = flags[keep]
    chunk["missing_cameras"] = np.array(missing_per_frame(tracked_result.missing_cameras(),
                                                          chunk["frames"].tolist()), dtype=str)
    chunk["warmup_frames"] = arrays.frames[: first - tracked.start]
    chunk["warmup_positions"] = arrays.positions[: first - tracked.start]
    return chunk


def continuity(previous: np.ndarray, warmup: np.ndarray, labels: Sequence[str]) -> tuple[np.ndarray | None, float]:
    """The relabelling of this chunk's dots that continues the previous chunk's labels on their
    shared frames: ``(index, median distance mm)`` where ``warmup[:, index]`` matches
    ``previous`` (-1: no partner), the identity first; ``(None, distance)`` when no candidate
    (the identity, row shifts of 1-2 rows, the tape reversed) is within
    :data:`CONTINUITY_TOLERANCE_MM`. ``previous``, ``warmup``: (W, D, 3) mm."""
    best: tuple[np.ndarray | None, float] = (None, float("inf"))
    for index in _relabellings(labels):
        moved = np.where(index[None, :, None] >= 0, warmup[:, np.maximum(index, 0)], np.nan)
        gaps = np.linalg.norm(moved - previous, axis=-1)
        gaps = gaps[np.isfinite(gaps)]
        if gaps.size == 0:
            continue
        distance = float(np.median(gaps))
        if distance < best[1]:
            best = (index, distance)
        if distance <= CONTINUITY_TOLERANCE_MM:
            return index, distance
    return None, best[1]


_LABEL = re.compile(r"^R(\d+)([A-Z])$")


def _relabellings(labels: Sequence[str]) -> list[np.ndarray]:
    """Index arrays for the identity, then each row shift of +-1 and +-2, then the reversed tape
    (rows and columns): ``index[d]`` = the dot of the new labelling that label ``d`` takes."""
    parsed = [_LABEL.match(label) for label in labels]
    if not all(parsed):
        return [np.arange(len(labels))]
    rows = [int(m.group(1)) for m in parsed if m]
    cols = [m.group(2) for m in parsed if m]
    where = {(r, c): d for d, (r, c) in enumerate(zip(rows, cols))}
    n_rows = max(rows)
    flip = {"L": "R", "R": "L"}

    def mapped(row_of, col_of) -> np.ndarray:
        return np.array([where.get((row_of(r), col_of(c)), -1) for r, c in zip(rows, cols)])

    out = [np.arange(len(labels))]
    for shift in (1, -1, 2, -2):
        out.append(mapped(lambda r, s=shift: r + s, lambda c: c))
    out.append(mapped(lambda r: n_rows + 1 - r, lambda c: flip.get(c, c)))
    return out


def _continue_labels(k: int, chunk: dict[str, np.ndarray], previous: dict[str, np.ndarray], labels: Sequence[str],
                     result: ChunkedResult) -> None:
    """Check chunk ``k``'s labels against the chunk before on their shared frames; relabel it
    when a shift or reversal fits, flag its frames (confidence 0, flag ``chunk_discontinuity``)
    when nothing does."""
    shared = np.isin(previous["frames"], chunk["warmup_frames"])
    if not shared.any():
        return
    warmup = chunk["warmup_positions"][np.isin(chunk["warmup_frames"], previous["frames"])]
    index, distance = continuity(previous["positions"][shared], warmup, labels)
    if index is not None and np.array_equal(index, np.arange(len(labels))):
        return
    if index is not None:
        log.warning("chunk %d: labels re-aligned to the chunk before (median %.1f mm on the shared frames)", k, distance)
        for name in ("positions", "status", "n_views", "residual", "confidence", "stretch"):
            values = chunk[name][:, np.maximum(index, 0)].copy()
            missing = index < 0
            if name == "status":
                values[:, missing] = MISSING
            elif name == "positions":
                values[:, missing] = np.nan
            else:
                values[:, missing] = 0 if name == "n_views" else np.nan
            chunk[name] = values
        result.relabelled_chunks.append(k)
        return
    log.warning("chunk %d: labels do not continue the chunk before (median %.1f mm apart); flagged", k, distance)
    chunk["confidence"] = np.zeros_like(chunk["confidence"])
    chunk["flags"] = np.array([f"{f};chunk_discontinuity".lstrip(";") for f in chunk["flags"]])
    result.discontinuous_chunks.append(k)


def _save_chunk(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez(handle, allow_pickle=False, **arrays)


def _load_chunk(path: Path) -> dict[str, np.ndarray] | None:
    """A saved chunk, or None when absent or unreadable (a rerun tracks it again)."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in CHUNK_ARRAYS}
    except (OSError, ValueError, KeyError) as exc:
        log.info("%s: unreadable saved chunk (%s); tracking it again", path, exc)
        return None


def _table(chunk: dict[str, np.ndarray], capture: Capture, missing: dict[str, list[int]]) -> MarkerTable:
    """A saved chunk's frames as a marker table (mm, world Z up); ``missing``: the whole
    capture's missing cameras (the marker files' headers hold them all)."""
    return MarkerTable.from_arrays(capture.tape.labels, chunk["positions"], capture.fps,
                                   status=chunk["status"].astype(object), n_views=chunk["n_views"],
                                   residual=chunk["residual"], first_frame=int(chunk["frames"][0]),
                                   confidence=chunk["confidence"], stretch=chunk["stretch"],
                                   meta={"subject": capture.subject.get("id", ""), "source": str(capture.root),
                                         MISSING_CAMERAS: missing})
