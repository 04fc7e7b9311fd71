"""Writing a synthetic capture folder (readable by :meth:`spinemocap.capture.Capture.open`).

Layout::

    OUT/capture.toml, rig.toml          (Capture.save; [subject] has up/facing and the phenotype;
                                         rig.toml is the calibrated rig: off by calibration_error_px)
    OUT/images/<cam>/000000.png         (or OUT/videos/<cam>.avi, lossless UT Video, with video=True)
    OUT/masks/<cam>/000000.png          tape silhouettes (255 = tape), always images
    OUT/groundtruth.npz                 see Scene.groundtruth (and write_camera_recordings)
    OUT/synth.toml                      the SynthConfig that made it
    OUT/reference.toml                  with ``reference``: the L-frame's design and pose (what a
                                         lab enters; capture.toml names it)

Every file goes through :mod:`spinemocap.fileio`'s atomic writers.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from ..capture import VIDEO_PATTERN, Capture
from ..fileio import atomic_write, write_toml
from ..media import VideoWriter
from ..timebase import CameraClock
from .clocks import AUDIO_RATE, CameraRecording, camera_audio, clap_time_s, plan_recordings
from .scene import DEVELOP_WORKERS, RenderedFrame, Scene, SynthConfig, build_scene


def write_png(path: Path, image: np.ndarray) -> None:
    """Encode ``image`` (8-bit, BGR or grey) as PNG and write it atomically (thread-safe: OpenCV
    encodes without the GIL)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    with atomic_write(path, "wb") as handle:
        handle.write(data.tobytes())


def frame_files(root: Path, capture: Capture, frame: int, rendered: RenderedFrame,
                images: bool = True) -> list[tuple[Path, np.ndarray]]:
    """(path, 8-bit image) of every PNG file of a rendered frame: the camera images (unless
    ``images`` is False, for video captures) and the tape masks (255 = tape)."""
    files = []
    for cam, image, mask in zip(capture.rig.names, rendered.images, rendered.masks):
        if images:
            files.append((root / capture.image_pattern.format(camera=cam, frame=frame), image))
        if mask is not None:  # rendered with its tape masks
            files.append((root / "masks" / cam / f"{frame:06d}.png", mask.astype(np.uint8) * 255))
    return files


def render_frames(scene: Scene, root: Path, capture: Capture, frames: Iterable[int], reference: bool = False,
                  videos: dict | None = None) -> None:
    """Render ``frames`` of ``scene`` and write their files under ``root`` (:func:`frame_files`;
    camera images go to the ``videos`` writers by camera name instead, when given).

    Each frame's PNG files are encoded and written on worker threads while the next frame
    renders. ``reference``: the reference renderer (files written one
    after the other in this thread), the peer of ``spinemocap bench render``."""
    if reference:
        for frame in frames:
            rendered = scene.render(frame, reference=True)
            _write_video_frames(videos, scene, rendered)
            for path, image in frame_files(root, capture, frame, rendered, images=videos is None):
                write_png(path, image)
        return
    with ThreadPoolExecutor(max_workers=DEVELOP_WORKERS, thread_name_prefix="synth-png") as pool:
        pending: list[Future] = []
        for frame in frames:
            rendered = scene.render(frame)
            for job in pending:  # the previous frame's files, written while this one rendered
                job.result()
            _write_video_frames(videos, scene, rendered)
            pending = [pool.submit(write_png, path, image)
                       for path, image in frame_files(root, capture, frame, rendered, images=videos is None)]
        for job in pending:
            job.result()


def _write_video_frames(videos: dict | None, scene: Scene, rendered: RenderedFrame) -> None:
    """Append a frame's camera images to the open video writers (none: nothing to do)."""
    if videos is None:
        return
    for cam, image in zip(scene.rig.names, rendered.images):
        videos[cam].write(image)


def write_groundtruth(scene: Scene, path: str | os.PathLike) -> Path:
    """Save ``scene.groundtruth`` as a compressed npz (atomically)."""
    path = Path(path)
    with atomic_write(path, "wb") as handle:
        np.savez_compressed(handle, allow_pickle=False, **scene.groundtruth)
    return path


def write_capture(config: SynthConfig, out_dir: str | os.PathLike, progress: bool = True) -> Path:
    """Render ``config`` into a capture folder ``out_dir``; returns its path."""
    from tqdm import tqdm

    root = Path(out_dir)
    scene = build_scene(config)
    media = "video" if config.video else "images"
    capture = Capture(root=root, name=config.name, fps=scene.fps, n_frames=scene.n_frames, rig=scene.calibrated_rig,
                      tape=scene.tape, subject=scene.subject(), media=media, video_pattern=VIDEO_PATTERN,
                      reference_file="reference.toml" if scene.reference is not None else None)
    root.mkdir(parents=True, exist_ok=True)
    if config.unsynchronised:
        try:
            truth = write_camera_recordings(scene, root, capture, progress)
        finally:
            scene.close()
        scene.groundtruth.update(truth)
        if config.camera_fps is not None:  # a lab knows its cameras' rates; their offsets stay unknown (0)
            capture.camera_clocks = {name: CameraClock(fps=float(rate))
                                     for name, rate in zip(capture.camera_names, config.camera_fps)}
        _finish(config, scene, capture, root)
        return root
    writers = {}
    try:
        if config.video:
            writers = _open_videos(root, capture, scene)
        frames = tqdm(range(scene.n_frames), desc=f"rendering {len(scene.rig)} cameras", unit="frame",
                      disable=not progress)
        render_frames(scene, root, capture, frames, videos=writers or None)
        for writer in writers.values():
            writer.close()  # renames the finished video into place
        writers = {}
    finally:
        for writer in writers.values():  # failure: drop partial videos
            writer.abort()
        scene.close()
    _finish(config, scene, capture, root)
    return root


def _finish(config: SynthConfig, scene: Scene, capture: Capture, root: Path) -> None:
    write_groundtruth(scene, root / "groundtruth.npz")
    write_toml(root / "synth.toml", {"synth": config.to_dict()})
    if scene.reference is not None:
        scene.reference.to_toml(root / "reference.toml")
    capture.save()  # last: a folder with capture.toml is complete


def write_camera_recordings(scene: Scene, root: Path, capture: Capture, progress: bool = True) -> dict[str, np.ndarray]:
    """Each camera's own recording (:mod:`spinemocap.synth.clocks`) written under ``root``: its
    frames on its clock and rate, from its start to the capture's last frame, without its dropped
    frames (gaps in the video's timestamps), with the clap on its audio track when
    ``config.clap``; no tape masks (they are per capture frame). The true clock offsets add the
    realism level's sync error (a camera's frame shows ``sync_offsets_s`` later). Returns the
    ground truth of the clocks: ``clock_offsets_s`` (C,) s, ``camera_fps`` (C,) frames/s,
    ``dropped_slots`` (K, 2) int [camera, slot], ``clap_time_s`` (capture time of the clap, s; NaN
    without one)."""
    from tqdm import tqdm

    config = scene.config
    n = len(scene.rig)
    offsets = np.zeros(n) if config.camera_offsets_s is None else np.array(config.camera_offsets_s, float)
    offsets = offsets - scene.sync_offsets_s
    rates = np.full(n, scene.fps) if config.camera_fps is None else np.array(config.camera_fps, float)
    rng = np.random.default_rng([scene.rng_seed, 5])
    recordings = plan_recordings(offsets, rates, float(scene.times[-1]), config.drop_frames, rng)
    clap_at = clap_time_s(recordings, float(scene.times[-1])) if config.clap else float("nan")
    bar = tqdm(total=sum(len(r.recorded) for r in recordings), desc=f"rendering {n} cameras on their own clocks",
               unit="image", disable=not progress)
    with bar:
        for c, recording in enumerate(recordings):
            _write_recording(scene, root, capture, c, recording, clap_at, rng, bar)
    dropped = [(c, k) for c, r in enumerate(recordings) for k in r.dropped]
    return {"clock_offsets_s": offsets, "camera_fps": rates, "clap_time_s": np.array(clap_at),
            "dropped_slots": np.array(dropped, dtype=np.int64).reshape(-1, 2)}


def _write_recording(scene: Scene, root: Path, capture: Capture, camera: int, recording: CameraRecording,
                     clap_at: float, rng: np.random.Generator, bar) -> None:
    cam = scene.rig[camera]
    if not scene.config.video:
        for slot in recording.recorded:
            image = scene.camera_image_at(camera, recording.capture_time(slot), slot, recording.fps)
            write_png(root / capture.image_pattern.format(camera=cam.name, frame=slot), image)
            bar.update()
        return
    audio = None
    if scene.config.clap:
        audio = camera_audio(recording, clap_at, gain=float(rng.uniform(0.5, 1.0)), rng=rng)
    writer = VideoWriter(root / capture.video_pattern.format(camera=cam.name), recording.fps, cam.size,
                         audio_rate=AUDIO_RATE if audio is not None else None)
    try:
        written = 0
        for slot in recording.recorded:
            image = scene.camera_image_at(camera, recording.capture_time(slot), slot, recording.fps)
            writer.write(image, slot)
            if audio is not None:  # the sound up to this frame's end, as the video goes
                upto = min(len(audio), int(round((slot + 1) / recording.fps * AUDIO_RATE)))
                writer.write_audio(audio[written:upto])
                written = max(written, upto)
            bar.update()
        if audio is not None:
            writer.write_audio(audio[written:])
        writer.close()
    except BaseException:
        writer.abort()
        raise


def _open_videos(root: Path, capture: Capture, scene: Scene) -> dict[str, VideoWriter]:
    return {cam.name: VideoWriter(root / capture.video_pattern.format(camera=cam.name), scene.fps, cam.size)
            for cam in scene.rig}
