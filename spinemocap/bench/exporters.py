"""``spinemocap bench export``: time our TRC and C3D writers/readers against the consumers'
own implementations on the same data (OpenSim's ``TRCFileAdapter``, ``ezc3d``).

Ours are timed end to end from/to a :class:`MarkerTable` (the dense-array conversion included);
the peers are timed on their own in-memory objects, built beforehand and not timed.
"""

from __future__ import annotations

import importlib.util
import json
import multiprocessing
import statistics
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable

import numpy as np

from exporters import read, write
from spinemocap.fileio import InputError, atomic_write
from spinemocap.markers import MarkerTable


@dataclass(frozen=True)
class FileTiming:
    """Median milliseconds to write and to read one file; ``bytes``: its size (ours; None for a
    peer, whose file is not ours to size)."""

    write_ms: float
    read_ms: float
    bytes: int | None = None

    def to_dict(self) -> dict[str, float | int]:
        """``write_ms``, ``read_ms`` and, where known, ``bytes``."""
        timing: dict[str, float | int] = {"write_ms": self.write_ms, "read_ms": self.read_ms}
        if self.bytes is not None:
            timing["bytes"] = self.bytes
        return timing


@dataclass(frozen=True)
class ExportBenchmark:
    """``spinemocap bench export``'s numbers: the table's ``frames`` and ``markers``, the
    ``repeat`` each median is taken over, and each file's timing by name (``ours_trc``,
    ``ours_c3d``, ``ours_csv``, ``ours_parquet``, ``ezc3d_c3d``, ``opensim_trc``)."""

    frames: int
    markers: int
    repeat: int
    timings: dict[str, FileTiming]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``export_bench.json`` holds: frames, markers, repeat, then one object
        per file."""
        return {"frames": self.frames, "markers": self.markers, "repeat": self.repeat,
                **{name: timing.to_dict() for name, timing in self.timings.items()}}


def synthetic_table(n_frames: int, n_markers: int, fps: float = 100.0, gap_share: float = 0.05,
                    seed: int = 0) -> MarkerTable:
    """Smooth random trajectories around 1 m height (mm) with ``gap_share`` of samples missing."""
    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(scale=0.5, size=(n_frames, n_markers, 3)), axis=0) + [0.0, 0.0, 1000.0]
    pos[rng.random((n_frames, n_markers)) < gap_share] = np.nan
    return MarkerTable.from_arrays([f"R{i // 3 + 1:02d}{'LCR'[i % 3]}" for i in range(n_markers)], pos, fps=fps,
                                   n_views=np.full((n_frames, n_markers), 4),
                                   residual=np.full((n_frames, n_markers), 0.5))


def _median_ms(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def _opensim_peer(trc_path: str, folder: str, repeat: int) -> FileTiming:
    """OpenSim's TRC reader and writer on ``trc_path`` (our file, same data). Runs in its own
    process: opensim's and ezc3d's SWIG string vectors clash once both are loaded."""
    import opensim as osim

    table = osim.TimeSeriesTableVec3(trc_path)
    path = str(Path(folder) / "peer.trc")
    return FileTiming(write_ms=_median_ms(lambda: osim.TRCFileAdapter.write(table, path), repeat),
                      read_ms=_median_ms(lambda: osim.TimeSeriesTableVec3(path), repeat))


def _ezc3d_peer(table: MarkerTable, folder: Path, repeat: int) -> FileTiming:
    try:
        import ezc3d
    except ImportError as exc:
        raise InputError("spinemocap bench export", "its C3D peer, ezc3d, is not installed: "
                         f"pip install 'spinemocap[bench]' (`make` installs it); import failed with: {exc}") from None

    arrays = table.to_arrays()
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [table.fps]
    c["parameters"]["POINT"]["LABELS"]["value"] = [str(l) for l in arrays.labels]
    del c["parameters"]["POINT"]["UNITS"]          # ezc3d cannot write its own empty default
    c.add_parameter("POINT", "UNITS", ["mm"])
    points = np.ones((4,) + arrays.positions.shape[1::-1])
    points[:3] = arrays.positions.transpose(2, 1, 0)
    c["data"]["points"] = points
    path = str(folder / "peer.c3d")
    return FileTiming(write_ms=_median_ms(lambda: c.write(path), repeat),
                      read_ms=_median_ms(lambda: ezc3d.c3d(path), repeat))


def run_export_benchmark(n_frames: int = 548, n_markers: int = 32, repeat: int = 5,
                         out: Path | None = None) -> ExportBenchmark:
    """Median write/read times (ms) of ours and the peers; printed as a table, saved as JSON
    (``out/export_bench.json``)."""
    table = synthetic_table(n_frames, n_markers)
    timings: dict[str, FileTiming] = {}
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        folder = Path(tmp)
        for fmt in ("trc", "c3d", "csv", "parquet"):
            path = folder / f"ours.{fmt}"
            timings[f"ours_{fmt}"] = FileTiming(write_ms=_median_ms(partial(write, table, path), repeat),
                                                read_ms=_median_ms(partial(read, path), repeat),
                                                bytes=path.stat().st_size)
        timings["ezc3d_c3d"] = _ezc3d_peer(table, folder, repeat)
        if importlib.util.find_spec("opensim") is None:  # not imported here: see _opensim_peer
            raise InputError("spinemocap bench export", "its TRC peer, OpenSim's Python package, is not "
                             "installed: pip install 'spinemocap[bench]' (`make` installs it)")
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            timings["opensim_trc"] = pool.submit(_opensim_peer, str(folder / "ours.trc"), tmp, repeat).result()
    results = ExportBenchmark(frames=n_frames, markers=n_markers, repeat=repeat, timings=timings)
    print(f"{n_frames} frames x {n_markers} markers, median of {repeat} (ms)")
    print(f"{'':14s} {'write':>9s} {'read':>9s}")
    for key, value in timings.items():
        print(f"{key:14s} {value.write_ms:9.1f} {value.read_ms:9.1f}")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        with atomic_write(out / "export_bench.json") as handle:
            json.dump(results.to_dict(), handle, indent=2)
    return results
