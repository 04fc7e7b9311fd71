"""Speed machinery (issue 15): detection by prediction finds the dots the full search finds, the
parallel path gives the serial path's output, masks are read only for the mask detector, and
the prefetching reader hands its errors to the consumer."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from spinemocap.app.run import track_source
from spinemocap.app.streaming import CaptureDetector, SpeedOptions, prefetched_frames
from spinemocap.fileio import InputError

pytest.importorskip("pyvista")


def _rendered(preset: str, frames: int, **overrides):
    from spinemocap.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig.preset(preset, frames=frames, **overrides))
    images = [scene.render(f, with_masks=False).images for f in range(frames)]
    return scene, images


def _same_dots(a, b) -> float:
    """Largest distance (px) between matched dots of two ViewDots lists; inf when counts differ."""
    worst = 0.0
    for va, vb in zip(a, b):
        if len(va) != len(vb):
            return float("inf")
        if len(va):
            worst = max(worst, float(np.linalg.norm(va.uv[:, None] - vb.uv[None], axis=2).min(axis=1).max()))
    return worst


def _prediction_vs_full(scene, images):
    gt = scene.groundtruth["dots"]
    full = CaptureDetector("net", scene.rig, SpeedOptions(predict=False, workers=1))
    predicted = CaptureDetector("net", scene.rig, SpeedOptions(predict=True, refresh_every=1000, workers=1))
    try:
        worst = 0.0
        for f, frame_images in enumerate(images):
            worst = max(worst, _same_dots(full(f, frame_images, None), predicted(f, frame_images, None)))
            predicted.observe(f, gt[f])
    finally:
        full.close()
        predicted.close()
    return worst, predicted.searches


@pytest.mark.slow
def test_prediction_finds_the_full_search_dots_on_the_studio():
    scene, images = _rendered("studio", 3)
    worst, searches = _prediction_vs_full(scene, images)
    assert searches["predicted"] == 2 * len(scene.rig) and searches["fallback"] == 0
    assert worst < 0.01


@pytest.fixture(scope="module")
def small_studio():
    """The studio's six cameras at a quarter of the pixels, two frames (rendered once per module)."""
    return _rendered("studio", 2, size=(1224, 800))


def test_prediction_finds_the_full_search_dots_on_a_small_studio(small_studio):
    # the default suite's version of the test above
    scene, images = small_studio
    worst, searches = _prediction_vs_full(scene, images)
    assert searches["full"] == len(scene.rig)            # only the first frame searched in full
    assert searches["predicted"] == len(scene.rig) and searches["fallback"] == 0
    assert worst < 0.01


def test_parallel_path_gives_the_serial_output():
    from spinemocap.bench.speed import MemorySource

    scene, images = _rendered("tiny", 3)
    source = MemorySource(images, scene.rig.names)

    def track(options):
        return track_source(source, scene.rig, scene.tape, scene.fps, up=scene.subject()["up"],
                            progress=False, speed=options)

    serial = track(SpeedOptions(workers=1, prefetch=0))
    parallel = track(SpeedOptions(workers=3, prefetch=2))
    a, b = serial.table.to_arrays(), parallel.table.to_arrays()
    np.testing.assert_array_equal(a["positions"], b["positions"])
    assert (a["status"] == b["status"]).all()
    assert serial.detector_searches == parallel.detector_searches


def test_masks_are_read_only_for_the_mask_detector(tmp_path):
    from spinemocap.app.run import track_capture
    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=2), tmp_path / "capture", progress=False)

    # damaged ground-truth masks: the net detector never opens them ...
    for png in (root / "masks").rglob("*.png"):
        png.write_bytes(b"not a png")
    table = track_capture(root, tmp_path / "out", detector="net", progress=False)
    assert np.isfinite(table.to_arrays()["positions"]).any()
    # ... the mask detector needs them and says which file is bad
    with pytest.raises(InputError, match="corrupt"):
        track_capture(root, tmp_path / "out", detector="mask", progress=False)
    shutil.rmtree(root / "masks")
    with pytest.raises(InputError, match="needs tape masks"):
        track_capture(root, tmp_path / "out", detector="mask", progress=False)


def test_prefetching_reader_raises_the_readers_error_and_stops():
    class Source:
        camera_names = ["a", "b"]
        n_frames = 5
        reads: list[int] = []

        def read(self, frame):
            self.reads.append(frame)
            if frame == 2:
                raise InputError(f"frame{frame}.png", "image file not found")
            return [np.zeros((4, 4, 3), np.uint8)] * 2

    source = Source()
    got = []
    with pytest.raises(InputError, match="frame2.png"):
        for frame, images, masks in prefetched_frames(source, range(5), prefetch=2):
            assert masks is None and len(images) == 2
            got.append(frame)
    assert got == [0, 1]
    assert max(source.reads) == 2  # the reader stopped at the error


def test_detector_dots_are_a_blob_pass_on_its_final_mask(small_studio):
    # The clean-up's blob pass is reused as the detector's dots (no second pass): they must be
    # the dots a separate pass over the detector's final mask finds (the pipeline before).
    from spinemocap.detect import Detector, find_dots

    _, images = small_studio
    detector = Detector("net")
    seen = 0
    for frame_images in images:
        for camera, image in enumerate(frame_images):
            view = detector.detect(image, camera=camera)
            uv, _ = find_dots(view.image, view.mask)
            assert len(view) == len(uv), f"camera {camera}"
            if len(uv):
                assert np.linalg.norm(view.uv[:, None] - uv[None], axis=2).min(axis=1).max() < 0.01
            seen += len(uv)
    assert seen > 100  # the tape was in view: the comparison was not empty
