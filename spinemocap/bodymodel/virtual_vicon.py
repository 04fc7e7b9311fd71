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
noise.

Gaps come from occlusion: the Vicon's cameras stand on a ring around the capture volume
(:class:`ViconCameraRing`; by default 8 cameras, as in a small gait lab, 3.5 m from the subject,
alternately 2.6 m and 1.8 m high, every camera seeing the whole volume: Vicon lenses are wide;
with 10 cameras not even the clavicle marker gaps at full flexion, with 8 it does). A marker sample is
reconstructed only when at least ``min_cameras`` (2) cameras see it; a camera sees it when the
marker does not face away (the angle between the skin normal under it and the direction to the
camera is at most ``max_view_angle_deg``, 100 deg: the sphere floats its radius above the skin, so
a little beyond the tangent plane it still shows) and no part of the body lies on the segment from
the marker to the camera (ray against the posed mesh, cast by the caller's ray caster: the studio's
``spinemocap.synth.visibility.MeshRayCaster`` through the application layer). Random short
dropouts (3-30 frames covering ``gap_share`` of the samples, as from a marker swap or a
flickering reflection) are a separate effect, off by default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..skin import SkinBinding, bind_to_surface, vertex_normals
from ..tape import TapeSpec
from .base import RestBody
from .markersets import PLUG_IN_GAIT, SPINE_MARKERS, level_point, place_markers

# blocked(starts, ends) -> (S,) bool: does the segment starts[s] -> ends[s] cross the posed body?
SegmentTest = Callable[[np.ndarray, np.ndarray], np.ndarray]
# ray_caster(vertices) -> the SegmentTest of the body posed with those (V, 3) mm vertices
RayCasterFactory = Callable[[np.ndarray], SegmentTest]


@dataclass(frozen=True)
class ViconCameraRing:
    """The Vicon's cameras on a ring around the capture volume (studio frame, mm, Z up):
    ``n_cameras`` at ``radius_mm`` (horizontal) from the volume's centre, heights cycling through
    ``heights_mm``, azimuths evenly over 360 deg from ``start_deg`` (0 = +X, counter-clockwise) or
    exactly ``azimuths_deg`` when given. Each camera is assumed to see the whole volume; a marker
    is hidden from it only by the body or by facing away (``max_view_angle_deg`` between the skin
    normal and the direction to the camera)."""

    n_cameras: int = 8
    radius_mm: float = 3500.0
    heights_mm: tuple[float, ...] = (2600.0, 1800.0)
    start_deg: float = 22.5
    azimuths_deg: tuple[float, ...] | None = None
    max_view_angle_deg: float = 100.0

    def centres(self, volume_centre_mm: np.ndarray) -> np.ndarray:
        """(C, 3) camera centres (mm) around ``volume_centre_mm`` (its height is ignored)."""
        if self.azimuths_deg is not None:
            azimuths = np.radians(np.asarray(self.azimuths_deg, float))
        else:
            azimuths = np.radians(self.start_deg + 360.0 * np.arange(self.n_cameras) / self.n_cameras)
        heights = np.resize(np.asarray(self.heights_mm, float), len(azimuths))
        x = volume_centre_mm[0] + self.radius_mm * np.cos(azimuths)
        y = volume_centre_mm[1] + self.radius_mm * np.sin(azimuths)
        return np.column_stack([x, y, heights])


def cameras_seeing(markers: np.ndarray, normals: np.ndarray, camera_centres: np.ndarray, blocked: SegmentTest,
                   max_view_angle_deg: float, lift_mm: float = 2.0) -> np.ndarray:
    """(M,) how many cameras (centres (C, 3) mm) see each marker (centres (M, 3) mm, skin normals
    under them (M, 3)): facing the camera within ``max_view_angle_deg`` and no body on the segment
    from the marker (lifted ``lift_mm`` along its normal) to the camera."""
    count = np.zeros(len(markers), int)
    cos_max = np.cos(np.radians(max_view_angle_deg))
    for centre in camera_centres:
        to_cam = centre - markers
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        facing = np.flatnonzero(np.einsum("md,md->m", to_cam, normals) >= cos_max)
        if len(facing):
            starts = markers[facing] + lift_mm * normals[facing]
            count[facing] += ~blocked(starts, np.repeat(centre[None], len(facing), axis=0))
    return count


@dataclass
class ViconSetup:
    """Recording settings; the transform/offset are the truth a cross-validation must recover.
    ``cameras``/``min_cameras``: occlusion gaps (see the module doc), tested ``occlusion_rate_hz``
    times a second and held in between (ray casting every 200 Hz sample costs 4x as much for
    gaps that last tens of ms or more); ``gap_share``: optional random dropouts on top (0 = none)."""

    rate_hz: float = 200.0
    clock_offset_s: float = 0.0473
    rotation_deg: tuple[float, float, float] = (0.4, -0.3, 92.0)  # xyz Euler, studio -> Vicon
    translation_mm: tuple[float, float, float] = (812.0, -1530.0, 4.5)
    marker_diameter_mm: float = 14.0
    noise_mm: float = 0.2
    cameras: ViconCameraRing = field(default_factory=ViconCameraRing)
    min_cameras: int = 2
    occlusion_rate_hz: float = 50.0
    gap_share: float = 0.0
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
    positions in the studio frame at studio times ``time_s - clock_offset_s``; ``cameras_seeing``
    (N, M) how many Vicon cameras saw each sample (-1: occlusion not modelled), ``occluded`` (N, M)
    gaps from occlusion, ``dropped`` (N, M) random dropouts, ``camera_centres`` (C, 3) mm studio
    frame."""

    labels: list[str]
    positions: np.ndarray
    time_s: np.ndarray
    truth_studio: np.ndarray
    setup: ViconSetup
    cameras_seeing: np.ndarray
    occluded: np.ndarray
    dropped: np.ndarray
    camera_centres: np.ndarray

    def groundtruth(self) -> dict[str, np.ndarray]:
        """Arrays for ``groundtruth.npz`` (prefix ``vicon_``)."""
        s = self.setup
        return {"vicon_R": s.R, "vicon_t_mm": s.t, "vicon_clock_offset_s": np.array(s.clock_offset_s),
                "vicon_rate_hz": np.array(s.rate_hz), "vicon_labels": np.array(self.labels),
                "vicon_time_s": self.time_s, "vicon_truth_studio_mm": self.truth_studio,
                "vicon_cameras_seeing": self.cameras_seeing.astype(np.int8), "vicon_occluded": self.occluded,
                "vicon_dropped": self.dropped, "vicon_camera_centres_mm": self.camera_centres}


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
           setup: ViconSetup | None = None, spine: bool = True, chunk: int = 64,
           ray_caster: RayCasterFactory | None = None, progress: bool = False) -> VirtualVicon:
    """Record the virtual Vicon over studio times [0, duration_s]: ``posed(times)`` returns the
    body's (N, V, 3) mm vertices (studio frame) at studio times (N,) s; ``rest`` is the same body at
    rest (studio frame) and ``tape_markers`` the markers on and beside its tape (built with the
    marker radius of ``setup``; the studio's: ``spinemocap.app.virtual_vicon``). ``ray_caster``
    (posed vertices -> segment test against that body) turns on occlusion gaps (module doc);
    without it no sample is occluded."""
    from tqdm import tqdm

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
    cameras = setup.cameras.centres(rest.vertices.mean(axis=0))
    if ray_caster is not None and len(cameras) < setup.min_cameras:
        raise ValueError(f"a Vicon ring of {len(cameras)} cameras cannot reconstruct markers that need "
                         f"{setup.min_cameras} cameras")
    stride = max(1, int(round(setup.rate_hz / setup.occlusion_rate_hz)))
    under: np.ndarray | None = None  # per marker, the vertex whose normal is the skin's under it
    truth, seeing = [], []
    with tqdm(total=len(studio_time), desc="virtual Vicon", unit=" frames", disable=not progress, leave=False) as bar:
        for start in range(0, len(studio_time), chunk):
            times = studio_time[start : start + chunk]
            for i, (t, v) in enumerate(zip(times, posed(times)), start):
                n = vertex_normals(v, rest.faces)
                markers = np.concatenate([skin.points(v, rest.faces, n), tape_markers.points(float(t), v, n)])
                truth.append(markers)
                if ray_caster is None:
                    seeing.append(np.full(len(markers), -1))
                elif i % stride:  # between occlusion instants: hold the last one
                    seeing.append(seeing[-1])
                else:
                    under = _nearest_vertices(v, markers) if under is None else under
                    seeing.append(cameras_seeing(markers, n[under], cameras, ray_caster(v),
                                                 setup.cameras.max_view_angle_deg))
            bar.update(len(times))
    truth_a, seeing_a = np.array(truth), np.array(seeing)
    vicon = truth_a @ setup.R.T + setup.t + rng.normal(0.0, setup.noise_mm, truth_a.shape)
    occluded = (seeing_a >= 0) & (seeing_a < setup.min_cameras)
    dropped = _gaps(len(vicon), vicon.shape[1], setup.gap_share, rng)
    vicon[occluded | dropped] = np.nan
    return VirtualVicon(labels_a + tape_markers.labels, vicon, vicon_time, truth_a, setup, seeing_a, occluded,
                        dropped, cameras)


def _nearest_vertices(vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) index of the vertex nearest each point."""
    from scipy.spatial import cKDTree

    return cKDTree(vertices).query(points)[1]


def _levels_under_tape(rest: RestBody, z_range_mm: tuple[float, float]) -> set[str]:
    """Spine levels whose rest height lies within the tape's dots' height range ``z_range_mm``
    (a marker cannot sit on the dots)."""
    lo, hi = z_range_mm[0] - 20.0, z_range_mm[1] + 20.0
    return {s for s in SPINE_MARKERS if lo <= level_point(rest, s)[2] <= hi}
