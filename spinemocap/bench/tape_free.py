"""Tape-free images: what a detector must find nothing in (``spinemocap bench detect --sets tape-free``).

Two sources, neither holding any tape:

- the photographs and scans scikit-image ships inside its package (``skimage.data``: people,
  animals, coins, text pages, brick, gravel, a rocket, microscope slides, ...; only those stored
  in the package, none that would be downloaded);
- rooms of motion-capture labs painted by :func:`spinemocap.synth.rooms.paint_room` (windows
  with blinds, curtains, doors, wall bars, treadmills, rails, posters with text, stripes and
  checkerboards, ceiling lights, motion-capture camera strobes), two in three with one or two
  other people standing in them (skin, hair, clothing edges, a bare back with a bra strap and
  moles), at the studio's and the sports cameras' sizes, with sensor noise and, in some, the
  studio's lens blur.

Scores per detector: false dots per 100 images (every dot is false), the share of images with
any dot, and the largest tape region (a connected component of the tape mask) as a share of its
image: the goal is <= 1 false dot per 100 images and no region above 0.1 % of its image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterator

import cv2
import numpy as np

from ..detect.blobs import labelled_components
from ..synth.rooms import paint_room
from .records import JsonRecord

# skimage.data loaders whose files ship inside the package (no download)
SKIMAGE_IMAGES = ("astronaut", "brick", "camera", "cell", "chelsea", "checkerboard", "clock", "coffee", "coins",
                  "colorwheel", "grass", "gravel", "hubble_deep_field", "immunohistochemistry", "logo", "moon",
                  "page", "retina", "rocket", "text")
ROOM_SIZES = ((1024, 768), (1920, 1080), (1280, 720))
ROOM_SEED_BASE = 70_000  # rooms of the benchmark: seeds from here on
MAX_FALSE_DOTS_PER_100 = 1.0
MAX_REGION_SHARE = 0.001


def skimage_images() -> Iterator[tuple[str, np.ndarray]]:
    """(name, BGR uint8 image) of each :data:`SKIMAGE_IMAGES` photograph; ImportError where
    scikit-image is missing."""
    import skimage.data

    for name in SKIMAGE_IMAGES:
        image = np.asarray(getattr(skimage.data, name)())
        yield f"skimage:{name}", as_bgr(image)
    left, right, _ = skimage.data.stereo_motorcycle()
    yield "skimage:motorcycle_left", as_bgr(left)
    yield "skimage:motorcycle_right", as_bgr(right)


def as_bgr(image: np.ndarray) -> np.ndarray:
    """Any skimage image (bool, float in [0, 1], uint8; grey, RGB or RGBA) as BGR uint8."""
    if image.dtype == bool:
        image = image.astype(np.uint8) * 255
    elif image.dtype != np.uint8:
        image = np.clip(np.asarray(image, float) * 255.0, 0, 255).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_RGBA2BGR)
    return cv2.cvtColor(image, cv2.COLOR_RGB2BGR)


def room_images(n: int, seed_base: int = ROOM_SEED_BASE, noise: float = 2.0) -> Iterator[tuple[str, np.ndarray]]:
    """``n`` painted lab rooms (:func:`paint_room`) at the sizes of :data:`ROOM_SIZES` in turn,
    with 0, 1 and 2 other people in turn, Gaussian sensor noise of ``noise`` grey levels, every
    third one slightly defocused."""
    for k in range(n):
        seed = seed_base + k
        size = ROOM_SIZES[k % len(ROOM_SIZES)]
        image = paint_room(size, seed, people=(k // len(ROOM_SIZES)) % 3).astype(np.float32)
        if k % 3 == 2:
            image = cv2.GaussianBlur(image, (0, 0), 0.8)
        image += np.random.default_rng(seed).normal(0, noise, image.shape).astype(np.float32)
        yield f"room:{seed}", np.clip(image, 0, 255).astype(np.uint8)


def tape_free_images(rooms: int, with_skimage: bool = True) -> Iterator[tuple[str, np.ndarray]]:
    """The tape-free set: scikit-image's photographs (where it imports), then ``rooms`` rooms."""
    if with_skimage:
        try:
            yield from skimage_images()
        except ImportError:
            pass
    yield from room_images(rooms)


@dataclass
class TapeFreeScore:
    """False detections of one detector over tape-free images."""

    images: int = 0
    false_dots: int = 0
    images_with_dots: int = 0
    largest_region_share: float = 0.0
    images_with_large_region: int = 0
    ms: list[float] = field(default_factory=list)
    worst: list[tuple[str, int, float]] = field(default_factory=list)  # (image, dots, largest region share)

    def add(self, name: str, uv: np.ndarray, mask: np.ndarray, ms: float) -> None:
        share = largest_region_share(mask)
        self.images += 1
        self.false_dots += len(uv)
        self.images_with_dots += int(len(uv) > 0)
        self.largest_region_share = max(self.largest_region_share, share)
        self.images_with_large_region += int(share > MAX_REGION_SHARE)
        self.ms.append(ms)
        if len(uv) or share > MAX_REGION_SHARE:
            self.worst.append((name, len(uv), share))

    def summary(self) -> TapeFreeSummary:
        per_100 = 100.0 * self.false_dots / max(self.images, 1)
        return TapeFreeSummary(
            images=self.images, false_dots=self.false_dots, false_dots_per_100_images=per_100,
            images_with_dots=self.images_with_dots, largest_region_share=self.largest_region_share,
            images_with_region_above_goal=self.images_with_large_region,
            goal_met=per_100 <= MAX_FALSE_DOTS_PER_100 and self.largest_region_share <= MAX_REGION_SHARE,
            ms_per_image=float(np.mean(self.ms)) if self.ms else 0.0,
            worst=sorted(self.worst, key=lambda t: (-t[1], -t[2]))[:10])


@dataclass(frozen=True)
class TapeFreeSummary(JsonRecord):
    """One detector over the tape-free images (:meth:`TapeFreeScore.summary`): images, false dots
    (in all and per 100 images), images with any dot, the largest tape region's share of its image
    (0-1) and the images whose region is above :data:`MAX_REGION_SHARE`, whether the goal is met,
    mean ms per image, and the ten worst images (name, dots, largest region share)."""

    images: int
    false_dots: int
    false_dots_per_100_images: float
    images_with_dots: int
    largest_region_share: float
    images_with_region_above_goal: int
    goal_met: bool
    ms_per_image: float
    worst: list[tuple[str, int, float]]



def largest_region_share(mask: np.ndarray) -> float:
    """The largest 8-connected component of ``mask`` (H, W) bool as a share of the image (0 when empty)."""
    if not mask.any():
        return 0.0
    _, _, areas = labelled_components(np.ascontiguousarray(mask))
    return float(areas[1:].max()) / mask.size


def score_tape_free(detectors: dict, rooms: int, with_skimage: bool = True,
                    progress: Callable[[str], None] | None = None) -> dict[str, TapeFreeSummary]:
    """Each of ``detectors`` (name -> object with ``detect(image)`` returning dots ``uv`` and a
    ``mask``) over :func:`tape_free_images`: per detector :meth:`TapeFreeScore.summary`."""
    scores = {name: TapeFreeScore() for name in detectors}
    for name, image in tape_free_images(rooms, with_skimage):
        for det_name, det in detectors.items():
            t = time.perf_counter()
            found = det.detect(image)
            scores[det_name].add(name, found.uv, found.mask, 1000 * (time.perf_counter() - t))
        if progress:
            progress(name)
    return {name: s.summary() for name, s in scores.items()}


# ---------------------------------------------------------------------------------- the lattice test alone
LATTICE_SEED = 71_000
WALL_BAR_GAPS = (2, 3, 4, 5, 6)  # gaps per rung


def _view(points: np.ndarray, rng: np.random.Generator, noise_px: float) -> np.ndarray:
    """``points`` (N, 2) (units of the nearest spacing) seen through a random affine map (any
    rotation, foreshortened to 0.4, sheared, 15-40 px per unit) with Gaussian noise."""
    a = rng.uniform(0, 2 * np.pi)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    affine = rotation @ np.array([[rng.uniform(0.4, 1.0), rng.uniform(-0.3, 0.3)], [0.0, 1.0]]) * rng.uniform(15, 40)
    return points @ affine.T + 500.0 + rng.normal(0, noise_px, points.shape)


def wall_bar_dots(rng: np.random.Generator) -> np.ndarray:
    """The gaps of wall bars as a detector finds them ((N, 2) px): a rectangular grid of
    :data:`WALL_BAR_GAPS` gaps per rung and 3-20 rungs, rung pitch 0.4-2.5 x the gap spacing,
    each gap missing with probability 0-0.3 (hidden or not found), in a random view."""
    gaps, rungs = int(rng.choice(WALL_BAR_GAPS)), int(rng.integers(3, 21))
    pitch = rng.uniform(0.4, 2.5)
    grid = np.array([(i, j * pitch) for i in range(gaps) for j in range(rungs)], float)
    grid = grid[rng.random(len(grid)) >= rng.uniform(0, 0.3)]
    return _view(grid, rng, 0.3)


def tape_dots(rng: np.random.Generator) -> np.ndarray:
    """A perforated tape's dots as a detector finds them ((N, 2) px): 3-13 rows alternating two
    and three dots (row pitch 1.2-2.5 x the in-row spacing, stretched by up to 30 %, +-5 % per row),
    bent along a circular arc (radius 20-80 spacings: a back), up to 2 dots missing, in a random view."""
    rows = int(rng.choice([3, 5, 7, 9, 11, 13]))
    pitch = rng.uniform(1.2, 2.5)
    stretch = rng.uniform(1.0, 1.3) * rng.uniform(0.95, 1.05, rows - 1)  # a taping tension, uneven along
    along = np.cumsum(np.r_[0.0, pitch * stretch])
    dots = np.array([(x, along[j]) for j in range(rows) for x in ((-0.5, 0.5) if j % 2 == 0 else (-1.0, 0.0, 1.0))])
    radius = rng.uniform(20, 80) * rng.choice([-1, 1])  # the back's curve, in spacings
    angle = dots[:, 1] / radius
    bent = np.c_[(radius - dots[:, 0]) * np.cos(angle) - radius, (radius - dots[:, 0]) * np.sin(angle)]
    missing = rng.choice(len(bent), size=int(rng.integers(0, 3)), replace=False)
    return _view(np.delete(bent, missing, axis=0), rng, 0.3)


@dataclass(frozen=True)
class LatticeScore(JsonRecord):
    """The lattice test on random views (:func:`score_lattice`): views of each kind, wall-bar
    grids and tapes it accepts (any dot kept), and the share of the tapes' dots it keeps (0-1)."""

    cases: int
    wall_bars_accepted: int
    tapes_accepted: int
    tape_dots_kept: float



def score_lattice(n: int, seed: int = LATTICE_SEED) -> LatticeScore:
    """The lattice test (:func:`spinemocap.detect.lattice.tape_regions` on a mask covering every
    dot) on ``n`` wall-bar grids (:func:`wall_bar_dots`) and ``n`` tapes (:func:`tape_dots`):
    how many of each it accepts (any dot kept) and the share of tape dots it keeps."""
    from ..detect.lattice import tape_regions

    rng = np.random.default_rng(seed)
    accepted = {"wall_bars": 0, "tapes": 0}
    kept_dots = total_dots = 0
    for _ in range(n):
        for kind, dots in (("wall_bars", wall_bar_dots(rng)), ("tapes", tape_dots(rng))):
            lo = np.floor(dots.min(axis=0)).astype(int) - 2
            hi = np.ceil(dots.max(axis=0)).astype(int) + 3
            mask = np.ones((hi[1] - lo[1], hi[0] - lo[0]), bool)
            _, keep = tape_regions(mask, dots - lo)
            accepted[kind] += int(keep.any())
            if kind == "tapes":
                kept_dots += int(keep.sum())
                total_dots += len(dots)
    return LatticeScore(cases=n, wall_bars_accepted=accepted["wall_bars"], tapes_accepted=accepted["tapes"],
                        tape_dots_kept=kept_dots / max(total_dots, 1))
