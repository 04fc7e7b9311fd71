"""Batch processing of a study: find every trial, get its markers, compute angles, write results.

Study layout (either)::

    ROOT/<subject>/<session or condition>/<trial>/capture.toml ...    (folders)
    manifest.csv with columns path[, subject, condition, trial, levels, c3d]  (paths relative to it)

Per trial, in ``OUT/<subject>/<condition>/<trial>/``:

- ``markers.csv`` -- the tracker's output (``--source tracked``; reused while newer than the
  capture's inputs);
- ``angles.csv`` -- per-frame angles (:mod:`spinemocap.analysis.angles`);
- ``segments.csv`` and ``shape.json`` -- segmental angles per frame and the tape midline at
  neutral, peak flexion and peak extension (:mod:`spinemocap.analysis.shape`), for the report;
- ``summary.json`` -- written last, atomically, like every file here: the trial's status (``ok``
  or ``failed`` with the reason), peaks, ranges, completeness and the reasons for NaN angles.

A trial is skipped when its ``summary.json`` says ``ok`` and is newer than every input (capture
manifest, rig, media or ground truth, level map, pelvis C3D); so an interrupted batch resumes
where it stopped, and a changed input is processed again. A failing trial is recorded with its
reason and never stops the others. Trials run on a local process pool (``workers``) or on a
Dask distributed cluster (``scheduler`` = ``tcp://HOST:PORT``), with a progress bar.

Interrupts: Ctrl-C (SIGINT; SIGTERM from ``spinemocap batch`` too) cancels the queued trials at
once, stops the running ones (a local worker gets SIGINT and abandons its trial, removing its
temporary files; on a Dask cluster the trial stops at its next frame through a distributed
Event), records every unfinished trial as ``interrupted`` in ``batch.log`` and ``batch.json``
and exits; a rerun resumes (finished trials are up to date). Local workers exit when the main
process dies (they watch their parent), so killing it leaves no orphans; a Dask cluster's
workers belong to the cluster, and the scheduler drops the dead client's queued trials.

Row-to-level maps, first found wins: the manifest's ``levels`` column, ``levels.toml`` in the
trial folder, a ``[levels]`` table in ``capture.toml``, ``levels.toml`` in the subject folder,
the batch-wide ``levels`` file, and for synthetic captures the ground truth's ``row_levels``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import time
import uuid
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Generator, Iterable, Iterator, Literal

import numpy as np
import pandas as pd
from tqdm import tqdm

from ..analysis.angles import AngleSettings, compute_angles
from ..analysis.frames import pelvis_frame_from_markers
from ..analysis.levels import LevelMap
from ..analysis.shape import key_frames, midline_profiles, segmental_angles
from ..capture import MANIFEST, Capture
from ..fileio import InputError, atomic_write, check_writable, clean_stale_temps, read_toml, strict_json
from ..markers import MarkerTable
from .c3d_inputs import read_pelvis_c3d
from .levels import find_level_map
from .results import TrackingStopped, results_complete
from .trial_summary import BatchResult, OpenSimStep, TrialAnalysis, TrialOutcome, TrialStatus, TrialSummary, ViewStep
from .worker_processes import exit_with_parent, join_or_kill

log = logging.getLogger("spinemocap.batch")

#: Where a trial's markers come from: tracked from its images, or the synthetic studio's ground truth.
MarkerSource = Literal["tracked", "groundtruth"]
SOURCES: tuple[MarkerSource, ...] = ("tracked", "groundtruth")
SUMMARY = "summary.json"
ANGLES = "angles.csv"
MARKERS = "markers.csv"
INTERRUPTED: TrialStatus = "interrupted"

OPENSIM_DIR = "opensim"  # spinemocap opensim's outputs per trial (run_batch(opensim=True))

SEGMENTS = "segments.csv"
SHAPE = "shape.json"


@dataclass
class Trial:
    """One trial of a study. ``problem`` is set when discovery already knows it cannot run."""

    subject: str
    condition: str
    trial: str
    capture_dir: str
    levels_file: str | None = None
    c3d_file: str | None = None
    problem: str | None = None

    @property
    def key(self) -> str:
        return "/".join(p for p in (self.subject, self.condition, self.trial) if p)


@dataclass
class TrialJob:
    """Everything a worker needs for one trial (plain data: it travels to other processes)."""

    trial: Trial
    out_dir: str
    source: MarkerSource = "tracked"
    levels_file: str | None = None
    settings: AngleSettings = field(default_factory=AngleSettings)
    force: bool = False
    detector: str = "net"
    stop_event: str | None = None  # name of a Dask distributed Event that asks the trial to stop

    opensim: bool = False  # also run spinemocap opensim into <trial out>/opensim
    view: bool = False  # also write the labelled videos and the 3D viewer into <trial out>/view

    def summary(self, status: TrialStatus, reason: str, **details: Any) -> TrialSummary:
        """This trial's summary with ``status`` and ``reason`` (``details``: the other
        :class:`TrialSummary` fields, e.g. ``analysis`` and ``elapsed_s``)."""
        t = self.trial
        return TrialSummary(key=t.key, subject=t.subject, condition=t.condition, trial=t.trial,
                            capture=t.capture_dir, source=self.source, status=status, reason=reason,
                            out_dir=self.out_dir, **details)

    def outcome(self, status: TrialStatus, reason: str) -> TrialOutcome:
        """A not-skipped outcome without analysis (failed before or while running, or interrupted)."""
        return TrialOutcome(self.summary(status, reason))


# ---------------------------------------------------------------------------------- discovery
def discover(root: str | os.PathLike) -> list[Trial]:
    """Trials under a study folder, or listed in a CSV manifest when ``root`` is a ``.csv``."""
    root = Path(root)
    if root.is_file() and root.suffix.lower() == ".csv":
        return _from_manifest(root)
    if not root.is_dir():
        raise InputError(root, "study folder not found")
    trials = []
    for manifest in sorted(root.rglob(MANIFEST)):
        parts = manifest.parent.relative_to(root).parts
        if any(p.startswith(".") for p in parts):
            continue
        trials.append(_trial_from_parts(parts, manifest.parent))
    # subject/session/trial folders without a capture are trials that cannot run: say so.
    captured = {Path(t.capture_dir) for t in trials}
    for folder in sorted(p for p in root.glob("*/*/*") if p.is_dir()):
        rel = folder.relative_to(root).parts
        if any(p.startswith(".") for p in rel) or folder in captured:
            continue
        if any(c in folder.parents or folder in c.parents for c in captured):
            continue
        trials.append(_trial_from_parts(rel, folder, problem=f"no {MANIFEST} in this trial folder (not a capture)"))
    if not trials:
        raise InputError(root, f"no captures found (no {MANIFEST} below this folder)")
    return trials


def _trial_from_parts(parts: tuple[str, ...], folder: Path, problem: str | None = None) -> Trial:
    subject = parts[0] if len(parts) >= 2 else ""
    condition = "/".join(parts[1:-1]) if len(parts) >= 3 else ""
    return Trial(subject, condition, parts[-1] if parts else folder.name, str(folder), problem=problem)


def _from_manifest(path: Path) -> list[Trial]:
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, ValueError, pd.errors.ParserError) as exc:
        raise InputError(path, f"cannot read the manifest ({exc})") from exc
    if "path" not in table.columns:
        raise InputError(path, f"manifest needs a 'path' column; it has {list(table.columns)}")
    trials = []
    for _, row in table.iterrows():
        folder = (path.parent / row["path"]).resolve()

        def get(name: str, row: pd.Series = row) -> str:
            return str(row.get(name, "") or "")

        trial = Trial(
            subject=get("subject"), condition=get("condition") or get("session"),
            trial=get("trial") or folder.name, capture_dir=str(folder),
            levels_file=str(path.parent / get("levels")) if get("levels") else None,
            c3d_file=str(path.parent / get("c3d")) if get("c3d") else None,
        )
        if not (folder / MANIFEST).is_file():
            trial.problem = f"no {MANIFEST} in {folder} (manifest {path.name})"
        trials.append(trial)
    if not trials:
        raise InputError(path, "the manifest lists no trials")
    return trials


# ---------------------------------------------------------------------------------- one trial
def process_trial(job: TrialJob) -> TrialOutcome:
    """Run one trial; never raises for bad data: returns its outcome, having written its
    ``summary.json`` (not when interrupted, nor when skipped as up to date)."""
    out = Path(job.out_dir)
    started = time.perf_counter()
    try:
        if job.trial.problem:
            raise InputError(job.trial.capture_dir, job.trial.problem)
        inputs = _input_files(job)
        cached = None if job.force else _up_to_date(out / SUMMARY, inputs)
        if cached is not None and (not job.opensim or cached.opensim is not None):
            return TrialOutcome(cached, skipped=True)
        with warnings.catch_warnings(record=True) as caught:  # into the summary and batch.log, not stderr
            warnings.simplefilter("always")
            analysed = _analyse(job, inputs)
        messages = tuple(dict.fromkeys(str(w.message) for w in caught))
        summary = replace(analysed, warnings=messages)
    except TrackingStopped:  # the batch is being interrupted: no summary, a rerun redoes the trial
        return job.outcome(INTERRUPTED, "interrupted (stopped while running)")
    except Exception as exc:  # one bad trial never stops the batch: record why it failed
        reason = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
        summary = job.summary("failed", reason)
    summary = replace(summary, elapsed_s=round(time.perf_counter() - started, 3))
    write_summary(summary)
    return TrialOutcome(summary)


def write_summary(summary: TrialSummary) -> None:
    """``summary.json`` in the trial's output folder, strict JSON (NaN and infinities as null),
    atomically."""
    with atomic_write(Path(summary.out_dir) / SUMMARY) as handle:
        handle.write(strict_json(summary.to_dict()))


def read_summary(path: Path) -> TrialSummary:
    """A trial's ``summary.json`` (its folder is the summary's ``out_dir``).

    Raises:
        InputError: unreadable, not JSON, or not a trial summary."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(path, f"unreadable trial summary ({exc})") from exc
    if not isinstance(data, dict):
        raise InputError(path, "not a trial summary (not a JSON object)")
    return TrialSummary.from_dict(data, path.parent)


def check_trial(job: TrialJob) -> str | None:
    """Why ``job`` cannot run, found before any trial is tracked: its capture (manifest, rig,
    tape, media), its row-to-level map and its pelvis C3D; None when all are in order."""
    try:
        if job.trial.problem:
            raise InputError(job.trial.capture_dir, job.trial.problem)
        capture = Capture.open(job.trial.capture_dir)
        if job.source == "tracked":
            if not _markers_reusable(job):  # to be tracked: every camera's media found, readable and paired
                source = capture.frame_source()
                close = getattr(source, "close", None)
                if close is not None:
                    close()
        elif not capture.has_groundtruth:
            raise InputError(capture.groundtruth_path, "no ground truth to take the markers from (`source='groundtruth'`)")
        _levels(job, capture)
        if job.trial.c3d_file and not Path(job.trial.c3d_file).is_file():
            raise InputError(job.trial.c3d_file, "pelvis C3D file not found")
    except InputError as exc:
        return str(exc)
    return None


def _analyse(job: TrialJob, inputs: list[Path]) -> TrialSummary:
    out = Path(job.out_dir)
    capture = Capture.open(job.trial.capture_dir)
    markers = _markers(job, capture, inputs)
    levels, levels_from = _levels(job, capture)
    pelvis = _pelvis_frames(job.trial.c3d_file, markers) if job.trial.c3d_file else None
    result = compute_angles(markers, capture.tape, levels, up=capture.up,
                            facing=capture.facing,
                            settings=job.settings, pelvis_frames=pelvis)
    with atomic_write(out / ANGLES) as handle:
        result.table.to_csv(handle, index=False, float_format="%.4f")
    write_shape(out, markers, capture, levels, job.settings, result.table)
    fps = markers.fps
    analysis = TrialAnalysis(
        n_frames=int(len(result.table)), fps=fps, duration_s=float(len(result.table) / fps),
        completeness_pct=100.0 * result.completeness, levels=levels.rows, levels_from=levels_from,
        lumbar_levels=(job.settings.lower, job.settings.thoracolumbar),
        pelvis_from="c3d" if pelvis is not None else "tape", notes=result.notes, stats=result.summary())
    return job.summary("ok", "", analysis=analysis,
                       opensim=_opensim(markers, capture, levels, out / OPENSIM_DIR) if job.opensim else None,
                       view=_view(capture, out) if job.view else None)


def _view(capture: Capture, out: Path) -> ViewStep:
    """``spinemocap view`` on the trial's tracked marker set (its output folder): labelled videos
    and the 3D viewer into ``out/view``, where the report links them. A trial without a tracked set
    or images keeps its results and records why."""
    from .viewer.layout import VIEWER_NAME, view_folder
    from .viewer.scene3d import write_viewer
    from .viewer.video import write_videos

    if not results_complete(out):
        return ViewStep("failed", "no tracked marker set in the trial's folder (ground-truth source?)")
    try:
        videos = write_videos(capture.root, out, view_folder(out), progress=False)
        write_viewer(capture.root, out, view_folder(out) / VIEWER_NAME)
    except InputError as exc:
        return ViewStep("failed", str(exc))
    return ViewStep("ok", frames=len(videos.frames), seconds=round(videos.seconds, 2))


def _opensim(markers: MarkerTable, capture: Capture, levels: LevelMap, out: Path) -> OpenSimStep:
    """spinemocap opensim on the trial's markers; a trial OpenSim cannot solve keeps its geometric
    angles and records why."""
    from ..opensim import run_opensim

    try:
        result = run_opensim(markers, capture.tape, levels, capture.up,
                             capture.subject.get("facing", (0.0, -1.0, 0.0)), out, source=str(capture.root))
    except InputError as exc:
        return OpenSimStep("failed", str(exc))
    s = result.summary
    return OpenSimStep("ok", marker_rms_mm=s.marker_rms_mm, marker_rms_mm_max=s.marker_rms_mm_max,
                       ms_per_frame=s.ms_per_frame, flagged_frames=len(s.flagged_frames),
                       driven_joints=tuple(s.driven_joints), out_dir=str(out))

def write_shape(out: Path, markers: MarkerTable, capture: Capture, levels: LevelMap, settings: AngleSettings,
                angles: pd.DataFrame) -> None:
    """The report's pictures of the spine: ``segments.csv`` (segmental angles per frame,
    :func:`shape.segmental_angles`) and ``shape.json`` (the tape midline at neutral, peak flexion
    and peak extension in the subject's axes, :func:`shape.midline_profiles`, with their frames)."""
    frames = key_frames(angles)
    with atomic_write(out / SEGMENTS) as handle:
        segmental_angles(markers, capture.tape, levels, settings).to_csv(handle, index=False, float_format="%.4f")
    profiles = midline_profiles(markers, capture.tape, frames, up=capture.up,
                                facing=capture.subject.get("facing", (0.0, -1.0, 0.0)), settings=settings)
    shape = {"frames": frames, "times_s": {k: float(angles["time"].iloc[f]) for k, f in frames.items()},
             "midline_mm": profiles}
    with atomic_write(out / SHAPE) as handle:
        handle.write(strict_json(shape, indent=None))


def _input_files(job: TrialJob) -> list[Path]:
    """Files whose modification makes a trial's results stale: the markers' inputs
    (:func:`_tracking_inputs`) and the analysis' (level maps, pelvis C3D)."""
    folder = Path(job.trial.capture_dir)
    files = _tracking_inputs(job)
    files += [Path(p) for p in (job.trial.levels_file, job.levels_file, job.trial.c3d_file) if p]
    files += [folder / "levels.toml", folder.parent.parent / "levels.toml"]
    return [p for p in files if p.is_file()]


def _tracking_inputs(job: TrialJob) -> list[Path]:
    """Files whose modification makes a trial's markers stale: its manifest and rig, and its
    media (each camera's video or images, inside the folder or not) or ground truth."""
    folder = Path(job.trial.capture_dir)
    files = [folder / MANIFEST]
    manifest = read_toml(folder / MANIFEST)
    files.append(folder / manifest.get("capture", {}).get("rig", "rig.toml"))
    if job.source == "groundtruth":
        files.append(folder / "groundtruth.npz")
    else:
        for media in ("images", "videos"):
            if (folder / media).is_dir():
                files += [p for p in (folder / media).rglob("*") if p.is_file()]
        for table in (manifest.get("camera") or {}).values():
            media_path = folder / table["media"] if isinstance(table, dict) and table.get("media") else None
            if media_path is not None and media_path.is_dir():
                files += [p for p in media_path.iterdir() if p.is_file()]
            elif media_path is not None:
                files.append(media_path)
    return [p for p in files if p.is_file()]


def _up_to_date(path: Path, inputs: Iterable[Path]) -> TrialSummary | None:
    """The trial's summary at ``path`` when it is ``ok`` and newer than every input; None when the
    trial is to be processed (no summary, an unreadable one, a failed trial, a changed input)."""
    if not path.is_file():
        return None
    try:
        summary = read_summary(path)
    except InputError:
        return None
    newest = max((p.stat().st_mtime for p in inputs), default=0.0)
    return summary if summary.ok and path.stat().st_mtime > newest else None


def _markers(job: TrialJob, capture: Capture, inputs: list[Path]) -> MarkerTable:
    if job.source == "groundtruth":
        return groundtruth_markers(capture)
    if job.source != "tracked":
        raise InputError(None, f"unknown marker source {job.source!r}; expected one of {SOURCES}")
    path = Path(job.out_dir) / MARKERS
    if not _markers_reusable(job):
        try:
            from ..app.run import track_capture
        except ImportError as exc:
            raise InputError(capture.root, f"the tracker is not available in this installation ({exc}); "
                             "use `source='groundtruth'` for synthetic captures") from exc
        track_capture(capture.root, Path(job.out_dir), mode="sequence", detector=job.detector, progress=False,
                      stop=_stop_check(job.stop_event))
    return read_markers_csv(path)


def _markers_reusable(job: TrialJob) -> bool:
    """Does the trial's output hold a complete marker set newer than the capture's own files (not
    re-tracked: level maps and the pelvis C3D change only the analysis)?"""
    path = Path(job.out_dir) / MARKERS
    return not job.force and _newer_than(path, _tracking_inputs(job)) and results_complete(path.parent)


def _stop_check(event_name: str | None) -> Callable[[], bool] | None:
    """On a Dask worker: a function telling whether the batch's stop Event is set."""
    if event_name is None:
        return None
    from distributed import Event, get_client

    event = Event(event_name, client=get_client())
    return event.is_set


def _newer_than(path: Path, inputs: Iterable[Path]) -> bool:
    return path.is_file() and path.stat().st_mtime > max((p.stat().st_mtime for p in inputs), default=0.0)


def groundtruth_markers(capture: Capture) -> MarkerTable:
    """The synthetic studio's exact dot positions (``groundtruth.npz``: ``labels`` (D,),
    ``dots`` (F, D, 3) mm) as a marker table; every dot counts as observed."""
    path = capture.groundtruth_path
    data = capture.groundtruth()
    if "dots" not in data or "labels" not in data:
        raise InputError(path, "ground truth lacks 'dots' or 'labels'")
    labels = [str(lab) for lab in data["labels"]]
    dots = np.asarray(data["dots"], float)
    return MarkerTable.from_arrays(labels, dots, fps=capture.fps,
                                   meta={"source": str(path), "subject": capture.subject.get("id", "")})


def read_markers_csv(path: str | os.PathLike) -> MarkerTable:
    """A marker table from the CSV the tracker writes (read by the exporters package)."""
    import exporters

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "marker table not found")
    return exporters.read(path)


def _levels(job: TrialJob, capture: Capture) -> tuple[LevelMap, str]:
    return find_level_map(capture, job.trial.levels_file, job.levels_file)


def _pelvis_frames(c3d_file: str, markers: MarkerTable) -> np.ndarray:
    """Pelvis frames from a C3D's LASI/RASI/LPSI/RPSI, resampled onto the marker table's times."""
    times, traj = read_pelvis_c3d(c3d_file)
    t = markers.to_arrays().time
    if t[-1] > times[-1] + 1e-6:
        raise InputError(c3d_file, f"C3D covers {times[-1]:.2f} s, the markers {t[-1]:.2f} s")
    resampled = {name: np.column_stack([np.interp(t, times, xyz[:, k]) for k in range(3)])
                 for name, xyz in traj.items()}
    return pelvis_frame_from_markers(resampled, source=c3d_file)[1]


# ---------------------------------------------------------------------------------- the batch
def trial_out_dir(out: Path, trial: Trial) -> Path:
    return out.joinpath(*[p for p in (trial.subject, trial.condition, trial.trial) if p])


def run_batch(root: str | os.PathLike, out: str | os.PathLike, *, source: MarkerSource = "tracked",
              workers: int = 2, scheduler: str | None = None, levels_file: str | None = None,
              settings: AngleSettings | None = None, force: bool = False,
              detector: str = "net", progress: bool = True, opensim: bool = False, view: bool = False) -> BatchResult:
    """Process every trial under ``root`` into ``out`` (see the module docstring).

    ``workers``: local processes (1 = in this process); ``scheduler``: a Dask distributed
    scheduler address (``tcp://HOST:PORT``) -- then the cluster's workers run the trials.
    ``detector``: the tracker's dot detector for ``source="tracked"`` (net, classical, mask).
    ``opensim``: also solve each trial with ``spinemocap opensim`` (into ``<trial>/opensim``).
    ``view``: also write each tracked trial's labelled videos and 3D viewer (into ``<trial>/view``,
    linked from the report).
    """
    if source not in SOURCES:
        raise InputError(None, f"unknown marker source {source!r}; expected one of {SOURCES}")
    out = check_writable(out)
    clean_stale_temps(out)
    trials = discover(root)
    settings = settings or AngleSettings()
    jobs = [TrialJob(t, str(trial_out_dir(out, t)), source, levels_file, settings, force, detector,
                     opensim=opensim, view=view)
            for t in trials]
    handler = logging.FileHandler(out / "batch.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    log.addHandler(handler)
    log.info("batch of %d trials from %s (source %s, %s)", len(jobs), root, source,
             f"scheduler {scheduler}" if scheduler else f"{workers} local workers")
    results = _checked(jobs)  # every trial's inputs, before any trial is tracked
    runnable = [job for job in jobs if job.trial.key not in {r.summary.key for r in results}]
    for result in results:
        _log_result(result)
    bar = tqdm(total=len(jobs), initial=len(results), desc="trials", unit="trial", disable=not progress)
    running = _execute(runnable, workers, scheduler)
    try:
        for result in running:
            results.append(result)
            _log_result(result)
            failed = sum(not r.summary.ok for r in results)
            bar.update()
            bar.set_postfix(done=len(results) - failed, failed=failed, remaining=len(jobs) - len(results))
    except KeyboardInterrupt:
        running.close()  # stops the workers (if the interrupt came while this loop was not waiting)
        _record_interrupted(jobs, results, out, root, source)
        raise
    finally:
        bar.close()
        log.removeHandler(handler)
        handler.close()
    _write_batch_json(out, root, source, jobs, results)
    return BatchResult(results)


def _checked(jobs: list[TrialJob]) -> list[TrialOutcome]:
    """The failed outcomes (written to each trial's ``summary.json``) of the trials whose inputs
    :func:`check_trial` refuses; the others are left to run."""
    failed = []
    for job in jobs:
        reason = check_trial(job)
        if reason is not None:
            summary = job.summary("failed", reason, elapsed_s=0.0)
            check_writable(job.out_dir, "trial output folder")
            write_summary(summary)
            failed.append(TrialOutcome(summary))
    return failed


def _record_interrupted(jobs: list[TrialJob], results: list[TrialOutcome], out: Path, root: str | os.PathLike[str],
                        source: MarkerSource) -> None:
    """Every trial without a final result becomes ``interrupted`` in batch.log and batch.json."""
    finished = {r.summary.key for r in results if r.summary.status != INTERRUPTED}
    stopped = {r.summary.key: r.summary for r in results if r.summary.status == INTERRUPTED}
    results[:] = [r for r in results if r.summary.status != INTERRUPTED]
    for job in jobs:
        key = job.trial.key
        if key in finished:
            continue
        reason = stopped[key].reason if key in stopped else "interrupted (not finished)"
        results.append(job.outcome(INTERRUPTED, reason))
        log.warning("%s %s; a rerun processes it", key, reason)
    log.warning("batch interrupted: %d of %d trials finished", len(finished), len(jobs))
    _write_batch_json(out, root, source, jobs, results)


def _write_batch_json(out: Path, root: str | os.PathLike[str], source: MarkerSource, jobs: list[TrialJob],
                      results: list[TrialOutcome]) -> None:
    order = {j.trial.key: k for k, j in enumerate(jobs)}
    results.sort(key=lambda r: order.get(r.summary.key, 0))
    with atomic_write(out / "batch.json") as handle:
        handle.write(strict_json({"root": str(root), "source": source, "trials": [r.to_dict() for r in results]}))


def _log_result(result: TrialOutcome) -> None:
    summary = result.summary
    if not summary.ok:
        log.error("%s failed: %s", summary.key, summary.reason)
        return
    for group, reasons in summary.notes.items():
        for reason, count in reasons.items():
            log.warning("%s: %s angles NaN in %d frames: %s", summary.key, group, count, reason)
    for message in summary.warnings:
        log.info("%s: %s", summary.key, message)
    log.info("%s %s", summary.key, "up to date, skipped" if result.skipped else "done")


def _execute(jobs: list[TrialJob], workers: int, scheduler: str | None) -> Generator[TrialOutcome, None, None]:
    if scheduler:
        yield from _execute_dask(jobs, scheduler)
    elif workers <= 1:
        for job in jobs:
            yield process_trial(job)
    else:
        yield from _execute_pool(jobs, workers)


# ---------------------------------------------------------------------------------- local pool
STOP_GRACE_S = 10.0     # how long stopped workers get to abandon their trial before they are killed
_TRIAL_RUNNING = False  # in a worker: a trial is being processed (SIGINT then interrupts it)


def _worker_init(parent_pid: int) -> None:
    """In each local worker: exit when the batch's process dies (no orphans), and on SIGINT
    interrupt the running trial (KeyboardInterrupt: its atomic writes remove their temporary
    files) or, when idle, exit quietly."""
    signal.signal(signal.SIGINT, _worker_sigint)
    exit_with_parent(parent_pid)  # the next run removes a killed trial's temporary files


def _worker_sigint(signum, frame) -> None:
    if _TRIAL_RUNNING:
        raise KeyboardInterrupt
    os._exit(0)


def _process_in_worker(job: TrialJob) -> TrialOutcome:
    global _TRIAL_RUNNING
    _TRIAL_RUNNING = True
    try:
        return process_trial(job)
    except KeyboardInterrupt:  # stopped: the trial's temporary files are gone; take no further trial
        os._exit(130)
    finally:
        _TRIAL_RUNNING = False


def _execute_pool(jobs: list[TrialJob], workers: int) -> Iterator[TrialOutcome]:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init, initargs=(os.getpid(),))
    futures: dict = {}
    try:
        futures = {pool.submit(_process_in_worker, job): job for job in jobs}
        for future in as_completed(futures):
            yield _result_or_failure(future, futures[future])
    except BaseException:  # KeyboardInterrupt, or the consumer closed us (GeneratorExit)
        _stop_pool(pool, list(futures))
        raise
    pool.shutdown(wait=True)


def _stop_pool(pool: ProcessPoolExecutor, futures: list) -> None:
    """Cancel queued trials at once, SIGINT the workers (their running trial stops), wait up to
    ``STOP_GRACE_S`` for them to exit, kill what is left."""
    for future in futures:
        future.cancel()
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            os.kill(process.pid, signal.SIGINT)
    join_or_kill(processes, STOP_GRACE_S)
    pool.shutdown(wait=False, cancel_futures=True)


# ---------------------------------------------------------------------------------- Dask
def _execute_dask(jobs: list[TrialJob], scheduler: str) -> Iterator[TrialOutcome]:
    """Run ``jobs`` on the Dask cluster at ``scheduler``, yielding each trial's summary.

    A worker that dies mid-trial (killed, out of memory) is survived by Dask itself: the trial
    runs again on another worker (a trial whose workers die ``distributed.scheduler.allowed-failures``
    times is recorded as failed); its outputs are only taken as done once written whole.

    Raises:
        InputError: the scheduler cannot be reached, or went away during the batch (after
            yielding the finished trials; their summaries are kept, a rerun does the rest).
    """
    from distributed import Client, Event
    from distributed import as_completed as dask_completed

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise InputError(scheduler, f"cannot reach the Dask scheduler ({exc})") from exc
    stop = Event(f"spinemocap-stop-{uuid.uuid4().hex}", client=client)
    futures: list = []
    finished = 0
    try:
        jobs = [replace(job, stop_event=stop.name) for job in jobs]
        futures = client.map(process_trial, jobs, pure=False, key=[f"trial-{j.trial.key}-{id(j)}" for j in jobs])
        by_key = {f.key: j for f, j in zip(futures, jobs)}
        for future in dask_completed(futures):
            if _scheduler_lost(future, client):
                raise SchedulerLost(scheduler, f"the Dask scheduler went away after {finished} of {len(jobs)} "
                                               "trials: their results are kept; start the scheduler again (or "
                                               "use another) and run the same command to do the rest")
            finished += 1
            yield _result_or_failure(future, by_key[future.key])
    except SchedulerLost:
        raise
    except BaseException:  # interrupted: drop queued trials, ask running ones to stop at their next frame
        with contextlib.suppress(Exception):
            stop.set()
            client.cancel(futures)
        raise
    finally:
        with contextlib.suppress(Exception):
            client.close(timeout=5)


class SchedulerLost(InputError):
    """The Dask scheduler went away in the middle of a batch."""


def _scheduler_lost(future, client) -> bool:
    """True when ``future`` was cancelled because the client lost its scheduler (not by us)."""
    if future.status != "cancelled":
        return False
    try:
        future.result(timeout=0)
    except Exception as exc:
        return "connection-lost" in str(exc) or client.status not in ("running", "newly-created")
    return False


def _result_or_failure(future: Any, job: TrialJob) -> TrialOutcome:
    """A finished future's outcome; a worker that died (not a bad trial) becomes a failure too."""
    try:
        outcome: TrialOutcome = future.result()
    except Exception as exc:
        return job.outcome("failed", f"worker failed: {type(exc).__name__}: {exc}")
    return outcome


def load_results(out: str | os.PathLike[str]) -> list[TrialSummary]:
    """Every trial summary under a batch output folder, sorted by trial key (each with its
    folder as ``out_dir``).

    Raises:
        InputError: no such folder, no summary in it, or a summary that cannot be read."""
    out = Path(out)
    if not out.is_dir():
        raise InputError(out, "batch output folder not found")
    summaries = [read_summary(path) for path in sorted(out.rglob(SUMMARY))
                 if path.parent.name != OPENSIM_DIR]  # not spinemocap opensim's own summary inside a trial
    if not summaries:
        raise InputError(out, f"no trial results ({SUMMARY}) found: run `spinemocap batch` first")
    return sorted(summaries, key=lambda s: s.key)
