"""Appearance options of the studio beyond the body and the lighting: the tape's colour and the
room behind the subject.

- :data:`TAPE_COLOURS`: kinesiology tape as labs buy it (RGB 0..1, the diffuse colour the renderer
  shades): ``black`` (the studio's tape so far), ``beige``, ``blue``, ``pink``, ``red``.
- :data:`BACKDROPS`: ``plain`` (the renderer's uniform background) or ``room``: a painted
  motion-capture room (:func:`spinemocap.synth.rooms.paint_room`, one view per camera, seeded by
  the scene and the camera) wherever the render shows the empty background; the subject, the
  tape and everything else drawn keep their pixels, and the tape mask and ground truth do not
  change.
- :class:`CameraLook`: what a lab's camera and light do to a frame after the sensor's noise:
  the light's colour temperature under a daylight white balance, mains flicker, auto-exposure,
  defocus, 8-bit 4:2:0 chroma, JPEG frames or H.264 at a sports camera's bitrate (PyAV).
  :data:`CAMERA_LOOKS`: ``ideal`` (none of it: the studio so far) or ``lab`` (per camera, a
  seeded draw from :func:`lab_camera_look`'s realistic mix).
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass
from typing import Literal, cast, get_args

import cv2
import numpy as np

from .rooms import paint_room

TapeColour = Literal["black", "beige", "blue", "pink", "red"]
TAPE_COLOURS: dict[str, tuple[float, float, float]] = {
    "black": (0.08, 0.08, 0.10),
    "beige": (0.78, 0.64, 0.50),
    "blue": (0.10, 0.30, 0.72),
    "pink": (0.90, 0.42, 0.60),
    "red": (0.72, 0.10, 0.12),
}
assert tuple(TAPE_COLOURS) == get_args(TapeColour)
Backdrop = Literal["plain", "room"]
BACKDROPS: tuple[str, ...] = get_args(Backdrop)


@functools.lru_cache(maxsize=16)
def room_view(size: tuple[int, int], scene_seed: int, camera: int) -> np.ndarray:
    """The room one camera sees behind the subject: RGB uint8 (H, W, 3) for ``size`` (width, height)
    (cached: the same array for the same arguments; read it, do not change it)."""
    bgr = paint_room(size, seed=int(np.random.default_rng([scene_seed, 7, camera]).integers(1 << 31)))
    return np.ascontiguousarray(bgr[..., ::-1])


def behind_subject(rgb: np.ndarray, empty_pixel: np.ndarray, room_rgb: np.ndarray) -> np.ndarray:
    """``rgb`` (H, W, 3; uint8 or float32 grey levels) with ``room_rgb`` (H, W, 3 uint8) wherever it
    shows exactly the renderer's empty background ``empty_pixel`` ((3,) uint8), in ``rgb``'s dtype."""
    empty = np.all(rgb == empty_pixel.astype(rgb.dtype), axis=2)
    out = rgb.copy()
    out[empty] = room_rgb[empty]
    return out


CameraLookName = Literal["ideal", "lab"]
CAMERA_LOOKS: tuple[str, ...] = get_args(CameraLookName)
Codec = Literal["none", "jpeg", "h264"]
DAYLIGHT_K = 6500.0
MAINS_HZ = 50.0


@dataclass(frozen=True)
class CameraLook:
    """One camera's look. ``colour_temperature_k``: the light's temperature, the camera's white
    balance set for daylight (:data:`DAYLIGHT_K`: no tint); ``flicker``: relative amplitude of the
    brightness ripple of lamps on the mains (twice :data:`MAINS_HZ`), sampled at each frame's
    time; ``exposure``: the auto-exposure's gain (1: as rendered); ``defocus_px``: Gaussian blur
    sigma (px); ``chroma_420``: colour at half resolution in both directions (8-bit YCbCr 4:2:0);
    ``codec``: ``jpeg`` at ``quality`` (1-100) or ``h264`` at ``bitrate_mbps`` for a video at
    ``fps`` (every frame coded alone, as the first frame of a recording), else none."""

    colour_temperature_k: float = DAYLIGHT_K
    flicker: float = 0.0
    exposure: float = 1.0
    defocus_px: float = 0.0
    chroma_420: bool = False
    codec: Codec = "none"
    quality: int = 90
    bitrate_mbps: float = 40.0
    fps: float = 100.0

    def apply(self, image_bgr: np.ndarray, time_s: float, phase: float = 0.0) -> np.ndarray:
        """``image_bgr`` (H, W, 3) uint8 as this camera delivers it at ``time_s`` s (``phase``:
        the flicker's phase, rad); a new array."""
        gain = self.exposure * (1.0 + self.flicker * np.sin(2 * np.pi * 2 * MAINS_HZ * time_s + phase))
        image = image_bgr.astype(np.float32) * (gain * white_balance_gains(self.colour_temperature_k))[None, None]
        if self.defocus_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.defocus_px)
        out = np.clip(image + 0.5, 0, 255).astype(np.uint8)
        if self.chroma_420:
            out = chroma_subsampled(out)
        if self.codec == "jpeg":
            ok, data = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(self.quality)])
            out = cv2.imdecode(data, cv2.IMREAD_COLOR)
        elif self.codec == "h264":
            out = h264_frame(out, self.bitrate_mbps, self.fps)
        return out


def white_balance_gains(temperature_k: float) -> np.ndarray:
    """(3,) B, G, R gains of light at ``temperature_k`` (1500-15000 K) seen by a camera balanced for
    daylight: the ratio of the two lights' colours (Planckian locus, Tanner Helland's fit), green 1."""
    def rgb(t: float) -> np.ndarray:
        t = np.clip(t, 1000.0, 40000.0) / 100.0
        r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
        g = 99.4708025861 * np.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
        b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307)
        return np.clip(np.array([b, g, r], float), 1.0, 255.0)

    ratio = rgb(temperature_k) / rgb(DAYLIGHT_K)
    return (ratio / ratio[1]).astype(np.float32)


def chroma_subsampled(image_bgr: np.ndarray) -> np.ndarray:
    """``image_bgr`` (H, W, 3) uint8 through 8-bit YCbCr 4:2:0: full-resolution luma, chroma averaged
    over 2x2 pixels and scaled back up."""
    ycc = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2YCrCb)
    h, w = ycc.shape[:2]
    half = cv2.resize(ycc[..., 1:], ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA)
    ycc[..., 1:] = cv2.resize(half, (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.cvtColor(ycc, cv2.COLOR_YCrCb2BGR)


def h264_frame(image_bgr: np.ndarray, bitrate_mbps: float, fps: float) -> np.ndarray:
    """``image_bgr`` (H, W, 3) uint8 coded by libx264 (PyAV) in 4:2:0 at ``bitrate_mbps`` for a
    ``fps`` video, and decoded (odd sizes are padded by a pixel, then cropped)."""
    import av

    h, w = image_bgr.shape[:2]
    padded = cv2.copyMakeBorder(image_bgr, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE)
    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=max(1, int(round(fps))))
        stream.width, stream.height = padded.shape[1], padded.shape[0]
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(bitrate_mbps * 1e6)
        stream.options = {"preset": "ultrafast", "tune": "zerolatency"}
        for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(padded), format="bgr24")):
            container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    buffer.seek(0)
    with av.open(buffer) as container:
        decoded = next(container.decode(video=0)).to_ndarray(format="bgr24")
    return np.ascontiguousarray(decoded[:h, :w])


def lab_camera_look(rng: np.random.Generator, fps: float) -> CameraLook:
    """A camera as labs have them, drawn from ``rng``: lamps of 2700-6500 K; mains flicker of up
    to 8 % in a third of the rooms; auto-exposure 0.75-1.25; slightly defocused in a third;
    4:2:0 chroma in most; JPEG frames (quality 70-95) in a fifth, H.264 at 15-60 Mb/s (sports
    cameras) in two fifths."""
    codec = str(rng.choice(["none", "jpeg", "h264", "h264"], p=[0.4, 0.2, 0.2, 0.2]))
    return CameraLook(
        colour_temperature_k=float(rng.uniform(2700, 6500)),
        flicker=float(rng.uniform(0, 0.08)) if rng.random() < 1 / 3 else 0.0,
        exposure=float(rng.uniform(0.75, 1.25)),
        defocus_px=float(rng.uniform(0.4, 1.2)) if rng.random() < 1 / 3 else 0.0,
        chroma_420=bool(codec == "h264" or rng.random() < 0.6),
        codec=cast(Codec, codec),
        quality=int(rng.integers(70, 96)),
        bitrate_mbps=float(rng.uniform(15, 60)),
        fps=fps,
    )


def camera_looks(name: str, cameras: int, scene_seed: int, fps: float) -> list[CameraLook] | None:
    """Per camera the :data:`CAMERA_LOOKS` ``name`` (``ideal``: None), seeded by the scene."""
    if name == "ideal":
        return None
    return [lab_camera_look(np.random.default_rng([scene_seed, 11, c]), fps) for c in range(cameras)]
