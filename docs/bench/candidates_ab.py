"""Issue 15: the candidate search before and after its speed-up, on a capture's frames: the same
candidates (blob-id rows, points) and CPU ms per frame (best of 5, the two alternating).

The dots come from the shipped ``net`` detector (full search of every camera image, sensor noise
added as ``bench speed --sensor-noise`` does); the previous search is loaded from a file, e.g.

    git show ef54a23:spinemocap/track/candidates.py > /tmp/candidates_before.py
    python docs/bench/candidates_ab.py CAPTURE_DIR /tmp/candidates_before.py --sensor-noise 3
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("before", type=Path, help="the previous spinemocap/track/candidates.py")
    parser.add_argument("--sensor-noise", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    import spinemocap.track.candidates as after
    from spinemocap.bench.speed import with_sensor_noise
    from spinemocap.capture import Capture
    from spinemocap.detect import Detector

    spec = importlib.util.spec_from_file_location("spinemocap.track.candidates_before", args.before)
    before = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = before  # type: ignore[union-attr]
    spec.loader.exec_module(before)  # type: ignore[union-attr]

    capture = Capture.open(args.capture)
    source, detector = capture.frame_source(), Detector("net")
    frames = [[detector.detect(image, camera=c) for c, image in
               enumerate(with_sensor_noise(source.read(f), args.sensor_noise, f))] for f in range(capture.n_frames)]
    a = [before.build_candidates(capture.rig, views) for views in frames]
    b = [after.build_candidates(capture.rig, views) for views in frames]
    same = all(np.array_equal(x.blob_ids, y.blob_ids) for x, y in zip(a, b))
    worst = max(float(np.abs(x.points - y.points).max(initial=0.0)) for x, y in zip(a, b))
    best = {"before": np.inf, "after": np.inf}
    for _ in range(args.repeats):
        for name, module in (("before", before), ("after", after)):
            start = time.process_time()
            for views in frames:
                module.build_candidates(capture.rig, views)
            best[name] = min(best[name], (time.process_time() - start) / len(frames))
    print(f"{len(frames)} frames, {np.mean([sum(len(v) for v in f) for f in frames]):.0f} dots and "
          f"{np.mean([len(x.points) for x in a]):.0f} candidates per frame; same blob-id rows: {same}; "
          f"largest point difference {worst:.1e} mm; CPU ms per frame: before {1000 * best['before']:.2f}, "
          f"after {1000 * best['after']:.2f} ({best['before'] / best['after']:.2f}x)")


if __name__ == "__main__":
    main()
