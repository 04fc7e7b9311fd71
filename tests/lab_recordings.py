"""A lab's recordings made from studio images, for the import tests: H.264 (or MPEG-4 Part 2
where this PyAV lacks libx264) MP4 files and a Qualisys QTM calibration export (``.qca.txt``)
written from a rig, in the layout QTM writes (intrinsics in 1/64 px sensor units, the camera
frame's y and z opposite to OpenCV's; :mod:`calibration.formats.qualisys` reads it back)."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

QTM_UNITS_PER_PX = 64
QCA_CAMERA = (
    '    <camera active="1" avg-residual="0.3" model="Miqus Video" point-count="900" serial="{serial}" '
    'viewrotation="0">\n'
    '      <fov_video bottom="{bottom}" left="0" right="{right}" top="0"/>\n'
    '      <fov_video_max bottom="{bottom}" left="0" right="{right}" top="0"/>\n'
    '      <transform {rotation} x="{c[0]!r}" y="{c[1]!r}" z="{c[2]!r}"/>\n'
    '      <intrinsic centerPointU="{cu!r}" centerPointV="{cv!r}" focalLengthU="{fu!r}" focalLengthV="{fv!r}" '
    'radialDistortion1="{d[0]!r}" radialDistortion2="{d[1]!r}" radialDistortion3="{d[4]!r}" sensorMaxU="{su}" '
    'sensorMaxV="{sv}" sensorMinU="0" sensorMinV="0" skew="{sk!r}" tangentalDistortion1="{d[2]!r}" '
    'tangentalDistortion2="{d[3]!r}"/>\n'
    "    </camera>\n")


def write_qca(rig, serials, path: Path, extra_rows: dict[str, int] | None = None) -> Path:
    """``rig``'s cameras as a QTM calibration export named by ``serials``; ``extra_rows``: camera
    name -> rows the calibration's sensor window has beyond the camera's image (its bottom)."""
    cameras = []
    for camera, serial in zip(rig, serials):
        width, height = camera.size
        height += (extra_rows or {}).get(camera.name, 0)
        M = np.diag([1.0, -1.0, -1.0]) @ camera.R  # QTM's camera frame: y and z opposite to OpenCV's
        rotation = " ".join(f'r{i + 1}{j + 1}="{float(M[i, j])!r}"' for i in range(3) for j in range(3))
        K = camera.K * QTM_UNITS_PER_PX
        cameras.append(QCA_CAMERA.format(
            serial=serial, bottom=height - 1, right=width - 1, rotation=rotation, c=[float(x) for x in camera.center],
            cu=float(K[0, 2]), cv=float(K[1, 2]), fu=float(K[0, 0]), fv=float(K[1, 1]), sk=float(K[0, 1]),
            d=[float(x) for x in camera.dist], su=width * QTM_UNITS_PER_PX, sv=height * QTM_UNITS_PER_PX))
    path.write_text("<?xml version='1.0' encoding='ASCII'?>\n<calibration type=\"regular\" source=\"QTM\">\n"
                    "  <cameras>\n" + "".join(cameras) + "  </cameras>\n</calibration>\n")
    return path


def video_codec() -> tuple[str, dict[str, str]]:
    """H.264 (libx264, nearly lossless) where this PyAV has it, else MPEG-4 Part 2 at its best quality."""
    import av

    try:
        av.codec.Codec("libx264", "w")
        return "libx264", {"crf": "4", "preset": "ultrafast"}
    except Exception:  # PyAV builds without GPL codecs
        return "mpeg4", {"qscale": "1"}


def write_mp4(path: Path, images: list[np.ndarray], fps: float) -> Path:
    """BGR uint8 ``images`` as an MP4 video at ``fps`` frames/s (yuv420p, :func:`video_codec`)."""
    import av

    codec, options = video_codec()
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001), options=options)
        stream.width, stream.height = images[0].shape[1], images[0].shape[0]
        stream.pix_fmt = "yuv420p"
        for image in images:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")))
        container.mux(stream.encode(None))
    return path
