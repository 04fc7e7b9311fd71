"""Issue 15: tracking accuracy of a capture's frames read from its PNG files (not held in memory),
for checking an inexact detector change against the ground truth: mean / p95 error (mm), label
swaps, the dots' status counts, and CPU s per frame (this process, cameras in threads as
``track`` runs them by default). Run it once per version, the package chosen by ``PYTHONPATH``:

    mkdir -p /tmp/main && git archive 36b0a78 spinemocap | tar -x -C /tmp/main
    OMP_NUM_THREADS=1 PYTHONPATH=/tmp/main python docs/bench/cleanup_accuracy.py CAPTURE_DIR --frames 0:100
    OMP_NUM_THREADS=1 PYTHONPATH=$PWD python docs/bench/cleanup_accuracy.py CAPTURE_DIR --frames 0:100 --save after.npz

``--save``: the tracked positions (F, D, 3) mm and status, for comparing two runs
(``--compare OTHER.npz`` prints the largest and mean position difference, mm).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import spinemocap
from spinemocap.app.run import parse_frames, track_source
from spinemocap.capture import Capture
from spinemocap.track.evaluate import evaluate_tracking


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--frames", default="0:100", help="A:B, as `track --frames` takes it")
    parser.add_argument("--save", type=Path, help="write the tracked positions here (.npz)")
    parser.add_argument("--compare", type=Path, help="an earlier run's --save file: position differences")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    capture = Capture.open(args.capture)
    source = capture.frame_source()
    frames = parse_frames(args.frames, source.n_frames)
    cpu, wall = time.process_time(), time.perf_counter()
    result = track_source(source, capture.rig, capture.tape, capture.fps, frames, up=capture.up, progress=False)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    accuracy = evaluate_tracking(result.table, capture.groundtruth(), float(capture.tape.graph.rest_length_mm.min()))
    n = len(frames)
    print(f"package {Path(spinemocap.__file__).parent}, frames {args.frames} ({n})")
    print(f"mean {accuracy.mean_error_mm:.4f} mm, p95 {accuracy.p95_error_mm:.4f} mm, max {accuracy.max_error_mm:.3f} mm, "
          f"swaps {accuracy.label_swaps}, status {accuracy.status_counts}")
    print(f"CPU {cpu / n:.3f} s/frame (PNG decoding included), wall {wall / n:.3f} s/frame, searches {result.detector_searches}")
    arrays = result.table.to_arrays()
    if args.save is not None:
        np.savez(args.save, positions=arrays["positions"], status=arrays["status"].astype(str))
    if args.compare is not None:
        other = np.load(args.compare)
        both = (arrays["status"] != "missing") & (other["status"] != "missing")
        diff = np.linalg.norm(arrays["positions"] - other["positions"], axis=2)[both]
        print(f"against {args.compare}: position difference max {diff.max():.4f} mm, mean {diff.mean():.5f} mm, "
              f"status differs at {int((arrays['status'] != other['status']).sum())} dot-frames")


if __name__ == "__main__":
    main()
