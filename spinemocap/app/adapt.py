"""The tape network adapted to a lab's own footage without labelling (``spinemocap detector adapt``).

A first tracking pass (the capture's current detector) vouches for some frames: frames without a
label-doubting flag whose tape is observed end to end. Their tracked 3D dots are the labels'
source: the tape's surface through them (a thin-plate spline from the flat tape's layout to the
tracked dots, extended to the tape's edges and ends) is projected into every camera through the
rig, lens distortion included, and filled as the tape mask; the observed dots' centres on the
tape's top surface are projected as the dot labels. The network is then fine-tuned on these
views mixed with the synthetic studio's (so that it keeps what it knew) and exported as a
weights file a capture names in ``[capture] detector_weights``.

What the labels cannot know: a body part or object between a camera and the tape (the tape's
own side facing away from a camera is left out; an arm across it is not). Labels are therefore
drawn only from frames the tracker vouches for, and a camera view only where its own detector
found some of the dots the labels place there (``LabelSettings.min_confirmed_share``).
Application layer: it joins the tracker's results, the studio and the detector's training.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

import cv2
import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import cKDTree
from tqdm import tqdm

from ..camera import Camera, Rig
from ..capture import Capture
from ..fileio import InputError, check_writable
from ..markers import OBSERVED, MarkerTable
from ..tape import TapeGraph, TapeSpec
from ..track.quality import flagged_from_confidence
from .results import read_results, write_markers
from .run import TrackResult, select_frames, track_source
from .training_data import SynthDataSettings, generate_synthetic

if TYPE_CHECKING:  # torch is imported only when the fine-tuning runs
    from ..detect.train import TrainSettings

log = logging.getLogger(__name__)

FIRST_PASS = "first_pass"   # the results folder of adapt's own first tracking pass, inside its output
ADAPT_DATA = "adapt_data"   # the capture's labelled views (shards), inside the output
STUDIO_DATA = "studio_data"  # the studio's views rendered for the mix, inside the output
SUBPIXEL_BITS = 4           # cv2.fillConvexPoly's fractional bits for the tape's outline


@dataclass(frozen=True)
class LabelSettings:
    """Which tracked frames and views become labels.

    ``min_observed_share``: share of the tape's dots a frame must have observed (its end rows
    among them: the tape's outline is then interpolated, never extrapolated by more than the
    tape's end margin); ``max_frames``: at most this many vouched-for frames, evenly spread;
    ``max_view_angle_deg``: a dot seen farther from face-on is left out of the dot labels;
    ``min_confirmed_share``: a camera view is used only where the first pass's detector found at
    least this share of the dots labelled in it within ``confirm_px`` (the tape is not hidden
    there); ``grid_mm``: the tape surface's sampling step for the outline."""

    min_observed_share: float = 0.8
    max_frames: int = 40
    max_view_angle_deg: float = 75.0
    min_confirmed_share: float = 0.25
    confirm_px: float = 3.0
    grid_mm: float = 5.0


@dataclass
class ViewLabels:
    """The labels of one camera image: ``mask`` (H, W) bool tape region, ``uv`` (N, 2) px (x, y)
    distorted dot centres, ``labels`` the N dots' names, ``camera`` the rig's index."""

    frame: int
    camera: int
    mask: np.ndarray
    uv: np.ndarray
    labels: list[str]


@dataclass
class AdaptResult:
    """What :func:`adapt_detector` did: ``weights`` the new weights file, ``frames`` the vouched-for
    frames used, ``views`` camera views labelled (``views_skipped`` left out: tape not confirmed),
    ``dots`` dot labels, ``training`` the training's metadata (``weights.json``)."""

    weights: Path
    results: Path
    frames: list[int]
    views: int
    views_skipped: int
    dots: int
    studio_views: int
    training: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------- frames
def vouched_frames(table: MarkerTable, graph: TapeGraph, min_observed_share: float = 0.8) -> list[int]:
    """Frames of ``table`` whose labels the tracker vouches for (no doubting flag, see
    :func:`spinemocap.track.quality.flagged_from_confidence`), with at least ``min_observed_share``
    of the tape's dots observed, its first and last row among them."""
    arrays = table.to_arrays()
    index = [list(arrays.labels).index(label) if label in arrays.labels else -1 for label in graph.labels]
    if min(index) < 0:
        missing = [label for label, i in zip(graph.labels, index) if i < 0]
        raise InputError(table.meta.get("source"), f"the marker table lacks the tape's dots {missing[:4]}; "
                                                   "give the results of tracking this capture")
    status = arrays.status[:, index]
    observed = status == OBSERVED
    flagged = flagged_from_confidence(status, arrays.confidence[:, index])
    rows = np.asarray(graph.row)
    ends = observed[:, rows == rows.min()].any(axis=1) & observed[:, rows == rows.max()].any(axis=1)
    keep = ~flagged & ends & (observed.mean(axis=1) >= min_observed_share)
    return [int(f) for f in arrays.frames[keep]]


def spread(frames: list[int], n: int) -> list[int]:
    """At most ``n`` of ``frames``, evenly spread over them (all when there are no more)."""
    if len(frames) <= n:
        return list(frames)
    return [frames[int(i)] for i in np.round(np.linspace(0, len(frames) - 1, n))]


# ---------------------------------------------------------------------------------- geometry
def tape_surface(graph: TapeGraph, tape: TapeSpec, points: np.ndarray, observed: np.ndarray, rig: Rig,
                 grid_mm: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """The tape's top surface through its tracked dots: ``vertices`` (A, B, 3) mm over the flat
    tape's width (A samples) and length to its ends (B samples), and ``normals`` (A, B, 3) unit,
    pointing away from the skin (to the side most cameras see). ``points`` (D, 3) mm are the
    skin points the tracker reports (one ``tape.thickness_mm`` below the surface); only
    ``observed`` (D,) dots shape the surface (a thin-plate spline from the flat layout)."""
    flat = graph.uv_mm[observed]
    spline = RBFInterpolator(flat, points[observed], kernel="thin_plate_spline", degree=1)
    v = graph.uv_mm[:, 1]
    across = np.linspace(-tape.width_mm / 2, tape.width_mm / 2, max(3, int(np.ceil(tape.width_mm / grid_mm)) + 1))
    length = v.max() - v.min() + 2 * tape.end_margin_mm
    along = np.linspace(v.min() - tape.end_margin_mm, v.max() + tape.end_margin_mm,
                        max(3, int(np.ceil(length / grid_mm)) + 1))
    uu, vv = np.meshgrid(across, along, indexing="ij")
    skin = spline(np.column_stack([uu.ravel(), vv.ravel()])).reshape(*uu.shape, 3)
    du, dv = np.gradient(skin, axis=0), np.gradient(skin, axis=1)
    normals = np.cross(du, dv)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    centre = skin.reshape(-1, 3).mean(axis=0)
    facing = [float(np.sign(np.mean(normals.reshape(-1, 3) @ (cam.center - centre)))) for cam in rig]
    if sum(facing) < 0:  # the normals point into the skin: turn them to the cameras' side
        normals = -normals
    return skin + tape.thickness_mm * normals, normals


def dot_normals(graph: TapeGraph, vertices: np.ndarray, normals: np.ndarray, tape: TapeSpec) -> np.ndarray:
    """(D, 3) the surface normal at each dot (the nearest sample of :func:`tape_surface`'s grid)."""
    v = graph.uv_mm[:, 1]
    a, b = vertices.shape[:2]
    across = np.linspace(-tape.width_mm / 2, tape.width_mm / 2, a)
    along = np.linspace(v.min() - tape.end_margin_mm, v.max() + tape.end_margin_mm, b)
    i = np.abs(graph.uv_mm[:, :1] - across[None]).argmin(axis=1)
    j = np.abs(graph.uv_mm[:, 1:] - along[None]).argmin(axis=1)
    return normals[i, j]


def view_angle_cos(camera: Camera, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N,) cosine of the angle between each surface normal and its direction to ``camera``."""
    to_camera = camera.center - points
    return np.einsum("ij,ij->i", normals, to_camera) / np.linalg.norm(to_camera, axis=1)


def tape_mask(camera: Camera, vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The tape's region (H, W) bool in ``camera``'s image: every cell of the surface grid whose
    side away from the skin faces the camera, projected with the lens distortion and filled."""
    w, h = camera.size
    mask = np.zeros((h, w), np.uint8)
    a, b = vertices.shape[:2]
    uv = camera.project(vertices.reshape(-1, 3)).reshape(a, b, 2)
    facing = view_angle_cos(camera, vertices.reshape(-1, 3), normals.reshape(-1, 3)).reshape(a, b) > 0
    scale = 1 << SUBPIXEL_BITS
    for i in range(a - 1):
        for j in range(b - 1):
            corners = uv[[i, i + 1, i + 1, i], [j, j, j + 1, j + 1]]
            if not np.isfinite(corners).all() or not facing[i:i + 2, j:j + 2].any():
                continue
            if (corners[:, 0].max() < 0 or corners[:, 1].max() < 0 or corners[:, 0].min() >= w
                    or corners[:, 1].min() >= h):
                continue
            pts = np.round(np.clip(corners, -4 * w, 4 * w) * scale).astype(np.int32)
            cv2.fillConvexPoly(mask, cv2.convexHull(pts), 1, cv2.LINE_8, SUBPIXEL_BITS)
    return mask.astype(bool)


def frame_labels(rig: Rig, tape: TapeSpec, points: np.ndarray, observed: np.ndarray, frame: int,
                 settings: LabelSettings = LabelSettings()) -> list[ViewLabels]:
    """Every camera's labels of one tracked frame: ``points`` (D, 3) mm the tracked dots (skin
    points, the graph's label order), ``observed`` (D,) the dots the tracker observed."""
    graph = tape.graph
    vertices, normals = tape_surface(graph, tape, points, observed, rig, settings.grid_mm)
    at_dots = dot_normals(graph, vertices, normals, tape)
    surface_dots = points + tape.thickness_mm * at_dots
    min_cos = np.cos(np.radians(settings.max_view_angle_deg))
    radius = tape.dot_diameter_mm / 2
    out = []
    for c, camera in enumerate(rig):
        uv = camera.project(surface_dots)
        w, h = camera.size
        # a dot near the frame's border is cut by it: no label (its blob's centre is not the dot's)
        rim = radius * camera.K[0, 0] / np.maximum(camera.depth(surface_dots), 1e-9)
        inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] >= rim) & (uv[:, 1] >= rim) & (uv[:, 0] < w - rim) & (uv[:, 1] < h - rim)
        seen = observed & inside & (view_angle_cos(camera, surface_dots, at_dots) > min_cos)
        out.append(ViewLabels(frame, c, tape_mask(camera, vertices, normals), uv[seen],
                              [label for label, s in zip(graph.labels, seen) if s]))
    return out


def confirmed_share(labels: ViewLabels, found_uv: np.ndarray, radius_px: float) -> float:
    """Share of the labelled dots with a detected dot ``found_uv`` (M, 2) px within ``radius_px``
    (1 when the view has no dot label: nothing to contradict)."""
    if not len(labels.uv):
        return 1.0
    if not len(found_uv):
        return 0.0
    distance, _ = cKDTree(found_uv).query(labels.uv)
    return float(np.mean(distance <= radius_px))


# ---------------------------------------------------------------------------------- workflow
def capture_labels(capture: Capture, table: MarkerTable, frames: list[int], pixels: dict[int, np.ndarray] | None,
                   settings: LabelSettings = LabelSettings()) -> Iterator[tuple[ViewLabels, np.ndarray, bool]]:
    """``(labels, image BGR, confirmed)`` per camera view of the vouched-for ``frames``:
    ``confirmed`` when the first pass's dots of that view (``pixels``: frame -> (D, C, 2) px,
    NaN where a camera did not observe the dot; None: every view counts as confirmed) hold at
    least ``settings.min_confirmed_share`` of the labelled dots."""
    graph = capture.tape.graph
    arrays = table.to_arrays()
    index = [list(arrays.labels).index(label) for label in graph.labels]
    row_of = {int(f): k for k, f in enumerate(arrays.frames)}
    source = capture.frame_source()
    try:
        for frame in frames:
            k = row_of[frame]
            points = arrays.positions[k, index]
            observed = (arrays.status[k, index] == OBSERVED) & np.isfinite(points).all(axis=1)
            images = source.read(frame)
            for labels in frame_labels(capture.rig, capture.tape, points, observed, frame, settings):
                image = images[labels.camera]
                if image is None:
                    continue
                found = None if pixels is None or frame not in pixels else pixels[frame][:, labels.camera]
                ok = True
                if found is not None:
                    found = found[np.isfinite(found).all(axis=1)]
                    ok = confirmed_share(labels, found, settings.confirm_px) >= settings.min_confirmed_share
                yield labels, image, ok
    finally:
        close = getattr(source, "close", None)
        if close is not None:
            close()


def first_pass(capture: Capture, out: Path, frames: str | None, progress: bool) -> TrackResult:
    """Track ``capture`` with its current detector and write the markers to ``out`` (also when
    the tape was missed in most frames: the frames where it was found may still teach)."""
    check_writable(out)
    result = track_source(capture.frame_source(), capture.rig, capture.tape, capture.fps,
                          select_frames(frames, capture.n_frames), up=capture.up, progress=progress,
                          mask_dir=capture.root / "masks", meta={"source": str(capture.root)},
                          weights=capture.detector_weights_path)
    write_markers(result.table, out)
    return result


def adapt_detector(capture_dir: str | Path, out: str | Path, results: str | Path | None = None,
                   label_settings: LabelSettings = LabelSettings(), train_settings: TrainSettings | None = None,
                   studio: Path | None = None, studio_settings: SynthDataSettings | None = None,
                   weights: Path | None = None, frames: str | None = None, progress: bool = True,
                   provenance: dict | None = None) -> AdaptResult:
    """Fine-tune the tape network on a capture's own vouched-for frames (see the module).

    ``results``: a results folder of tracking this capture (its ``markers.csv``); None: track it
    first into ``out/first_pass`` with the capture's current detector (then each view's own
    detections confirm its labels). ``train_settings``: :class:`spinemocap.detect.train.TrainSettings`
    (default: 4 epochs of 30 batches at learning rate 1e-3); ``studio``: a folder of studio
    training shards to mix in (``spinemocap detector train``'s ``OUT/data``), else
    ``studio_settings`` scenes are rendered into ``out/studio_data``; ``weights``: the weights to
    start from (default: those the capture names, else the shipped ones); ``frames``: the frames
    the first pass tracks (:mod:`spinemocap.frames`). Writes ``out/weights.pt`` (+ ``weights.json``,
    ``training.png``, the labelled views as shards in ``out/adapt_data``). Like ``detector train``,
    the fine-tuning resumes from ``out/checkpoint.pt`` when run again into the same ``out``; a new
    ``out`` starts afresh.

    Raises:
        InputError: no frame vouched for, or no camera view confirmed (the detector finds too
            little of this tape to learn from: label some images and use ``detector finetune``).
    """
    from ..detect.dataset import load_shards, save_shard, split_of, views_of
    from ..detect.detector import shipped_weights_path
    from ..detect.train import TrainSettings, train

    capture = Capture.open(capture_dir)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = weights or capture.detector_weights_path or shipped_weights_path()
    pixels: dict[int, np.ndarray] | None = None
    if results is None:
        results = out / FIRST_PASS
        first = first_pass(capture, results, frames, progress)
        table = first.table
        pixels = dict(zip(first.frame_numbers(), first.pixels()))
    else:
        table = read_results(results)
    chosen = spread(vouched_frames(table, capture.tape.graph, label_settings.min_observed_share), label_settings.max_frames)
    if not chosen:
        raise InputError(results, "no frame of the first tracking pass is vouched for (unflagged, its tape observed "
                                  "end to end): nothing to learn from; label a few images and use "
                                  "'spinemocap detector finetune'")
    data = out / ADAPT_DATA
    data.mkdir(exist_ok=True)
    n_views = n_skipped = n_dots = 0
    rng = np.random.default_rng(0)
    bar = tqdm(total=len(chosen) * len(capture.rig), desc="labelling views", unit="view", disable=not progress)
    for labels, image, confirmed in capture_labels(capture, table, chosen, pixels, label_settings):
        bar.update()
        if not confirmed:
            n_skipped += 1
            continue
        stem = f"{capture.name}_{capture.camera_names[labels.camera]}_f{labels.frame:06d}"
        save_shard(data / f"{stem}.npz", views_of(image, labels.mask, rng), split_of(stem, 0.15),
                   {"source": stem, "dots": len(labels.uv)})
        n_views += 1
        n_dots += len(labels.uv)
    bar.close()
    if n_views == 0:
        raise InputError(capture.root, f"none of the {n_skipped} camera views of the vouched-for frames shows the "
                                       "dots the tracked tape places there: nothing to learn from")
    train_views, val_views = load_shards(data)
    if studio is None:
        studio = out / STUDIO_DATA
        generate_synthetic(studio, studio_settings or SynthDataSettings(scenes=8, layouts=("tiny", "artificial")),
                           progress=progress)
    studio_train, studio_val = load_shards(studio)
    n_studio = len(studio_train) + len(studio_val)
    train_views.extend(studio_train)
    val_views.extend(studio_val)
    settings = train_settings or TrainSettings(epochs=4, steps=30, lr=1e-3)
    meta = train(train_views, val_views, out, settings, init_weights=start, progress=progress,
                 provenance={**(provenance or {}), "data": {"kind": "adapted", "capture": str(capture.root),
                                                           "results": str(results), "frames": chosen,
                                                           "views": n_views, "dots": n_dots,
                                                           "studio": str(studio), "studio_views": n_studio}})
    return AdaptResult(out / "weights.pt", Path(results), chosen, n_views, n_skipped, n_dots, n_studio, meta)

