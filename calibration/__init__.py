"""Camera calibration: boards, intrinsics, extrinsics with bundle adjustment, Vicon wand
co-registration and calibration file formats. Depends only on spinemocap's core modules
(:mod:`spinemocap.camera`, :mod:`spinemocap.geometry`, :mod:`spinemocap.markers`,
:mod:`spinemocap.fileio`, ...); the Vicon C3D is read by the application layer
(:mod:`spinemocap.app.c3d_inputs`, with ``exporters.read``) and handed in as a marker table.

Pipeline (one module per step):

* :mod:`calibration.boards` — board spec (checkerboard / ChArUco), detection, view checks;
* :mod:`calibration.intrinsics` — one camera's K and distortion from board views;
* :mod:`calibration.extrinsics` — PnP spanning tree + bundle adjustment, world frame from the floor;
* :mod:`calibration.wand` — Vicon wand: identify, triangulate, clock offset, similarity transform;
* :mod:`calibration.formats` — ours, Pose2Sim/Anipose TOML, Qualisys .qca.txt, Vicon .xcp;
* :mod:`calibration.check` — per-camera table and reprojection-error plot;
* :mod:`calibration.geometry` — triangulation, Umeyama, rig transforms (shared helpers);

The benchmark (``spinemocap bench calibration``) and the synthetic renders of boards and a wand
wave it and the tests use live in the application layer: :mod:`spinemocap.bench.calibration`,
:mod:`spinemocap.bench.calibration_scenes`.
"""
