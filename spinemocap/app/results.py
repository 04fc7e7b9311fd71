"""The results folder of a tracked capture (application layer, light to import): the marker
files written as one consistent set with a manifest, and the signal that stops a tracking run.

``markers.csv``, ``markers.trc`` and ``markers.c3d`` come from one run or the folder says it is
incomplete: :func:`write_markers` stages all three, then swaps them in and writes
``markers.manifest.json`` (run id, size and SHA-256 per file) last; :func:`results_run_id`
checks a folder against its manifest.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
import uuid
from pathlib import Path
from typing import Callable, Iterable

import exporters

from ..fileio import (
    InputError,
    OutputError,
    atomic_write,
    check_writable,
    clean_stale_temps,
    fsync_dir,
    temp_name,
    writing,
)
from ..markers import MarkerTable

log = logging.getLogger(__name__)

#: Marker files looked for in a results folder given as input, in this order.
READABLE_MARKER_FILES = ("markers.csv", "markers.parquet", "markers.c3d", "markers.trc")

RESULTS_MANIFEST = "markers.manifest.json"
RESULT_FILES = ("markers.csv", "markers.trc", "markers.c3d")


class TrackingStopped(Exception):
    """The caller asked the tracking to stop (a batch being interrupted); nothing was written."""


def write_markers(table: MarkerTable, out_dir: str | Path) -> list[Path]:
    """``markers.csv``, ``markers.trc`` and ``markers.c3d`` of ``table`` in ``out_dir``, as one set
    (:func:`write_marker_parts`)."""
    return write_marker_parts(lambda: [table], table.n_frames, out_dir)


def write_marker_parts(parts: Callable[[], Iterable[MarkerTable]], n_frames: int, out_dir: str | Path) -> list[Path]:
    """``markers.csv``, ``markers.trc`` and ``markers.c3d`` in ``out_dir``, consistent as a set,
    of a table given in consecutive parts: ``parts()`` yields them anew for each file (the same
    labels and meta, ``n_frames`` frames in all), and each file is written one part at a time, so
    a long capture's set needs the memory of one part.

    All three are written into a staging folder first (a failing writer leaves the previous set
    untouched); then the manifest ``markers.manifest.json`` is removed, the files are renamed
    into place and a new manifest (run id, size and SHA-256 of each file) is written last. A kill
    in between leaves no manifest or one that does not match: :func:`results_run_id` tells.
    Staging folders and temporary files of a killed run are removed here.

    Raises:
        OutputError: the disk filled up or the folder turned read-only; the folder then holds no
            manifest that matches, so :func:`results_complete` says it is incomplete."""
    out = check_writable(out_dir)
    clean_stale_temps(out)
    staging = temp_name(out / "markers", suffix="")
    with writing(out, "marker files"):
        staging.mkdir()
        return _write_set(parts, n_frames, out, staging)


def _write_set(parts: Callable[[], Iterable[MarkerTable]], n_frames: int, out: Path, staging: Path) -> list[Path]:
    """Stage the set in ``staging``, swap it into ``out``, write the manifest last."""
    try:
        staged = []
        for name in RESULT_FILES:
            try:
                exporters.write_parts(parts(), staging / name, n_frames)
            except OutputError:     # a full disk: said for the results folder by write_markers
                raise
            except InputError as exc:  # name the file the user asked for, not the staging folder's
                raise InputError(out / name, exc.problem.replace(str(staging), str(out))) from None
            staged.append(staging / name)
        manifest = {"run_id": uuid.uuid4().hex, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                    "files": {p.name: {"bytes": p.stat().st_size, "sha256": _sha256(p)} for p in staged}}
        (out / RESULTS_MANIFEST).unlink(missing_ok=True)
        fsync_dir(out)
        for path in staged:
            os.replace(path, out / path.name)
        fsync_dir(out)
        with atomic_write(out / RESULTS_MANIFEST) as handle:
            json.dump(manifest, handle, indent=1)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out / name for name in RESULT_FILES]


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def results_complete(out_dir: str | Path) -> bool:
    """True when the marker files in ``out_dir`` are one complete set (:func:`results_run_id`);
    False, with the reason logged, otherwise (the caller redoes them)."""
    try:
        results_run_id(out_dir)
    except InputError as exc:
        log.info("%s", exc)
        return False
    return True


def results_run_id(out_dir: str | Path) -> str:
    """The run id of the marker files in ``out_dir`` when they form one complete set written by
    :func:`write_markers` (every file present with the manifest's size and SHA-256);
    :class:`InputError` naming the folder otherwise (an interrupted write, files of two runs)."""
    out = Path(out_dir)
    manifest_path = out / RESULTS_MANIFEST
    try:
        manifest = json.loads(manifest_path.read_text())
        files = manifest["files"]
        for name in RESULT_FILES:
            path = out / name
            if path.stat().st_size != files[name]["bytes"] or _sha256(path) != files[name]["sha256"]:
                raise InputError(out, f"{name} does not belong to the run in {RESULTS_MANIFEST}: "
                                      "the result files are from different runs")
        return str(manifest["run_id"])
    except InputError:
        raise
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(out, f"incomplete set of marker files (no valid {RESULTS_MANIFEST}: {exc}); "
                              "the run that wrote them was interrupted") from exc


def find_markers(results: Path) -> Path:
    """The marker file inside a results folder (the first of :data:`READABLE_MARKER_FILES`), or
    ``results`` itself when it is a file. Raises :class:`InputError` naming ``results`` when
    neither is there."""
    if results.is_dir():
        for name in READABLE_MARKER_FILES:
            if (results / name).is_file():
                return results / name
        raise InputError(results, f"results folder holds none of {', '.join(READABLE_MARKER_FILES)}")
    if not results.is_file():
        raise InputError(results, "no such marker file or results folder")
    return results


def read_results(results: str | os.PathLike) -> MarkerTable:
    """The marker table of a results folder or marker file (:func:`find_markers`)."""
    return exporters.read(find_markers(Path(results)))


def tracked_set_file(path: str | Path) -> bool:
    """Is ``path`` one of the marker files of a tracked set (a results folder with a manifest)?"""
    path = Path(path)
    return path.name in RESULT_FILES and (path.parent / RESULTS_MANIFEST).is_file()


def record_replaced(path: str | Path, note: str) -> None:
    """After ``path``, a file of a tracked set, was replaced on purpose (``export --force``): its
    size and SHA-256 in the manifest, with ``note`` saying what it now holds, so that the manifest
    stays true (:func:`results_run_id` checks the new file)."""
    path = Path(path)
    manifest_path = path.parent / RESULTS_MANIFEST
    manifest = json.loads(manifest_path.read_text())
    manifest["files"][path.name] = {"bytes": path.stat().st_size, "sha256": _sha256(path), "replaced": note}
    with atomic_write(manifest_path) as handle:
        json.dump(manifest, handle, indent=1)
