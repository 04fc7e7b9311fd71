"""Camera calibration: boards, intrinsics, extrinsics with bundle adjustment, Vicon wand
co-registration and calibration file formats. Depends only on :mod:`spinemocap.camera`."""
