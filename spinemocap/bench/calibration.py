"""``spinemocap bench calibration``: accuracy and time of the calibration pipeline on exact
synthetic renders of a 6-camera ring, with peers in the same run:

* board stage (ChArUco, the reference) — peer: OpenCV ``calibrateCamera`` per camera + PnP
  spanning tree (no bundle adjustment); ours: the same followed by the robust bundle
  adjustment, once with Ceres (pycolmap) and once with scipy (BA seconds and accuracy of both);
* checkerboard stage — the same pipeline with a checkerboard (corner order resolved across
  cameras, every other board frame held upside down), compared with ChArUco's errors;
* wand-wave stage — all extrinsics from a wand wave alone (no board), compared with ChArUco;
  wand-length error over the volume;
* Vicon wand stage — peer: the clock offset from speed cross-correlation alone (1 ms grid);
  ours: the joint offset + similarity refinement.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from datetime import date
from typing import Any, Hashable, Iterable

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.boards import BoardDetection, BoardSpec, detect_board
from calibration.extrinsics import calibrate_extrinsics, floor_world_transform, initial_poses
from calibration.intrinsics import calibrate_from_detections
from calibration.wand import WandSpec, coarse_offset, detect_wand_views, register_wand, triangulate_wand
from calibration.wandwave import calibrate_wand_wave
from spinemocap.camera import Camera, Rig
from spinemocap.fileio import atomic_write
from spinemocap.rig_adjust import Backend

from ..app.c3d_inputs import read_vicon_wand, write_vicon_wand_c3d
from .calibration_scenes import make_ring_rig, render_calibration_session, render_wand_calibration, render_wand_wave
from .records import JsonRecord

BOARD = "charuco:6x5:120"


@dataclass(frozen=True)
class RigErrors(JsonRecord):
    """A calibrated rig against the truth, worst camera of each: focal length (%), camera centre
    (mm) and orientation (deg)."""

    focal_pct: float
    centre_mm: float
    rotation_deg: float



@dataclass(frozen=True)
class AdjustedRig:
    """The board session's extrinsics after one bundle-adjustment backend: the rig's errors, wall
    and CPU seconds of the calibration, the worst camera's reprojection RMS (px), the board's
    RMS (mm) and the views the adjustment left out."""

    errors: RigErrors
    seconds: float
    cpu_seconds: float
    rms_px: float
    board_rms_mm: float
    views_left_out: int

    def to_dict(self) -> dict[str, Any]:
        """The rig's errors, then the other fields, in one object."""
        return {**self.errors.to_dict(), "seconds": self.seconds, "cpu_seconds": self.cpu_seconds,
                "rms_px": self.rms_px, "board_rms_mm": self.board_rms_mm, "views_left_out": self.views_left_out}


@dataclass(frozen=True)
class BoardRow:
    """One board session (:func:`board_stage`): the board, seed, image size (px), intrinsic views
    per camera and synchronized frames; the peer's errors without bundle adjustment, seconds of
    rendering and of detection plus intrinsics, and the rig per adjustment backend (in the order
    run; the first is ``ours_ba``)."""

    board: str
    seed: int
    size: list[int]
    intrinsic_views: int
    frames: int
    peer_no_ba: RigErrors
    seconds: dict[str, float]
    adjusted: dict[Backend, AdjustedRig]

    @property
    def ours_ba(self) -> AdjustedRig:
        """The rig of the first backend run (Ceres by default)."""
        return next(iter(self.adjusted.values()))

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the fields, ``ba_<backend>`` per backend, then ``ours_ba``."""
        return {"board": self.board, "seed": self.seed, "size": self.size, "intrinsic_views": self.intrinsic_views,
                "frames": self.frames, "peer_no_ba": self.peer_no_ba.to_dict(), "seconds": self.seconds,
                **{f"ba_{backend}": rig.to_dict() for backend, rig in self.adjusted.items()},
                "ours_ba": self.ours_ba.to_dict()}


@dataclass(frozen=True)
class WandWaveRow:
    """All extrinsics from a wand wave (:func:`wandwave_stage`): the wand, seed, frames, where the
    intrinsics came from, the rig's errors, the wand length's RMS and largest error (mm), the
    worst camera's reprojection RMS (px), the same rig's errors and length RMS with the true
    lenses, and seconds of rendering, detection and calibration."""

    wand: str
    seed: int
    frames: int
    intrinsics: str
    errors: RigErrors
    length_rms_mm: float
    length_max_mm: float
    rms_px: float
    true_intrinsics: RigErrors
    true_intrinsics_length_rms_mm: float
    seconds: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: the rig's errors flattened in, ``true_intrinsics`` with its length RMS."""
        return {"wand": self.wand, "seed": self.seed, "frames": self.frames, "intrinsics": self.intrinsics,
                **self.errors.to_dict(), "length_rms_mm": self.length_rms_mm, "length_max_mm": self.length_max_mm,
                "rms_px": self.rms_px,
                "true_intrinsics": {**self.true_intrinsics.to_dict(), "length_rms_mm": self.true_intrinsics_length_rms_mm},
                "seconds": self.seconds}


@dataclass(frozen=True)
class ViconWandRow(JsonRecord):
    """The Vicon wand co-registration (:func:`wand_stage`): seed, frames and frames with the whole
    wand identified; the clock offset's error (ms) of the correlation-only peer and of ours; the
    registration's rotation (deg), translation (mm) and scale; the worst marker RMS (mm); seconds
    of detection plus triangulation and of registration."""

    seed: int
    frames: int
    identified: int
    peer_offset_err_ms: float
    ours_offset_err_ms: float
    rotation_err_deg: float
    translation_err_mm: float
    scale: float
    max_marker_rms_mm: float
    seconds: dict[str, float]



def rig_errors(truth: Rig, estimate: Rig) -> RigErrors:
    """Worst-camera errors: focal (%), centre (mm), rotation (deg)."""
    focal = max(abs(e.K[0, 0] / t.K[0, 0] - 1) * 100 for t, e in zip(truth, estimate))
    centre = max(float(np.linalg.norm(e.center - t.center)) for t, e in zip(truth, estimate))
    rot = max(float(np.degrees(Rotation.from_matrix(e.R @ t.R.T).magnitude())) for t, e in zip(truth, estimate))
    return RigErrors(focal_pct=focal, centre_mm=centre, rotation_deg=rot)


def board_stage(size: int, n_intrinsic: int, n_frames: int, seed: int, board_text: str = BOARD,
                backends: tuple[Backend, ...] = ("ceres", "scipy")) -> BoardRow:
    """One board session: intrinsics per camera, then extrinsics with each BA backend."""
    return board_session(size, n_intrinsic, n_frames, seed, board_text, backends)[0]


def board_session(size: int, n_intrinsic: int, n_frames: int, seed: int, board_text: str = BOARD,
                  backends: tuple[Backend, ...] = ("ceres", "scipy")) -> tuple[BoardRow, Rig]:
    """:func:`board_stage`'s row and the intrinsics it calibrated (poses not set)."""
    board = BoardSpec.parse(board_text)
    truth = make_ring_rig(6, size=(size, size * 3 // 4), seed=seed)
    t0 = time.perf_counter()
    session = render_calibration_session(truth, board, n_intrinsic, n_frames, n_floor=3, seed=seed,
                                         half_turns=board.kind == "checkerboard")
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    detections: dict[str, dict[Hashable, BoardDetection]] = {}
    intrinsics: list[Camera] = []
    for cam in truth:
        views: dict[Hashable, BoardDetection] = {(cam.name, i): d for i, im in enumerate(session.intrinsic[cam.name]) if (d := detect_board(im, board))}
        intrinsics.append(calibrate_from_detections(views, [], cam.size, board, cam.name).camera)
        views.update({f: d for f, im in enumerate(session.capture.images[cam.name]) if (d := detect_board(im, board))})
        detections[cam.name] = views
    t_intr = time.perf_counter() - t0
    intr_rig = Rig(intrinsics)
    poses, boards = initial_poses(intr_rig, board, detections)
    peer = Rig([Camera(c.name, c.K, c.dist, R, t, c.size) for c, (R, t) in zip(intrinsics, poses)])
    R, t = floor_world_transform(board, boards, session.floor_frames)
    peer = peer.transformed(R, t)
    adjusted: dict[Backend, AdjustedRig] = {}
    for backend in backends:
        t0, c0 = time.perf_counter(), time.process_time()
        result = calibrate_extrinsics(intr_rig, board, detections, floor_frame=session.floor_frames, progress=False,
                                      backend=backend)
        adjusted[backend] = AdjustedRig(rig_errors(truth, result.rig), seconds=time.perf_counter() - t0,
                                        cpu_seconds=time.process_time() - c0, rms_px=max(result.rms_px.values()),
                                        board_rms_mm=result.board_rms_mm, views_left_out=len(result.rejected))
    row = BoardRow(board=str(board), seed=seed, size=list(truth[0].size), intrinsic_views=n_intrinsic,
                   frames=n_frames, peer_no_ba=rig_errors(truth, peer),
                   seconds={"render": t_render, "detect_intrinsics": t_intr}, adjusted=adjusted)
    return row, intr_rig


def wandwave_stage(size: int, seed: int, wand_text: str, seconds: float, intrinsics: Rig) -> WandWaveRow:
    """All extrinsics from a wand wave alone (Ceres bundle adjustment) with ``intrinsics`` (from
    the ChArUco session of the same rig), and the same with the true lenses (the ideal case)."""
    wand = WandSpec.parse(wand_text)
    truth = make_ring_rig(6, size=(size, size * 3 // 4), seed=seed)
    t0 = time.perf_counter()
    wave = render_wand_calibration(truth, wand, duration_s=seconds, seed=seed + 5)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    frames = ([wave.images[c.name][f] for c in truth] for f in range(len(wave.world_mm)))
    views = detect_wand_views(frames, wand, progress=False)
    t_detect = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = calibrate_wand_wave(intrinsics, views, wand, wave.floor_frames, progress=False)
    t_cal = time.perf_counter() - t0
    lenses = Rig([Camera(c.name, c.K, c.dist, np.eye(3), np.zeros(3), c.size) for c in truth])
    ideal = calibrate_wand_wave(lenses, views, wand, wave.floor_frames, progress=False)
    return WandWaveRow(wand=wand_text, seed=seed, frames=len(views), intrinsics="ChArUco session's",
                       errors=rig_errors(truth, result.rig), length_rms_mm=result.length_rms_mm,
                       length_max_mm=float(np.abs(result.length_error_mm).max()), rms_px=max(result.rms_px.values()),
                       true_intrinsics=rig_errors(truth, ideal.rig), true_intrinsics_length_rms_mm=ideal.length_rms_mm,
                       seconds={"render": t_render, "detect": t_detect, "calibrate": t_cal})


def wand_stage(seed: int, tmp_c3d: str) -> ViconWandRow:
    """The Vicon wand stage on a rendered wave of ``seed`` (its C3D written to ``tmp_c3d``)."""
    wave = render_wand_wave(make_ring_rig(6, size=(800, 600), seed=seed), duration_s=4.0, seed=seed + 3,
                            offset_s=0.0137 + 0.01 * seed)
    write_vicon_wand_c3d(tmp_c3d, wave.vicon_mm, wave.vicon_rate, wave.wand)
    t0 = time.perf_counter()
    frames = ([wave.images[c.name][f] for c in wave.rig] for f in range(len(wave.world_mm)))
    points = triangulate_wand(wave.rig, frames, wave.wand, progress=False)
    t_tri = time.perf_counter() - t0
    vicon = read_vicon_wand(tmp_c3d, wave.wand)
    t0 = time.perf_counter()
    coarse, _ = coarse_offset(points, wave.fps, vicon.points_mm, vicon.rate)
    reg = register_wand(points, wave.fps, vicon, wave.wand)
    t_reg = time.perf_counter() - t0
    return ViconWandRow(
        seed=seed, frames=len(points), identified=int(np.all(np.isfinite(points), axis=(1, 2)).sum()),
        peer_offset_err_ms=abs(coarse - wave.offset_s) * 1000, ours_offset_err_ms=abs(reg.offset_s - wave.offset_s) * 1000,
        rotation_err_deg=float(np.degrees(Rotation.from_matrix(reg.R @ wave.R.T).magnitude())),
        translation_err_mm=float(np.linalg.norm(reg.t - wave.t)), scale=reg.scale,
        max_marker_rms_mm=max(reg.residual_mm.values()),
        seconds={"detect_triangulate": t_tri, "register": t_reg},
    )


@dataclass(frozen=True)
class CalibrationHeadline(JsonRecord):
    """The worst case over seeds (:func:`headline`): ChArUco (Ceres), checkerboard and wand-wave
    centre (mm) and rotation (deg) errors, the wand length's RMS (mm), the bundle adjustment's
    seconds and errors per backend, Ceres's speed-up over scipy, and the goals met."""

    charuco_centre_error_mm: float
    charuco_rotation_error_deg: float
    checkerboard_centre_error_mm: float
    checkerboard_rotation_error_deg: float
    wandwave_centre_error_mm: float
    wandwave_rotation_error_deg: float
    wandwave_length_error_mm: float
    ba_seconds_ceres: float
    ba_seconds_scipy: float
    ba_centre_error_mm_ceres: float
    ba_centre_error_mm_scipy: float
    ba_rotation_error_deg_ceres: float
    ba_rotation_error_deg_scipy: float
    ba_speedup_ceres_vs_scipy: float
    goals: dict[str, bool]



@dataclass(frozen=True)
class CalibrationBenchResult:
    """``bench calibration``'s numbers (:func:`run_benchmark`): the machine, the boards and the
    wand, every seed's rows per stage and the headline (its keys at the top level of the JSON)."""

    machine: str
    board: str
    checkerboard: str
    wand_wave: str
    boards: list[BoardRow]
    checkerboards: list[BoardRow]
    wandwaves: list[WandWaveRow]
    wand: list[ViconWandRow]
    headline: CalibrationHeadline

    def to_dict(self) -> dict[str, Any]:
        return {"machine": self.machine, "board": self.board, "checkerboard": self.checkerboard,
                "wand_wave": self.wand_wave, "boards": [r.to_dict() for r in self.boards],
                "checkerboards": [r.to_dict() for r in self.checkerboards],
                "wandwaves": [r.to_dict() for r in self.wandwaves], "wand": [r.to_dict() for r in self.wand],
                **self.headline.to_dict()}


def run_benchmark(size: int, n_intrinsic: int, n_frames: int, seeds: list[int], out: str,
                  checkerboard: str = "checkerboard:4x7:120", wand: str = "t",
                  wand_seconds: float = 4.0) -> CalibrationBenchResult:
    """Every stage for each of ``seeds`` (images ``size`` px wide, ``n_intrinsic`` intrinsic views
    per camera, ``n_frames`` synchronized board frames), printed as it goes; the numbers are
    written to ``out`` (JSON) and returned."""
    import tempfile

    boards: list[BoardRow] = []
    checks: list[BoardRow] = []
    waves: list[WandWaveRow] = []
    vicon: list[ViconWandRow] = []
    for seed in seeds:
        b, intrinsics = board_session(size, n_intrinsic, n_frames, seed)
        boards.append(b)
        print(f"seed {seed} ChArUco {b.size[0]}x{b.size[1]}: no-BA peer centre {b.peer_no_ba.centre_mm:.2f} mm "
              f"rot {b.peer_no_ba.rotation_deg:.3f} deg | " + " | ".join(
                  f"BA {k}: centre {b.adjusted[k].errors.centre_mm:.2f} mm rot {b.adjusted[k].errors.rotation_deg:.3f} deg "
                  f"focal {b.adjusted[k].errors.focal_pct:.3f} % in {b.adjusted[k].seconds:.1f} s"
                  for k in ("ceres", "scipy")))
        c = board_stage(size, n_intrinsic, n_frames, seed, checkerboard, backends=("ceres",))
        checks.append(c)
        print(f"seed {seed} {checkerboard}: centre {c.ours_ba.errors.centre_mm:.2f} mm rot "
              f"{c.ours_ba.errors.rotation_deg:.3f} deg focal {c.ours_ba.errors.focal_pct:.3f} % "
              f"({c.ours_ba.views_left_out} views left out)")
        w = wandwave_stage(size, seed, wand, wand_seconds, intrinsics)
        waves.append(w)
        print(f"seed {seed} wand wave ({wand}, ChArUco intrinsics): centre {w.errors.centre_mm:.2f} mm rot "
              f"{w.errors.rotation_deg:.4f} deg, wand length error RMS {w.length_rms_mm:.3f} mm (max "
              f"{w.length_max_mm:.2f}); calibration {w.seconds['calibrate']:.1f} s | true lenses: centre "
              f"{w.true_intrinsics.centre_mm:.2f} mm rot {w.true_intrinsics.rotation_deg:.4f} deg")
        with tempfile.TemporaryDirectory() as tmp:
            v = wand_stage(seed, f"{tmp}/wand.c3d")
        vicon.append(v)
        print(f"seed {seed} Vicon wand: offset error correlation-only {v.peer_offset_err_ms:.3f} ms, refined "
              f"{v.ours_offset_err_ms:.4f} ms; rotation {v.rotation_err_deg:.4f} deg, translation "
              f"{v.translation_err_mm:.3f} mm, scale {v.scale:.5f}; {v.identified}/{v.frames} frames")
    results = CalibrationBenchResult(
        machine=f"{platform.processor() or platform.machine()}, {date.today()}", board=BOARD,
        checkerboard=checkerboard, wand_wave=wand, boards=boards, checkerboards=checks, wandwaves=waves, wand=vicon,
        headline=headline(boards, checks, waves))
    for key, value in results.headline.to_dict().items():
        if isinstance(value, (float, int)) and not isinstance(value, bool):
            print(f"{key}: {value:.4g}")
    with atomic_write(out) as handle:
        json.dump(results.to_dict(), handle, indent=2)
    print(f"wrote {out}")
    return results


def headline(boards: list[BoardRow], checks: list[BoardRow], waves: list[WandWaveRow]) -> CalibrationHeadline:
    """Worst case over seeds of every row and the goals."""
    def worst(values: Iterable[float]) -> float:
        return max(float(v) for v in values)

    charuco_centre = worst(b.adjusted["ceres"].errors.centre_mm for b in boards)
    charuco_rotation = worst(b.adjusted["ceres"].errors.rotation_deg for b in boards)
    check_centre = worst(c.ours_ba.errors.centre_mm for c in checks)
    check_rotation = worst(c.ours_ba.errors.rotation_deg for c in checks)
    wave_centre = worst(w.errors.centre_mm for w in waves)
    wave_rotation = worst(w.errors.rotation_deg for w in waves)
    wave_length = worst(w.length_rms_mm for w in waves)
    ceres_s = worst(b.adjusted["ceres"].seconds for b in boards)
    scipy_s = worst(b.adjusted["scipy"].seconds for b in boards)
    return CalibrationHeadline(
        charuco_centre_error_mm=charuco_centre, charuco_rotation_error_deg=charuco_rotation,
        checkerboard_centre_error_mm=check_centre, checkerboard_rotation_error_deg=check_rotation,
        wandwave_centre_error_mm=wave_centre, wandwave_rotation_error_deg=wave_rotation,
        wandwave_length_error_mm=wave_length, ba_seconds_ceres=ceres_s, ba_seconds_scipy=scipy_s,
        ba_centre_error_mm_ceres=charuco_centre,
        ba_centre_error_mm_scipy=worst(b.adjusted["scipy"].errors.centre_mm for b in boards),
        ba_rotation_error_deg_ceres=charuco_rotation,
        ba_rotation_error_deg_scipy=worst(b.adjusted["scipy"].errors.rotation_deg for b in boards),
        ba_speedup_ceres_vs_scipy=scipy_s / ceres_s,
        goals={"checkerboard_within_1.5x_charuco": bool(check_centre <= 1.5 * charuco_centre
                                                        and check_rotation <= 1.5 * charuco_rotation),
               "wandwave_within_1.5x_charuco": bool(wave_centre <= 1.5 * charuco_centre
                                                    and wave_rotation <= 1.5 * charuco_rotation),
               "wand_length_rms_le_0.5mm": bool(wave_length <= 0.5),
               "ba_le_3s": bool(ceres_s <= 3.0)})
