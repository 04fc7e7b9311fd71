"""The tracker's 3D stages alone, this checkout against a peer checkout, on views detected once.

    # detect once (the shipped `net` detector, sequence mode, cameras serial) and keep the views
    python docs/bench/track3d_ab.py cache CAPTURE_DIR VIEWS_DIR --frames 40
    # the 3D stages of both checkouts on those views, alternating, CPU per stage (min over runs),
    # and the two outputs compared (positions, residuals, status, flags, routes, confidence, rig)
    python docs/bench/track3d_ab.py compare VIEWS_DIR CAPTURE_DIR --peer /path/to/other/checkout --reps 7 [--fresh]

With ``--fresh`` each run reads every frame's views from disk again (memory flat in the number of
frames, and views that hold their colour image, as sequence tracking's do, make their grey image
in each run as a real run does; the reading is left out of the CPU totals).

Stage times are this thread's CPU (the stage timer's clock swapped for ``time.thread_time``), so
they survive a shared machine's load better than wall time. The tracker's evidence threads
(``EvidenceConfig.threads``) are not in them: ``process_cpu`` counts every thread of the process,
``wall`` the elapsed time (both without the reading of ``--fresh``). The peer package is imported under
another name (``sm_peer``) from ``PEER/spinemocap``. Views hold the grey (or colour) images and
masks MRF2 needs: ~45 MB (~94 MB) per 6-camera 2448x1600 frame on disk.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import importlib.util
import os
import pickle
import sys
import time
import types
import warnings
from pathlib import Path

import numpy as np

STAGES = ("candidates", "edges", "lp", "mrf1", "mrf2", "status")
FIELDS = ("positions", "status", "n_views", "residual", "route", "lp_status", "note", "flags", "stretch",
          "gate_px", "pixels", "relocated", "extrapolated", "unanchored")


def cache(capture_dir: Path, views_dir: Path, frames: int) -> None:
    from spinemocap.app.run import make_detector, run_tracking, source_views
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.capture import Capture

    cap = Capture.open(capture_dir)
    speed = SpeedOptions(workers=1, prefetch=0)
    detect = make_detector("net", cap.rig, speed)
    views_dir.mkdir(parents=True, exist_ok=True)

    def recorded():
        for frame, views, ms in source_views(cap.frame_source(), range(frames), detect, speed):
            with open(views_dir / f"{frame:04d}.pkl", "wb") as fh:
                pickle.dump(views, fh, protocol=5)
            yield frame, views, ms

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_tracking(recorded(), cap.rig, cap.tape, cap.fps, up=cap.up, progress=False, n_frames=frames,
                     on_frame=lambda frame, r: detect.observe(frame, r.positions if r.solved else None))
    detect.close()


def _load_peer(path: Path):
    spec = importlib.util.spec_from_file_location("sm_peer", path / "spinemocap" / "__init__.py",
                                                  submodule_search_locations=[str(path / "spinemocap")])
    module = importlib.util.module_from_spec(spec)
    sys.modules["sm_peer"] = module
    spec.loader.exec_module(module)


def _differences(a, b, tol_mm: float = 1e-9) -> tuple[list[str], float]:
    """What differs between two runs' outputs (beyond ``tol_mm`` / 1e-9 relative), and the
    largest float difference."""
    bad, worst = [], 0.0
    da, db = a.table.data, b.table.data
    for c in da.columns:
        x, y = da[c].to_numpy(), db[c].to_numpy()
        if x.dtype.kind == "f":
            if not np.array_equal(np.isnan(x), np.isnan(y)):
                bad.append(f"table {c}: NaN pattern")
                continue
            d = float(np.nanmax(np.abs(x - y), initial=0.0))
            worst = max(worst, d)
            if d > tol_mm:
                bad.append(f"table {c}: {d:.3g}")
        elif not (x == y).all():
            bad.append(f"table {c}")
    for i, (fa, fb) in enumerate(zip(a.frames, b.frames)):
        for k in FIELDS:
            x, y = getattr(fa, k), getattr(fb, k)
            if isinstance(x, np.ndarray) and x.dtype.kind == "f":
                same_nan = np.array_equal(np.isnan(x), np.isnan(y))
                d = float(np.nanmax(np.abs(x - y), initial=0.0)) if same_nan else np.inf
                worst = max(worst, d)
                if d > tol_mm:
                    bad.append(f"frame {i} {k}: {d:.3g}")
            elif isinstance(x, np.ndarray):
                if x.shape != y.shape or not (x == y).all():
                    bad.append(f"frame {i} {k}")
            elif k == "stretch":
                for f, u in dataclasses.asdict(x).items():
                    v = getattr(y, f)
                    if u != v and not (isinstance(u, float) and abs(u - v) <= 1e-9 * max(1.0, abs(u))):
                        bad.append(f"frame {i} stretch.{f}")
            elif k == "gate_px":
                if not abs(x - y) <= 1e-9 * max(1.0, abs(x)):
                    bad.append(f"frame {i} gate_px")
            elif x != y:
                bad.append(f"frame {i} {k}: {x!r} / {y!r}")
    if len(a.frames) != len(b.frames):
        bad.append("frame count")
    if (a.calibration_warning or "") != (b.calibration_warning or ""):
        bad.append("calibration warning")
    return bad, worst


def compare(views_dir: Path, capture_dir: Path, peer: Path, reps: int, fresh: bool = False) -> int:
    from spinemocap.capture import Capture

    _load_peer(peer)
    runners = {}
    for name, package in (("this", "spinemocap"), ("peer", "sm_peer")):
        timing = importlib.import_module(package + ".timing")
        timing.time = types.SimpleNamespace(perf_counter=time.thread_time)  # type: ignore[attr-defined]
        runners[name] = importlib.import_module(package + ".app.run").run_tracking
    print(f"this: {importlib.import_module('spinemocap').__file__}\npeer: {sys.modules['sm_peer'].__file__}")
    cap = Capture.open(capture_dir)
    files = sorted(views_dir.glob("*.pkl"))
    views = None if fresh else [pickle.loads(f.read_bytes()) for f in files]
    n = len(files)

    def run(name):
        loading = np.zeros(3)  # thread CPU, process CPU, wall

        def clocks():
            return np.array([time.thread_time(), time.process_time(), time.perf_counter()])

        def frames():
            for f in range(n):
                if views is not None:
                    yield f, views[f], 0.0
                    continue
                t = clocks()
                v = pickle.loads(files[f].read_bytes())  # fresh views: nothing made lazily by an earlier run
                loading[:] += clocks() - t
                yield f, v, 0.0

        c0 = clocks()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = runners[name](frames(), cap.rig, cap.tape, cap.fps, up=cap.up, progress=False, n_frames=n)
        cpu, process_cpu, wall = 1000 * (clocks() - c0 - loading) / n
        per = {
            "all frames": {k: sum(fr.stage_ms.get(k, 0.0) for fr in result.frames) / n for k in STAGES},
            "frames 1..": {k: sum(fr.stage_ms.get(k, 0.0) for fr in result.frames[1:]) / max(n - 1, 1) for k in STAGES},
            "frame 0": {k: result.frames[0].stage_ms.get(k, 0.0) for k in STAGES},
        }
        per["all frames"]["cpu_total"] = cpu  # this thread's
        per["all frames"]["process_cpu"] = process_cpu  # all threads' (the tracker's own threads too)
        per["all frames"]["wall"] = wall
        return per, result

    run("this"), run("peer")  # warm-up
    runs: dict[str, list] = {"this": [], "peer": []}
    loads = []
    for rep in range(reps):
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            runs[name].append(run(name))
        loads.append(os.getloadavg()[0])
    print(f"{n} frames, {reps} runs each, CPU ms per frame (min over runs); 1-min load {min(loads):.2f}-{max(loads):.2f}")
    routes = {}
    for fr in runs["this"][-1][1].frames:
        routes[fr.route] = routes.get(fr.route, 0) + 1
    print("routes:", routes)
    for part in ("all frames", "frames 1..", "frame 0"):
        for name in ("peer", "this"):
            best = {k: min(r[0][part][k] for r in runs[name]) for k in runs[name][0][0][part]}
            total = sum(best[k] for k in STAGES)
            print(f"{part:>10} {name:>4}: 3D {total:7.2f} | " + " ".join(f"{k} {v:.2f}" for k, v in best.items()))
    bad, worst = _differences(runs["peer"][-1][1], runs["this"][-1][1])
    print(f"largest float difference {worst:.3g} (mm / px / ratio)")
    print("IDENTICAL" if not bad else "DIFFERENT: " + "; ".join(bad[:20]))
    return 0 if not bad else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cache")
    c.add_argument("capture", type=Path)
    c.add_argument("views", type=Path)
    c.add_argument("--frames", type=int, default=40)
    m = sub.add_parser("compare")
    m.add_argument("views", type=Path)
    m.add_argument("capture", type=Path)
    m.add_argument("--peer", type=Path, required=True)
    m.add_argument("--reps", type=int, default=5)
    m.add_argument("--fresh", action="store_true",
                   help="read each frame's views from disk in every run (memory flat; views holding the colour "
                        "image make their grey image afresh in each run, as in a real run)")
    a = ap.parse_args()
    if a.cmd == "cache":
        cache(a.capture, a.views, a.frames)
        return 0
    return compare(a.views, a.capture, a.peer, a.reps, a.fresh)


if __name__ == "__main__":
    sys.exit(main())
