"""Experiment (issue 15, GPU lease): how fast is detection when each camera runs in its own process
(no GIL shared between cameras) instead of a thread of one process?

Each of the capture's cameras gets a process with its own ``Detector`` (network on ``--device``,
one torch and one OpenCV thread); it decodes its camera's images, adds the lab's sensor noise, and
detects them replayed forward and backward for ``--frames`` frames the way sequence mode does: a
full two-stage search every 10th frame, else only the box around the previous frame's mask (grown
by 40 px, as :class:`spinemocap.app.streaming.CaptureDetector` grows its predicted box). After two
warm-up frames all processes start together (a barrier); detection frames/s = frames / the slowest
camera's seconds (CPU s: with ``--threads`` the whole process's). No tracking, no transfer of the results to a tracker: an upper bound of what
processes could give the detection stage.

    python docs/bench/detect_processes_probe.py CAPTURE_DIR --device cuda --frames 100
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import queue
import threading
import time
from pathlib import Path


def _camera(capture_dir: str, camera: int, frames: int, device: str, noise: float, barrier, results) -> None:
    import cv2
    import torch

    from spinemocap.app.camera_processes import mask_box
    from spinemocap.app.streaming import _training_padded_box
    from spinemocap.bench.speed import replay_order, with_sensor_noise
    from spinemocap.capture import Capture
    from spinemocap.detect import Detector

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    capture = Capture.open(Path(capture_dir))
    source = capture.frame_source()
    images = [with_sensor_noise([source.read_camera(camera, f)], noise, f)[0] for f in range(capture.n_frames)]
    order = replay_order(len(images), frames + 2)
    detector = Detector("net", device=device)
    box = None
    dots = 0

    def detect(k: int):
        nonlocal box, dots
        image = images[order[k]]
        boxes = detector.tape_boxes([image])[0] if box is None or k % 10 == 0 else [box]
        view = detector.detect(image, camera=camera, boxes=boxes)
        found = mask_box(view.mask)
        box = None if found is None else _training_padded_box(
            found[1].start - 40.0, found[0].start - 40.0, found[1].stop + 40.0, found[0].stop + 40.0, image.shape[:2])
        dots += len(view)

    for k in range(2):  # warm-up
        detect(k)
    barrier.wait()
    start, cpu = time.perf_counter(), time.process_time()
    dots = 0
    for k in range(2, frames + 2):
        detect(k)
    results.put((camera, time.perf_counter() - start, time.process_time() - cpu, dots))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--sensor-noise", type=float, default=3.0)
    parser.add_argument("--threads", action="store_true", help="cameras in threads of one process instead")
    args = parser.parse_args()
    from spinemocap.capture import Capture

    n_cameras = len(Capture.open(args.capture).rig)
    if args.threads:  # the same work in threads of this process, for comparison
        barrier, results = threading.Barrier(n_cameras), queue.Queue()
        make = threading.Thread
    else:
        ctx = mp.get_context("spawn")  # CUDA cannot be forked
        barrier, results = ctx.Barrier(n_cameras), ctx.Queue()
        make = ctx.Process  # type: ignore[assignment]
    procs = [make(target=_camera, args=(str(args.capture), c, args.frames, args.device, args.sensor_noise,
                                        barrier, results)) for c in range(n_cameras)]
    for p in procs:
        p.start()
    rows = sorted(results.get() for _ in procs)
    for p in procs:
        p.join()
    slowest = max(r[1] for r in rows)
    print(f"detection in {n_cameras} {'threads' if args.threads else 'processes'}, network on {args.device}, {args.frames} frames: "
          f"{args.frames / slowest:.2f} frames/s ({1000 * slowest / args.frames:.1f} ms per frame); "
          f"CPU s per frame (all cameras) {(max if args.threads else sum)(r[2] for r in rows) / args.frames:.3f}; "
          f"per camera s: {[round(r[1], 2) for r in rows]}, dots per frame {sum(r[3] for r in rows) / args.frames:.1f}")


if __name__ == "__main__":
    main()
