"""cProfile of tracking a capture from its files, cameras one after the other (no threads, so the
profile sees every call): CPU s per frame, each 3D stage's ms per 10-frame block, the top calls.

    python docs/bench/profile_capture.py CAPTURE_DIR --frames 100 --out profile.prof
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
import warnings
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("profile.prof"))
    args = parser.parse_args()
    from spinemocap.app.run import track_source
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.capture import Capture

    capture = Capture.open(args.capture)
    n = min(args.frames, capture.n_frames)
    warnings.simplefilter("ignore")
    profile = cProfile.Profile()
    cpu = time.process_time()
    profile.enable()
    result = track_source(capture.frame_source(), capture.rig, capture.tape, capture.fps, range(n), up=capture.up,
                          progress=False, speed=SpeedOptions(workers=1, prefetch=0))
    profile.disable()
    print(f"CPU s/frame {(time.process_time() - cpu) / n:.3f} (profiled)")
    for stage in ("detect", "candidates", "lp", "mrf1", "mrf2", "status"):
        ms = np.array([frame.stage_ms.get(stage, 0.0) for frame in result.frames])
        blocks = [round(float(b.mean()), 1) for b in np.array_split(ms, max(1, n // 10))]
        print(f"{stage}: mean {ms.mean():.1f} ms, by 10-frame block {blocks}")
    profile.dump_stats(args.out)
    pstats.Stats(profile).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
