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
from datetime import date
from typing import Any, Hashable

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

BOARD = "charuco:6x5:120"


def rig_errors(truth: Rig, estimate: Rig) -> dict[str, float]:
    """Worst-camera errors: focal (%), centre (mm), rotation (deg)."""
    focal = max(abs(e.K[0, 0] / t.K[0, 0] - 1) * 100 for t, e in zip(truth, estimate))
    centre = max(float(np.linalg.norm(e.center - t.center)) for t, e in zip(truth, estimate))
    rot = max(float(np.degrees(Rotation.from_matrix(e.R @ t.R.T).magnitude())) for t, e in zip(truth, estimate))
    return {"focal_pct": focal, "centre_mm": centre, "rotation_deg": rot}


def board_stage(size: int, n_intrinsic: int, n_frames: int, seed: int, board_text: str = BOARD,
                backends: tuple[Backend, ...] = ("ceres", "scipy")) -> dict:
    """One board session: intrinsics per camera, then extrinsics with each BA backend."""
    return board_session(size, n_intrinsic, n_frames, seed, board_text, backends)[0]


def board_session(size: int, n_intrinsic: int, n_frames: int, seed: int, board_text: str = BOARD,
                  backends: tuple[Backend, ...] = ("ceres", "scipy")) -> tuple[dict, Rig]:
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
    out = {"board": str(board), "seed": seed, "size": list(truth[0].size), "intrinsic_views": n_intrinsic,
           "frames": n_frames, "peer_no_ba": rig_errors(truth, peer),
           "seconds": {"render": t_render, "detect_intrinsics": t_intr}}
    for backend in backends:
        t0, c0 = time.perf_counter(), time.process_time()
        result = calibrate_extrinsics(intr_rig, board, detections, floor_frame=session.floor_frames, progress=False,
                                      backend=backend)
        out[f"ba_{backend}"] = {**rig_errors(truth, result.rig), "seconds": time.perf_counter() - t0,
                                "cpu_seconds": time.process_time() - c0,
                                "rms_px": max(result.rms_px.values()), "board_rms_mm": result.board_rms_mm,
                                "views_left_out": len(result.rejected)}
    out["ours_ba"] = out[f"ba_{backends[0]}"]
    return out, intr_rig


def wandwave_stage(size: int, seed: int, wand_text: str, seconds: float, intrinsics: Rig) -> dict:
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
    return {"wand": wand_text, "seed": seed, "frames": len(views), "intrinsics": "ChArUco session's",
            **rig_errors(truth, result.rig), "length_rms_mm": result.length_rms_mm,
            "length_max_mm": float(np.abs(result.length_error_mm).max()), "rms_px": max(result.rms_px.values()),
            "true_intrinsics": {**rig_errors(truth, ideal.rig), "length_rms_mm": ideal.length_rms_mm},
            "seconds": {"render": t_render, "detect": t_detect, "calibrate": t_cal}}


def wand_stage(seed: int, tmp_c3d: str) -> dict:
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
    return {
        "seed": seed, "frames": len(points), "identified": int(np.all(np.isfinite(points), axis=(1, 2)).sum()),
        "peer_offset_err_ms": abs(coarse - wave.offset_s) * 1000, "ours_offset_err_ms": abs(reg.offset_s - wave.offset_s) * 1000,
        "rotation_err_deg": float(np.degrees(Rotation.from_matrix(reg.R @ wave.R.T).magnitude())),
        "translation_err_mm": float(np.linalg.norm(reg.t - wave.t)), "scale": reg.scale,
        "max_marker_rms_mm": max(reg.residual_mm.values()),
        "seconds": {"detect_triangulate": t_tri, "register": t_reg},
    }


def run_benchmark(size: int, n_intrinsic: int, n_frames: int, seeds: list[int], out: str,
                  checkerboard: str = "checkerboard:4x7:120", wand: str = "t", wand_seconds: float = 4.0) -> dict:
    import tempfile

    results: dict[str, Any] = {"machine": f"{platform.processor() or platform.machine()}, {date.today()}", "board": BOARD,
                     "checkerboard": checkerboard, "wand_wave": wand, "boards": [], "checkerboards": [],
                     "wandwaves": [], "wand": []}
    for seed in seeds:
        b, intrinsics = board_session(size, n_intrinsic, n_frames, seed)
        results["boards"].append(b)
        print(f"seed {seed} ChArUco {b['size'][0]}x{b['size'][1]}: no-BA peer centre {b['peer_no_ba']['centre_mm']:.2f} mm "
              f"rot {b['peer_no_ba']['rotation_deg']:.3f} deg | " + " | ".join(
                  f"BA {k}: centre {b[f'ba_{k}']['centre_mm']:.2f} mm rot {b[f'ba_{k}']['rotation_deg']:.3f} deg "
                  f"focal {b[f'ba_{k}']['focal_pct']:.3f} % in {b[f'ba_{k}']['seconds']:.1f} s" for k in ("ceres", "scipy")))
        c = board_stage(size, n_intrinsic, n_frames, seed, checkerboard, backends=("ceres",))
        results["checkerboards"].append(c)
        print(f"seed {seed} {checkerboard}: centre {c['ours_ba']['centre_mm']:.2f} mm rot {c['ours_ba']['rotation_deg']:.3f} deg "
              f"focal {c['ours_ba']['focal_pct']:.3f} % ({c['ours_ba']['views_left_out']} views left out)")
        w = wandwave_stage(size, seed, wand, wand_seconds, intrinsics)
        results["wandwaves"].append(w)
        print(f"seed {seed} wand wave ({wand}, ChArUco intrinsics): centre {w['centre_mm']:.2f} mm rot "
              f"{w['rotation_deg']:.4f} deg, wand length error RMS {w['length_rms_mm']:.3f} mm (max "
              f"{w['length_max_mm']:.2f}); calibration {w['seconds']['calibrate']:.1f} s | true lenses: centre "
              f"{w['true_intrinsics']['centre_mm']:.2f} mm rot {w['true_intrinsics']['rotation_deg']:.4f} deg")
        with tempfile.TemporaryDirectory() as tmp:
            v = wand_stage(seed, f"{tmp}/wand.c3d")
        results["wand"].append(v)
        print(f"seed {seed} Vicon wand: offset error correlation-only {v['peer_offset_err_ms']:.3f} ms, refined "
              f"{v['ours_offset_err_ms']:.4f} ms; rotation {v['rotation_err_deg']:.4f} deg, translation "
              f"{v['translation_err_mm']:.3f} mm, scale {v['scale']:.5f}; {v['identified']}/{v['frames']} frames")
    results.update(headline(results))
    for key, value in results.items():
        if isinstance(value, (float, int)) and not isinstance(value, bool):
            print(f"{key}: {value:.4g}")
    with atomic_write(out) as handle:
        json.dump(results, handle, indent=2)
    print(f"wrote {out}")
    return results


def headline(results: dict) -> dict:
    """Worst case over seeds of every row, the headline keys, and the goals."""
    def worst(rows: list[dict], *path: str) -> float:
        values = []
        for row in rows:
            value: Any = row
            for key in path:
                value = value[key]
            values.append(float(value))
        return max(values)

    boards, checks, waves = results["boards"], results["checkerboards"], results["wandwaves"]
    h: dict[str, float] = {
        "charuco_centre_error_mm": worst(boards, "ba_ceres", "centre_mm"),
        "charuco_rotation_error_deg": worst(boards, "ba_ceres", "rotation_deg"),
        "checkerboard_centre_error_mm": worst(checks, "ours_ba", "centre_mm"),
        "checkerboard_rotation_error_deg": worst(checks, "ours_ba", "rotation_deg"),
        "wandwave_centre_error_mm": worst(waves, "centre_mm"),
        "wandwave_rotation_error_deg": worst(waves, "rotation_deg"),
        "wandwave_length_error_mm": worst(waves, "length_rms_mm"),
        "ba_seconds_ceres": worst(boards, "ba_ceres", "seconds"),
        "ba_seconds_scipy": worst(boards, "ba_scipy", "seconds"),
        "ba_centre_error_mm_ceres": worst(boards, "ba_ceres", "centre_mm"),
        "ba_centre_error_mm_scipy": worst(boards, "ba_scipy", "centre_mm"),
        "ba_rotation_error_deg_ceres": worst(boards, "ba_ceres", "rotation_deg"),
        "ba_rotation_error_deg_scipy": worst(boards, "ba_scipy", "rotation_deg"),
    }
    h["ba_speedup_ceres_vs_scipy"] = h["ba_seconds_scipy"] / h["ba_seconds_ceres"]
    out: dict[str, Any] = dict(h)
    out["goals"] = {
        "checkerboard_within_1.5x_charuco": bool(h["checkerboard_centre_error_mm"] <= 1.5 * h["charuco_centre_error_mm"]
                                                 and h["checkerboard_rotation_error_deg"] <= 1.5 * h["charuco_rotation_error_deg"]),
        "wandwave_within_1.5x_charuco": bool(h["wandwave_centre_error_mm"] <= 1.5 * h["charuco_centre_error_mm"]
                                             and h["wandwave_rotation_error_deg"] <= 1.5 * h["charuco_rotation_error_deg"]),
        "wand_length_rms_le_0.5mm": bool(h["wandwave_length_error_mm"] <= 0.5),
        "ba_le_3s": bool(h["ba_seconds_ceres"] <= 3.0),
    }
    return out
