"""A virtual Vicon: reflective markers on a posed body, as a Vicon system would record them.

Markers: Plug-in Gait full body and spine markers (C7, T4, T8, T10, L1, L3, S1; those under the
tape are left out) placed by :mod:`.markersets`, plus tape markers at chosen 2-dot rows: one on
the tape's centre line (``VT_Rnn``, midway between the row's two dots, on top of the tape) and one
beside it on either side (``VT_RnnL`` / ``VT_RnnR`` on the skin, ``beside_mm`` beyond the tape's
edge; L = the subject's left). A marker's centre sits its radius (half the marker diameter, 14 mm
by default) above the surface along the normal; markers may be misplaced on the skin.

Recording: the Vicon runs its own clock and frame: a studio instant ``t`` is Vicon time
``t + clock_offset_s``; a studio point ``X`` is ``R X + t`` in the Vicon frame (both Z up, mm).
Frames are sampled at ``rate_hz`` on the Vicon clock over the studio's duration, with Gaussian
noise and gaps (dropouts of a few frames, as when a marker is briefly hidden).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..skin import SkinBinding, bind_to_surface, vertex_normals
from ..tape import TapeSpec
from .base import RestBody
from .markersets import PLUG_IN_GAIT, SPINE_MARKERS, level_point, place_markers


@dataclass
class ViconSetup:
    """Recording settings; the transform/offset are the truth a cross-validation must recover."""

    rate_hz: float = 200.0
    clock_offset_s: float = 0.0473
    rotation_deg: tuple[float, float, float] = (0.4, -0.3, 92.0)  # xyz Euler, studio -> Vicon
    translation_mm: tuple[float, float, float] = (812.0, -1530.0, 4.5)
    marker_diameter_mm: float = 14.0
    noise_mm: float = 0.2
    gap_share: float = 0.02
    misplacement_mm: float = 0.0
    beside_mm: float = 15.0
    seed: int = 0

    @property
    def R(self) -> np.ndarray:
        return Rotation.from_euler("xyz", self.rotation_deg, degrees=True).as_matrix()

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self.translation_mm, float)


@dataclass
class VirtualVicon:
    """``labels`` (M,), ``positions`` (N, M, 3) mm in the Vicon frame at Vicon times
    ``time_s`` (N,) = frame / rate (NaN in gaps), ``truth_studio`` (N, M, 3) noise- and gap-free
    positions in the studio frame at studio times ``time_s - clock_offset_s``."""

    labels: list[str]
    positions: np.ndarray
    time_s: np.ndarray
    truth_studio: np.ndarray
    setup: ViconSetup

    def groundtruth(self) -> dict[str, np.ndarray]:
        """Arrays for ``groundtruth.npz`` (prefix ``vicon_``)."""
        s = self.setup
        return {"vicon_R": s.R, "vicon_t_mm": s.t, "vicon_clock_offset_s": np.array(s.clock_offset_s),
                "vicon_rate_hz": np.array(s.rate_hz), "vicon_labels": np.array(self.labels),
                "vicon_time_s": self.time_s, "vicon_truth_studio_mm": self.truth_studio}


@dataclass
class TapeMarkers:
    """The Vicon markers on and beside a tape: ``labels`` (per 2-dot row ``VT_Rnn``, ``VT_RnnL``,
    ``VT_RnnR``), ``z_range_mm`` the rest height range (mm) of the tape's dots (no spine marker is
    stuck there) and ``points(time_s, vertices, normals)`` -> (M, 3) marker centres (mm, studio
    frame) on the body posed at studio time ``time_s`` (vertices/vertex normals (V, 3))."""

    labels: list[str]
    z_range_mm: tuple[float, float]
    points: Callable[[float, np.ndarray, np.ndarray], np.ndarray]


def tape_marker_layout(spec: TapeSpec, rows: list[int], beside_mm: float) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Labels of the tape markers (see module docstring) at 2-dot rows ``rows`` (0-based), the flat
    tape coordinates (R, 2) mm of the centre markers and (R, 2, 2) of the beside markers (L, R)."""
    graph = spec.graph
    labels, centres, sides = [], [], []
    for r in rows:
        v = float(graph.uv_mm[graph.row == r, 1].mean())
        name = f"VT_R{r + 1:02d}"
        labels += [name, name + "L", name + "R"]
        centres.append([0.0, v])
        # u positive toward the subject's right
        sides.append([[-(spec.width_mm / 2 + beside_mm), v], [spec.width_mm / 2 + beside_mm, v]])
    return labels, np.array(centres, float), np.array(sides, float)


def interleave_rows(centres: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """(R, 3) centre and (2R, 3) beside markers (row by row, L then R) -> (3R, 3) in label order."""
    return np.concatenate([centres[:, None], sides.reshape(-1, 2, 3)], axis=1).reshape(-1, 3)


def default_tape_rows(spec: TapeSpec) -> list[int]:
    """Three 2-dot rows: the second, the middle and the last but one."""
    two = [r for r in range(spec.n_rows) if (spec.graph.row == r).sum() == 2]
    return sorted({two[0], two[len(two) // 2], two[-1]})


def skin_marker_binding(rest: RestBody, labels: list[str], radius_mm: float, misplacement_mm: float,
                        rng: np.random.Generator) -> tuple[list[str], SkinBinding]:
    """Skin markers placed by rule, each optionally misplaced by ``misplacement_mm`` along the
    skin in a random direction, floated ``radius_mm`` above it."""
    kept, vertices = place_markers(rest, labels)
    points = rest.vertices[vertices].copy()
    normals = rest.normals[vertices]
    if misplacement_mm > 0:
        shift = rng.normal(size=points.shape)
        shift -= np.einsum("nd,nd->n", shift, normals)[:, None] * normals
        points += misplacement_mm * shift / np.linalg.norm(shift, axis=1, keepdims=True)
    binding = bind_to_surface(rest.vertices, rest.faces, points + 20.0 * normals, -normals,
                              np.full(len(points), radius_mm))
    return kept, binding


def _gaps(n_frames: int, n_markers: int, share: float, rng: np.random.Generator) -> np.ndarray:
    """(N, M) True where a marker is missing: dropouts of 3-30 frames covering ~``share``."""
    missing = np.zeros((n_frames, n_markers), bool)
    if share <= 0 or n_frames < 4:
        return missing
    mean_len = 12
    for m in range(n_markers):
        for _ in range(rng.poisson(share * n_frames / mean_len)):
            start = rng.integers(0, n_frames)
            missing[start : start + rng.integers(3, 31), m] = True
    return missing


def record(rest: RestBody, tape_markers: TapeMarkers, posed: Callable[[np.ndarray], np.ndarray], duration_s: float,
           setup: ViconSetup | None = None, spine: bool = True, chunk: int = 64) -> VirtualVicon:
    """Record the virtual Vicon over studio times [0, duration_s]: ``posed(times)`` returns the
    body's (N, V, 3) mm vertices (studio frame) at studio times (N,) s; ``rest`` is the same body at
    rest (studio frame) and ``tape_markers`` the markers on and beside its tape (built with the
    marker radius of ``setup``; the studio's: ``spinemocap.app.virtual_vicon``)."""
    setup = setup or ViconSetup()
    rng = np.random.default_rng(setup.seed)
    radius = setup.marker_diameter_mm / 2
    under_tape = _levels_under_tape(rest, tape_markers.z_range_mm)
    wanted = list(PLUG_IN_GAIT) + [s for s in SPINE_MARKERS if spine and s not in PLUG_IN_GAIT]
    skin_labels = [s for s in wanted if s not in under_tape]
    labels_a, skin = skin_marker_binding(rest, skin_labels, radius, setup.misplacement_mm, rng)
    first = int(np.ceil(setup.clock_offset_s * setup.rate_hz - 1e-9))
    last = int(np.floor((duration_s + setup.clock_offset_s) * setup.rate_hz + 1e-9))
    vicon_time = np.arange(first, last + 1) / setup.rate_hz
    studio_time = np.clip(vicon_time - setup.clock_offset_s, 0.0, duration_s)
    truth = []
    for start in range(0, len(studio_time), chunk):
        times = studio_time[start : start + chunk]
        for t, v in zip(times, posed(times)):
            n = vertex_normals(v, rest.faces)
            truth.append(np.concatenate([skin.points(v, rest.faces, n), tape_markers.points(float(t), v, n)]))
    truth_a = np.array(truth)
    vicon = truth_a @ setup.R.T + setup.t + rng.normal(0.0, setup.noise_mm, truth_a.shape)
    vicon[_gaps(len(vicon), vicon.shape[1], setup.gap_share, rng)] = np.nan
    return VirtualVicon(labels_a + tape_markers.labels, vicon, vicon_time, truth_a, setup)


def _levels_under_tape(rest: RestBody, z_range_mm: tuple[float, float]) -> set[str]:
    """Spine levels whose rest height lies within the tape's dots' height range ``z_range_mm``
    (a marker cannot sit on the dots)."""
    lo, hi = z_range_mm[0] - 20.0, z_range_mm[1] + 20.0
    return {s for s in SPINE_MARKERS if lo <= level_point(rest, s)[2] <= hi}
