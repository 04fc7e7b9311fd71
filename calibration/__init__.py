"""Camera calibration: boards, intrinsics, extrinsics with bundle adjustment, Vicon wand
co-registration and calibration file formats. Depends only on :mod:`spinemocap.camera`,
:mod:`spinemocap.fileio` (and :mod:`exporters` for reading the Vicon C3D when present).

Pipeline (one module per step):

* :mod:`calibration.boards` — board spec (checkerboard / ChArUco), detection, view checks;
* :mod:`calibration.intrinsics` — one camera's K and distortion from board views;
* :mod:`calibration.extrinsics` — PnP spanning tree + bundle adjustment, world frame from the floor;
* :mod:`calibration.wand` — Vicon wand: identify, triangulate, clock offset, similarity transform;
* :mod:`calibration.formats` — ours, Pose2Sim/Anipose TOML, Qualisys .qca.txt, Vicon .xcp;
* :mod:`calibration.check` — per-camera table and reprojection-error plot;
* :mod:`calibration.geometry` — triangulation, Umeyama, rig transforms (shared helpers);
* :mod:`calibration.benchmark` — ``spinemocap bench calibration``.

Synthetic renders of boards and a wand wave for tests live in
:mod:`spinemocap.synth.calibration_scenes`.
"""
