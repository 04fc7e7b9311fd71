"""Surface textures of the studio: the tape's finish and the marks on the subject's skin.

- :data:`TAPE_FINISHES`: ``smooth`` (the uniform colour the studio renders otherwise), ``weave``
  (the cotton weave of kinesiology tape: threads along and across, ribs of uneven brightness) or
  ``printed`` (a pattern printed on the tape: stripes, camouflage blots or repeated lettering in
  a contrasting ink). :func:`tape_texture` paints it on the flat tape (mm along and across).
- :data:`SKIN_MARKS`: ``hair``, ``freckles``, ``moles``, ``sweat`` and ``tattoo``.
  :func:`skin_texture` paints hair, freckles, moles and a tattoo on the back of the rest body
  (a picture seen from behind: x across, z up, mm); ``sweat`` is the skin's sheen
  (:data:`SWEAT_SPECULAR`), not a picture.

Textures are RGB uint8 images in the surface's own colours, laid on the meshes by per-vertex
texture coordinates (:class:`SurfaceTexture`). They colour what the cameras see and nothing
else: the tape mask, the dots and the visibility are geometry's. The skin's marks lie on the
skin, under the tape, so they show through its holes as on a real back; none of them covers
the tape. :func:`lab_surfaces` draws a lab's mix of all of them from a seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import cv2
import numpy as np

TapeFinish = Literal["smooth", "weave", "printed"]
TAPE_FINISHES: tuple[str, ...] = get_args(TapeFinish)
SkinMark = Literal["hair", "freckles", "moles", "sweat", "tattoo"]
SKIN_MARKS: tuple[str, ...] = get_args(SkinMark)

TAPE_TEXELS_PER_MM = 4.0
SKIN_TEXELS_PER_MM = 2.0
# the body's rest-pose back the skin texture covers (x across, z up, mm): wide enough for the
# shoulders, from below the buttocks to above the neck (clamped to plain skin beyond)
SKIN_EXTENT_X_MM = (-320.0, 320.0)
SKIN_BELOW_S1_MM, SKIN_ABOVE_C7_MM = 350.0, 150.0
# skin's (specular, specular power): the studio's dry skin and a sweaty sheen
DRY_SPECULAR = (0.08, 10.0)
SWEAT_SPECULAR = (0.55, 28.0)

_PRINT_WORDS = ("FLEX", "SPORT", "ELASTIC", "ACTIVE", "K-TAPE", "PRO", "MOVE")


@dataclass(frozen=True)
class SurfaceTexture:
    """An RGB uint8 ``image`` (H, W, 3) laid on a flat chart as a picture: ``origin_mm`` (x, y)
    the chart point at the image's bottom-left corner, ``texels_per_mm``; chart x runs right
    along the image's columns, chart y up its rows (row 0 is the top)."""

    image: np.ndarray
    origin_mm: tuple[float, float]
    texels_per_mm: float

    def coordinates(self, chart_mm: np.ndarray) -> np.ndarray:
        """(N, 2) texture coordinates in [0, 1] of chart points ``chart_mm`` (N, 2) mm (clamped:
        points off the image take its edge)."""
        h, w = self.image.shape[:2]
        xy = (np.asarray(chart_mm, float) - np.array(self.origin_mm)) * self.texels_per_mm
        return np.clip(xy / np.array([w, h], float), 0.0, 1.0)  # texture t runs up from the bottom row


@dataclass(frozen=True)
class SurfaceLook:
    """What the tape and skin look like: the tape's ``finish`` (:data:`TAPE_FINISHES`) and the
    skin's ``marks`` (a subset of :data:`SKIN_MARKS`)."""

    finish: str = "smooth"
    marks: tuple[str, ...] = ()

    @property
    def sweaty(self) -> bool:
        return "sweat" in self.marks

    @property
    def painted_marks(self) -> tuple[str, ...]:
        """The marks :func:`skin_texture` paints (all but the sheen)."""
        return tuple(m for m in self.marks if m != "sweat")


def lab_surfaces(rng: np.random.Generator) -> SurfaceLook:
    """A lab's tape and skin, drawn from ``rng``: tape smooth in two fifths, woven in two fifths,
    printed in a fifth; hair on a third of the backs, freckles on a quarter, moles on most,
    a sweaty sheen on a quarter, a tattoo on a fifth."""
    finish = str(rng.choice(TAPE_FINISHES, p=[0.4, 0.4, 0.2]))
    odds = {"hair": 1 / 3, "freckles": 0.25, "moles": 0.7, "sweat": 0.25, "tattoo": 0.2}
    return SurfaceLook(finish, tuple(m for m in SKIN_MARKS if rng.random() < odds[m]))


def _rgb255(rgb: tuple[float, float, float]) -> np.ndarray:
    return np.clip(np.asarray(rgb, np.float32) * 255.0, 0, 255)


def tape_texture(finish: str, tape_rgb: tuple[float, float, float], width_mm: float, v_range_mm: tuple[float, float],
                 seed: int) -> SurfaceTexture | None:
    """The tape's ``finish`` (:data:`TAPE_FINISHES`) painted over its flat chart (x across the
    tape in [-``width_mm``/2, ``width_mm``/2], y along it over ``v_range_mm``), in ``tape_rgb``
    (RGB 0..1); None for ``smooth``. Raises ValueError for an unknown finish."""
    if finish not in TAPE_FINISHES:
        raise ValueError(f"unknown tape finish {finish!r}; choose from {list(TAPE_FINISHES)}")
    if finish == "smooth":
        return None
    rng = np.random.default_rng([seed, 31])
    t = TAPE_TEXELS_PER_MM
    w, h = int(np.ceil(width_mm * t)) + 2, int(np.ceil((v_range_mm[1] - v_range_mm[0]) * t)) + 2
    base = _rgb255(tape_rgb)
    image = np.broadcast_to(base, (h, w, 3)).astype(np.float32)
    if finish == "weave":
        image = _weave(image, base, rng)
    else:
        image = _printed(image, base, rng)
    return SurfaceTexture(np.clip(image + 0.5, 0, 255).astype(np.uint8), (-width_mm / 2, v_range_mm[0]), t)


def _weave(image: np.ndarray, base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Cotton weave: warp threads along the tape and weft across (pitch 1-1.6 mm), each thread of
    its own brightness, crossing over and under; dark tape shows it as a grey sheen."""
    h, w = image.shape[:2]
    t = TAPE_TEXELS_PER_MM
    pitch = rng.uniform(1.0, 1.6) * t
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    warp_threads = rng.normal(0, 0.35, int(w / pitch) + 2)[(xx / pitch).astype(int)]
    weft_threads = rng.normal(0, 0.35, int(h / pitch) + 2)[(yy / pitch).astype(int)]
    over = np.sin(np.pi * xx / pitch) * np.sin(np.pi * yy / pitch)  # +: warp on top, -: weft on top
    ribs = np.where(over > 0, np.abs(np.sin(np.pi * xx / pitch)) + warp_threads,
                    np.abs(np.sin(np.pi * yy / pitch)) + weft_threads) - 0.6
    amplitude = 0.22 * base + 12.0
    return image + amplitude[None, None] * ribs[..., None]


def _printed(image: np.ndarray, base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A printed pattern in an ink that contrasts with the tape: diagonal stripes, camouflage
    blots or repeated lettering."""
    h, w = image.shape[:2]
    t = TAPE_TEXELS_PER_MM
    light_tape = float(base.mean()) > 110
    ink = (np.array(rng.uniform(10, 70, 3)) if light_tape else np.array(rng.uniform(170, 250, 3))).astype(np.float32)
    coverage = np.zeros((h, w), np.float32)
    kind = str(rng.choice(["stripes", "camouflage", "lettering"]))
    if kind == "stripes":
        pitch, thick = rng.uniform(6, 14) * t, rng.uniform(1.0, 3.0) * t
        for k in range(-h, w + h, int(pitch)):
            cv2.line(coverage, (k, 0), (k + h, h), 1.0, int(thick), cv2.LINE_AA)
    elif kind == "camouflage":
        for _ in range(int(h * w / (60 * t * t))):
            centre = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
            axes = (int(rng.uniform(2, 6) * t), int(rng.uniform(1, 4) * t))
            cv2.ellipse(coverage, centre, axes, float(rng.uniform(0, 180)), 0, 360, float(rng.uniform(0.4, 1.0)), -1)
    else:
        scale = 0.12 * t
        y = int(rng.uniform(4, 10) * t)
        while y < h:
            word = str(rng.choice(_PRINT_WORDS))
            _text(coverage, word, (int(rng.uniform(0, 8) * t), y), cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(scale * 2)))
            y += int(rng.uniform(10, 20) * t)
    coverage = np.clip(coverage, 0, 1)[..., None]
    return image * (1 - coverage) + ink[None, None] * coverage


def _text(coverage: np.ndarray, text: str, origin: tuple[int, int], font: int, scale: float, thickness: int) -> None:
    """Write ``text`` into the float ``coverage`` (H, W) in [0, 1] (OpenCV writes text on 8-bit images only)."""
    canvas = np.zeros(coverage.shape, np.uint8)
    cv2.putText(canvas, text, origin, font, scale, 255, thickness, cv2.LINE_AA)
    np.maximum(coverage, canvas.astype(np.float32) / 255.0, out=coverage)


def skin_extent(s1_height_mm: float, c7_height_mm: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The rest back the skin texture covers: (x range, z range) mm."""
    return SKIN_EXTENT_X_MM, (s1_height_mm - SKIN_BELOW_S1_MM, c7_height_mm + SKIN_ABOVE_C7_MM)


def skin_texture(marks: tuple[str, ...], skin_rgb: tuple[float, float, float],
                 extent_mm: tuple[tuple[float, float], tuple[float, float]], spine_x_mm: float,
                 seed: int) -> SurfaceTexture | None:
    """The skin's painted ``marks`` (hair, freckles, moles, tattoo; the sheen is not painted) on
    its colour ``skin_rgb`` (RGB 0..1) over ``extent_mm`` ((x0, x1), (z0, z1)) of the rest back
    seen from behind, the spine at ``spine_x_mm``; None when none is painted. Chart x is the
    body's x, chart y its height z. Raises ValueError for an unknown mark."""
    unknown = [m for m in marks if m not in SKIN_MARKS]
    if unknown:
        raise ValueError(f"unknown skin marks {unknown}; choose from {list(SKIN_MARKS)}")
    painted = [m for m in SKIN_MARKS if m in marks and m != "sweat"]
    if not painted:
        return None
    (x0, x1), (z0, z1) = extent_mm
    t = SKIN_TEXELS_PER_MM
    w, h = int(np.ceil((x1 - x0) * t)) + 1, int(np.ceil((z1 - z0) * t)) + 1
    image = np.broadcast_to(_rgb255(skin_rgb), (h, w, 3)).astype(np.float32)
    painters = {"hair": _hair, "freckles": _freckles, "moles": _moles, "tattoo": _tattoo}
    spine_col = (spine_x_mm - x0) * t
    for mark in painted:
        image = painters[mark](image, spine_col, np.random.default_rng([seed, 41, SKIN_MARKS.index(mark)]))
    image[[0, -1]] = _rgb255(skin_rgb)  # plain edges: the body beyond the extent takes them
    image[:, [0, -1]] = _rgb255(skin_rgb)
    return SurfaceTexture(np.clip(image + 0.5, 0, 255).astype(np.uint8), (x0, z0), t)


def _darken(image: np.ndarray, shade: np.ndarray, tint: np.ndarray) -> np.ndarray:
    """``image`` darkened by ``shade`` (H, W) in [0, 1] toward ``tint`` times the skin (RGB factors)."""
    return image * (1 - shade[..., None] * (1 - tint[None, None]))


def _hair(image: np.ndarray, spine_col: float, rng: np.random.Generator) -> np.ndarray:
    """Body hair: thousands of short dark strokes (4-12 mm) combed away from the spine and upward,
    denser toward the shoulders and the small of the back."""
    h, w = image.shape[:2]
    t = SKIN_TEXELS_PER_MM
    shade = np.zeros((h, w), np.float32)
    n = int(rng.uniform(0.5, 2.0) * h * w / (t * t * 100))  # 0.5-2 hairs per cm^2
    xs, ys = rng.uniform(0, w, n), rng.uniform(0, h, n)
    side = np.sign(xs - spine_col)
    angle = np.deg2rad(rng.normal(60, 20, n)) * side  # up and outward from the midline
    length = rng.uniform(4, 12, n) * t
    for x, y, a, ln, s in zip(xs, ys, angle, length, rng.uniform(0.2, 0.55, n)):
        cv2.line(shade, (int(x), int(y)), (int(x + ln * np.sin(a)), int(y - ln * np.cos(a))), float(s), 1, cv2.LINE_AA)
    return _darken(image, np.clip(shade, 0, 0.8), np.array([0.35, 0.28, 0.22], np.float32))


def _freckles(image: np.ndarray, spine_col: float, rng: np.random.Generator) -> np.ndarray:
    """Freckles: hundreds of small light-brown spots (1-3 mm), thickest over the shoulders."""
    h, w = image.shape[:2]
    t = SKIN_TEXELS_PER_MM
    shade = np.zeros((h, w), np.float32)
    n = int(rng.uniform(300, 900))
    ys = h * rng.beta(1.2, 2.2, n)  # row 0 is the top: most freckles high on the back
    for x, y, r, s in zip(rng.uniform(0, w, n), ys, rng.uniform(0.5, 1.5, n) * t, rng.uniform(0.2, 0.45, n)):
        cv2.circle(shade, (int(x), int(y)), max(1, int(r)), float(s), -1, cv2.LINE_AA)
    shade = cv2.GaussianBlur(shade, (0, 0), 0.6)
    return _darken(image, shade, np.array([0.75, 0.52, 0.35], np.float32))


def _moles(image: np.ndarray, spine_col: float, rng: np.random.Generator) -> np.ndarray:
    """Moles: 4-25 round dark-brown spots of 2-7 mm, anywhere on the back."""
    h, w = image.shape[:2]
    t = SKIN_TEXELS_PER_MM
    shade = np.zeros((h, w), np.float32)
    n = int(rng.integers(4, 26))
    for x, y, r, s in zip(rng.uniform(0, w, n), rng.uniform(0, h, n), rng.uniform(1.0, 3.5, n) * t,
                          rng.uniform(0.5, 0.8, n)):
        cv2.circle(shade, (int(x), int(y)), max(1, int(r)), float(s), -1, cv2.LINE_AA)
    return _darken(image, shade, np.array([0.30, 0.20, 0.15], np.float32))


def _tattoo(image: np.ndarray, spine_col: float, rng: np.random.Generator) -> np.ndarray:
    """A tattoo in dark ink (some colour fill): a tribal band of thick curves, a ringed mandala
    or lettering, 8-25 cm across, on the shoulder blades or the low back."""
    h, w = image.shape[:2]
    t = SKIN_TEXELS_PER_MM
    ink = np.zeros((h, w), np.float32)
    size = rng.uniform(80, 250) * t
    cx = spine_col + rng.normal(0, 60) * t
    cy = h * float(rng.choice([rng.uniform(0.15, 0.3), rng.uniform(0.48, 0.58)]))  # from the top of the extent
    kind = str(rng.choice(["tribal", "mandala", "lettering"]))
    if kind == "tribal":
        for k in range(int(rng.integers(3, 7))):
            start = np.array([cx - size / 2 + k * size / 8, cy + rng.normal(0, size / 8)])
            pts = [start + np.array([i * size / 10, size / 6 * np.sin(i / 2.0 + k)]) for i in range(8)]
            cv2.polylines(ink, [np.array(pts, np.int32)], False, 1.0, max(2, int(rng.uniform(3, 8) * t)), cv2.LINE_AA)
    elif kind == "mandala":
        for r in np.linspace(size / 8, size / 2, int(rng.integers(3, 6))):
            cv2.circle(ink, (int(cx), int(cy)), int(r), 1.0, max(1, int(1.5 * t)), cv2.LINE_AA)
        for a in np.linspace(0, 2 * np.pi, int(rng.integers(8, 16)), endpoint=False):
            cv2.line(ink, (int(cx), int(cy)), (int(cx + size / 2 * np.cos(a)), int(cy + size / 2 * np.sin(a))), 1.0,
                     max(1, int(t)), cv2.LINE_AA)
    else:
        scale = size / 250
        _text(ink, str(rng.choice(["FAMILY", "1987", "STRENGTH", "LIBERTAD", "MOM"])), (int(cx - size / 2), int(cy)),
              cv2.FONT_HERSHEY_TRIPLEX, scale, max(2, int(scale * 4)))
    colour = np.array([0.12, 0.14, 0.22], np.float32) if rng.random() < 0.7 else np.array(rng.uniform(0.1, 0.7, 3), np.float32)
    return _darken(image, np.clip(ink, 0, 1) * 0.9, colour)
