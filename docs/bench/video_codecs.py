"""Lossless codecs for a capture's videos: frames of one camera re-encoded in each (through PyAV),
with the file size per image, the encoding CPU, the decoding CPU per image (``VideoDecoder.read``:
demux, decode, BGR; one thread, ``--rounds`` rounds) and whether every pixel came back exactly.

    python docs/bench/video_codecs.py VIDEO OUT_DIR --start 40 --frames 12 [NAME ...]

NAME: the variants below (default: all). The decoding instructions per image, which do not depend
on the machine's load, were counted with ``valgrind --tool=callgrind`` over a script that decodes
1 and 4 frames of each file (docs/BENCHMARKS.md, issue 15, branch ``vdec``).
"""

from __future__ import annotations

import argparse
import os
import time
from fractions import Fraction

import av
import cv2
import numpy as np

from spinemocap.capture import VideoDecoder

# name: (codec, pixel format stored, container, encoder options)
VARIANTS = {
    "ut_left": ("utvideo", "gbrp", "avi", {"pred": "left"}),
    "ut_none": ("utvideo", "gbrp", "avi", {"pred": "none"}),
    "ut_median": ("utvideo", "gbrp", "avi", {"pred": "median"}),
    "magic_left": ("magicyuv", "gbrp", "avi", {"pred": "left"}),
    "magic_gradient": ("magicyuv", "gbrp", "avi", {"pred": "gradient"}),
    "magic_median": ("magicyuv", "gbrp", "avi", {"pred": "median"}),
    "ffvhuff_left": ("ffvhuff", "gbrp", "avi", {"pred": "left"}),
    "ffvhuff_plane": ("ffvhuff", "gbrp", "avi", {"pred": "plane"}),
    "ffvhuff_median": ("ffvhuff", "gbrp", "avi", {"pred": "median"}),
    "huffyuv_bgra_left": ("huffyuv", "bgra", "avi", {"pred": "left"}),
    "huffyuv_rgb24_left": ("huffyuv", "rgb24", "avi", {"pred": "left"}),
    "zlib1": ("zlib", "bgr24", "avi", {"compression_level": "1"}),
    "raw": ("rawvideo", "bgr24", "avi", {}),
}


def encode(name: str, frames: list[np.ndarray], out_dir: str) -> tuple[str, float]:
    codec, pix_fmt, ext, options = VARIANTS[name]
    path = os.path.join(out_dir, f"{name}.{ext}")
    height, width = frames[0].shape[:2]
    container = av.open(path, "w")
    stream = container.add_stream(codec, rate=Fraction(100))
    stream.width, stream.height, stream.pix_fmt = width, height, pix_fmt
    stream.options = dict(options)
    cpu = time.process_time()
    for image in frames:
        container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="bgr24")))
    container.mux(stream.encode(None))
    container.close()
    return path, (time.process_time() - cpu) / len(frames)


def decode(path: str, frames: list[np.ndarray]) -> tuple[float, bool]:
    decoder = VideoDecoder(path)
    cpu, exact = 0.0, True
    for i, expected in enumerate(frames):
        start = time.thread_time()
        image = decoder.read(i)
        cpu += time.thread_time() - start
        exact = exact and np.array_equal(image, expected)  # not timed
        del image
    decoder.close()
    return cpu / len(frames), exact


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video")
    parser.add_argument("out_dir")
    parser.add_argument("names", nargs="*", default=list(VARIANTS))
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    os.makedirs(args.out_dir, exist_ok=True)
    source = VideoDecoder(args.video)
    frames = [source.read(args.start + i).copy() for i in range(args.frames)]
    source.close()
    raw_mb = frames[0].nbytes / 1e6
    files = {}
    for name in args.names:
        try:
            path, enc = encode(name, frames, args.out_dir)
        except av.error.FFmpegError as exc:
            print(f"{name}: cannot encode ({exc})", flush=True)
            continue
        files[name] = path
        size = os.path.getsize(path) / len(frames) / 1e6
        print(f"{name:20s} {size:6.2f} MB/image ({size / raw_mb:.0%} of raw), encoding {1e3 * enc:6.1f} CPU ms/image",
              flush=True)
    for rnd in range(args.rounds):
        for name, path in files.items():
            cpu, exact = decode(path, frames)
            print(f"round {rnd} {name:20s} decoding {1e3 * cpu:6.2f} CPU ms/image, exact {exact}", flush=True)


if __name__ == "__main__":
    main()
