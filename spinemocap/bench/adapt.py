"""The adaptation benchmark (``spinemocap bench adapt``): ``detector adapt`` on an appearance the
lab's weights handle poorly, before and after, on the same capture and on a second one.

The studio renders a ``tiny`` capture whose tape and skin the starting weights have not learnt
(default: red tape on darker skin at the ``lab`` level, :data:`SHIFTED`) and a second one of the same appearance (another seed: body,
motion, lighting) that adaptation never sees. ``detector adapt`` then learns from the first
capture's own tracked frames (no ground truth used), starting from those weights (default: the
studio-only ones, :data:`STUDIO_WEIGHTS`), and both captures are scored with the starting and the
adapted weights: dot recall and precision of the detector on every ``step``-th frame
against the dots' true centres on the tape surface (one-to-one within
:data:`spinemocap.bench.detect.MATCH_PX`; dots the studio marks hidden or within half a dot of the
border are left out, detections near them count neither way), and the tracked error (mean / p95
mm), swapped dot-frames and flagged frames of ``track`` against the ground truth.
"""

from __future__ import annotations

import json
import platform
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..app.adapt import LabelSettings, adapt_detector
from ..app.run import NoTapeFound, TrackingWarning, track_capture_result
from ..app.training_data import SynthDataSettings
from ..camera import Camera
from ..capture import MANIFEST, Capture, set_detector_weights
from ..detect.detector import STUDIO_WEIGHTS, shipped_weights_path
from ..fileio import atomic_write
from ..markers import OBSERVED
from ..synth import SynthConfig
from ..synth.writer import write_capture
from ..track.evaluate import evaluate_tracking
from .detect import match
from .records import JsonRecord

#: The shifted appearance: red tape on darker skin (the studio-only weights :data:`STUDIO_WEIGHTS`
#: find about two thirds of its dots; the default lab-mix weights learnt red tape), at the ``lab``
#: level (skin strain, tape tension, 0.5 px calibration error, sensor noise).
SHIFTED = {"tape_colour": "red", "skin_tone": 0.7, "realism": "lab"}
SEEN_SEED, UNSEEN_SEED = 0, 1


@dataclass(frozen=True)
class DetectionScore(JsonRecord):
    """The ``net`` detector's dots against a capture's truth (:func:`detection_scores`): recall,
    precision, and the dots found, missed and found where no visible dot is."""

    recall: float
    precision: float
    dots_found: int
    dots_missed: int
    false_dots: int



@dataclass(frozen=True)
class TrackingScore(JsonRecord):
    """``track`` of a capture against its truth (:func:`tracking_scores`): mean and 95th
    percentile error, mean error of the observed dots (mm), swapped dot-frames, flagged and
    unsolved frames, and the share of dot-frames observed (0-1)."""

    mean_mm: float
    p95_mm: float
    observed_mean_mm: float
    swaps: int
    flagged_frames: int
    unsolved_frames: int
    observed_share: float



@dataclass(frozen=True)
class TrackingFailure(JsonRecord):
    """``track`` found no tape: its problem, recorded in the row."""

    error: str



@dataclass(frozen=True)
class AdaptRow:
    """One capture ("adapted on" or "unseen") with one set of weights ("start" or "adapted"): the
    detection and the tracking scores."""

    capture: str
    weights: str
    detection: DetectionScore
    tracking: TrackingScore | TrackingFailure

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: capture, weights, the detection's keys, then ``tracking``."""
        return {"capture": self.capture, "weights": self.weights, **self.detection.to_dict(),
                "tracking": self.tracking.to_dict()}


@dataclass(frozen=True)
class AdaptNumbers:
    """``bench adapt``'s numbers (:func:`run_adapt_benchmark`): the shifted appearance, preset,
    frames per capture, frame step of the detection scores, the starting weights, the training
    settings, the adapted labels (frames, views, views skipped, dots, studio views), the machine,
    the wall seconds and every row."""

    appearance: dict[str, Any]
    preset: str
    frames: int
    step: int
    start_weights: str
    train: dict[str, int]
    labels: dict[str, int]
    machine: str
    wall_s: float
    rows: list[AdaptRow]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``--json`` writes."""
        return {"appearance": self.appearance, "preset": self.preset, "frames": self.frames, "step": self.step,
                "start_weights": self.start_weights, "train": self.train, "labels": self.labels,
                "machine": self.machine, "wall_s": self.wall_s, "rows": [row.to_dict() for row in self.rows]}


def detection_scores(capture: Capture, weights: Path | None, step: int = 2) -> DetectionScore:
    """Dot recall and precision of the ``net`` detector with ``weights`` (None: shipped) on every
    ``step``-th frame of a studio capture (see the module)."""
    from ..detect import Detector

    detector = Detector("net", weights=weights) if weights else Detector("net")
    truth = capture.groundtruth()
    surface = truth["dots"] + capture.tape.thickness_mm * truth["dot_normals"]
    true_rig = [Camera(name, truth["rig_K"][c], truth["rig_dist"][c], truth["rig_R"][c], truth["rig_t"][c], camera.size)
                for c, (name, camera) in enumerate(zip(capture.camera_names, capture.rig))]
    found = missed = false = 0
    source = capture.frame_source()
    try:
        for frame in range(0, capture.n_frames, step):
            for c, image in enumerate(source.read(frame)):
                if image is None:
                    continue
                camera = true_rig[c]
                uv = camera.project(surface[frame])
                h, w = image.shape[:2]
                half = 0.5 * capture.tape.dot_diameter_mm * camera.K[0, 0] / camera.depth(surface[frame])
                inside = (uv[:, 0] >= half) & (uv[:, 1] >= half) & (uv[:, 0] < w - half) & (uv[:, 1] < h - half)
                visible = truth["visible"][frame, c] & inside
                dots = detector.detect(image, camera=c).uv
                i, j = match(dots, uv[visible])
                hidden_near = match(np.delete(dots, i, axis=0), uv[~visible])[0]
                found += len(i)
                missed += int(visible.sum()) - len(i)
                false += len(dots) - len(i) - len(hidden_near)
    finally:
        close = getattr(source, "close", None)
        if close is not None:
            close()
    return DetectionScore(recall=found / max(found + missed, 1), precision=found / max(found + false, 1),
                          dots_found=found, dots_missed=missed, false_dots=false)


def tracking_scores(capture_dir: Path, out: Path) -> TrackingScore | TrackingFailure:
    """``track`` of a studio capture (its ``detector_weights`` if named) scored against its ground truth."""
    capture = Capture.open(capture_dir)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TrackingWarning)
            result = track_capture_result(capture_dir, out, progress=False)
    except NoTapeFound as exc:
        return TrackingFailure(exc.problem)
    accuracy = evaluate_tracking(result.table, capture.groundtruth(), capture.tape.graph.min_spacing_mm)
    arrays = result.table.to_arrays()
    observed = arrays.status == OBSERVED
    return TrackingScore(mean_mm=accuracy.mean_error_mm, p95_mm=accuracy.p95_error_mm,
                         observed_mean_mm=accuracy.observed.mean, swaps=accuracy.label_swaps,
                         flagged_frames=len(result.flagged_frames()),
                         unsolved_frames=accuracy.frames_without_solution, observed_share=float(observed.mean()))


def run_adapt_benchmark(work: Path, frames: int = 30, epochs: int = 4, steps: int = 30, studio_scenes: int = 6,
                        appearance: dict | None = None, step: int = 2, progress: bool = True,
                        say: Callable[[str], None] = print, start_weights: Path | None = None) -> AdaptNumbers:
    """Render, adapt and score (see the module) in the folder ``work``; returns the JSON-ready
    numbers. ``start_weights``: the weights the lab has before adapting, the peer scored beside the adapted
    ones (default: the studio-only weights, which the shifted appearance shifts)."""
    from ..detect.train import TrainSettings

    start = time.perf_counter()
    appearance = appearance or SHIFTED
    start_weights = start_weights or shipped_weights_path(STUDIO_WEIGHTS)
    captures = {}
    for name, seed in (("adapted on", SEEN_SEED), ("unseen", UNSEEN_SEED)):
        root = work / f"capture_{seed}"
        if not (root / "capture.toml").is_file():
            write_capture(SynthConfig.preset("tiny", frames=frames, seed=seed, **appearance), root, progress=progress)
        captures[name] = root
    out = work / "adapted"
    adapted = adapt_detector(captures["adapted on"], out, label_settings=LabelSettings(),
                             train_settings=TrainSettings(epochs=epochs, steps=steps, lr=1e-3),
                             studio_settings=SynthDataSettings(scenes=studio_scenes, layouts=("tiny", "artificial")),
                             weights=start_weights, progress=progress)
    rows = []
    for name, root in captures.items():
        for label, weights in (("start", start_weights), ("adapted", adapted.weights)):
            detection = detection_scores(Capture.open(root), weights, step)
            manifest = (root / MANIFEST).read_text()  # the weights named for track, then the manifest restored
            set_detector_weights(root, weights)
            try:
                tracking = tracking_scores(root, work / "tracked" / f"{root.name}_{label}")
            finally:
                (root / MANIFEST).write_text(manifest)
            row = AdaptRow(name, label, detection, tracking)
            rows.append(row)
            say(describe(row))
    return AdaptNumbers(appearance=appearance, preset="tiny", frames=frames, step=step, start_weights=str(start_weights),
                        train={"epochs": epochs, "steps": steps, "studio_scenes": studio_scenes},
                        labels={"frames": len(adapted.frames), "views": adapted.views,
                                "views_skipped": adapted.views_skipped, "dots": adapted.dots,
                                "studio_views": adapted.studio_views},
                        machine=f"{platform.machine()} {platform.processor() or ''}".strip(),
                        wall_s=time.perf_counter() - start, rows=rows)


def describe(row: AdaptRow) -> str:
    t = row.tracking
    tracked = (f"{t.mean_mm:.2f} mm mean (p95 {t.p95_mm:.2f}), {t.swaps} swaps, {t.flagged_frames} flagged, "
               f"{t.unsolved_frames} unsolved" if isinstance(t, TrackingScore) else t.error)
    return (f"{row.capture:>10} / {row.weights:<7}: recall {row.detection.recall:.3f}, precision "
            f"{row.detection.precision:.3f}; tracked {tracked}")


def format_table(numbers: AdaptNumbers) -> str:
    lines = ["| capture | weights | dot recall | dot precision | tracked mean / p95 mm | swaps | flagged frames | unsolved |",
             "|---|---|---|---|---|---|---|---|"]
    for r in numbers.rows:
        t = r.tracking
        tracked = (f"{t.mean_mm:.2f} / {t.p95_mm:.2f} | {t.swaps} | {t.flagged_frames} | {t.unsolved_frames}"
                   if isinstance(t, TrackingScore) else f"{t.error} | - | - | all")
        lines.append(f"| {r.capture} | {r.weights} | {r.detection.recall:.3f} | {r.detection.precision:.3f} | {tracked} |")
    return "\n".join(lines)


def save(numbers: AdaptNumbers, path: Path) -> None:
    """The numbers as indented JSON (atomic; the folder made if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as handle:
        json.dump(numbers.to_dict(), handle, indent=2, default=float)
