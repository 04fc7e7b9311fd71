"""Issue 15: the detector's clean-up (stages 2-3 after the network) before and after a change, on
a capture's frames: the same dots and masks, and CPU ms per camera image and per frame, the two
versions alternating image by image in one process (the same load for both).

1. A tracking run (``track_source``, frames in memory, cameras serial) records what the tracker
   hands the detector per camera image: its boxes (full search every 10th frame, predicted boxes
   in between) and the network's mask of every box (the network is not timed: it is the same code).
2. Both versions then clean up every recorded image with those network masks
   (``Detector._segment_with_dots``: extension, snap, dots, kept instances). ``--grey``: the
   'after' version is given the image's grey levels, as ``Detector.detect`` gives them since
   the clean-up's fourth round (it converts the image once for MRF2 anyway): not timed.
   ``--grey-before``: the previous version is given it too (a previous version from that round
   on takes it), so that both are timed as ``detect()`` runs them.
   Dots (positions and confidences) and masks are compared bit for bit. ``--inexact``: for a
   change that is not bit for bit (session 27's cleanup6), the differences are counted instead
   (images whose masks differ and by how many pixels, dot counts, dots without a partner within
   1 px, the largest shift of partnered dots) and the timing goes on.

The previous package is imported under another name, e.g.

    mkdir -p /tmp/before && git archive f1ffc42 spinemocap | tar -x -C /tmp/before
    mv /tmp/before/spinemocap /tmp/before/spinemocap_before
    OMP_NUM_THREADS=1 python docs/bench/cleanup_ab.py CAPTURE_DIR /tmp/before --frames 20 --rounds 5
    # frames 40-79 (the heavy flexion part), the grey image given to the new version
    OMP_NUM_THREADS=1 python docs/bench/cleanup_ab.py CAPTURE_DIR /tmp/before --first 40 --frames 40 --grey
    # both versions given the grey image (the previous one takes it too)
    OMP_NUM_THREADS=1 python docs/bench/cleanup_ab.py CAPTURE_DIR /tmp/before --first 40 --frames 40 --grey --grey-before
    # an inexact change: count what differs
    OMP_NUM_THREADS=1 python docs/bench/cleanup_ab.py CAPTURE_DIR /tmp/before --first 40 --frames 40 --grey --grey-before --inexact
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
import warnings
from pathlib import Path

import cv2
import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("before", type=Path, help="a folder holding the previous package as spinemocap_before/")
    parser.add_argument("--first", type=int, default=0, help="first frame tracked")
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--grey", action="store_true", help="give the 'after' version the grey image (not timed)")
    parser.add_argument("--grey-before", action="store_true", help="with --grey: give it to the previous version too")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--inexact", action="store_true", help="count differing masks and dots instead of stopping")
    args = parser.parse_args()
    cv2.setNumThreads(1)  # as the tracker's camera threads set it

    sys.path.insert(0, str(args.before))
    import spinemocap_before.detect.detector as before_detector

    import spinemocap.detect.detector as after_detector
    from spinemocap.app.run import track_source
    from spinemocap.app.streaming import SpeedOptions
    from spinemocap.bench.speed import MemorySource
    from spinemocap.capture import Capture, to_grey

    cap = Capture.open(args.capture)
    source = cap.frame_source()
    span = range(args.first, args.first + args.frames)
    frames = [source.read(f) if f in span else [] for f in range(span.stop)]
    where = {id(image): (f, c) for f, images in enumerate(frames) for c, image in enumerate(images)}
    greys = {(f, c): to_grey(image) for f, images in enumerate(frames) for c, image in enumerate(images)} if args.grey else {}

    # 1. record the tracker's boxes and the network's masks
    calls, nets, current = [], {}, {}
    segment_boxes, net_mask = after_detector.NetSegmenter.segment_boxes, after_detector.NetSegmenter._net_mask

    def recording_segment_boxes(self, image, boxes, *grey):
        current[0] = where[id(image)]
        calls.append((current[0], list(boxes)))
        return segment_boxes(self, image, boxes, *grey)

    def recording_net_mask(self, image, box):
        mask = net_mask(self, image, box)
        nets[(current[0], _key(box))] = mask.copy()
        return mask

    after_detector.NetSegmenter.segment_boxes = recording_segment_boxes
    after_detector.NetSegmenter._net_mask = recording_net_mask
    warnings.simplefilter("ignore")
    result = track_source(MemorySource(frames, list(source.camera_names)), cap.rig, cap.tape, cap.fps,
                          span, up=cap.up, progress=False, speed=SpeedOptions(workers=1, prefetch=0))
    after_detector.NetSegmenter.segment_boxes = segment_boxes
    print(f"recorded {len(calls)} camera images ({result.detector_searches}), {len(nets)} network masks")

    # 2. both versions on the recorded images, the network's masks replayed
    for module in (after_detector, before_detector):
        module.NetSegmenter._net_mask = lambda self, image, box: nets[(current[threading.get_ident()], _key(box))]
    detectors = {"before": before_detector.Detector("net"), "after": after_detector.Detector("net")}

    def clean_up(name, key, boxes):
        current[threading.get_ident()] = key
        if greys and (name == "after" or args.grey_before):
            return detectors[name]._segment_with_dots(frames[key[0]][key[1]], boxes, greys[key])
        return detectors[name]._segment_with_dots(frames[key[0]][key[1]], boxes)

    if args.inexact:
        _count_differences(calls, clean_up)
    else:
        dots = worst = 0.0
        for key, boxes in calls:
            a, b = clean_up("before", key, boxes), clean_up("after", key, boxes)
            if len(a.uv) != len(b.uv) or not (a.mask == b.mask).all() or not (a.confidence == b.confidence).all():
                raise SystemExit(f"frame {key[0]} camera {key[1]}: other dots or mask ({len(a.uv)} vs {len(b.uv)} dots)")
            dots += len(a.uv)
            worst = max(worst, float(np.abs(a.uv - b.uv).max()) if len(a.uv) else 0.0)
        print(f"same masks and dot counts on every image ({int(dots)} dots), largest position difference {worst:.2g} px")

    cpu = alternating_rounds(calls, lambda name, call: clean_up(name, *call), args.rounds, args.frames)
    for name, values in cpu.items():
        m = float(np.median(values))
        print(f"{name}: median {m * 1e3 / args.frames:.1f} CPU ms/frame, {m * 1e3 / len(calls):.2f} ms/camera image")
    print(f"after / before (medians): {np.median(cpu['after']) / np.median(cpu['before']):.3f}")


def alternating_rounds(calls: list, run, rounds: int, n_frames: int) -> dict[str, list[float]]:
    """Time ``run(name, call)`` of the versions ``before`` and ``after`` over every recorded call,
    ``rounds`` times, the versions' order swapped every round (thread CPU, so other threads' work
    is not counted); print each round's CPU ms per frame and the ratio; return each version's CPU
    seconds per round."""
    cpu: dict[str, list[float]] = {"before": [], "after": []}
    for r in range(rounds):
        total = {"before": 0.0, "after": 0.0}
        for call in calls:
            for name in (("before", "after") if r % 2 == 0 else ("after", "before")):
                t = time.thread_time()
                run(name, call)
                total[name] += time.thread_time() - t
        for name in total:
            cpu[name].append(total[name])
        print(f"round {r}: before {total['before'] * 1e3 / n_frames:.2f}, after {total['after'] * 1e3 / n_frames:.2f} "
              f"CPU ms/frame, ratio {total['after'] / total['before']:.3f} (1-min load {os.getloadavg()[0]:.1f})")
    return cpu


def _count_differences(calls, clean_up) -> None:
    """Print how the two versions' masks and dots differ over the recorded images: images with
    another mask (and the differing pixels, as a share of the masks' pixels), images with another
    dot count, dots of either version without a partner of the other within 1 px, and the largest
    and 99th-percentile distance of partnered dots (px)."""
    images = masks = counts = unpartnered = mask_px = differing_px = 0
    dots = 0
    shifts: list[np.ndarray] = []
    for key, boxes in calls:
        a, b = clean_up("before", key, boxes), clean_up("after", key, boxes)
        images += 1
        differ = int(np.count_nonzero(a.mask != b.mask))
        masks += differ > 0
        differing_px += differ
        mask_px += int(np.count_nonzero(a.mask))
        counts += len(a.uv) != len(b.uv)
        dots += len(a.uv)
        if len(a.uv) and len(b.uv):
            distance = np.linalg.norm(a.uv[:, None] - b.uv[None], axis=2)
            unpartnered += int((distance.min(axis=1) > 1.0).sum() + (distance.min(axis=0) > 1.0).sum())
            nearest = distance.min(axis=1)
            shifts.append(nearest[nearest <= 1.0])
        else:
            unpartnered += len(a.uv) + len(b.uv)
    shift = np.concatenate(shifts) if shifts else np.zeros(0)
    print(f"{images} images, {dots} dots before: masks differ on {masks} images ({differing_px} of {mask_px} mask px, "
          f"{differing_px / max(mask_px, 1):.2%}), dot counts differ on {counts}, {unpartnered} dots without a partner "
          f"within 1 px; partnered dots moved by at most {shift.max() if len(shift) else 0:.3g} px "
          f"(99th percentile {np.percentile(shift, 99) if len(shift) else 0:.3g} px)")


def _key(box) -> tuple[int, int, int, int]:
    return box[0].start, box[0].stop, box[1].start, box[1].stop


if __name__ == "__main__":
    main()
