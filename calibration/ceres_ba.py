"""Bundle adjustment of a camera rig and a rigid target (board or wand) with Ceres, through
pycolmap (COLMAP's own bundle adjuster, sparse Schur solver, analytic Jacobians).

The problem is mapped onto COLMAP's rig model with the roles of the objects swapped: the world
of the COLMAP reconstruction is the *target's* frame, so the target's points (board corners or
wand markers, mm) are the same constant 3D points in every frame; each capture frame is a COLMAP
frame whose ``rig_from_world`` is the target's pose in the reference camera's frame; each camera
is a sensor of one rig with ``sensor_from_rig`` its pose relative to the reference camera (the
reference sensor is the identity, which fixes the gauge; the constant target points fix the
scale). Intrinsics use COLMAP's ``OPENCV`` model (fx fy cx cy k1 k2 p1 p2), the same projection
as OpenCV's with k3 = 0, so pixels and principal points pass through unchanged.

Same inputs and outputs as the scipy path in :func:`calibration.extrinsics.bundle_adjust`.
"""

from __future__ import annotations

import numpy as np

from spinemocap.camera import Camera, Rig

Pose = tuple[np.ndarray, np.ndarray]


def ceres_unsupported(intrinsics: Rig) -> str | None:
    """Why the Ceres path cannot take this problem (None when it can): COLMAP's OPENCV model has no k3."""
    if any(abs(cam.dist[4]) > 0 for cam in intrinsics):
        return "a camera has a k3 radial term (COLMAP's OPENCV model has none)"
    return None


def _sensor(pycolmap, camera_index: int):
    return pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=camera_index + 1)


def _rigid(pycolmap, R: np.ndarray, t: np.ndarray):
    return pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(R, float)), np.asarray(t, float))


def bundle_adjust_ceres(intrinsics: Rig, model: np.ndarray, cam_index: np.ndarray, frame_index: np.ndarray,
                        point_index: np.ndarray, pixels: np.ndarray, poses: list[Pose], targets: list[Pose],
                        reference: int = 0, refine_intrinsics: bool = True, loss_scale_px: float = 1.0,
                        max_iterations: int = 100) -> tuple[Rig, list[Pose]]:
    """Refine camera poses (world -> camera), target poses (target -> world) and optionally
    fx fy cx cy k1 k2 p1 p2 by minimizing the Huber-robust reprojection error (``loss_scale_px``).

    ``model`` (P, 3): target points, mm; observation k is point ``point_index[k]`` of target pose
    ``frame_index[k]`` seen at distorted pixel ``pixels[k]`` by camera ``cam_index[k]``. The
    ``reference`` camera's pose stays fixed. Returns the refined rig and target poses.
    """
    import pycolmap

    rec = pycolmap.Reconstruction()
    R_ref, t_ref = poses[reference]
    rig = pycolmap.Rig(rig_id=1)
    for c, cam in enumerate(intrinsics):
        params = [cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2], *cam.dist[:4]]
        rec.add_camera(pycolmap.Camera(camera_id=c + 1, model="OPENCV", width=cam.size[0], height=cam.size[1],
                                       params=params))
        if c == reference:
            rig.add_ref_sensor(_sensor(pycolmap, c))
        else:  # camera pose relative to the reference camera
            R_c, t_c = poses[c]
            rig.add_sensor(_sensor(pycolmap, c), _rigid(pycolmap, R_c @ R_ref.T, t_c - R_c @ R_ref.T @ t_ref))
    rec.add_rig(rig)
    point_ids = [rec.add_point3D(p, pycolmap.Track()) for p in np.asarray(model, float)]

    config = pycolmap.BundleAdjustmentConfig()
    image_id = 0
    for f, (R_t, t_t) in enumerate(targets):
        in_frame = np.flatnonzero(frame_index == f)
        cams = np.unique(cam_index[in_frame])
        if not len(cams):
            continue
        frame = pycolmap.Frame(frame_id=f + 1, rig_id=1)
        # target -> reference camera
        frame.rig_from_world = _rigid(pycolmap, R_ref @ R_t, R_ref @ t_t + t_ref)
        images = []
        for c in cams:
            image_id += 1
            frame.add_data_id(pycolmap.data_t(sensor_id=_sensor(pycolmap, int(c)), id=image_id))
            images.append((image_id, in_frame[cam_index[in_frame] == c]))
        rec.add_frame(frame)
        for iid, rows in images:
            image = pycolmap.Image(name=f"{f}_{iid}", keypoints=pixels[rows], camera_id=int(cam_index[rows[0]]) + 1,
                                   image_id=iid)
            image.frame_id = f + 1
            rec.add_image(image)
        rec.register_frame(f + 1)
        for iid, rows in images:
            config.add_image(iid)
            for k, row in enumerate(rows):
                rec.add_observation(point_ids[point_index[row]], pycolmap.TrackElement(iid, k))
    for pid in point_ids:
        config.add_constant_point(pid)
    if not refine_intrinsics:
        for c in range(len(intrinsics)):
            config.set_constant_cam_intrinsics(c + 1)

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_principal_point = options.refine_extra_params = refine_intrinsics
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.HUBER
    options.ceres.loss_function_scale = loss_scale_px
    options.ceres.solver_options.max_num_iterations = max_iterations
    options.ceres.solver_options.function_tolerance = 1e-12
    options.ceres.solver_options.gradient_tolerance = 1e-10
    options.ceres.solver_options.parameter_tolerance = 1e-12
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()

    solved = rec.rig(1)
    cameras = []
    for c, cam in enumerate(intrinsics):
        if c == reference:
            R_c, t_c = R_ref, t_ref
        else:
            rel = solved.sensor_from_rig(_sensor(pycolmap, c))
            if rel is None:
                raise RuntimeError(f"the adjustment dropped camera {cam.name!r} from the rig")
            R_rel, t_rel = rel.rotation.matrix(), np.asarray(rel.translation)
            R_c, t_c = R_rel @ R_ref, R_rel @ t_ref + t_rel
        fx, fy, cx, cy, *dist4 = rec.camera(c + 1).params
        K = np.array([[fx, cam.K[0, 1], cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        cameras.append(Camera(cam.name, K, np.array([*dist4, cam.dist[4]]), R_c, t_c, cam.size))
    refined = []
    for f, pose in enumerate(targets):
        world = rec.frame(f + 1).rig_from_world if rec.exists_frame(f + 1) else None
        if world is None:  # a target the adjustment did not pose keeps its start
            refined.append(pose)
            continue
        R_f, t_f = world.rotation.matrix(), np.asarray(world.translation)
        refined.append((R_ref.T @ R_f, R_ref.T @ (t_f - t_ref)))
    return Rig(cameras), refined


__all__ = ["bundle_adjust_ceres", "ceres_unsupported"]
