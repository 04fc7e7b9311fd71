"""Experiment (issue 15, H100 lease of branch speeddet): is the GPU network's CPU cost per call higher for
a new input shape (cuDNN builds a plan per shape)? Crops of random sizes of one camera image go through
the stage-2 network (``NetSegmenter._logits``), timed per call; output in gpu_shapes_probe_h100.txt.

    python docs/bench/gpu_shapes_probe.py IMAGE.png
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np
import torch

from spinemocap.detect import Detector


def main() -> None:
    image = cv2.imread(sys.argv[1])
    network = Detector("net", device="cuda")._segment

    def run(label: str, shapes: list[tuple[int, int]]) -> None:
        cpu, wall = time.process_time(), time.perf_counter()
        for h, w in shapes:
            network._logits(np.ascontiguousarray(image[600:600 + h, 1000:1000 + w]))
        torch.cuda.synchronize()
        print(f"{label:40s} CPU {1e3 * (time.process_time() - cpu) / len(shapes):6.2f} ms/call, "
              f"wall {1e3 * (time.perf_counter() - wall) / len(shapes):6.2f} ms/call")

    network._logits(np.ascontiguousarray(image[600:728, 1000:1128]))  # CUDA start-up, not timed
    torch.cuda.synchronize()
    sizes = [tuple(int(v) for v in s) for s in np.random.default_rng(0).integers(60, 256, (90, 2))]
    run("30 new shapes (cuDNN on)", sizes[:30])
    run("the same 30 shapes again", sizes[:30])
    run("one shape 30 times", [(200, 176)] * 30)
    torch.backends.cudnn.enabled = False
    run("30 other new shapes, cuDNN off", sizes[30:60])
    run("the same 30 again, cuDNN off", sizes[30:60])
    torch.backends.cudnn.enabled = True
    run("30 further new shapes (cuDNN on)", sizes[60:90])


if __name__ == "__main__":
    main()
