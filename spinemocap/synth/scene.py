"""The synthetic studio: configuration, scene assembly, ground truth and rendering.

Pipeline of :func:`build_scene`: phenotype -> anny body -> tape laid on the rest skin (bound by
barycentric coordinates) -> motion sampled at the frame times -> posed meshes -> camera rig
around the tape -> occluders. Ground truth (dots, normals, keypoints, projections, visibility,
applied angles) is computed on first access of :attr:`Scene.groundtruth`; images are rendered
on demand per frame (:meth:`Scene.render`, :meth:`Scene.frame_source`).

Everything random (lens imperfections, balls, lighting, skin tone, sensor noise) derives from
``config.seed``, so a seed reproduces a capture exactly.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import cv2
import numpy as np

from ..camera import Rig
from ..skin import vertex_normals
from ..tape import TapeSpec
from .appearance import (
    BACKDROPS,
    CAMERA_LOOKS,
    CODECS,
    TAPE_COLOURS,
    TAPE_ROLLS,
    behind_subject,
    camera_looks,
    roll_layout,
    room_view,
)
from .body import ANGLE_NAMES, JOINT_DEPTHS, LEVELS, PHENOTYPE_KEYS, Body, JointDepth
from .lab_errors import clock_offsets_s, perturb_rig
from .motions import MOTIONS, spine_motion
from .occluders import (
    CLOTHING_ITEMS,
    OCCLUSION_LEVELS,
    Clothing,
    FallingBalls,
    Garment,
    SportsBraBand,
    balls_for,
    sphere_mesh,
    wear_clothing,
)
from .reference import ReferenceMeshes, reference_meshes, studio_reference
from .render import Appearance, CameraRenderer, MeshTexture, SceneMeshes
from .rigs import LAYOUTS, arc_rig
from .shutter import Shutter, exposed, rolling_shutter_uv, row_weights
from .skin_strain import SkinStrain
from .surfaces import (
    DRY_SPECULAR,
    SKIN_MARKS,
    SWEAT_SPECULAR,
    TAPE_FINISHES,
    SurfaceLook,
    skin_extent,
    skin_texture,
    tape_texture,
)
from .tape_on_skin import (
    SYNTH_TAPE_THICKNESS_MM,
    BackChart,
    PosedTape,
    TapeOnSkin,
    TapeTension,
    back_chart,
    rows_to_pass,
)
from .visibility import MeshRayCaster, dot_visibility

log = logging.getLogger(__name__)

# the largest clock offset a studio camera may have, s
MAX_CAMERA_OFFSET_S = 5.0
POSE_CHUNK = 64  # frames posed together (anny is batched) and kept in memory
# worker threads that develop rendered canvases (lens, noise, masks) while VTK renders the next
# camera; one per core beyond the one VTK's render loop runs on, at least one
DEVELOP_WORKERS = max(1, (os.cpu_count() or 2) - 1)
SKIN_LIGHT = np.array([0.93, 0.78, 0.68])
SKIN_DARK = np.array([0.42, 0.28, 0.20])

_PRESETS: dict[str, dict] = {
    "tiny": {"frames": 4, "fps": 4.0, "cameras": 3, "size": (480, 360), "motion": "mixed"},
    # the paper's 13-row tape (32 dots): from S1 it passes T12/L1 by four or more rows
    "artificial": {"frames": 548, "fps": 100.0, "cameras": 4, "size": (1024, 768), "rows": 13, "motion": "mixed"},
    "studio": {"frames": 300, "fps": 100.0, "cameras": 6, "size": (2448, 1600), "rows": 13, "motion": "mixed"},
}

# Realism levels: the values of the realism fields a level sets when they are not given.
# ideal: no skin strain, tape laid at its spec, exact calibration and sync);
# skin (SynthConfig's default): a real back under an exact set-up (Schober skin strain);
# lab: a real back in a real lab (15 % taping tension, 0.5 px calibration error, 1 ms sync
# error, sensor noise of 3 grey levels) -- the benchmarks' default.
RealismSetting = Literal["skin_strain", "tape_tension", "calibration_error_px", "sync_error_ms", "noise"]
REALISM_LEVELS: dict[str, dict[RealismSetting, float]] = {
    "ideal": {"skin_strain": 0.0, "tape_tension": 0.0, "calibration_error_px": 0.0, "sync_error_ms": 0.0, "noise": 2.0},
    "skin": {"skin_strain": 1.0, "tape_tension": 0.0, "calibration_error_px": 0.0, "sync_error_ms": 0.0, "noise": 2.0},
    "lab": {"skin_strain": 1.0, "tape_tension": 0.15, "calibration_error_px": 0.5, "sync_error_ms": 1.0, "noise": 3.0},
}
# rows: by default enough to pass the T12/L1 junction by this many rows at rest
ROWS_PAST_THORACOLUMBAR = 2


@dataclass
class SynthConfig:
    """Everything that defines a synthetic capture. Lengths mm, times s, sizes (width, height) px.

    ``occlusion`` names a ball rate (``none``/``light``/``heavy``, see
    :mod:`spinemocap.synth.occluders`); ``balls`` overrides the number of balls released over the
    sequence. ``blur`` is the exposure as a fraction of the frame interval (0 = sharp);
    ``noise`` the sensor noise standard deviation in 8-bit grey levels; ``distortion`` scales
    the random lens distortion (0 = ideal pinhole); ``skin_tone`` runs from 0 (light) to 1
    (dark), None picks one from the seed; ``phenotype`` holds anny's parameters in [0, 1]
    (anny's convention: gender 0 = male .. 1 = female; age 0 = newborn .. 0.5 = young adult ..
    1 = old; muscle, weight, height, proportions; ``sex`` is an alias of gender); ``joint_depth``
    where the spine bends under the skin (:data:`spinemocap.synth.body.JointDepth`: anny's joints,
    or moved to the published depth of the vertebral bodies).
    ``tape_start``: the vertebral level (S2..T1) of the tape's first row, S1 by default; ``rows``
    None picks the smallest odd count that passes the T12/L1 junction by
    :data:`ROWS_PAST_THORACOLUMBAR` rows on this body (at rest, with the tension), fewer (at
    least 3) where the back above a high start is shorter.
    ``realism`` (:data:`REALISM_LEVELS`: ``ideal``, ``skin`` = default, ``lab``) sets every realism
    field left None: ``skin_strain`` scales the Schober skin strain of
    :mod:`spinemocap.synth.skin_strain` (0 = off, 1 = a healthy adult, the subject's figures drawn
    from the seed), ``tape_tension``, ``calibration_error_px``, ``sync_error_ms`` and ``noise``.
    ``tape_tension``: the tape was laid stretched along its length by this fraction (0.2 = its dots
    sit 20 % farther apart on the skin than the roll's spec), unevenly along the tape (seeded, see
    :class:`spinemocap.synth.tape_on_skin.TapeTension`); ``capture.toml`` keeps the roll's spec.
    ``calibration_error_px``: the written ``rig.toml`` is perturbed (rotations, centres, focal
    lengths) so that the true dots reproject through it with this RMS per camera, while the images
    come from the true rig (kept in the ground truth); ``sync_error_ms``: RMS of per-camera clock
    offsets (each camera renders at its own offset times). See :mod:`spinemocap.synth.lab_errors`.
    Cameras that are not synchronised (see :mod:`spinemocap.timebase` for the clock convention):
    ``camera_offsets_s`` (C,) each camera's clock minus the capture's, s (whole or fractional
    frames, at most :data:`MAX_CAMERA_OFFSET_S`): camera ``c`` starts recording at capture time
    ``-camera_offsets_s[c]`` and its frame ``k`` shows capture time ``k / camera_fps[c] -
    camera_offsets_s[c]``; ``camera_fps`` (C,) each camera's own rate (default ``fps``, the
    capture's); ``drop_frames``: that many frames (seeded cameras and places) are missing from the
    videos, leaving gaps in their timestamps; ``clap``: the videos carry a mono audio track with a
    hand clap heard by every camera. Any of them makes every camera record on its own clock until
    the capture's last frame; the truth is in the ground truth (``clock_offsets_s``,
    ``camera_fps``, ``dropped_slots``, ``clap_time_s``).
    ``reference``: an L-frame of five markers stands beside the subject in view of the cameras
    (:mod:`spinemocap.synth.reference`): rendered in the images, its design and pose written to
    ``reference.toml`` (what a lab enters), its markers' true projections in the ground truth.
    Appearance (:mod:`spinemocap.synth.appearance`, :mod:`spinemocap.synth.surfaces`):
    ``tape_colour``, ``tape_roll`` (hole diameter and spacing; ``capture.toml`` names the roll's
    layout, so the tracker knows it), ``tape_finish``, ``skin_marks`` (any of hair, freckles,
    moles, sweat, tattoo: on the skin, under the tape), ``clothing`` (any of shorts, bra_strap:
    solids that hide the tape in the mask and the visibility where they cross it), ``backdrop``,
    ``bystanders`` (other people standing in the ``room`` backdrop, painted into each camera's
    room view on their own: a 2D hard negative, not a second body in 3D), ``camera_look``; ``rolling_shutter_ms`` sets every camera's readout time (None: the camera
    look's; rows are exposed one after the other, the ground truth's ``uv`` is where each dot was
    when its row was read, ``visible`` at the frame's instant) and ``camera_codec`` every
    camera's codec (None: the camera look's).
    """

    layout: str = "tiny"  # the preset whose camera layout is used (rigs.LAYOUTS)
    frames: int = 4
    fps: float = 100.0
    cameras: int = 3
    size: tuple[int, int] = (480, 360)
    rows: int | None = None
    motion: str = "mixed"
    occlusion: str = "none"
    balls: int | None = None
    band: bool = False
    band_level: str = "T9"
    seed: int = 0
    phenotype: dict = field(default_factory=dict)
    skin_tone: float | None = None
    blur: float = 0.0
    noise: float | None = None
    distortion: float = 1.0
    tape_start: str = "S1"
    realism: str = "skin"
    skin_strain: float | None = None
    tape_tension: float | None = None
    calibration_error_px: float | None = None
    sync_error_ms: float | None = None
    supersample: int = 1
    reference: bool = False
    video: bool = False
    name: str = "synthetic"
    camera_offsets_s: tuple[float, ...] | None = None
    camera_fps: tuple[float, ...] | None = None
    drop_frames: int = 0
    clap: bool = False
    tape_colour: str = "black"  # appearance.TAPE_COLOURS
    backdrop: str = "plain"  # appearance.BACKDROPS: the renderer's uniform background or a painted lab room
    bystanders: int = 0  # other people in the painted room (backdrop "room" only)
    camera_look: str = "ideal"  # appearance.CAMERA_LOOKS: light and camera effects after the sensor (ideal: none)
    tape_roll: str = "standard"  # appearance.TAPE_ROLLS: hole diameter, row pitch and column spacing
    tape_finish: str = "smooth"  # surfaces.TAPE_FINISHES
    skin_marks: tuple[str, ...] = ()  # surfaces.SKIN_MARKS
    clothing: tuple[str, ...] = ()  # occluders.CLOTHING_ITEMS
    rolling_shutter_ms: float | None = None  # every camera's readout (None: the camera look's)
    camera_codec: str | None = None  # appearance.CODECS for every camera (None: the camera look's)
    joint_depth: JointDepth = "anny"  # body.JOINT_DEPTHS: where the spine bends under the skin

    def __post_init__(self) -> None:
        self.size = (int(self.size[0]), int(self.size[1]))
        self.phenotype = dict(self.phenotype)
        if "sex" in self.phenotype:
            self.phenotype["gender"] = self.phenotype.pop("sex")
        problems = []
        if self.realism not in REALISM_LEVELS:
            raise ValueError(f"invalid synthetic studio settings: unknown realism level {self.realism!r} "
                             f"(choose from {list(REALISM_LEVELS)})")
        for name, value in REALISM_LEVELS[self.realism].items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if self.layout not in LAYOUTS:
            problems.append(f"unknown camera layout {self.layout!r} (choose from {sorted(LAYOUTS)})")
        if self.frames < 1:
            problems.append(f"frames must be >= 1 (got {self.frames})")
        if not self.fps > 0:
            problems.append(f"fps must be positive (got {self.fps})")
        if self.cameras < 1:
            problems.append(f"cameras must be >= 1 (got {self.cameras})")
        if min(self.size) < 16:
            problems.append(f"image size {self.size} is too small (min 16 px)")
        if self.rows is not None and (self.rows < 1 or self.rows % 2 == 0):
            problems.append(f"rows must be odd and >= 1: rows alternate 2/3 dots and start and end with a 2-dot row (got {self.rows})")
        if self.motion not in MOTIONS:
            problems.append(f"unknown motion {self.motion!r} (choose from {sorted(MOTIONS)})")
        if self.occlusion not in OCCLUSION_LEVELS:
            problems.append(f"unknown occlusion level {self.occlusion!r} (choose from {list(OCCLUSION_LEVELS)})")
        if self.balls is not None and self.balls < 0:
            problems.append(f"balls must be >= 0 (got {self.balls})")
        if not 0 <= self.blur <= 1:
            problems.append(f"blur (exposure / frame interval) must lie in [0, 1] (got {self.blur})")
        level = {name: float(getattr(self, name)) for name in REALISM_LEVELS[self.realism]}  # all set now
        if level["noise"] < 0 or self.distortion < 0:
            problems.append("noise and distortion must be >= 0")
        if self.skin_tone is not None and not 0 <= self.skin_tone <= 1:
            problems.append(f"skin_tone must lie in [0, 1] (got {self.skin_tone})")
        if self.joint_depth not in JOINT_DEPTHS:
            problems.append(f"unknown joint depth {self.joint_depth!r} (choose from {list(JOINT_DEPTHS)})")
        unknown = set(self.phenotype) - set(PHENOTYPE_KEYS)
        if unknown:
            problems.append(f"unknown phenotype keys {sorted(unknown)} (known: {list(PHENOTYPE_KEYS)} and 'sex')")
        if any(not 0 <= float(v) <= 1 for v in self.phenotype.values()):
            problems.append("phenotype values must lie in [0, 1]")
        for level_field in ("tape_start", "band_level"):
            if getattr(self, level_field) not in LEVELS:
                problems.append(f"{level_field} {getattr(self, level_field)!r} is not a vertebral level (choose from {list(LEVELS)})")
        if not 0 <= level["skin_strain"] <= 3:
            problems.append(f"skin_strain (a scale of the Schober skin strain, 1 = a healthy adult) must lie in [0, 3] "
                            f"(got {self.skin_strain})")
        if not -0.3 <= level["tape_tension"] <= 0.8:
            problems.append(f"tape_tension must lie in [-0.3, 0.8] (kinesiology tape gives out at about 1.4-1.6 "
                            f"times its rest length; got {self.tape_tension})")
        if not 0 <= level["calibration_error_px"] <= 20:
            problems.append(f"calibration_error_px must lie in [0, 20] (got {self.calibration_error_px})")
        if not 0 <= level["sync_error_ms"] <= 50:
            problems.append(f"sync_error_ms must lie in [0, 50] (got {self.sync_error_ms})")
        if self.supersample < 1:
            problems.append("supersample must be >= 1")
        problems += self._clock_problems()
        if self.tape_colour not in TAPE_COLOURS:
            problems.append(f"unknown tape_colour {self.tape_colour!r} (choose from {list(TAPE_COLOURS)})")
        if self.backdrop not in BACKDROPS:
            problems.append(f"unknown backdrop {self.backdrop!r} (choose from {list(BACKDROPS)})")
        if self.bystanders < 0 or (self.bystanders and self.backdrop != "room"):
            problems.append(f"bystanders must be >= 0 and stand in the room backdrop (got {self.bystanders} with "
                            f"backdrop {self.backdrop!r})")
        if self.camera_look not in CAMERA_LOOKS:
            problems.append(f"unknown camera_look {self.camera_look!r} (choose from {list(CAMERA_LOOKS)})")
        problems += self._surface_problems()
        if problems:
            raise ValueError("invalid synthetic studio settings: " + "; ".join(problems))

    def _surface_problems(self) -> list[str]:
        problems = []
        if self.tape_roll not in TAPE_ROLLS:
            problems.append(f"unknown tape_roll {self.tape_roll!r} (choose from {list(TAPE_ROLLS)})")
        if self.tape_finish not in TAPE_FINISHES:
            problems.append(f"unknown tape_finish {self.tape_finish!r} (choose from {list(TAPE_FINISHES)})")
        for name, vocabulary in (("skin_marks", SKIN_MARKS), ("clothing", CLOTHING_ITEMS)):
            values = (getattr(self, name),) if isinstance(getattr(self, name), str) else tuple(getattr(self, name))
            unknown = [v for v in values if v not in vocabulary]
            if unknown:
                problems.append(f"unknown {name} {unknown} (choose any of {list(vocabulary)})")
            setattr(self, name, tuple(v for v in vocabulary if v in values))  # vocabulary order, no repeats
        if self.rolling_shutter_ms is not None and not 0 <= self.rolling_shutter_ms <= 100:
            problems.append(f"rolling_shutter_ms (the readout from the top row to the bottom row) must lie in [0, 100] "
                            f"(got {self.rolling_shutter_ms})")
        if self.camera_codec is not None and self.camera_codec not in CODECS:
            problems.append(f"unknown camera_codec {self.camera_codec!r} (choose from {list(CODECS)})")
        return problems

    def realism_setting(self, name: RealismSetting) -> float:
        """The lab-error setting ``name``: the field where set, else the realism level's value."""
        value = getattr(self, name)
        return float(value) if value is not None else REALISM_LEVELS[self.realism][name]

    def _clock_problems(self) -> list[str]:
        problems = []
        for name in ("camera_offsets_s", "camera_fps"):
            values = getattr(self, name)
            if values is None:
                continue
            values = tuple(float(v) for v in values)
            setattr(self, name, values)
            if len(values) != self.cameras:
                problems.append(f"{name} needs one value per camera ({self.cameras}), got {len(values)}")
        if self.camera_offsets_s is not None and any(not abs(v) <= MAX_CAMERA_OFFSET_S for v in self.camera_offsets_s):
            problems.append(f"camera offsets must lie within +-{MAX_CAMERA_OFFSET_S:g} s (got {list(self.camera_offsets_s)})")
        if self.camera_fps is not None and any(not 0 < v <= 1000 for v in self.camera_fps):
            problems.append(f"camera frame rates must lie in (0, 1000] (got {list(self.camera_fps)})")
        if self.drop_frames < 0:
            problems.append(f"drop_frames must be >= 0 (got {self.drop_frames})")
        if (self.drop_frames or self.clap) and not self.video:
            problems.append("dropped frames and the clap's audio need videos (video = true): an image folder has "
                            "no timestamps or sound")
        return problems

    @property
    def unsynchronised(self) -> bool:
        """Does every camera record on its own clock (offsets, own rates, drops or a clap)?"""
        return (self.camera_offsets_s is not None or self.camera_fps is not None or self.drop_frames > 0
                or self.clap)

    @classmethod
    def preset(cls, name: str, /, **overrides) -> SynthConfig:
        """A named preset (``tiny``, ``artificial``, ``studio``) with fields overridden."""
        if name not in _PRESETS:
            raise ValueError(f"unknown preset {name!r}; choose from {sorted(_PRESETS)}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(overrides) - known
        if unknown:
            raise ValueError(f"unknown synthetic studio settings {sorted(unknown)}; known: {sorted(known)}")
        values = dict(_PRESETS[name], layout=name)
        values.update({k: v for k, v in overrides.items() if v is not None or k in ("balls", "skin_tone")})
        return cls(**values)

    @property
    def duration_s(self) -> float:
        return self.frames / self.fps

    @property
    def n_balls(self) -> int:
        return self.balls if self.balls is not None else balls_for(self.occlusion, self.duration_s)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["size"] = list(self.size)
        for name in ("camera_offsets_s", "camera_fps", "skin_marks", "clothing"):
            if d[name] is not None:
                d[name] = list(d[name])
        return {k: v for k, v in d.items() if v is not None}


@dataclass
class RenderedFrame:
    """One rendered instant: ``images`` BGR uint8 (H, W, 3) and ``masks`` (H, W) bool tape
    silhouettes (None when rendered without masks), one per camera in rig order."""

    images: list[np.ndarray]
    masks: list[np.ndarray | None]


class SceneFrameSource:
    """In-process :class:`spinemocap.capture.FrameSource`: renders frames on demand (images only;
    ``scene.render(i)`` also gives the tape masks)."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.camera_names = scene.rig.names
        self.n_frames = scene.n_frames

    def read(self, frame: int) -> list[np.ndarray]:
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        return self.scene.render(frame, with_masks=False).images


@functools.lru_cache(maxsize=4)
def cached_body(phenotype: tuple, joint_depth: JointDepth = "anny") -> Body:
    """One :class:`Body` per phenotype, joint depth and process (posing is cheap, building is not)."""
    return Body(dict(phenotype), joint_depth)


@functools.lru_cache(maxsize=4)
def cached_back_chart(phenotype: tuple, joint_depth: JointDepth = "anny") -> BackChart:
    """The taut strip's chart over a body's back, cached: it casts ~20k rays (seconds)."""
    return back_chart(cached_body(phenotype, joint_depth))


@functools.lru_cache(maxsize=8)
def cached_tape_on_skin(phenotype: tuple, rows: int | None, start_level: str,
                        tension: TapeTension | None = None, roll: str = "standard",
                        joint_depth: JointDepth = "anny") -> TapeOnSkin:
    """The tape of the :data:`~spinemocap.synth.appearance.TAPE_ROLLS` ``roll`` laid on a body
    (cached); ``rows`` None: enough rows to pass T12/L1 by :data:`ROWS_PAST_THORACOLUMBAR` rows."""
    body, chart = cached_body(phenotype, joint_depth), cached_back_chart(phenotype, joint_depth)
    tension = tension or TapeTension()
    layout = roll_layout(roll)
    if rows is None:
        probe = TapeSpec(n_rows=1, thickness_mm=SYNTH_TAPE_THICKNESS_MM, **layout)
        s0 = chart.arc_at_height(body.level_heights()[start_level])
        rows = rows_to_pass(chart, probe, s0, tension, body.junction_height("L1", "T12"), ROWS_PAST_THORACOLUMBAR)
    spec = TapeSpec(n_rows=rows, thickness_mm=SYNTH_TAPE_THICKNESS_MM, **layout)
    return TapeOnSkin(body, spec, start_level, tension, chart)


class Scene:
    """A built synthetic scene. See the module docstring; use :func:`build_scene`."""

    def __init__(self, config: SynthConfig):
        self.config = config
        self.rng_seed = int(config.seed)
        rng = np.random.default_rng([self.rng_seed, 1])
        phenotype = tuple(sorted(config.phenotype.items()))
        self.body = cached_body(phenotype, config.joint_depth)
        tension = TapeTension(config.tape_tension, self.rng_seed) if config.tape_tension else TapeTension()
        self.tape_on_skin = cached_tape_on_skin(phenotype, config.rows, config.tape_start, tension, config.tape_roll,
                                                config.joint_depth)
        self.tape = self.tape_on_skin.spec
        self.skin = SkinStrain.for_subject(self.rng_seed, config.realism_setting("skin_strain"))
        self.labels: list[str] = list(self.tape.labels)
        self.fps = float(config.fps)
        self.n_frames = int(config.frames)
        self.times = np.arange(self.n_frames) / self.fps
        self.commanded_deg = spine_motion(config.motion, self.times)
        # posed meshes are kept one chunk of frames at a time per camera clock (a long sequence
        # would need GBs); this first pass records the applied angles
        self._chunks: dict[float, tuple[int, np.ndarray]] = {}
        applied = []
        for start in range(0, self.n_frames, POSE_CHUNK):
            vertices, angles = self.body.pose(self.commanded_deg[start : start + POSE_CHUNK])
            applied.append(angles)
            self._chunks[0.0] = (start // POSE_CHUNK, vertices)
        self.angles_deg = np.concatenate(applied)
        rest_dots = self.tape_on_skin.pose(self.body.rest_vertices).dots()
        self.target = rest_dots.mean(axis=0)
        self.rig: Rig = arc_rig(LAYOUTS[config.layout], config.cameras, config.size, self.target,
                                config.distortion, rng)
        # the lab's errors draw from their own streams, so turning them on changes nothing else
        self.sync_offsets_s = clock_offsets_s(len(self.rig), config.realism_setting("sync_error_ms"),
                                              np.random.default_rng([self.rng_seed, 4]))
        if (config.calibration_error_px or 0.0) > 0:  # posing the calibration frames costs a pass over the motion
            self.calibrated_rig, self.calibration_rms_px = perturb_rig(
                self.rig, self._calibration_points(), config.realism_setting("calibration_error_px"),
                np.random.default_rng([self.rng_seed, 3]))
        else:
            self.calibrated_rig, self.calibration_rms_px = self.rig, np.zeros(len(self.rig))
        # the reference object stands still: placed after the rig, it draws from no random stream
        self.reference = studio_reference(self.target, self.rig) if config.reference else None
        self.reference_meshes: ReferenceMeshes | None = (reference_meshes(self.reference)
                                                         if self.reference is not None else None)
        self.balls = FallingBalls.generate(config.n_balls, config.duration_s, self.target, rng)
        self.band = self._clothing(rest_dots)
        tone = config.skin_tone if config.skin_tone is not None else rng.uniform(0.0, 0.8)
        skin = (1 - tone) * SKIN_LIGHT + tone * SKIN_DARK
        self.surfaces = SurfaceLook(config.tape_finish, config.skin_marks)
        specular, power = SWEAT_SPECULAR if self.surfaces.sweaty else DRY_SPECULAR
        self.appearance = Appearance(
            skin_rgb=(float(skin[0]), float(skin[1]), float(skin[2])),
            tape_rgb=TAPE_COLOURS[config.tape_colour],
            light_position=(float(rng.uniform(-1500, 1500)), float(rng.uniform(2000, 3500)), float(rng.uniform(2200, 3200))),
            light_intensity=float(rng.uniform(0.75, 1.0)),
            fill_intensity=float(rng.uniform(0.25, 0.45)),
            skin_specular=specular, skin_specular_power=power,
        )
        self.skin_tone = float(tone)
        self.camera_looks = camera_looks(config.camera_look, config.cameras, self.rng_seed, config.fps,
                                         config.rolling_shutter_ms, config.camera_codec)
        # (C,) each camera's rolling-shutter readout, s (0: a global shutter)
        self.readout_s = np.array([look.readout_ms * 1e-3 for look in self.camera_looks] if self.camera_looks
                                  else np.zeros(len(self.rig)))
        self._renderers: list[CameraRenderer] | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._still_windows: dict[tuple, list] = {}  # camera_image_at's last still scene's windows

    # ------------------------------------------------------------------ geometry per instant
    def _posed(self, frame: int | None = None, time_s: float | None = None,
               offset_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and vertex normals at a frame (seen by a clock ``offset_s`` ahead) or
        at any instant ``time_s``."""
        if time_s is None:
            v = self.frame_vertices(self._frame_given(frame), offset_s)
        else:
            v = self.body.pose(spine_motion(self.config.motion, [time_s]))[0][0].astype(float)
        return v, vertex_normals(v, self.body.faces)

    @staticmethod
    def _frame_given(frame: int | None) -> int:
        if frame is None:
            raise ValueError("give a frame or an instant (time_s)")
        return frame

    def _instant(self, frame: int | None, time_s: float | None, offset_s: float) -> float:
        """The instant (s) of ``frame`` on a clock ``offset_s`` ahead, or ``time_s`` when given."""
        return float(self.times[self._frame_given(frame)] + offset_s) if time_s is None else time_s

    def frame_vertices(self, frame: int, offset_s: float = 0.0) -> np.ndarray:
        """(V, 3) posed body vertices (mm) at a frame, as seen by a camera whose clock runs
        ``offset_s`` ahead of the nominal frame times."""
        key = float(offset_s)
        index = frame // POSE_CHUNK
        cached = self._chunks.get(key)
        if cached is None or cached[0] != index:
            start = index * POSE_CHUNK
            times = self.times[start : start + POSE_CHUNK] + key
            cached = (index, self.body.pose(spine_motion(self.config.motion, times))[0])
            self._chunks[key] = cached
        return cached[1][frame - index * POSE_CHUNK].astype(float)

    def _calibration_points(self, n_frames: int = 8) -> np.ndarray:
        """True dot positions (N, 3) mm over up to ``n_frames`` frames spread over the sequence:
        the points against which the calibration error is measured."""
        frames = np.unique(np.linspace(0, self.n_frames - 1, min(n_frames, self.n_frames)).round().astype(int))
        return np.concatenate([self.posed_tape(int(f)).dots() for f in frames])

    def posed_tape(self, frame: int | None = None, time_s: float | None = None, offset_s: float = 0.0,
                   posed: tuple[np.ndarray, np.ndarray] | None = None) -> PosedTape:
        """The tape on the body at a frame (on a clock ``offset_s`` ahead) or at any instant
        ``time_s``, with the subject's skin strain; ``posed`` reuses already posed (vertices,
        normals) of that instant."""
        t = self._instant(frame, time_s, offset_s)
        v, n = posed if posed is not None else self._posed(frame, time_s, offset_s)
        return self.tape_on_skin.pose(v, n, self.skin, spine_motion(self.config.motion, [t])[0])

    def frame_dots(self, frame: int) -> np.ndarray:
        """(D, 3) true dot centres (mm) at a frame's nominal time."""
        return self.posed_tape(frame).dots()

    def _band_vertices(self, vertices: np.ndarray, normals: np.ndarray) -> np.ndarray | None:
        return None if self.band is None else self.band.vertices(vertices, normals)

    def meshes(self, frame: int | None = None, time_s: float | None = None, offset_s: float = 0.0) -> SceneMeshes:
        """Posed geometry at a frame (seen by a clock ``offset_s`` ahead) or any instant ``time_s``."""
        t = self._instant(frame, time_s, offset_s)
        v, n = self._posed(frame, time_s, offset_s)
        centres, radii = self.balls.at(t)
        return SceneMeshes(
            body_vertices=v, body_normals=n,
            tape_vertices=self.posed_tape(frame, time_s, offset_s, posed=(v, n)).strip_vertices(),
            occluders=sphere_mesh(centres, radii) if len(centres) else None,
            band_vertices=self._band_vertices(v, n),
        )

    def _occluding_mesh(self, v: np.ndarray, n: np.ndarray, with_reference: bool = True) -> MeshRayCaster:
        """The posed body (with the band) and, unless told otherwise, the reference object."""
        parts = [(v, self.body.faces)]
        if self.band is not None:
            parts.append((self.band.vertices(v, n), self.band.faces))
        if with_reference and self._reference_solid is not None:
            parts.append(self._reference_solid)
        vertices, faces, offset = [], [], 0
        for pv_, pf in parts:
            vertices.append(pv_)
            faces.append(pf + offset)
            offset += len(pv_)
        return MeshRayCaster(np.concatenate(vertices), np.concatenate(faces))

    @cached_property
    def _reference_solid(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(vertices, faces) of the reference object's bars, pole and marker spheres (world mm)."""
        meshes = self.reference_meshes
        if meshes is None:
            return None
        spheres = sphere_mesh(meshes.marker_centres, np.full(len(meshes.marker_centres), meshes.marker_radius))
        sphere_faces = np.asarray(spheres.faces).reshape(-1, 4)[:, 1:]
        return (np.concatenate([meshes.frame_vertices, np.asarray(spheres.points)]),
                np.concatenate([meshes.frame_faces, sphere_faces + len(meshes.frame_vertices)]))

    def _reference_visibility(self, rig: Rig, v: np.ndarray, n: np.ndarray, centres: np.ndarray,
                              radii: np.ndarray) -> np.ndarray:
        """(C, N) bool: the reference markers each camera of ``rig`` sees (inside its image, not
        hidden by the body or a ball). A sphere faces every camera: its visible disc is the one
        normal to the ray, so each camera is tested with the normals pointing at it."""
        assert self.reference is not None
        world = self.reference.world_mm
        caster = self._occluding_mesh(v, n, with_reference=False)  # a marker's own sphere is not an occluder
        out = np.zeros((len(rig), len(world)), bool)
        for c, cam in enumerate(rig):
            toward = cam.center - world
            toward /= np.linalg.norm(toward, axis=1, keepdims=True)
            single = rig.subset([cam.name])
            # the segment starts on the sphere's near side (RAY_LIFT_MM beyond its centre is inside it)
            out[c] = dot_visibility(single, world, toward, cam.project(world)[None], caster, centres, radii,
                                    self.reference.marker_diameter_mm / 2)[0]
        return out

    def frame_groundtruth(self, frame: int) -> dict[str, np.ndarray]:
        """Ground truth of one frame (see :attr:`groundtruth` for the keys and units). Dots,
        normals and keypoints are at the nominal frame time; ``uv`` and ``visible`` are what each
        camera saw at its own clock's time."""
        v, n = self._posed(frame)
        tos = self.tape_on_skin
        tape = self.posed_tape(frame, posed=(v, n))
        dots, normals = tape.dots(), tape.dot_normals()
        uv = np.empty((len(self.rig), len(dots), 2))
        visible = np.empty((len(self.rig), len(dots)), dtype=bool)
        n_ref = self.reference.n_markers if self.reference is not None else 0
        reference_visible = np.zeros((len(self.rig), n_ref), dtype=bool)
        for offset in np.unique(self.sync_offsets_s):
            cams = np.flatnonzero(self.sync_offsets_s == offset)
            if offset == 0.0:
                v_c, n_c, dots_c, normals_c = v, n, dots, normals
            else:
                v_c, n_c = self._posed(frame, offset_s=float(offset))
                tape_c = self.posed_tape(frame, offset_s=float(offset), posed=(v_c, n_c))
                dots_c, normals_c = tape_c.dots(), tape_c.dot_normals()
            rig = self.rig.subset([self.rig.names[c] for c in cams])
            uv_c = rig.project(dots_c)
            centres, radii = self.balls.at(self.times[frame] + offset)
            uv[cams] = uv_c
            for c in cams:  # a rolling shutter sees each dot when its row is read
                uv[c] = self._rolling_shutter_uv(int(c), float(self.times[frame] + offset), uv[c])
            visible[cams] = dot_visibility(rig, dots_c, normals_c, uv_c, self._occluding_mesh(v_c, n_c), centres,
                                           radii, self.tape.dot_diameter_mm / 2)
            if n_ref:
                reference_visible[cams] = self._reference_visibility(rig, v_c, n_c, centres, radii)
        out = {
            "dots": dots, "dot_normals": normals, "uv": uv, "visible": visible,
            "keypoints": tos.keypoints.points(v, self.body.faces),
        }
        if n_ref:
            out["reference_visible"] = reference_visible
        return out

    def _rolling_shutter_uv(self, camera: int, time_s: float, uv: np.ndarray) -> np.ndarray:
        """(D, 2) where camera ``camera`` sees the dots in its frame at ``time_s`` (its middle
        row's instant): ``uv`` (D, 2), their projections at that instant, for a global shutter
        (or one too short for them to move); under a rolling shutter each where it was when its
        row was read, between the same instants the render blends."""
        shutter = self._shutter(camera, time_s, self.fps)
        if shutter.row_weights is None or self.camera_looks is None:
            return uv
        cam = self.rig[camera]
        at_instants = np.stack([cam.project(self.posed_tape(time_s=t).dots()) for t in shutter.instants])
        return rolling_shutter_uv(np.array(shutter.instants), at_instants,
                                  time_s + self.camera_looks[camera].row_times(cam.size[1]))

    @cached_property
    def groundtruth(self) -> dict[str, np.ndarray]:
        """Exact ground truth, same keys as ``groundtruth.npz``:

        ``labels`` (D,) str; ``dots`` (F, D, 3) mm; ``dot_normals`` (F, D, 3) outward unit normals;
        ``visible`` (F, C, D) bool; ``uv`` (F, C, D, 2) distorted pixels (under a rolling shutter where
        each dot was when its row was read; ``visible`` at the frame's instant); ``fps``; ``times`` (F,) s;
        ``angles_deg`` (F, 3) applied [flexion, lateral bending, axial rotation] (signs in
        :mod:`spinemocap.synth.motions`), ``angle_names``; ``keypoints`` (F, 8, 3) mm: back
        skin landmarks a keypoint tracker follows for the plane baselines, named by
        ``keypoint_names`` (hips, waist, shoulder-blade angles, shoulders; left then right; see
        :func:`spinemocap.synth.tape_on_skin.back_keypoints`); ``row_levels``
        (n_rows,) str vertebral level nearest each row (approximate, see
        :mod:`spinemocap.synth.body`); ``level_names`` (L,) str vertebral levels S2..C7 and their
        junctions (``"T12/L1"``, upper level first) with ``level_rows`` (L,) the fractional 1-based
        row where each lies on the rest tape (NaN off the tape); ``camera_names``.

        With a reference object (``config.reference``): ``reference_labels`` (N,),
        ``reference_world_mm`` (N, 3) its markers' true centres, ``reference_uv`` (C, N, 2) their
        distorted projections through the true rig, ``reference_visible`` (F, C, N) bool.

        The tape's true layout (the tracker is given only the roll's spec in ``capture.toml``):
        ``tape_tension`` the nominal taping tension; ``laid_stretch`` (n_rows - 1,) the laid arc
        length between consecutive rows on the rest skin divided by the spec's row pitch (the
        uneven tension profile); ``row_spacing_mm`` (F, n_rows - 1) the 3D distance between the
        centres (mean of the L and R dots) of consecutive rows in each frame, and
        ``row_stretch`` (F, n_rows - 1) that over the spec's pitch (tension times skin strain:
        the stretch a tracker must cope with); ``width_stretch`` (F, n_rows) the L-R distance of
        each row over the spec's.

        The true rig (``rig.toml`` holds the calibrated one, perturbed by
        ``calibration_error_px``): ``rig_K`` (C, 3, 3), ``rig_dist`` (C, 5), ``rig_R`` (C, 3, 3),
        ``rig_t`` (C, 3) mm; ``calibration_rms_px`` (C,) how far the written rig reprojects the
        true dots; ``sync_offset_s`` (C,) each camera's clock offset (its frame ``f`` shows the
        instant ``times[f] + sync_offset_s[c]``).
        """
        from tqdm import tqdm

        # a property takes no progress switch: the bar shows on a terminal only (tqdm's None), so
        # `--no-progress` runs writing to a log stay clean
        frames = [self.frame_groundtruth(f) for f in tqdm(range(self.n_frames), desc="ground truth", unit="frame",
                                                          disable=True if self.n_frames < 50 else None, leave=False)]
        gt = {key: np.stack([fr[key] for fr in frames]) for key in frames[0]}
        gt.update(
            labels=np.array(self.labels),
            fps=np.array(self.fps),
            times=self.times.copy(),
            angles_deg=self.angles_deg.copy(),
            angle_names=np.array(ANGLE_NAMES),
            keypoint_names=np.array(self.tape_on_skin.keypoint_names),
            row_levels=np.array(self.tape_on_skin.row_levels),
            level_names=np.array(list(self.tape_on_skin.level_rows())),
            level_rows=np.array(list(self.tape_on_skin.level_rows().values())),
            camera_names=np.array(self.rig.names),
        )
        gt.update(self.layout_truth(gt["dots"]))
        gt.update(
            rig_K=np.stack([c.K for c in self.rig]), rig_dist=np.stack([c.dist for c in self.rig]),
            rig_R=np.stack([c.R for c in self.rig]), rig_t=np.stack([c.t for c in self.rig]),
            calibration_rms_px=self.calibration_rms_px.copy(), sync_offset_s=self.sync_offsets_s.copy(),
        )
        if self.reference is not None:
            world = self.reference.world_mm
            gt.update(reference_labels=np.array(self.reference.labels), reference_world_mm=world,
                      reference_uv=self.rig.project(world))
        return gt

    def layout_truth(self, dots: np.ndarray) -> dict[str, np.ndarray]:
        """The tape's true layout (see :attr:`groundtruth`) from (F, D, 3) dot positions (mm)."""
        spec, graph = self.tape, self.tape.graph
        labels = self.labels
        left = [labels.index(f"R{r + 1:02d}L") for r in range(spec.n_rows)]
        right = [labels.index(f"R{r + 1:02d}R") for r in range(spec.n_rows)]
        centres = 0.5 * (dots[:, left] + dots[:, right])
        spacing = np.linalg.norm(np.diff(centres, axis=1), axis=2)
        nominal_width = np.abs(graph.uv_mm[right, 0] - graph.uv_mm[left, 0])
        width = np.linalg.norm(dots[:, right] - dots[:, left], axis=2)
        return {
            "tape_tension": np.array(self.config.tape_tension),
            "laid_stretch": self.tape_on_skin.tension.row_spacing_mm(spec) / spec.row_pitch_mm,
            "row_spacing_mm": spacing,
            "row_stretch": spacing / spec.row_pitch_mm,
            "width_stretch": width / nominal_width,
        }

    # ------------------------------------------------------------------ rendering
    @property
    def renderers(self) -> list[CameraRenderer]:
        if self._renderers is None:
            strip = self.tape_on_skin.strip
            skin, tape = self._textures()
            self._renderers = [
                CameraRenderer(cam, self.body.faces, strip.faces_holes, strip.faces_solid, self.appearance,
                               band_faces=None if self.band is None else self.band.faces, supersample=self.config.supersample,
                               reference=self.reference_meshes, band_colours=None if self.band is None else self.band.colours,
                               skin_texture=skin, tape_texture=tape)
                for cam in self.rig
            ]
        return self._renderers

    def _textures(self) -> tuple[MeshTexture | None, MeshTexture | None]:
        """The skin's and the tape's textures (:mod:`spinemocap.synth.surfaces`) in the appearance's
        colours as they are now (None: a uniform colour)."""
        heights = self.body.level_heights()
        skin = skin_texture(self.surfaces.painted_marks, self.appearance.skin_rgb, skin_extent(heights["S1"], heights["C7"]),
                            float(self.target[0]), self.rng_seed)
        strip = self.tape_on_skin.strip
        tape = tape_texture(self.surfaces.finish, self.appearance.tape_rgb, self.tape.width_mm,
                            (float(strip.uv[:, 1].min()), float(strip.uv[:, 1].max())), self.rng_seed)
        return (None if skin is None else MeshTexture(skin.image, skin.coordinates(self.body.rest_vertices[:, [0, 2]])),
                None if tape is None else MeshTexture(tape.image, tape.coordinates(strip.uv)))

    def _clothing(self, rest_dots: np.ndarray) -> Clothing | None:
        """The sports-bra band (``config.band``) and the garments of ``config.clothing`` (seeded
        colours and places) as one mesh; None when there is neither."""
        garments: list[tuple[Garment, tuple[float, float, float] | None]] = []
        if self.config.band:
            garments.append((SportsBraBand(self.body, self.body.level_heights()[self.config.band_level]), None))
        if self.config.clothing:
            garments += wear_clothing(self.body, self.config.clothing, float(rest_dots[:, 2].min()),
                                      np.random.default_rng([self.rng_seed, 13]))
        return Clothing(garments) if garments else None

    def render(self, frame: int, with_masks: bool = True, reference: bool = False) -> RenderedFrame:
        """Render one frame in every camera (each at its own clock's time): BGR images (with blur
        and noise) and tape masks.

        VTK renders the cameras one after the other in this thread, each only over the canvas
        rectangle the scene covers in it; each camera's lens resampling, sensor noise and mask
        resampling run on a worker thread meanwhile (numpy and OpenCV release the GIL), so they
        overlap the next camera's rendering. ``reference`` renders the reference way (whole
        canvas, one thread, the reference implementations): the peer of ``spinemocap bench
        render`` and the tests' reference (same ground truth; images equal up to rounding on a
        few anti-aliased edges, see :meth:`CameraRenderer.render_window`)."""
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        if reference:
            return self._render_reference(frame, with_masks)
        pool = self._develop_pool()
        developing = []
        shared: dict[tuple[float, ...], list[SceneMeshes]] = {}
        for c, renderer in enumerate(self.renderers):
            offset = float(self.sync_offsets_s[c])
            shutter = self._shutter(c, float(self.times[frame]) + offset, self.fps)
            meshes = self._instant_meshes(frame, offset, shutter.instants, shared)
            windows, mask_windows = [], []
            for k, instant in enumerate(meshes):
                windows.append(renderer.render_window(instant))
                if with_masks and (k == 0 or shutter.row_weights is not None):  # the geometry just loaded
                    mask_windows.append(renderer.render_mask_window(instant))
            developing.append(pool.submit(self._develop, frame, c, windows, mask_windows, with_masks, shutter.row_weights))
        developed = [job.result() for job in developing]
        return RenderedFrame([image for image, _ in developed], [mask for _, mask in developed])

    def _instant_meshes(self, frame: int, offset_s: float, instants: tuple[float, ...],
                        shared: dict[tuple[float, ...], list[SceneMeshes]]) -> list[SceneMeshes]:
        """The geometry of ``instants`` (s; the frame's instant on a clock ``offset_s`` ahead is
        posed from the frame's cached chunk); ``shared`` holds each set of instants' geometry, so
        cameras on the same clock pose once."""
        if instants not in shared:
            frame_instant = float(self.times[frame]) + offset_s
            shared[instants] = [self.meshes(frame, offset_s=offset_s) if t == frame_instant else self.meshes(time_s=t)
                                for t in instants]
        return shared[instants]

    def _develop(self, frame: int, camera: int, windows: list[tuple[np.ndarray, int, int]],
                 mask_windows: list[tuple[np.ndarray, int, int] | None], with_mask: bool,
                 row_weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Rendered windows of one camera (:meth:`CameraRenderer.render_window`, the frame instant
        then the exposure's) -> BGR image (lens, exposure average or rolling shutter, sensor) and
        tape mask (from ``mask_windows``: one, or one per instant under a rolling shutter with
        ``row_weights`` (H, instants)). No VTK: safe on a worker thread."""
        renderer = self.renderers[camera]
        images = [renderer.image_through_lens(window) for window in windows]
        masks = [renderer.mask_through_lens(window) for window in mask_windows] if with_mask else []
        rgb, mask = exposed(images, masks, row_weights)
        return self._look(self._sensor(self._backdrop(rgb, camera), frame, camera), frame, camera), mask

    def _look(self, image_bgr: np.ndarray, frame: int, camera: int) -> np.ndarray:
        """``image_bgr`` through the camera's :class:`CameraLook` (``ideal``: as it is)."""
        if self.camera_looks is None:
            return image_bgr
        phase = float(np.random.default_rng([self.rng_seed, 12, camera]).uniform(0, 2 * np.pi))
        return self.camera_looks[camera].apply(image_bgr, frame / self.fps, phase)

    def _backdrop(self, rgb: np.ndarray, camera: int) -> np.ndarray:
        """``rgb`` with the configured backdrop where it shows the empty background (``plain``: as it is)."""
        if self.config.backdrop == "plain":
            return rgb
        renderer = self.renderers[camera]
        room = room_view(renderer.camera.size, self.rng_seed, camera, self.config.bystanders)
        return behind_subject(rgb, renderer.background_pixel(), room)

    def _develop_pool(self) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=DEVELOP_WORKERS, thread_name_prefix="synth-develop")
        return self._pool

    def _render_reference(self, frame: int, with_masks: bool) -> RenderedFrame:
        """:meth:`render` in its reference form: one thread, reference lens, mask and sensor."""
        images, masks = [], []
        shared: dict[tuple[float, ...], list[SceneMeshes]] = {}
        for c, renderer in enumerate(self.renderers):
            offset = float(self.sync_offsets_s[c])
            shutter = self._shutter(c, float(self.times[frame]) + offset, self.fps)
            meshes = self._instant_meshes(frame, offset, shutter.instants, shared)
            rendered = [renderer.render_reference(m, with_mask=with_masks and (k == 0 or shutter.row_weights is not None))
                        for k, m in enumerate(meshes)]
            rgb, mask = exposed([image for image, _ in rendered], [m for _, m in rendered if m is not None],
                                shutter.row_weights)
            images.append(self._look(self._sensor_reference(self._backdrop(rgb, c), frame, c), frame, c))
            masks.append(mask)
        return RenderedFrame(images, masks)

    def _shutter(self, camera: int, time_s: float, fps: float) -> Shutter:
        """When camera ``camera`` exposes its frame at ``time_s`` s (``fps``: its frame rate, for
        the motion blur's exposure): the frame instant and the blur's sub-frame instants; under a
        rolling shutter whose readout moves the dots by 0.3 px or more, instants spread over the
        readout (and the exposure) with each row's weights on them."""
        exposure = self.config.blur / fps
        blur = [time_s]
        if exposure > 0:
            half = 0.5 * exposure
            blur += [float(x) for x in np.linspace(time_s - half, time_s + half, 7) if abs(x - time_s) > 1e-12]
        readout = float(self.readout_s[camera])
        if readout <= 0 or self.camera_looks is None:
            return Shutter(tuple(blur))
        cam = self.rig[camera]
        span = (time_s - 0.5 * (readout + exposure), time_s + 0.5 * (readout + exposure))
        ends = [cam.project(self.posed_tape(time_s=t).dots()) for t in span]
        motion_px = float(np.nanmax(np.linalg.norm(ends[1] - ends[0], axis=1)))
        if not motion_px >= 0.3:
            return Shutter(tuple(blur))
        # at most about a pixel of motion between instants (16 at most), 7 across a blurred exposure
        n = int(np.clip(np.ceil(motion_px) + 1, 2, 16))
        if exposure > 0:
            n = int(np.clip(max(n, np.ceil(7 * (readout + exposure) / exposure)), 2, 16))
        instants = np.linspace(span[0], span[1], n)
        rows = time_s + self.camera_looks[camera].row_times(cam.size[1])
        return Shutter(tuple(float(t) for t in instants), row_weights(instants, rows, exposure))

    def _sensor(self, rgb: np.ndarray, frame: int, camera: int) -> np.ndarray:
        """Sensor noise (seeded per frame and camera) and conversion to BGR uint8; ``rgb`` (H, W, 3)
        in grey levels, uint8 or float32. Same pixels as :meth:`_sensor_reference`: the same
        normal draws (``normal(0, s)`` is ``s * standard_normal()``, drawn by the same generator),
        added in float32 in place."""
        noise = float(self.config.noise or 0.0)
        if noise > 0:
            draws = np.random.default_rng([self.rng_seed, 2, frame, camera]).standard_normal(rgb.shape)
            draws *= noise
            image = draws.astype(np.float32)
            del draws
            image += rgb
        else:
            image = rgb.astype(np.float32)
        image += np.float32(0.5)
        np.clip(image, 0, 255, out=image)
        return cv2.cvtColor(image.astype(np.uint8), cv2.COLOR_RGB2BGR)

    def _sensor_reference(self, rgb: np.ndarray, frame: int, camera: int) -> np.ndarray:
        """:meth:`_sensor` in its reference form: the peer of ``spinemocap bench render``."""
        image = rgb.astype(np.float32)
        noise = float(self.config.noise or 0.0)
        if noise > 0:
            rng = np.random.default_rng([self.rng_seed, 2, frame, camera])
            image += rng.normal(0.0, noise, image.shape).astype(np.float32)
        return cv2.cvtColor(np.clip(image + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)

    # ------------------------------------------------------------------ cameras on their own clocks
    def camera_image_at(self, camera: int, time_s: float, slot: int, camera_fps: float) -> np.ndarray:
        """The BGR uint8 image camera ``camera`` (rig order) takes at capture time ``time_s`` s as
        its own frame ``slot`` (which seeds the sensor noise), at ``camera_fps`` frames/s (the
        motion blur's exposure)."""
        shutter = self._shutter(camera, time_s, camera_fps)
        instants = shutter.instants
        renderer = self.renderers[camera]
        # a still scene (the same pose, no ball in the air: a recording's lead-in before the motion
        # starts) renders the same windows; only the sensor noise differs from frame to frame
        key = (camera, tuple(float(a) for a in np.round(spine_motion(self.config.motion, [time_s])[0], 12)))
        still = len(instants) == 1 and not len(self.balls.at(time_s)[1])
        windows = self._still_windows.get(key) if still else None
        if windows is None:
            windows = [renderer.render_window(self.meshes(time_s=t)) for t in instants]
            if still:
                self._still_windows = {key: windows}
        image, _ = self._develop(slot, camera, windows, [], False, shutter.row_weights)
        return image

    def frame_source(self) -> SceneFrameSource:
        """A :class:`spinemocap.capture.FrameSource` that renders frames on demand."""
        return SceneFrameSource(self)

    def subject(self) -> dict:
        """The ``[subject]`` table of capture.toml."""
        return {
            "id": f"anny-seed{self.rng_seed}",
            "up": [0.0, 0.0, 1.0],
            "facing": [0.0, -1.0, 0.0],
            "phenotype": {k: float(v) for k, v in self.body.phenotype.items()},
            "skin_tone": self.skin_tone,
            "tape_start": self.config.tape_start,
        }

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        for r in self._renderers or []:
            r.close()
        self._renderers = None


def build_scene(config: SynthConfig) -> Scene:
    """Assemble a scene; raises ``ValueError`` when no camera sees the tape in the first frame."""
    scene = Scene(config)
    first = scene.frame_groundtruth(0)
    if not first["visible"].any():
        raise ValueError(
            f"no camera sees the tape in the first frame ({config.cameras} cameras, layout "
            f"{config.layout!r}, size {config.size}); use more cameras or another layout"
        )
    return scene
