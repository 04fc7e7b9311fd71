"""``spinemocap bench calibration``: accuracy and time of the calibration pipeline on exact
synthetic renders of a 6-camera ring, compared with a peer in the same run:

* board stage — peer: OpenCV ``calibrateCamera`` per camera + PnP spanning tree (no bundle
  adjustment); ours: the same followed by the sparse robust bundle adjustment;
* wand stage — peer: the clock offset from speed cross-correlation alone (1 ms grid); ours: the
  joint offset + similarity refinement.
"""

from __future__ import annotations

import json
import platform
import time
from datetime import date
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.boards import BoardSpec, detect_board
from calibration.extrinsics import calibrate_extrinsics, floor_world_transform, initial_poses
from calibration.geometry import transform_rig
from calibration.intrinsics import calibrate_from_detections
from calibration.wand import coarse_offset, register_wand, triangulate_wand
from spinemocap.camera import Camera, Rig
from spinemocap.fileio import atomic_write

from ..app.c3d_inputs import read_vicon_wand, write_vicon_wand_c3d
from .calibration_scenes import make_ring_rig, render_calibration_session, render_wand_wave

BOARD = "charuco:6x5:120"


def rig_errors(truth: Rig, estimate: Rig) -> dict[str, float]:
    """Worst-camera errors: focal (%), centre (mm), rotation (deg)."""
    focal = max(abs(e.K[0, 0] / t.K[0, 0] - 1) * 100 for t, e in zip(truth, estimate))
    centre = max(float(np.linalg.norm(e.center - t.center)) for t, e in zip(truth, estimate))
    rot = max(float(np.degrees(Rotation.from_matrix(e.R @ t.R.T).magnitude())) for t, e in zip(truth, estimate))
    return {"focal_pct": focal, "centre_mm": centre, "rotation_deg": rot}


def board_stage(size: int, n_intrinsic: int, n_frames: int, seed: int) -> dict:

    board = BoardSpec.parse(BOARD)
    truth = make_ring_rig(6, size=(size, size * 3 // 4), seed=seed)
    t0 = time.perf_counter()
    session = render_calibration_session(truth, board, n_intrinsic, n_frames, n_floor=3, seed=seed)
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    detections, intrinsics = {}, []
    for cam in truth:
        views = {(cam.name, i): d for i, im in enumerate(session.intrinsic[cam.name]) if (d := detect_board(im, board))}
        intrinsics.append(calibrate_from_detections(views, [], cam.size, board, cam.name).camera)
        views.update({f: d for f, im in enumerate(session.capture.images[cam.name]) if (d := detect_board(im, board))})
        detections[cam.name] = views
    t_intr = time.perf_counter() - t0
    intr_rig = Rig(intrinsics)
    poses, boards = initial_poses(intr_rig, board, detections)
    peer = Rig([Camera(c.name, c.K, c.dist, R, t, c.size) for c, (R, t) in zip(intrinsics, poses)])
    R, t = floor_world_transform(board, boards, session.floor_frames)
    peer = transform_rig(peer, R, t)
    t0 = time.perf_counter()
    result = calibrate_extrinsics(intr_rig, board, detections, floor_frame=session.floor_frames, progress=False)
    t_ba = time.perf_counter() - t0
    return {
        "seed": seed, "size": list(truth[0].size), "intrinsic_views": n_intrinsic, "frames": n_frames,
        "peer_no_ba": rig_errors(truth, peer), "ours_ba": rig_errors(truth, result.rig),
        "rms_px": max(result.rms_px.values()), "board_rms_mm": result.board_rms_mm,
        "seconds": {"render": t_render, "detect_intrinsics": t_intr, "extrinsics_ba": t_ba},
    }


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


def run_benchmark(size: int, n_intrinsic: int, n_frames: int, seeds: list[int], out: str) -> dict:
    import tempfile

    results: dict[str, Any] = {"machine": f"{platform.processor() or platform.machine()}, {date.today()}", "board": BOARD,
               "boards": [], "wand": []}
    for seed in seeds:
        b = board_stage(size, n_intrinsic, n_frames, seed)
        results["boards"].append(b)
        print(f"seed {seed} boards {b['size'][0]}x{b['size'][1]}: no-BA peer focal {b['peer_no_ba']['focal_pct']:.3f} % "
              f"centre {b['peer_no_ba']['centre_mm']:.2f} mm rot {b['peer_no_ba']['rotation_deg']:.3f} deg | BA focal "
              f"{b['ours_ba']['focal_pct']:.3f} % centre {b['ours_ba']['centre_mm']:.2f} mm rot "
              f"{b['ours_ba']['rotation_deg']:.3f} deg | RMS {b['rms_px']:.3f} px board {b['board_rms_mm']:.3f} mm | "
              f"BA {b['seconds']['extrinsics_ba']:.1f} s")
        with tempfile.TemporaryDirectory() as tmp:
            w = wand_stage(seed, f"{tmp}/wand.c3d")
        results["wand"].append(w)
        print(f"seed {seed} wand: offset error correlation-only {w['peer_offset_err_ms']:.3f} ms, refined "
              f"{w['ours_offset_err_ms']:.4f} ms; rotation {w['rotation_err_deg']:.4f} deg, translation "
              f"{w['translation_err_mm']:.3f} mm, scale {w['scale']:.5f}; {w['identified']}/{w['frames']} frames; "
              f"triangulation {w['seconds']['detect_triangulate']:.1f} s")
    with atomic_write(out) as handle:
        json.dump(results, handle, indent=2)
    print(f"wrote {out}")
    return results
