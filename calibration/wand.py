"""Vicon wand co-registration: put a calibrated RGB rig into the Vicon frame.

Pipeline: detect the wand's bright markers in every RGB frame -> identify them from the wand's
geometry (two collinear triples meeting at the T junction) -> triangulate with the rig ->
read the Vicon C3D of the same wave -> coarse time offset by cross-correlating the wand's speed
-> joint refinement of offset and similarity transform (Umeyama start, robust least squares
with the Vicon trajectory spline-interpolated at RGB times) -> rig in the Vicon frame.
Optionally the rig's camera poses are first bundle-adjusted with the wand as a rigid target
(:func:`refine_rig_with_wand`).

Clocks: RGB frame i is at ``t_rgb = i / fps``; Vicon frame j at ``t_vicon = j / rate``; the
offset is defined by ``t_vicon = t_rgb + offset``. Similarity: ``X_vicon = s R X_rig + t`` (mm).

Wand layout (:class:`WandSpec`, defaults): a 5-marker T-wand in the style of Vicon's 5-marker
calibration wand, 14 mm markers, all in one plane (wand frame, mm)::

    WAND2 (-120, 0) ---- WAND1 (0, 0) ------------ WAND3 (240, 0)     cross bar
                           |
                         WAND4 (0, -160)                             stem
                           |
                         WAND5 (0, -400)

WAND1 (the junction) lies on both lines; on the cross bar it lies between the others, with the
short side (120 mm) to WAND2; on the stem it is an end, WAND4 lies between WAND1 and WAND5.
In Nexus, label the wand's markers WAND1..WAND5 in this layout before exporting the C3D.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Hashable, Iterable, Iterator, Sequence

import cv2
import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from spinemocap.camera import Rig
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable

from .geometry import rigid_fit, triangulate, umeyama


@dataclass(frozen=True)
class WandSpec:
    """Marker layout of a wand, mm, in the wand's frame: by default the planar 5-marker T-wand
    (see module doc); :meth:`parse` also makes 2- and 3-marker linear wands.

    ``kind``: ``"t"`` or ``"linear"``; ``x_axis``: the two markers whose direction is the world X
    axis when the wand lies on the floor (the origin is below the first); ``floor_height_mm``:
    height of the marker centres above the floor when the wand lies on it (default: the marker
    radius)."""

    labels: tuple[str, ...] = ("WAND1", "WAND2", "WAND3", "WAND4", "WAND5")
    points_mm: np.ndarray = field(default_factory=lambda: np.array(
        [[0, 0, 0], [-120, 0, 0], [240, 0, 0], [0, -160, 0], [0, -400, 0]], float))
    marker_diameter_mm: float = 14.0
    kind: str = "t"
    x_axis: tuple[int, int] = (0, 2)
    floor_height_mm: float | None = None

    @classmethod
    def parse(cls, text: str) -> "WandSpec":
        """``t`` (the 5-marker T-wand above), ``linear:LENGTH_MM`` (2 markers LENGTH apart) or
        ``linear:A_MM:LENGTH_MM`` (3 markers at 0, A and LENGTH along a line; A must be at most
        0.43 LENGTH or at least 0.57 LENGTH so the two ends can be told apart)."""
        parts = text.strip().lower().split(":")
        if parts[0] in ("t", "t-wand", "t5") and len(parts) == 1:
            return cls()
        along = _positions_along(parts[1:]) if parts[0] == "linear" and len(parts) in (2, 3) else None
        if along is None:
            raise InputError("wand", f"cannot parse wand {text!r}; expected t, linear:LENGTH_MM or "
                             "linear:A_MM:LENGTH_MM (increasing positive distances)")
        if len(along) == 3 and abs(along[1] / along[2] - 0.5) < 0.07:
            raise InputError("wand", f"linear wand {text!r}: the middle marker is too near the middle (the ends "
                             "cannot be told apart); it must sit at <= 0.43 or >= 0.57 of the length")
        points = np.array([[a, 0.0, 0.0] for a in along])
        return cls(tuple(f"WAND{k + 1}" for k in range(len(along))), points, kind="linear",
                   x_axis=(0, len(along) - 1))

    @property
    def n_markers(self) -> int:
        return len(self.points_mm)

    @property
    def ordered(self) -> bool:
        """Whether a single view tells every marker apart (not so for a 2-marker wand)."""
        return self.n_markers != 2

    @property
    def height_on_floor_mm(self) -> float:
        return self.marker_diameter_mm / 2 if self.floor_height_mm is None else self.floor_height_mm

    @property
    def length_pair(self) -> tuple[int, int]:
        """The two markers farthest apart ("the wand length")."""
        d = self.distances
        i, j = np.unravel_index(np.argmax(d), d.shape)
        return (int(min(i, j)), int(max(i, j)))

    @property
    def distances(self) -> np.ndarray:
        p = self.points_mm
        return np.linalg.norm(p[:, None] - p[None], axis=2)


def _positions_along(values: list[str]) -> list[float] | None:
    """[0, d1, d2...] from distance strings, or None unless they are numbers increasing from 0."""
    try:
        along = [0.0] + [float(v) for v in values]
    except ValueError:
        return None
    return along if all(b > a for a, b in itertools.pairwise(along)) else None


# ---------------------------------------------------------------------- 2D detection
def detect_blobs(image: np.ndarray, min_area: int = 4, max_area: int = 5000) -> np.ndarray:
    """(N, 2) sub-pixel centroids of bright round blobs (intensity-weighted above background)."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    background = float(np.median(grey[::8, ::8]))
    peak = float(grey.max())
    if peak - background < 40:
        return np.zeros((0, 2))
    level = (background + peak) / 2
    mask = grey > level
    ys, xs = np.nonzero(mask)
    # Work in the bounding box of the bright pixels (markers are a tiny part of the image).
    pad = 12
    oy, ox = max(int(ys.min()) - pad, 0), max(int(xs.min()) - pad, 0)
    grey = grey[oy:int(ys.max()) + pad + 1, ox:int(xs.max()) + pad + 1]
    mask = mask[oy:int(ys.max()) + pad + 1, ox:int(xs.max()) + pad + 1]
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    weights = np.clip(grey.astype(np.float32) - background, 0, None)
    centres = []
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        if not min_area <= area <= max_area or max(w, h) > 2.5 * min(w, h):
            continue
        pad = max(2, int(0.5 * max(w, h)))
        y0, y1, x0, x1 = max(y - pad, 0), y + h + pad, max(x - pad, 0), x + w + pad
        patch = weights[y0:y1, x0:x1] * (cv2.dilate((labels[y0:y1, x0:x1] == k).astype(np.uint8),
                                                    np.ones((3, 3), np.uint8), iterations=pad) > 0)
        total = patch.sum()
        vv, uu = np.mgrid[y0:y0 + patch.shape[0], x0:x0 + patch.shape[1]]
        centres.append([ox + (uu * patch).sum() / total, oy + (vv * patch).sum() / total])
    return np.asarray(centres, float).reshape(-1, 2)


def identify_wand(blobs: np.ndarray, wand: WandSpec, max_line_error: float = 0.02) -> np.ndarray | None:
    """Order 5 image blobs as the wand's markers (rows in :attr:`WandSpec.labels` order), or
    None when the view is ambiguous. Uses only projective facts (collinearity, betweenness) plus
    the cross bar's 1:2 side ratio."""
    if len(blobs) != 5:
        return None
    scores = []
    for triple in itertools.combinations(range(5), 3):
        p = blobs[list(triple)]
        d = np.linalg.norm(p[:, None] - p[None], axis=2)
        i, j = np.unravel_index(np.argmax(d), d.shape)
        middle = 3 - i - j
        span = d[i, j]
        line = (p[j] - p[i]) / span
        rel = p[middle] - p[i]
        off = abs(line[0] * rel[1] - line[1] * rel[0]) / span
        scores.append((off, triple, (triple[i], triple[middle], triple[j])))
    scores.sort(key=lambda s: s[0])
    (_, t1, o1), (off2, t2, o2) = scores[0], scores[1]
    if off2 > max_line_error or scores[2][0] < 3 * off2 or len(set(t1) & set(t2)) != 1:
        return None
    junction = (set(t1) & set(t2)).pop()
    cross, stem = (o1, o2) if o1[1] == junction else (o2, o1)
    if cross[1] != junction or stem[1] == junction:
        return None
    # Cross bar: short side (WAND2) vs long side (WAND3); a ratio near 1 is too ambiguous.
    a, b = cross[0], cross[2]
    da, db = np.linalg.norm(blobs[a] - blobs[junction]), np.linalg.norm(blobs[b] - blobs[junction])
    if max(da, db) < 1.3 * min(da, db):
        return None
    short, long_ = (a, b) if da < db else (b, a)
    near = stem[1]
    far = stem[0] if stem[2] == junction else stem[2]
    return blobs[[junction, short, long_, near, far]]


def identify_linear_wand(blobs: np.ndarray, wand: WandSpec, max_line_error: float = 0.02) -> np.ndarray | None:
    """Order the blobs of a linear wand as its markers, or None when the view is ambiguous. Three
    markers: collinear, the middle one between the others, the end nearer the middle marker is
    the wand's nearer end (image distance ratio >= 1.3). Two markers: returned as found (which
    end is which is settled later across cameras, :mod:`calibration.wandwave`)."""
    if len(blobs) != wand.n_markers:
        return None
    if wand.n_markers == 2:
        return blobs.copy() if np.linalg.norm(blobs[1] - blobs[0]) > 3.0 else None
    d = np.linalg.norm(blobs[:, None] - blobs[None], axis=2)
    i, j = np.unravel_index(np.argmax(d), d.shape)
    middle = 3 - i - j
    line = (blobs[j] - blobs[i]) / d[i, j]
    rel = blobs[middle] - blobs[i]
    if abs(line[0] * rel[1] - line[1] * rel[0]) / d[i, j] > max_line_error:
        return None
    near_model = wand.distances[0, 1] < wand.distances[1, 2]  # marker 0 is the end nearer the middle one
    di, dj = d[i, middle], d[j, middle]
    if max(di, dj) < 1.3 * min(di, dj):
        return None
    near, far = (i, j) if di < dj else (j, i)
    first, last = (near, far) if near_model else (far, near)
    return blobs[[first, middle, last]]


def identify_markers(blobs: np.ndarray, wand: WandSpec) -> np.ndarray | None:
    """The wand's markers in label order from one image's blobs (T-wand or linear), or None."""
    return identify_wand(blobs, wand) if wand.kind == "t" else identify_linear_wand(blobs, wand)


# ---------------------------------------------------------------------- 3D from the rig
WandViews = list[list[np.ndarray | None]]  # [frame][camera] -> (M, 2) identified pixels or None


def detect_wand_views(frames: Iterable[Sequence[np.ndarray]], wand: WandSpec, progress: bool = True) -> WandViews:
    """Identified wand markers per frame and camera for ``frames[f][c]`` = image of camera c at
    frame f (any iterable, e.g. streamed videos)."""
    return [[identify_markers(detect_blobs(img), wand) for img in images]
            for images in tqdm(frames, desc="wand markers", unit=" frames", disable=not progress, leave=False)]


def triangulate_wand_views(rig: Rig, views: WandViews, wand: WandSpec, max_fit_mm: float = 3.0) -> np.ndarray:
    """(F, M, 3) wand markers in the rig frame; NaN where fewer than two cameras identified the
    wand or the triangulated shape is more than ``max_fit_mm`` RMS from the wand's."""
    out = np.full((len(views), wand.n_markers, 3), np.nan)
    for f, per_cam in enumerate(views):
        pts = triangulate_markers(rig, per_cam)
        if pts is not None and rigid_fit(wand.points_mm, pts)[2] <= max_fit_mm:
            out[f] = pts
    return out


def triangulate_markers(rig: Rig, per_cam: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """(M, 3) markers of one frame (rig frame, mm) triangulated from every camera that identified
    them (``per_cam[c]``: (M, 2) pixels in label order, or None); None when fewer than two did."""
    seen = [(c, v) for c, v in enumerate(per_cam) if v is not None]
    if len(seen) < 2:
        return None
    cams, views = [c for c, _ in seen], [v for _, v in seen]
    return np.stack([triangulate([rig[c] for c in cams], np.stack([v[k] for v in views]))
                     for k in range(len(views[0]))])


def triangulate_wand(rig: Rig, frames: Iterable[Sequence[np.ndarray]], wand: WandSpec,
                     max_fit_mm: float = 3.0, progress: bool = True) -> np.ndarray:
    """Detect, identify and triangulate: (F, 5, 3) wand markers in the rig frame (see above)."""
    return triangulate_wand_views(rig, detect_wand_views(frames, wand, progress), wand, max_fit_mm)


def refine_rig_with_wand(rig: Rig, views: WandViews, points: np.ndarray, wand: WandSpec,
                         reference: int = 0, progress: bool = True) -> Rig:
    """Bundle-adjust the camera poses (intrinsics fixed, ``reference`` camera fixed) with the wand
    as a rigid target of known geometry: every identified marker in every camera is an
    observation, each wand pose a free 6-dof body started from the triangulated markers."""
    from .boards import BoardDetection
    from .extrinsics import bundle_adjust

    detections: dict = {cam.name: {} for cam in rig}
    poses: dict[Hashable, tuple[np.ndarray, np.ndarray]] = {}
    for f, per_cam in enumerate(views):
        if not np.all(np.isfinite(points[f])):
            continue
        R, t, _ = rigid_fit(wand.points_mm, points[f])
        poses[f] = (R, t)
        for cam, pix in zip(rig, per_cam):
            if pix is not None:
                detections[cam.name][f] = BoardDetection(np.arange(wand.n_markers), pix)
    if len(poses) < 20:
        raise InputError("wand videos", f"only {len(poses)} triangulated wand frames; cannot refine the rig")
    refined, _, _ = bundle_adjust(rig, wand.points_mm, detections, [(c.R, c.t) for c in rig], poses,
                                  reference, refine_intrinsics=False, progress=progress)
    return refined


def synchronized_frames(sources: Sequence[str | os.PathLike], n_cameras: int
                        ) -> tuple[Iterator[list[np.ndarray]], float]:
    """Stream synchronized frames from one video (or image folder) per camera; returns the
    iterator of per-frame image lists (rig order) and the first video's frame rate (0 if unknown).
    Stops at the shortest source."""
    if len(sources) != n_cameras:
        raise InputError("sources", f"{len(sources)} videos for a rig of {n_cameras} cameras; give one per camera")
    from .intrinsics import iter_images

    fps = 0.0
    first = Path(sources[0])
    if first.is_file():
        cap = cv2.VideoCapture(str(first))
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        cap.release()
    streams = [iter_images(src, max_video_frames=10 ** 9) for src in sources]

    def frames() -> Iterator[list[np.ndarray]]:
        for items in zip(*streams):
            yield [image for _, image in items]

    return frames(), fps


# ---------------------------------------------------------------------- Vicon C3D
@dataclass
class ViconWand:
    """Wand markers from Vicon: ``points_mm`` (J, 5, 3) NaN where missing; ``rate`` Hz."""

    points_mm: np.ndarray
    rate: float
    source: str


def vicon_wand_from_table(table: MarkerTable, wand: WandSpec, source: str | os.PathLike | None = None) -> ViconWand:
    """The wand markers of a Vicon marker table (read from its C3D by the application layer with
    ``exporters.read``; labels as in ``wand.labels``, case-insensitive, subject prefixes like
    ``Wand:WAND1`` accepted). ``source`` names the file in errors."""
    labels = [str(lab) for lab in table.labels]
    _, points = table.dense()
    rate = float(table.fps)
    path = source
    simple = [lab.split(":")[-1].strip().upper() for lab in labels]
    index = []
    missing = []
    for lab in wand.labels:
        if lab.upper() in simple:
            index.append(simple.index(lab.upper()))
        else:
            missing.append(lab)
    if missing:
        raise InputError(path, f"wand markers {missing} not in the C3D (it has {labels[:12]}). Label the "
                         f"wand's markers {list(wand.labels)} in Nexus (layout in calibration/wand.py) and "
                         "export the wand wave again")
    pts = points[:, index]
    valid = np.all(np.isfinite(pts), axis=(1, 2))
    if valid.sum() < 20:
        raise InputError(path, f"only {int(valid.sum())} frames with all wand markers; capture a longer "
                         "wand wave with the wand in view of the Vicon cameras")
    return ViconWand(pts, rate, str(path))


# ---------------------------------------------------------------------- time + transform
@dataclass
class WandRegistration:
    """Rig -> Vicon: ``X_v = scale R X_rig + t`` (mm) and ``t_vicon = t_rgb + offset_s``;
    per-marker RMS residuals (mm) over ``n_frames`` matched frames."""

    R: np.ndarray
    t: np.ndarray
    scale: float
    offset_s: float
    residual_mm: dict[str, float]
    n_frames: int
    rig_in_vicon: Rig | None = None

    def summary(self) -> str:
        angles = Rotation.from_matrix(self.R).as_euler("xyz", degrees=True)
        lines = [
            f"time offset (t_vicon - t_rgb): {1000 * self.offset_s:+.2f} ms over {self.n_frames} frames",
            f"rotation (xyz Euler): {np.array2string(angles, precision=3)} deg; translation "
            f"{np.array2string(self.t, precision=2)} mm; scale {self.scale:.5f}"
            + ("  <-- rig scale differs from Vicon by more than 0.5 %: check the board's square size"
               if abs(self.scale - 1) > 0.005 else ""),
        ]
        lines += [f"  {lab}: residual RMS {res:.2f} mm" for lab, res in self.residual_mm.items()]
        return "\n".join(lines)


def speed(points: np.ndarray, dt: float) -> np.ndarray:
    """(T,) speed (mm/s) of the markers' centroid, central differences; NaN where unknown."""
    centroid = points.mean(axis=1)
    v = np.full(len(points), np.nan)
    v[1:-1] = np.linalg.norm(centroid[2:] - centroid[:-2], axis=1) / (2 * dt)
    return v


def coarse_offset(rgb: np.ndarray, fps: float, vicon: np.ndarray, rate: float,
                  max_offset_s: float = 2.0, step_s: float = 0.001) -> tuple[float, float]:
    """Offset (s) maximizing the correlation of the wand's speed in both systems; returns
    (offset, correlation). Speed is invariant to the unknown rigid transform."""
    s_rgb, s_vic = speed(rgb, 1 / fps), speed(vicon, 1 / rate)
    t_rgb = np.arange(len(rgb)) / fps
    t_vic = np.arange(len(vicon)) / rate
    ok_vic = np.isfinite(s_vic)
    best = (0.0, -np.inf)
    for tau in np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s):
        query = t_rgb + tau
        inside = np.isfinite(s_rgb) & (query >= t_vic[ok_vic][0]) & (query <= t_vic[ok_vic][-1])
        if inside.sum() < 20:
            continue
        other = np.interp(query[inside], t_vic[ok_vic], s_vic[ok_vic])
        r = np.corrcoef(s_rgb[inside], other)[0, 1]
        if r > best[1]:
            best = (float(tau), float(r))
    if not np.isfinite(best[1]):
        raise InputError("wand", "RGB and Vicon wand recordings do not overlap in time within "
                         f"+-{max_offset_s} s; record both systems during the same wave")
    return best


def register_wand(rig_points: np.ndarray, fps: float, vicon: ViconWand, wand: WandSpec,
                  max_offset_s: float = 2.0) -> WandRegistration:
    """Time offset and similarity transform from wand markers in the rig frame (F, 5, 3) at
    ``fps`` and the Vicon wand (see module doc)."""
    n_rgb = int(np.all(np.isfinite(rig_points), axis=(1, 2)).sum())
    if n_rgb < 20:
        raise InputError("wand videos", f"the wand was identified in only {n_rgb} frames (need 20): wave "
                         "it slowly through the volume seen by at least two cameras, markers unoccluded")
    tau0, corr = coarse_offset(rig_points, fps, vicon.points_mm, vicon.rate, max_offset_s)
    spline, t_lo, t_hi = _vicon_spline(vicon)
    t_rgb = np.arange(len(rig_points)) / fps
    # Frames matched throughout the refinement: inside the Vicon recording with a 50 ms margin.
    ok = (np.all(np.isfinite(rig_points), axis=(1, 2)) & (t_rgb + tau0 >= t_lo + 0.05)
          & (t_rgb + tau0 <= t_hi - 0.05))
    source = rig_points[ok].reshape(-1, 3)
    R0, t0, s0 = umeyama(source, spline(t_rgb[ok] + tau0).reshape(-1, 3))
    x0 = np.concatenate([[0.0], Rotation.from_matrix(R0).as_rotvec(), t0, [np.log(s0)]])

    def residuals(x: np.ndarray) -> np.ndarray:
        pred = np.exp(x[7]) * source @ Rotation.from_rotvec(x[1:4]).as_matrix().T + x[4:7]
        return (pred - spline(t_rgb[ok] + tau0 + x[0]).reshape(-1, 3)).ravel()

    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=2.0,
                        x_scale=[1e-3, 1e-3, 1e-3, 1e-3, 1.0, 1.0, 1.0, 1e-3])
    offset = tau0 + fit.x[0]
    R, t, s = Rotation.from_rotvec(fit.x[1:4]).as_matrix(), fit.x[4:7], float(np.exp(fit.x[7]))
    err = np.linalg.norm(residuals(fit.x).reshape(-1, wand.n_markers, 3), axis=2)
    residual = {lab: float(np.sqrt(np.mean(err[:, k] ** 2))) for k, lab in enumerate(wand.labels)}
    return WandRegistration(R, t, s, float(offset), residual, int(ok.sum()))


def _vicon_spline(vicon: ViconWand):
    """Cubic spline of the Vicon markers over time (gaps bridged only inside valid stretches)."""
    t = np.arange(len(vicon.points_mm)) / vicon.rate
    ok = np.all(np.isfinite(vicon.points_mm), axis=(1, 2))
    spline = CubicSpline(t[ok], vicon.points_mm[ok].reshape(ok.sum(), -1), axis=0)
    return spline, float(t[ok][0]), float(t[ok][-1])


def coregister(rig: Rig, frames: Iterable[Sequence[np.ndarray]], fps: float, vicon: ViconWand,
               wand: WandSpec | None = None, max_offset_s: float = 2.0, refine_extrinsics: bool = False,
               progress: bool = True) -> WandRegistration:
    """Whole pipeline: RGB frames (``frames[f][c]``, rig camera order) + the Vicon wand markers
    (:func:`vicon_wand_from_table`) -> registration
    with ``rig_in_vicon`` filled in. ``refine_extrinsics`` first bundle-adjusts the rig's poses
    with the wand's markers (:func:`refine_rig_with_wand`)."""
    wand = wand or WandSpec()
    if not fps or fps <= 0:
        raise InputError("fps", "unknown RGB frame rate; give the cameras' frame rate")
    views = detect_wand_views(frames, wand, progress)
    points = triangulate_wand_views(rig, views, wand)
    if refine_extrinsics:
        rig = refine_rig_with_wand(rig, views, points, wand, progress=progress)
        points = triangulate_wand_views(rig, views, wand)
    result = register_wand(points, fps, vicon, wand, max_offset_s)
    result.rig_in_vicon = rig.transformed(result.R, result.t, result.scale)
    return result


__all__ = ["WandSpec", "WandRegistration", "ViconWand", "detect_blobs", "identify_wand", "triangulate_wand",
           "detect_wand_views", "triangulate_wand_views", "refine_rig_with_wand",
           "vicon_wand_from_table", "coarse_offset", "identify_markers", "identify_linear_wand", "triangulate_markers", "register_wand", "coregister",
           "synchronized_frames"]
