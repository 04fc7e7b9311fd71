"""MRF2's refinements alone, this checkout against a peer checkout, on the inputs a tracking run gave.

    # views cached as track3d_ab.py cache makes them; the refinements of the carried frames are
    # recorded from one tracking run (this checkout), then both checkouts' refine_mrf2 run on them
    python docs/bench/mrf2_ab.py VIEWS_DIR CAPTURE_DIR --peer /path/to/other/checkout --reps 7

Each refinement is given the same positions, evidence images (built once), tape, feasible points
and a fresh ``np.random.default_rng(k)`` in both checkouts; the two are run alternately, all
refinements per run, and timed in this thread's CPU (ms per refinement, min and median over the
runs). The outputs are compared bit for bit. The frame solved in full (the first) is left out.
The peer package is imported under another name (``sm_peer``) from ``PEER/spinemocap``.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import pickle
import sys
import time
import warnings
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("views", type=Path)
    ap.add_argument("capture", type=Path)
    ap.add_argument("--peer", type=Path, required=True)
    ap.add_argument("--reps", type=int, default=7)
    a = ap.parse_args()

    import spinemocap.track.mrf2 as mrf2
    import spinemocap.track.pipeline as pipeline
    from spinemocap.app.run import run_tracking
    from spinemocap.capture import Capture

    spec = importlib.util.spec_from_file_location("sm_peer", a.peer / "spinemocap" / "__init__.py",
                                                  submodule_search_locations=[str(a.peer / "spinemocap")])
    module = importlib.util.module_from_spec(spec)
    sys.modules["sm_peer"] = module
    spec.loader.exec_module(module)
    peer_refine = importlib.import_module("sm_peer.track.mrf2").refine_mrf2

    cap = Capture.open(a.capture)
    calls = []
    this_refine = mrf2.refine_mrf2

    def recorded(positions, tape, rig, evidence, config, rng=None, feasible_points=None):
        calls.append((np.array(positions), tape, evidence, config,
                      None if feasible_points is None else np.array(feasible_points)))
        return this_refine(positions, tape, rig, evidence, config, rng=rng, feasible_points=feasible_points)

    pipeline.refine_mrf2 = recorded
    files = sorted(a.views.glob("*.pkl"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_tracking(((i, pickle.loads(f.read_bytes()), 0.0) for i, f in enumerate(files)), cap.rig, cap.tape,
                     cap.fps, up=cap.up, progress=False)
    pipeline.refine_mrf2 = this_refine
    calls = calls[1:]
    print(f"{len(calls)} refinements of carried frames")
    runners = {"this": this_refine, "peer": peer_refine}
    times: dict[str, list[float]] = {"this": [], "peer": []}
    outputs = {}
    for rep in range(a.reps + 1):  # the first pair warms up
        for name in ("peer", "this") if rep % 2 == 0 else ("this", "peer"):
            t = time.thread_time()
            outputs[name] = [runners[name](p, tape, cap.rig, ev, cfg, rng=np.random.default_rng(k), feasible_points=fp).positions
                             for k, (p, tape, ev, cfg, fp) in enumerate(calls)]
            if rep:
                times[name].append(1000 * (time.thread_time() - t) / max(len(calls), 1))
    for name in ("peer", "this"):
        print(f"{name}: ms per refinement min {min(times[name]):.2f} median {np.median(times[name]):.2f}")
    print(f"ratio this / peer: min {min(times['this']) / min(times['peer']):.3f} "
          f"median {np.median(times['this']) / np.median(times['peer']):.3f}")
    same = all(np.array_equal(x, y) for x, y in zip(outputs["this"], outputs["peer"]))
    print("IDENTICAL" if same else "DIFFERENT")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
