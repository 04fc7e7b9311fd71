"""Backgrounds of real motion-capture rooms, painted in 2D: the studio's hard negatives.

A lab films its subject in front of whatever the room holds; several of those things look like
perforated tape to a detector that has only seen a plain backdrop (dark bars with bright gaps,
rows of bright spots). :func:`paint_room` paints one seeded room view (BGR uint8) from these
:data:`ROOM_ITEMS`:

- ``window``: a bright window in a dark frame with cross bars, often behind horizontal blinds
  (slats a few px apart, lit from behind) or vertical blinds;
- ``curtain``: vertical folds (a sinusoidal shading) hanging from a rail;
- ``door``: a door leaf in a frame with a handle and a kick plate;
- ``wall_bars``: gymnasium wall bars (vertical posts, regularly spaced round rungs);
- ``treadmill``: a dark belt between metal side rails, with upright posts and a hand rail;
- ``rails``: horizontal hand / wall rails on brackets;
- ``poster``: a sheet with text lines, bold stripes or a checkerboard;
- ``ceiling_light``: bright panels and round downlights with glare;
- ``strobe``: motion-capture cameras (dark bodies with a ring of bright infrared-strobe LEDs
  around the lens), as ceiling- or tripod-mounted cameras appear in another camera's view.

Other people (``people``): the experimenter or the next subject standing in the room, front or
back on, in a T-shirt or with a bare back (a sports bra's strap, moles), in shorts or trousers:
skin, hair and clothing edges where the detector has seen only the subject's. They are painted
over the furniture from their own random stream, so a seed's furniture is the same with or
without them.

Every item is drawn by OpenCV primitives from a ``numpy`` generator, so a seed gives the same
room. Sizes scale with the image; nothing here knows about tape (the tape-free benchmark and the
renderer's backdrops use it).
"""

from __future__ import annotations

from typing import Literal, get_args

import cv2
import numpy as np

RoomItem = Literal["window", "curtain", "door", "wall_bars", "treadmill", "rails", "poster", "ceiling_light", "strobe"]
ROOM_ITEMS: tuple[str, ...] = get_args(RoomItem)

PEOPLE_STREAM = 13  # the people's random stream: seed's generator key beside the room's
# skin (BGR) from light to dark, and hair colours
_SKIN_LIGHT_BGR = np.array([173.0, 199.0, 237.0])
_SKIN_DARK_BGR = np.array([51.0, 71.0, 107.0])
_HAIR_BGR = ((20, 20, 25), (30, 45, 70), (60, 110, 170), (150, 160, 170), (25, 35, 50))
_TEXT_WORDS = ("GAIT LAB", "EXIT", "NO RUNNING", "SPINE", "CALIBRATE", "LAB 2", "RESEARCH", "FIRE DOOR",
               "KEEP CLEAR", "MOTION", "Vicon", "SAFETY FIRST", "Room 1.14", "0123456789")


def paint_room(size: tuple[int, int], seed: int, items: tuple[str, ...] | None = None,
               n_items: int | None = None, people: int = 0) -> np.ndarray:
    """A room view of ``size`` (width, height) px as BGR uint8: a wall (uneven lighting), a floor,
    ``items`` (default: ``n_items`` picked from :data:`ROOM_ITEMS` by the seed; at least one
    strobe camera or window in most rooms) and ``people`` other people standing in it. Raises
    ValueError for an unknown item or a negative count of people."""
    w, h = size
    rng = np.random.default_rng(seed)
    if items is None:
        k = int(n_items if n_items is not None else rng.integers(3, 7))
        items = tuple(str(i) for i in rng.choice(ROOM_ITEMS, size=min(k, len(ROOM_ITEMS)), replace=False))
    unknown = [i for i in items if i not in ROOM_ITEMS]
    if unknown:
        raise ValueError(f"unknown room items {unknown}; choose from {list(ROOM_ITEMS)}")
    if people < 0:
        raise ValueError(f"people must be >= 0 (got {people})")
    image = _wall_and_floor(w, h, rng)
    painters = {"window": _window, "curtain": _curtain, "door": _door, "wall_bars": _wall_bars,
                "treadmill": _treadmill, "rails": _rails, "poster": _poster, "ceiling_light": _ceiling_light,
                "strobe": _strobes}
    for item in items:
        painters[item](image, rng)
    crowd = np.random.default_rng([seed, PEOPLE_STREAM])
    for _ in range(people):
        _person(image, crowd)
    return image


def _colour(rng: np.random.Generator, lo: int, hi: int, tint: float = 12.0) -> tuple[int, int, int]:
    base = rng.uniform(lo, hi)
    red, green, blue = (int(np.clip(base + rng.normal(0, tint), 0, 255)) for _ in range(3))
    return red, green, blue


def _wall_and_floor(w: int, h: int, rng: np.random.Generator) -> np.ndarray:
    wall = np.array(_colour(rng, 110, 225, 10), np.float32)
    floor = np.array(_colour(rng, 40, 150, 15), np.float32)
    horizon = int(h * rng.uniform(0.6, 0.9))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    # a broad light fall-off across the wall (a window or a lamp to one side)
    cx, cy = rng.uniform(-0.5, 1.5) * w, rng.uniform(-0.5, 0.5) * h
    fall = 1.0 - rng.uniform(0.15, 0.4) * np.sqrt(((xx - cx) / w) ** 2 + ((yy - cy) / h) ** 2)
    image = np.where((yy < horizon)[..., None], wall, floor) * fall[..., None]
    cv2.line(image, (0, horizon), (w, horizon), tuple(float(v) * 0.5 for v in wall), max(2, h // 120))  # skirting
    return np.clip(image, 0, 255).astype(np.uint8)


def _box(rng: np.random.Generator, image: np.ndarray, w_frac: tuple[float, float], h_frac: tuple[float, float]
         ) -> tuple[int, int, int, int]:
    h, w = image.shape[:2]
    bw, bh = int(w * rng.uniform(*w_frac)), int(h * rng.uniform(*h_frac))
    x0, y0 = int(rng.uniform(-0.1, 1.0) * w - bw / 2), int(rng.uniform(-0.1, 0.9) * h - bh / 2)
    return x0, y0, x0 + bw, y0 + bh


def _window(image: np.ndarray, rng: np.random.Generator) -> None:
    x0, y0, x1, y1 = _box(rng, image, (0.15, 0.45), (0.25, 0.6))
    frame = _colour(rng, 20, 240, 5)
    sky = _colour(rng, 200, 255, 8)
    cv2.rectangle(image, (x0, y0), (x1, y1), sky, -1)
    t = max(3, (x1 - x0) // 25)
    cv2.rectangle(image, (x0, y0), (x1, y1), frame, t)
    cv2.line(image, ((x0 + x1) // 2, y0), ((x0 + x1) // 2, y1), frame, t)  # mullion
    if rng.random() < 0.5:
        cv2.line(image, (x0, (y0 + y1) // 2), (x1, (y0 + y1) // 2), frame, t)  # transom
    blinds = rng.choice(["horizontal", "vertical", "none"], p=[0.55, 0.25, 0.2])
    slat = _colour(rng, 60, 230, 10)
    if blinds == "horizontal":
        pitch = int(rng.integers(5, 16))
        gap = max(1, int(pitch * rng.uniform(0.15, 0.5)))
        bottom = int(y0 + (y1 - y0) * rng.uniform(0.5, 1.0))  # blinds partly raised
        for y in range(y0, bottom, pitch):
            cv2.rectangle(image, (x0 + t, y), (x1 - t, y + pitch - gap), slat, -1)
        cv2.rectangle(image, (x0 + t, bottom - 3), (x1 - t, bottom + 2), frame, -1)  # bottom rail
        if rng.random() < 0.7:  # ladder cords across the slats
            for x in np.linspace(x0 + t, x1 - t, int(rng.integers(2, 5)) + 2)[1:-1]:
                cv2.line(image, (int(x), y0), (int(x), bottom), frame, 1)
    elif blinds == "vertical":
        pitch = int(rng.integers(12, 40))
        gap = max(1, int(pitch * rng.uniform(0.05, 0.3)))
        for x in range(x0 + t, x1 - t, pitch):
            cv2.rectangle(image, (x, y0 + t), (x + pitch - gap, y1 - t), slat, -1)


def _curtain(image: np.ndarray, rng: np.random.Generator) -> None:
    h, w = image.shape[:2]
    x0, _, x1, _ = _box(rng, image, (0.1, 0.4), (0.5, 0.5))
    y0, y1 = int(rng.uniform(0, 0.15) * h), int(rng.uniform(0.6, 1.0) * h)
    x0, x1 = max(0, x0), min(w, x1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return
    colour = np.array(_colour(rng, 30, 200, 30), np.float32)
    period = rng.uniform(12, 45)
    xs = np.arange(x0, x1, dtype=np.float32)
    shade = 0.75 + 0.25 * np.sin(2 * np.pi * xs / period + rng.uniform(0, 6)) ** 3
    image[y0:y1, x0:x1] = np.clip(colour[None, None] * shade[None, :, None], 0, 255).astype(np.uint8)
    cv2.line(image, (x0 - 10, y0), (x1 + 10, y0), (60, 60, 60), max(2, h // 150))  # the rail


def _door(image: np.ndarray, rng: np.random.Generator) -> None:
    h, w = image.shape[:2]
    x0, y0, x1, _ = _box(rng, image, (0.1, 0.2), (0.5, 0.5))
    y0, y1 = int(h * rng.uniform(0.1, 0.3)), int(h * rng.uniform(0.75, 0.95))
    leaf, frame = _colour(rng, 60, 220, 20), _colour(rng, 20, 230, 5)
    cv2.rectangle(image, (x0, y0), (x1, y1), leaf, -1)
    cv2.rectangle(image, (x0, y0), (x1, y1), frame, max(3, (x1 - x0) // 12))
    hx, hy = int(x0 + 0.82 * (x1 - x0)), int(y0 + 0.55 * (y1 - y0))
    cv2.rectangle(image, (hx - 2, hy - 2), (hx + max(4, (x1 - x0) // 8), hy + 3), (190, 190, 195), -1)  # handle
    cv2.rectangle(image, (x0, int(y1 - 0.12 * (y1 - y0))), (x1, y1), (150, 150, 155), -1)  # kick plate
    if rng.random() < 0.5:  # a vision panel
        cv2.rectangle(image, (int(x0 + 0.3 * (x1 - x0)), int(y0 + 0.1 * (y1 - y0))),
                      (int(x0 + 0.7 * (x1 - x0)), int(y0 + 0.35 * (y1 - y0))), _colour(rng, 170, 250, 5), -1)


def _wall_bars(image: np.ndarray, rng: np.random.Generator) -> None:
    x0, y0, x1, y1 = _box(rng, image, (0.1, 0.35), (0.5, 0.8))
    wood = _colour(rng, 90, 200, 20)
    posts = int(rng.integers(2, 5))
    post_w = max(3, (x1 - x0) // 25)
    xs = np.linspace(x0, x1, posts)
    for x in xs:
        cv2.rectangle(image, (int(x) - post_w, y0), (int(x) + post_w, y1), wood, -1)
    pitch = max(6, int((y1 - y0) / rng.uniform(10, 25)))
    rung = max(2, pitch // 3)
    for y in range(y0, y1, pitch):
        cv2.rectangle(image, (x0, y), (x1, y + rung), tuple(int(v * 0.85) for v in wood), -1)


def _treadmill(image: np.ndarray, rng: np.random.Generator) -> None:
    h, w = image.shape[:2]
    x0, _, x1, _ = _box(rng, image, (0.3, 0.7), (0.2, 0.2))
    y0, y1 = int(h * rng.uniform(0.65, 0.8)), int(h * rng.uniform(0.85, 1.0))
    cv2.rectangle(image, (x0, y0), (x1, y1), (28, 28, 30), -1)  # belt
    metal = _colour(rng, 120, 220, 5)
    rail = max(3, (y1 - y0) // 8)
    cv2.rectangle(image, (x0 - rail, y0 - rail), (x1 + rail, y0), metal, -1)
    cv2.rectangle(image, (x0 - rail, y1), (x1 + rail, y1 + rail), metal, -1)
    for x in np.linspace(x0, x1, int(rng.integers(6, 14))):  # screw heads on the side rail
        cv2.circle(image, (int(x), y1 + rail // 2), max(1, rail // 3), (40, 40, 40), -1)
    top = int(y0 - h * rng.uniform(0.25, 0.45))
    for x in (x0 + rail, x1 - rail):  # uprights and the hand rail
        cv2.line(image, (x, y0), (x, top), metal, max(3, rail))
    cv2.line(image, (x0 + rail, top), (x1 - rail, top), metal, max(3, rail))
    cv2.rectangle(image, (int((x0 + x1) / 2 - w * 0.06), top - h // 20), (int((x0 + x1) / 2 + w * 0.06), top),
                  (35, 35, 40), -1)  # the console


def _rails(image: np.ndarray, rng: np.random.Generator) -> None:
    h, w = image.shape[:2]
    metal = _colour(rng, 100, 230, 5)
    for _ in range(int(rng.integers(1, 4))):
        y = int(h * rng.uniform(0.3, 0.8))
        thick = max(3, h // int(rng.integers(60, 140)))
        cv2.line(image, (0, y), (w, y), metal, thick)
        cv2.line(image, (0, y + thick // 2 + 1), (w, y + thick // 2 + 1), tuple(int(v * 0.5) for v in metal), 1)
        for x in range(int(rng.integers(0, w // 6)), w, int(w * rng.uniform(0.15, 0.3))):  # brackets
            cv2.rectangle(image, (x - thick, y), (x + thick, y + 3 * thick), (70, 70, 75), -1)


def _poster(image: np.ndarray, rng: np.random.Generator) -> None:
    x0, y0, x1, y1 = _box(rng, image, (0.1, 0.25), (0.15, 0.35))
    paper = _colour(rng, 190, 250, 5)
    ink = _colour(rng, 0, 70, 30)
    cv2.rectangle(image, (x0, y0), (x1, y1), paper, -1)
    kind = rng.choice(["text", "stripes", "checkerboard"])
    if kind == "text":
        scale = max(0.3, (y1 - y0) / 160)
        y = y0 + int(25 * scale)
        while y < y1 - 5:
            word = str(rng.choice(_TEXT_WORDS))
            cv2.putText(image, word, (x0 + 4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, ink, max(1, int(2 * scale)), cv2.LINE_AA)
            y += int(30 * scale)
    elif kind == "stripes":
        pitch = int(rng.integers(6, 30))
        vertical = rng.random() < 0.5
        for k in range(0, (x1 - x0) if vertical else (y1 - y0), pitch):
            if vertical:
                cv2.rectangle(image, (x0 + k, y0), (x0 + k + pitch // 2, y1), ink, -1)
            else:
                cv2.rectangle(image, (x0, y0 + k), (x1, y0 + k + pitch // 2), ink, -1)
    else:  # a calibration checkerboard
        square = int(rng.integers(6, 25))
        for i, y in enumerate(range(y0, y1 - square + 1, square)):
            for j, x in enumerate(range(x0, x1 - square + 1, square)):
                if (i + j) % 2:
                    cv2.rectangle(image, (x, y), (x + square - 1, y + square - 1), ink, -1)


def _ceiling_light(image: np.ndarray, rng: np.random.Generator) -> None:
    h, w = image.shape[:2]
    y = int(h * rng.uniform(0.0, 0.2))
    for x in np.linspace(0, w, int(rng.integers(2, 6)) + 2)[1:-1]:
        x = int(x + rng.normal(0, w / 30))
        if rng.random() < 0.5:  # a panel with a grid of louvres
            pw, ph = int(w * rng.uniform(0.08, 0.16)), int(h * rng.uniform(0.02, 0.05))
            cv2.rectangle(image, (x - pw, y - ph), (x + pw, y + ph), (250, 250, 250), -1)
            for k in range(x - pw, x + pw, max(4, pw // 6)):
                cv2.line(image, (k, y - ph), (k, y + ph), (170, 170, 175), 1)
        else:  # a round downlight with glare
            r = max(3, int(h * rng.uniform(0.01, 0.025)))
            glare = np.zeros(image.shape[:2], np.float32)
            cv2.circle(glare, (x, y), 3 * r, 1.0, -1)
            glare = cv2.GaussianBlur(glare, (0, 0), r)
            image[:] = np.clip(image + 90 * glare[..., None], 0, 255).astype(np.uint8)
            cv2.circle(image, (x, y), r, (255, 255, 255), -1)


def _strobes(image: np.ndarray, rng: np.random.Generator) -> None:
    """Motion-capture cameras: a dark body, a dark lens, a ring of bright LEDs round it."""
    h, w = image.shape[:2]
    for _ in range(int(rng.integers(1, 5))):
        cx, cy = int(rng.uniform(0.05, 0.95) * w), int(rng.uniform(0.02, 0.5) * h)
        r = max(6, int(h * rng.uniform(0.015, 0.06)))
        body = _colour(rng, 15, 60, 3)
        cv2.rectangle(image, (cx - int(1.5 * r), cy - int(1.4 * r)), (cx + int(1.5 * r), cy + int(1.8 * r)), body, -1)
        cv2.circle(image, (cx, cy), int(0.55 * r), (12, 12, 14), -1)  # the lens
        n = int(rng.choice([8, 10, 12, 16, 20, 24]))
        rings = 1 if rng.random() < 0.6 else 2
        led = max(1, int(round(r * rng.uniform(0.07, 0.14))))
        for ring in range(rings):
            rr = r * (0.8 + 0.3 * ring)
            for k in range(n):
                a = 2 * np.pi * (k + 0.5 * ring) / n
                cv2.circle(image, (int(round(cx + rr * np.cos(a))), int(round(cy + rr * np.sin(a)))), led,
                           (255, 255, 255) if rng.random() < 0.8 else (180, 180, 255), -1, cv2.LINE_AA)
        if rng.random() < 0.5:  # a tripod or a ceiling clamp
            cv2.line(image, (cx, cy + int(1.8 * r)), (cx, min(h - 1, cy + int(6 * r))), (50, 50, 55), max(2, r // 5))


def _person(image: np.ndarray, rng: np.random.Generator) -> None:
    """A standing person, feet on the floor near the horizon, 45-95 % of the image tall, seen from
    the front or the back: head and hair, neck, a T-shirt or a bare back (with a sports bra's strap
    and a few moles), arms, shorts or trousers, legs and shoes; lit from one side."""
    h, w = image.shape[:2]
    before = image.copy()
    tall = h * rng.uniform(0.45, 0.95)
    unit = tall / 7.5  # the head's height: a standing adult is ~7.5 heads tall
    cx, feet = rng.uniform(0.05, 0.95) * w, h * rng.uniform(0.8, 1.05)
    tone = rng.uniform(0.0, 1.0)
    skin = tuple(float(v) for v in (1 - tone) * _SKIN_LIGHT_BGR + tone * _SKIN_DARK_BGR)
    hair = _HAIR_BGR[int(rng.integers(len(_HAIR_BGR)))]
    shirt, legwear = _colour(rng, 20, 235, 60), _colour(rng, 15, 160, 40)
    bare_back = rng.random() < 0.3
    trousers = rng.random() < 0.5
    lean = rng.normal(0.0, 0.04) * unit

    def at(x_heads: float, y_heads: float) -> tuple[int, int]:  # body coordinates: heads from the feet up
        return int(round(cx + x_heads * unit + lean * y_heads)), int(round(feet - y_heads * unit))

    shoulder, hip, knee = 6.3, 3.9, 2.0
    thick = max(2, int(0.42 * unit))
    for side in (-1, 1):  # legs, then shoes
        cv2.line(image, at(0.35 * side, hip), at(0.4 * side, knee), legwear if trousers else skin, thick, cv2.LINE_AA)
        cv2.line(image, at(0.4 * side, knee), at(0.42 * side, 0.2), legwear if trousers else skin, int(thick * 0.85),
                 cv2.LINE_AA)
        cv2.ellipse(image, at(0.48 * side, 0.1), (max(2, int(0.35 * unit)), max(1, int(0.14 * unit))), 0, 0, 360,
                    (30, 30, 35), -1, cv2.LINE_AA)
    if not trousers:  # shorts over the thighs
        cv2.fillConvexPoly(image, np.array([at(-0.85, hip + 0.2), at(0.85, hip + 0.2), at(0.85, hip - 1.1),
                                            at(-0.85, hip - 1.1)], np.int32), legwear, cv2.LINE_AA)
    torso = np.array([at(-1.0, shoulder), at(1.0, shoulder), at(0.8, hip), at(-0.8, hip)], np.int32)
    cv2.fillConvexPoly(image, torso, skin if bare_back else shirt, cv2.LINE_AA)
    cv2.rectangle(image, at(-0.85, hip + 0.25), at(0.85, hip - 0.05), legwear, -1)  # waistband
    arm = max(2, int(0.3 * unit))
    swing = rng.uniform(-0.25, 0.25, size=2)
    for side, out in zip((-1, 1), swing):
        elbow, hand = at(side * (1.15 + out), shoulder - 1.5), at(side * (1.2 + 1.5 * out), shoulder - 2.9)
        cv2.line(image, at(side * 0.95, shoulder - 0.1), elbow, skin, arm, cv2.LINE_AA)
        cv2.line(image, elbow, hand, skin, arm, cv2.LINE_AA)
        if not bare_back:  # the T-shirt's sleeve
            cv2.line(image, at(side * 0.95, shoulder - 0.1), at(side * (1.08 + 0.5 * out), shoulder - 0.8), shirt,
                     int(arm * 1.3), cv2.LINE_AA)
    if bare_back:
        strap = _colour(rng, 10, 240, 60)
        cv2.rectangle(image, at(-0.92, shoulder - 1.2), at(0.92, shoulder - 1.55), strap, -1)
        for x_heads in (-0.45, 0.45):
            cv2.line(image, at(x_heads, shoulder), at(x_heads * 1.1, shoulder - 1.2), strap, max(1, int(0.1 * unit)))
        for _ in range(int(rng.integers(0, 6))):  # moles
            cv2.circle(image, at(rng.uniform(-0.7, 0.7), rng.uniform(hip + 0.3, shoulder - 0.3)),
                       max(1, int(0.04 * unit)), tuple(0.45 * c for c in skin), -1, cv2.LINE_AA)
    cv2.line(image, at(0.0, shoulder - 0.1), at(0.0, shoulder + 0.45), skin, max(2, int(0.45 * unit)), cv2.LINE_AA)
    head = at(0.0, shoulder + 0.95)
    axes = (max(2, int(0.38 * unit)), max(2, int(0.5 * unit)))
    cv2.ellipse(image, head, axes, 0, 0, 360, skin, -1, cv2.LINE_AA)
    from_behind = rng.random() < 0.5  # hair over the whole head, or a cap over its top half
    cv2.ellipse(image, head, (axes[0] + 1, axes[1] + 1), 0, 0 if from_behind else 180, 360, hair, -1, cv2.LINE_AA)
    # side light: the figure (the pixels just painted) darker towards one side
    figure = np.any(image != before, axis=2)
    light = np.clip((np.arange(w, dtype=np.float32) - cx) / (2.0 * unit), -1.0, 1.0) * rng.choice([-1.0, 1.0])
    shade = 1.0 - rng.uniform(0.05, 0.15) * (1.0 + light)
    image[figure] = np.clip(image.astype(np.float32) * shade[None, :, None], 0, 255).astype(np.uint8)[figure]
