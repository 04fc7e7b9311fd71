"""The detection benchmark (``spinemocap bench detect``): tape masks and dots on held-out synthetic renders, with a peer.

Test sets (bodies, seeds and so lighting never used in training: seeds from
``HELD_OUT_SEED_BASE``, phenotypes from a separate random stream):

- ``studio``: the paper's studio, 6 cameras at 2448x1600, sharp, no occluders;
- ``blur+balls``: the artificial layout (4 cameras, 1024x768) with motion blur and falling balls;
- ``held-out``: the appearance family no training set holds: blue tape (refused by the training
  data), in front of painted lab rooms, through the ``lab`` camera look (lamp colour, flicker,
  exposure, defocus, 4:2:0, JPEG and H.264), both drawn from held-out seeds; the artificial
  layout at the ``lab`` realism level with light occlusion;
- ``held-out+subject``: the same with a lab's subject drawn per scene
  (:func:`spinemocap.synth.appearance.lab_subject`: tape roll and finish, skin marks, clothing);
- ``lab+people``: the training tape colour on a lab's subject in a painted room with two other
  people standing in it, through the ``lab`` camera look, at the ``lab`` realism level;
- ``tape-free``: images without any tape (:mod:`spinemocap.bench.tape_free`: scikit-image's
  photographs and painted lab rooms): false dots per 100 images and the largest tape region.

Renders are 2x supersampled (anti-aliased, as a real sensor integrates over each pixel); without
it dot edges are hard pixel steps and centroids carry ~0.1 px of aliasing error.

Methods: ``net`` and ``classical`` (:class:`spinemocap.detect.Detector`, dot size estimated from
the mask, as the tracker calls it), ``net (every region)`` (the network without the lattice test:
every tape region and dot it finds), ``blobs in exact mask`` (our dot detector given the true
mask: dot detection alone), and the peer ``SimpleBlobDetector`` (OpenCV, whole frame, told the
true dot size), also with its blobs kept only inside the net's mask.

Ground truth: each visible dot's centre on the tape surface (the studio floats the tape
one tape thickness (``TapeSpec.thickness_mm``) above the skin; the holes the camera sees are in that surface), projected
with the camera model; dots within half a dot of the frame border are left out. Matching is one
to one within 2 px. A detection near a dot the studio marks occluded counts neither way (a
partly hidden dot may or may not be found).

Two recalls: over every dot the studio marks visible (its centre seen; up to 78 deg from face-on;
one of four rim points may be behind a ball), and over *unoccluded* dots, the goal's measure: the
whole hole in view, i.e. no ball over any rim point and the tape's own wall hiding less than
``MAX_WALL_HIDDEN`` of the hole (seen at angle a from face-on, the opening of a hole of
diameter d in tape of thickness t shows the skin disc shifted by t tan a: a lens; for 0.8 mm tape
and 10 mm dots a quarter is hidden at ~67 deg). Recall per view-angle bin is in the JSON.
"""

from __future__ import annotations

import json
import logging
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal

import numpy as np
from scipy.optimize import linear_sum_assignment
from tqdm import tqdm

from ..app.training_data import HELD_OUT_FAMILY, HELD_OUT_SEED_BASE
from ..capture import to_grey
from ..detect import find_dots
from ..fileio import atomic_path, atomic_write
from ..synth import SynthConfig, build_scene
from ..synth.appearance import lab_subject
from ..synth.occluders import segments_blocked_by_spheres
from ..synth.visibility import rim_points
from ..timing import StageTimer
from .records import JsonRecord
from .tape_free import (
    MAX_FALSE_DOTS_PER_100,
    MAX_REGION_SHARE,
    LatticeScore,
    TapeFreeSummary,
    score_lattice,
    score_tape_free,
)

log = logging.getLogger(__name__)

MATCH_PX = 2.0
MAX_WALL_HIDDEN = 0.25  # unoccluded: the tape's wall hides less than this share of the hole
VIEW_ANGLE_BINS_DEG = (0, 45, 60, 70, 78)
SEQUENCE_FRAMES = 200  # 2 s of the 'mixed' motion; test frames are spread over it (varied poses)
HELD_OUT = "held-out"
HELD_OUT_SUBJECT = "held-out+subject"
WITH_PEOPLE = "lab+people"


@dataclass
class TestSet:
    name: str
    preset: str
    scenes: int
    frames: int
    blur: float
    occlusion: str
    supersample: int = 2  # anti-aliasing: a camera pixel integrates light over its area
    realism: str = "skin"
    tape_colour: str = "black"
    backdrop: str = "plain"
    camera_look: str = "ideal"
    seed_offset: int = 0  # the set's scenes: seeds HELD_OUT_SEED_BASE + 100 k + 10 attempt + seed_offset
    subject: Literal["plain", "lab"] = "plain"  # lab: the tape's roll and finish, skin marks, clothing drawn per scene
    bystanders: int = 0  # other people standing in the room backdrop


TEST_SETS = {
    "studio": TestSet("studio", "studio", scenes=3, frames=1, blur=0.0, occlusion="none", seed_offset=1),
    "blur+balls": TestSet("blur+balls", "artificial", scenes=1, frames=2, blur=0.5, occlusion="heavy", seed_offset=0),
    "tiny": TestSet("tiny", "tiny", scenes=1, frames=1, blur=0.0, occlusion="none", supersample=3,
                    seed_offset=2),  # quick check only
    # the tape colour no training set holds (app.training_data.HELD_OUT_FAMILY), in rooms and
    # camera looks of held-out seeds
    HELD_OUT: TestSet(HELD_OUT, "artificial", scenes=3, frames=2, blur=0.0, occlusion="light", realism="lab",
                      tape_colour=HELD_OUT_FAMILY["tape_colour"], backdrop="room", camera_look="lab", seed_offset=3),
    HELD_OUT_SUBJECT: TestSet(HELD_OUT_SUBJECT, "artificial", scenes=3, frames=2, blur=0.0, occlusion="light",
                              realism="lab", tape_colour=HELD_OUT_FAMILY["tape_colour"], backdrop="room",
                              camera_look="lab", seed_offset=4, subject="lab"),
    # the training colour in a lab's room with two other people standing in it: skin, hair and
    # clothing that are not the subject's
    WITH_PEOPLE: TestSet(WITH_PEOPLE, "artificial", scenes=2, frames=2, blur=0.0, occlusion="light", realism="lab",
                         backdrop="room", camera_look="lab", seed_offset=5, subject="lab", bystanders=2),
}
TAPE_FREE = "tape-free"
TAPE_FREE_ROOMS = 60
LATTICE_CASES = 300  # random wall-bar grids and tapes for the lattice test alone
DEFAULT_SETS = ["studio", "blur+balls", HELD_OUT, HELD_OUT_SUBJECT, WITH_PEOPLE, TAPE_FREE]


# ---------------------------------------------------------------------------------- scoring
def match(pred: np.ndarray, gt: np.ndarray, radius: float = MATCH_PX) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching within ``radius``: index pairs (pred_i, gt_j) minimising total distance."""

    if len(pred) == 0 or len(gt) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d = np.linalg.norm(pred[:, None] - gt[None], axis=2)
    cost = np.where(d <= radius, d, 1e6)
    i, j = linear_sum_assignment(cost)
    ok = d[i, j] <= radius
    return i[ok], j[ok]


class DotScore:
    """Accumulates true/false positives, misses and centroid errors over images."""

    def __init__(self):
        self.tp = self.fp = self.fn = 0
        self.errors: list[float] = []
        self.unoccluded = [0, 0]  # found, total
        self.by_angle = np.zeros((len(VIEW_ANGLE_BINS_DEG) - 1, 2), int)  # found, total per bin

    def add(self, pred: np.ndarray, gt_visible: np.ndarray, gt_hidden: np.ndarray,
            unoccluded: np.ndarray | None = None, view_angle_deg: np.ndarray | None = None) -> None:
        """``gt_visible`` (N, 2) / ``gt_hidden`` (M, 2) px; ``unoccluded`` (N,) bool and
        ``view_angle_deg`` (N,) describe the visible dots."""
        i, j = match(pred, gt_visible)
        self.tp += len(i)
        self.fn += len(gt_visible) - len(j)
        self.errors += list(np.linalg.norm(pred[i] - gt_visible[j], axis=1))
        found = np.zeros(len(gt_visible), bool)
        found[j] = True
        if unoccluded is not None:
            self.unoccluded[0] += int(found[unoccluded].sum())
            self.unoccluded[1] += int(unoccluded.sum())
        if view_angle_deg is not None:
            b = np.clip(np.digitize(view_angle_deg, VIEW_ANGLE_BINS_DEG) - 1, 0, len(self.by_angle) - 1)
            np.add.at(self.by_angle, (b, 0), found.astype(int))
            np.add.at(self.by_angle, (b, 1), 1)
        rest = np.setdiff1d(np.arange(len(pred)), i)
        if len(rest) and len(gt_hidden):
            near_hidden = np.linalg.norm(pred[rest][:, None] - gt_hidden[None], axis=2).min(axis=1) <= MATCH_PX
            rest = rest[~near_hidden]
        self.fp += len(rest)

    def summary(self) -> DotSummary:
        e = np.asarray(self.errors)
        edges = VIEW_ANGLE_BINS_DEG
        return DotSummary(
            recall=self.tp / max(self.tp + self.fn, 1),
            recall_unoccluded=self.unoccluded[0] / max(self.unoccluded[1], 1),
            unoccluded_dots=self.unoccluded[1],
            recall_by_view_angle={f"{edges[k]}-{edges[k + 1]} deg": {"recall": f / n if n else None, "dots": int(n)}
                                  for k, (f, n) in enumerate(self.by_angle)},
            precision=self.tp / max(self.tp + self.fp, 1),
            centroid_rms_px=float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan"),
            centroid_p95_px=float(np.percentile(e, 95)) if len(e) else float("nan"),
            true_positives=self.tp, false_positives=self.fp, missed=self.fn)


@dataclass(frozen=True)
class DotSummary(JsonRecord):
    """A detector's dots against the truth over a test set (:meth:`DotScore.summary`): recall
    over all visible dots and over the unoccluded ones (with their number), recall per view-angle
    bin ("A-B deg" -> recall, None without dots, and dots), precision, centroid RMS and 95th
    percentile (px), true and false positives and missed dots."""

    recall: float
    recall_unoccluded: float
    unoccluded_dots: int
    recall_by_view_angle: dict[str, dict[str, float | int | None]]
    precision: float
    centroid_rms_px: float
    centroid_p95_px: float
    true_positives: int
    false_positives: int
    missed: int



def simple_blob_detector(dot_px: float):
    """OpenCV's SimpleBlobDetector set up for bright dots of diameter ``dot_px`` (given the truth)."""
    import cv2

    area = np.pi * dot_px ** 2 / 4
    p = cv2.SimpleBlobDetector.Params()
    p.blobColor = 255
    p.minThreshold, p.maxThreshold, p.thresholdStep = 10, 240, 10
    p.filterByArea, p.minArea, p.maxArea = True, 0.15 * area, 2.2 * area
    p.filterByCircularity, p.minCircularity = True, 0.5
    p.filterByInertia, p.minInertiaRatio = True, 0.25
    p.filterByConvexity, p.minConvexity = True, 0.8
    p.minDistBetweenBlobs = 0.5 * dot_px
    return cv2.SimpleBlobDetector.create(p)


# ---------------------------------------------------------------------------------- data
def held_out_scene(test: TestSet, k: int, attempts: int = 5):
    """Scene ``k`` of a test set. A body on which the studio cannot lay the tape (it raises
    ValueError, e.g. for some extreme phenotypes) is replaced by the next seed's body."""

    for attempt in range(attempts):
        seed = HELD_OUT_SEED_BASE + 100 * k + 10 * attempt + test.seed_offset
        rng = np.random.default_rng([seed, 99])
        phenotype = {key: float(rng.uniform(0.1, 0.9)) for key in ("gender", "age", "muscle", "weight", "height")}
        subject: dict = dict(lab_subject(np.random.default_rng([seed, 98]))) if test.subject == "lab" else {}
        cfg = SynthConfig.preset(test.preset, frames=SEQUENCE_FRAMES, seed=seed, phenotype=phenotype,
                                 blur=test.blur, occlusion=test.occlusion, skin_tone=float(rng.uniform(0, 1)),
                                 supersample=test.supersample, realism=test.realism, tape_colour=test.tape_colour,
                                 backdrop=test.backdrop, bystanders=test.bystanders, camera_look=test.camera_look,
                                 **subject)
        try:
            return build_scene(cfg), cfg
        except ValueError as exc:
            log.warning("held-out scene seed %d unusable (%s); trying the next seed", seed, exc)
    raise RuntimeError(f"no usable held-out scene for {test.name} after {attempts} seeds")


def frames_of(test: TestSet) -> list[int]:
    """Frame indices spread evenly inside the sequence (not its neutral start)."""
    return [int((i + 1) * SEQUENCE_FRAMES / (test.frames + 1)) for i in range(test.frames)]


def surface_uv(scene, frame: int, gt: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C, D, 2) projections of dot centres on the tape surface, (C, D) visibility, (C,) dot px.
    ``gt``: the frame's ground truth when the caller has it already."""
    gt = gt if gt is not None else scene.frame_groundtruth(frame)
    surface = gt["dots"] + scene.tape.thickness_mm * gt["dot_normals"]
    uv = np.stack([cam.project(surface) for cam in scene.rig])
    dot_px = np.array([cam.K[0, 0] * scene.tape.dot_diameter_mm / np.median(cam.depth(surface)) for cam in scene.rig])
    return uv, gt["visible"], dot_px


def hole_open_share(view_angle_deg: np.ndarray, thickness_mm: float, dot_diameter_mm: float) -> np.ndarray:
    """Share of a hole's skin disc seen past the tape's own wall at ``view_angle_deg`` from
    face-on: the lens where the bottom disc and the opening, shifted by t tan(a), overlap."""
    r = dot_diameter_mm / 2
    shift = np.minimum(thickness_mm * np.tan(np.radians(np.minimum(view_angle_deg, 89.9))), 2 * r)
    lens = 2 * r * r * np.arccos(shift / (2 * r)) - shift / 2 * np.sqrt(4 * r * r - shift ** 2)
    return lens / (np.pi * r * r)


def dot_view_conditions(scene, frame: int, gt: dict) -> tuple[np.ndarray, np.ndarray]:
    """(C, D) view angle from face-on (deg) and (C, D) bool: no ball over any of the four rim
    points the studio's visibility test samples; ``gt``: the frame's ground truth."""

    dots, normals = gt["dots"], gt["dot_normals"]
    rims = rim_points(dots, normals, scene.tape.dot_diameter_mm / 2).reshape(-1, 3)
    centres, radii = scene.balls.at(scene.times[frame])
    angles, clear = [], []
    for cam in scene.rig:
        to_cam = cam.center - dots
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        angles.append(np.degrees(np.arccos(np.clip(np.einsum("dk,dk->d", to_cam, normals), -1, 1))))
        hidden = segments_blocked_by_spheres(np.repeat(cam.center[None], len(rims), axis=0), rims, centres, radii)
        clear.append(~hidden.reshape(len(dots), 4).any(axis=1))
    return np.array(angles), np.array(clear)


# ---------------------------------------------------------------------------------- run
def run_detect_benchmark(sets: list[str] | None = None, scenes: int | None = None, weights: Path | None = None,
                         threads: int = 1, say: Callable[[str], None] = print,
                         rooms: int | None = None) -> DetectResults:
    """Score the detectors and the peer on the held-out test sets; returns every number.
    ``scenes`` overrides each set's scene count, ``rooms`` the tape-free set's painted rooms; ``say`` gets each set's table as it is done."""
    from ..detect import Detector  # loads torch

    options: dict = {"threads": threads}
    if weights:
        options["weights"] = weights
    detectors = {"net": Detector("net", **options), "net (every region)": Detector("net", lattice=False, **options),
                 "classical": Detector("classical")}
    by_set: dict[str, SetResult | TapeFreeResult] = {}
    results = DetectResults(f"{platform.machine()} {platform.processor() or ''}".strip(), by_set)
    for set_name in sets or DEFAULT_SETS:
        if set_name == TAPE_FREE:
            by_set[TAPE_FREE] = tape_free = run_tape_free(detectors, rooms)
            say(format_tape_free(tape_free))
            continue
        test = TEST_SETS[set_name]
        n_scenes = scenes or test.scenes
        scores = {k: DotScore() for k in (*detectors, "blobs in exact mask", "SimpleBlobDetector",
                                           "SimpleBlobDetector in net mask")}
        iou = {k: [0, 0] for k in detectors}
        timer = StageTimer()
        n_images = 0
        bar = tqdm(total=n_scenes * test.frames, desc=f"bench detect [{set_name}]", unit="frame")
        for k in range(n_scenes):
            scene, cfg = held_out_scene(test, k)
            for f in frames_of(test):
                rendered = scene.render(f)
                gt = scene.frame_groundtruth(f)
                uv_all, visible, dot_px = surface_uv(scene, f, gt)
                view_angle, rim_clear = dot_view_conditions(scene, f, gt)
                open_share = hole_open_share(view_angle, scene.tape.thickness_mm, scene.tape.dot_diameter_mm)
                for c, (image, true_mask) in enumerate(zip(rendered.images, rendered.masks)):
                    h, w = true_mask.shape
                    border = dot_px[c] / 2
                    inside = ((uv_all[c, :, 0] >= border) & (uv_all[c, :, 0] < w - border)
                              & (uv_all[c, :, 1] >= border) & (uv_all[c, :, 1] < h - border))
                    seen = visible[c] & inside
                    gt_vis, gt_hidden = uv_all[c][seen], uv_all[c][~seen]
                    conditions = {"unoccluded": (rim_clear[c] & (open_share[c] >= 1 - MAX_WALL_HIDDEN))[seen],
                                  "view_angle_deg": view_angle[c][seen]}
                    n_images += 1
                    for name, det in detectors.items():
                        t = time.perf_counter()
                        dots = det.detect(image, camera=c)
                        timer.add(f"{name}_total", 1000 * (time.perf_counter() - t))
                        timer.add(f"{name}_segment", 1000 * det.last_timings["segment_s"])
                        timer.add(f"{name}_dots", 1000 * det.last_timings["dots_s"])
                        scores[name].add(dots.uv, gt_vis, gt_hidden, **conditions)
                        iou[name][0] += int((dots.tape_mask & true_mask).sum())
                        iou[name][1] += int((dots.tape_mask | true_mask).sum())
                        if name == "net":
                            net_mask = dots.tape_mask
                    t = time.perf_counter()
                    uv, _ = find_dots(image, true_mask)
                    timer.add("blobs in exact mask", 1000 * (time.perf_counter() - t))
                    scores["blobs in exact mask"].add(uv, gt_vis, gt_hidden, **conditions)
                    t = time.perf_counter()
                    grey = to_grey(image)
                    keypoints = simple_blob_detector(dot_px[c]).detect(grey)
                    timer.add("SimpleBlobDetector_total", 1000 * (time.perf_counter() - t))
                    peer = np.array([kp.pt for kp in keypoints], float).reshape(-1, 2)
                    scores["SimpleBlobDetector"].add(peer, gt_vis, gt_hidden, **conditions)
                    if len(peer):
                        iu = np.clip(np.round(peer).astype(int), 0, [w - 1, h - 1])
                        peer = peer[net_mask[iu[:, 1], iu[:, 0]]]
                    scores["SimpleBlobDetector in net mask"].add(peer, gt_vis, gt_hidden, **conditions)
                bar.update(1)
            scene.close()
        bar.close()
        summary = SetResult(
            images=n_images, image_size=list(cfg.size), preset=test.preset, blur=test.blur, occlusion=test.occlusion,
            supersample=test.supersample, scenes=n_scenes, frames_per_scene=test.frames,
            mask_iou={name: i / max(u, 1) for name, (i, u) in iou.items()},
            dots={name: s.summary() for name, s in scores.items()},
            time={f"{k}_ms_per_camera_frame": v for k, v in timer.mean_ms().items()})
        by_set[set_name] = summary
        say(format_set(set_name, summary))
    return results


@dataclass(frozen=True)
class SetResult(JsonRecord):
    """One test set with tape: camera images scored and their size (px), the set's preset, blur,
    occlusion and supersampling, scenes and frames per scene, each detector's mask IoU with the
    true tape, each method's dots (:class:`DotSummary`) and the mean ms per camera-frame of each
    stage (keys ``<stage>_ms_per_camera_frame``)."""

    images: int
    image_size: list[int]
    preset: str
    blur: float
    occlusion: str
    supersample: int
    scenes: int
    frames_per_scene: int
    mask_iou: dict[str, float]
    dots: dict[str, DotSummary]
    time: dict[str, float]



@dataclass(frozen=True)
class TapeFreeResult:
    """The ``tape-free`` set (:func:`run_tape_free`): painted rooms, the goals, each detector's
    false detections and the lattice test alone."""

    rooms: int
    detectors: dict[str, TapeFreeSummary]
    lattice_test: LatticeScore

    def to_dict(self) -> dict[str, Any]:
        """The JSON object (``"tape_free": true`` first, then the rooms and the goals)."""
        return {"tape_free": True, "rooms": self.rooms,
                "goal": {"max_false_dots_per_100_images": MAX_FALSE_DOTS_PER_100, "max_region_share": MAX_REGION_SHARE},
                "detectors": {name: score.to_dict() for name, score in self.detectors.items()},
                "lattice_test": self.lattice_test.to_dict()}


@dataclass(frozen=True)
class DetectResults:
    """``bench detect``'s numbers (:func:`run_detect_benchmark`): the machine and each test set's
    result, in the order run."""

    machine: str
    sets: dict[str, SetResult | TapeFreeResult]

    def to_dict(self) -> dict[str, Any]:
        return {"machine": self.machine, "sets": {name: result.to_dict() for name, result in self.sets.items()}}


def run_tape_free(detectors: dict, rooms: int | None = None) -> TapeFreeResult:
    """The ``tape-free`` set: each detector's false detections (:func:`score_tape_free`) over
    scikit-image's photographs and ``rooms`` painted rooms (default :data:`TAPE_FREE_ROOMS`)."""
    n_rooms = rooms or TAPE_FREE_ROOMS
    bar = tqdm(desc=f"bench detect [{TAPE_FREE}]", unit="image")
    scores = score_tape_free(detectors, n_rooms, progress=lambda _: bar.update(1))
    bar.close()
    return TapeFreeResult(n_rooms, scores, score_lattice(LATTICE_CASES))


def format_tape_free(s: TapeFreeResult) -> str:
    """The tape-free set's table, as printed."""
    first = next(iter(s.detectors.values()))
    lines = [f"\n== {TAPE_FREE}: {first.images} images without tape ({s.rooms} painted lab rooms), goal "
             f"<= {MAX_FALSE_DOTS_PER_100:g} false dot per 100 images, no tape region above "
             f"{100 * MAX_REGION_SHARE:g} % of its image",
             f"{'detector':24s} {'false dots':>10s} {'per 100':>8s} {'images w/ dots':>14s} {'largest region %':>16s} "
             f"{'goal':>5s} {'ms/image':>9s}"]
    for name, d in s.detectors.items():
        lines.append(f"{name:24s} {d.false_dots:10d} {d.false_dots_per_100_images:8.1f} {d.images_with_dots:14d} "
                     f"{100 * d.largest_region_share:16.3f} {'met' if d.goal_met else 'not':>5s} {d.ms_per_image:9.0f}")
    lat = s.lattice_test
    lines.append(f"the lattice test alone on {lat.cases} random views each: wall-bar grids kept as tape "
                 f"{lat.wall_bars_accepted}, tapes kept {lat.tapes_accepted} ({100 * lat.tape_dots_kept:.1f} % of their dots)")
    return "\n".join(lines)


def save(results: DetectResults, path: Path) -> None:
    """The numbers as JSON (atomic)."""
    with atomic_write(path) as handle:
        json.dump(results.to_dict(), handle, indent=2)


def plot(results: DetectResults, path: Path) -> None:
    """One row per test set: recall/precision, centroid RMS, time per camera-frame, per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = {name: s for name, s in results.sets.items() if isinstance(s, SetResult)}  # the sets with tape
    fig, axes = plt.subplots(len(sets), 3, figsize=(16, 4.4 * len(sets)), squeeze=False)
    for row, (name, s) in zip(axes, sets.items()):
        methods = list(s.dots)
        y = np.arange(len(methods))
        bars = {"recall (visible)": "recall", "recall (unoccluded)": "recall_unoccluded", "precision": "precision"}
        for k, (label, key) in enumerate(bars.items()):
            row[0].barh(y + 0.27 * (k - 1), [getattr(s.dots[m], key) for m in methods], 0.27, label=label)
        lowest = min(getattr(d, key) for d in s.dots.values() for key in bars.values())
        row[0].set_xlim(min(0.9, lowest) - 0.01, 1.0)
        row[0].axvline(0.99, color="k", lw=0.8, ls="--")
        row[0].legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=3, fontsize=8)
        row[1].barh(y, [s.dots[m].centroid_rms_px for m in methods], 0.6)
        row[1].axvline(0.2, color="k", lw=0.8, ls="--")
        row[1].set_xlabel("centroid error RMS (px)")
        for ax in row[:2]:
            ax.set_yticks(y, methods)
        row[0].set_title(f"{name}: {s.images} images {s.image_size[0]}x{s.image_size[1]}")
        times = {k.replace("_ms_per_camera_frame", ""): v for k, v in s.time.items() if "total" in k}
        row[2].barh(np.arange(len(times)), list(times.values()), 0.6)
        row[2].set_yticks(np.arange(len(times)), list(times))
        row[2].set_xlabel("ms per camera-frame (mask + dots)")
        row[2].set_title("mask IoU: " + ", ".join(f"{k} {v:.3f}" for k, v in s.mask_iou.items()), fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def format_set(name: str, s: SetResult) -> str:
    """One test set's table, as printed."""
    lines = [f"\n== {name}: {s.images} camera images {s.image_size[0]}x{s.image_size[1]}, "
             f"blur {s.blur}, occlusion {s.occlusion}",
             "mask IoU: " + ", ".join(f"{k} {v:.3f}" for k, v in s.mask_iou.items())]
    n_unoccluded = next(iter(s.dots.values())).unoccluded_dots
    lines.append(f"{'dots':32s} {'recall':>7s} {'unocc.':>7s} {'precision':>9s} {'RMS px':>7s} {'p95 px':>7s}   "
                 f"(unoccluded: {n_unoccluded} of the visible dots)")
    for k, d in s.dots.items():
        lines.append(f"{k:32s} {d.recall:7.4f} {d.recall_unoccluded:7.4f} {d.precision:9.4f} "
                     f"{d.centroid_rms_px:7.3f} {d.centroid_p95_px:7.3f}")
    lines.append("time per camera-frame: " + ", ".join(
        f"{k.replace('_ms_per_camera_frame', '')} {v:.1f} ms" for k, v in s.time.items()))
    return "\n".join(lines)
