"""Writing a synthetic capture folder (readable by :meth:`spinemocap.capture.Capture.open`).

Layout::

    OUT/capture.toml, rig.toml          (Capture.save; [subject] has up/facing and the phenotype;
                                         rig.toml is the calibrated rig: off by calibration_error_px)
    OUT/images/<cam>/000000.png         (or OUT/videos/<cam>.avi, lossless UT Video, with video=True)
    OUT/masks/<cam>/000000.png          tape silhouettes (255 = tape), always images
    OUT/groundtruth.npz                 see Scene.groundtruth
    OUT/synth.toml                      the SynthConfig that made it

Every file goes through :mod:`spinemocap.fileio`'s atomic writers.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..capture import VIDEO_PATTERN, Capture, VideoWriter
from ..fileio import atomic_write, write_toml
from .scene import Scene, SynthConfig, build_scene


def _write_png(path: Path, image: np.ndarray) -> None:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    with atomic_write(path, "wb") as handle:
        handle.write(data.tobytes())


def write_groundtruth(scene: Scene, path: str | os.PathLike) -> Path:
    """Save ``scene.groundtruth`` as a compressed npz (atomically)."""
    path = Path(path)
    with atomic_write(path, "wb") as handle:
        np.savez_compressed(handle, **scene.groundtruth)
    return path


def write_capture(config: SynthConfig, out_dir: str | os.PathLike, progress: bool = True) -> Path:
    """Render ``config`` into a capture folder ``out_dir``; returns its path."""
    from tqdm import tqdm

    root = Path(out_dir)
    scene = build_scene(config)
    media = "video" if config.video else "images"
    capture = Capture(root=root, name=config.name, fps=scene.fps, n_frames=scene.n_frames, rig=scene.calibrated_rig,
                      tape=scene.tape, subject=scene.subject(), media=media, video_pattern=VIDEO_PATTERN)
    root.mkdir(parents=True, exist_ok=True)
    writers = {}
    try:
        if config.video:
            writers = _open_videos(root, capture, scene)
        for frame in tqdm(range(scene.n_frames), desc=f"rendering {len(scene.rig)} cameras", unit="frame",
                          disable=not progress):
            rendered = scene.render(frame)
            for cam, image, mask in zip(scene.rig.names, rendered.images, rendered.masks):
                if config.video:
                    writers[cam].write(image)
                else:
                    _write_png(root / capture.image_pattern.format(camera=cam, frame=frame), image)
                _write_png(root / "masks" / cam / f"{frame:06d}.png", mask.astype(np.uint8) * 255)
        for writer in writers.values():
            writer.close()  # renames the finished video into place
        writers = {}
    finally:
        for writer in writers.values():  # failure: drop partial videos
            writer.abort()
        scene.close()
    write_groundtruth(scene, root / "groundtruth.npz")
    write_toml(root / "synth.toml", {"synth": config.to_dict()})
    capture.save()  # last: a folder with capture.toml is complete
    return root


def _open_videos(root: Path, capture: Capture, scene: Scene) -> dict[str, VideoWriter]:
    return {cam.name: VideoWriter(root / capture.video_pattern.format(camera=cam.name), scene.fps, cam.size)
            for cam in scene.rig}
