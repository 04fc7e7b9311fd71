"""Appearance options of the studio beyond the body and the lighting: the tape's colour and the
room behind the subject.

- :data:`TAPE_COLOURS`: kinesiology tape as labs buy it (RGB 0..1, the diffuse colour the renderer
  shades): ``black`` (the studio's tape so far), ``beige``, ``blue``, ``pink``, ``red``.
- :data:`BACKDROPS`: ``plain`` (the renderer's uniform background) or ``room``: a painted
  motion-capture room (:func:`spinemocap.synth.rooms.paint_room`, one view per camera, seeded by
  the scene and the camera, with other people standing in it where asked) wherever the render
  shows the empty background; the subject, the
  tape and everything else drawn keep their pixels, and the tape mask and ground truth do not
  change.
- :data:`TAPE_ROLLS`: perforated rolls as labs buy them, each a hole diameter, row pitch and
  column spacing (mm); the roll's layout is the capture's :class:`~spinemocap.tape.TapeSpec`
  (``capture.toml``), so the tracker is told the spacing it films.
- :class:`CameraLook`: what a lab's camera and light do to a frame after the sensor's noise:
  the light's colour temperature under a daylight white balance, mains flicker, auto-exposure,
  defocus, 8-bit 4:2:0 chroma, JPEG frames or H.264 / H.265 at a sports camera's bitrate (PyAV),
  and a rolling shutter's readout time (the scene renders it: :meth:`CameraLook.row_times`).
  :data:`CAMERA_LOOKS`: ``ideal`` (none of it: the studio so far) or ``lab`` (per camera, a
  seeded draw from :func:`lab_camera_look`'s realistic mix).

The tape's finish, the skin's marks and clothing are in :mod:`spinemocap.synth.surfaces` and
:mod:`spinemocap.synth.occluders`.
"""

from __future__ import annotations

import dataclasses
import functools
import io
from dataclasses import dataclass
from typing import Literal, TypedDict, cast, get_args

import cv2
import numpy as np

from .occluders import CLOTHING_ITEMS
from .rooms import paint_room
from .surfaces import lab_surfaces

TapeColour = Literal["black", "beige", "blue", "pink", "red"]
TAPE_COLOURS: dict[str, tuple[float, float, float]] = {
    "black": (0.08, 0.08, 0.10),
    "beige": (0.78, 0.64, 0.50),
    "blue": (0.10, 0.30, 0.72),
    "pink": (0.90, 0.42, 0.60),
    "red": (0.72, 0.10, 0.12),
}
assert tuple(TAPE_COLOURS) == get_args(TapeColour)
# perforated rolls: (hole diameter, row pitch, column spacing) mm on a 50 mm wide tape
TapeRoll = Literal["standard", "small_holes", "large_holes", "close_rows", "wide_rows"]
TAPE_ROLLS: dict[str, tuple[float, float, float]] = {
    "standard": (10.0, 25.0, 15.0),
    "small_holes": (7.0, 25.0, 15.0),
    "large_holes": (12.0, 25.0, 15.0),
    "close_rows": (10.0, 20.0, 14.0),
    "wide_rows": (10.0, 30.0, 16.0),
}
assert tuple(TAPE_ROLLS) == get_args(TapeRoll)


def roll_layout(roll: str) -> dict[str, float]:
    """The :class:`~spinemocap.tape.TapeSpec` fields of a :data:`TAPE_ROLLS` roll."""
    diameter, pitch, columns = TAPE_ROLLS[roll]
    return {"dot_diameter_mm": diameter, "row_pitch_mm": pitch, "column_spacing_mm": columns}


class LabSubject(TypedDict):
    """:class:`~spinemocap.synth.SynthConfig` settings of the tape and the subject."""

    tape_roll: str
    tape_finish: str
    skin_marks: tuple[str, ...]
    clothing: tuple[str, ...]


def lab_subject(rng: np.random.Generator) -> LabSubject:
    """The :class:`~spinemocap.synth.SynthConfig` settings of a lab's tape and subject drawn from
    ``rng``: the standard roll in three fifths of the labs, each other :data:`TAPE_ROLLS` roll in
    a tenth; the tape's finish and the skin's marks of :func:`~spinemocap.synth.surfaces.lab_surfaces`;
    shorts on half the subjects, a sports bra's back strap on three in ten."""
    roll = str(rng.choice(list(TAPE_ROLLS), p=[0.6, 0.1, 0.1, 0.1, 0.1]))
    surfaces = lab_surfaces(rng)
    odds = {"shorts": 0.5, "bra_strap": 0.3}
    clothing = tuple(item for item in CLOTHING_ITEMS if rng.random() < odds[item])
    return LabSubject(tape_roll=roll, tape_finish=surfaces.finish, skin_marks=surfaces.marks, clothing=clothing)


Backdrop = Literal["plain", "room"]
BACKDROPS: tuple[str, ...] = get_args(Backdrop)


@functools.lru_cache(maxsize=16)
def room_view(size: tuple[int, int], scene_seed: int, camera: int, people: int = 0) -> np.ndarray:
    """The room one camera sees behind the subject, with ``people`` other people standing in it:
    RGB uint8 (H, W, 3) for ``size`` (width, height) (cached: the same array for the same
    arguments; read it, do not change it)."""
    seed = int(np.random.default_rng([scene_seed, 7, camera]).integers(1 << 31))
    bgr = paint_room(size, seed=seed, people=people)
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
Codec = Literal["none", "jpeg", "h264", "h265"]
CODECS: tuple[str, ...] = get_args(Codec)
_ENCODERS = {"h264": "libx264", "h265": "libx265"}
DAYLIGHT_K = 6500.0
MAINS_HZ = 50.0


@dataclass(frozen=True)
class CameraLook:
    """One camera's look. ``colour_temperature_k``: the light's temperature, the camera's white
    balance set for daylight (:data:`DAYLIGHT_K`: no tint); ``flicker``: relative amplitude of the
    brightness ripple of lamps on the mains (twice :data:`MAINS_HZ`), sampled at each frame's
    time; ``exposure``: the auto-exposure's gain (1: as rendered); ``defocus_px``: Gaussian blur
    sigma (px); ``chroma_420``: colour at half resolution in both directions (8-bit YCbCr 4:2:0);
    ``codec``: ``jpeg`` at ``quality`` (1-100) or ``h264`` / ``h265`` at ``bitrate_mbps`` for a
    video at ``fps`` (every frame coded alone, as the first frame of a recording), else none;
    ``readout_ms``: a rolling shutter's readout, from the top row's exposure to the bottom row's
    (0: a global shutter)."""

    colour_temperature_k: float = DAYLIGHT_K
    flicker: float = 0.0
    exposure: float = 1.0
    defocus_px: float = 0.0
    chroma_420: bool = False
    codec: Codec = "none"
    quality: int = 90
    bitrate_mbps: float = 40.0
    fps: float = 100.0
    readout_ms: float = 0.0

    def row_times(self, height: int) -> np.ndarray:
        """(height,) when each image row is exposed, s, relative to the frame's instant (the
        middle row's): all 0 for a global shutter."""
        if self.readout_ms <= 0 or height < 2:
            return np.zeros(height)
        return (np.arange(height) / (height - 1) - 0.5) * self.readout_ms * 1e-3

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
        elif self.codec in _ENCODERS:
            out = video_frame(out, self.codec, self.bitrate_mbps, self.fps)
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


def video_frame(image_bgr: np.ndarray, codec: str, bitrate_mbps: float, fps: float) -> np.ndarray:
    """``image_bgr`` (H, W, 3) uint8 coded by libx264 (``codec`` ``h264``) or libx265 (``h265``)
    through PyAV in 4:2:0 at ``bitrate_mbps`` for a ``fps`` video, and decoded (odd sizes are
    padded by a pixel, then cropped). Raises ValueError for another codec."""
    if codec not in _ENCODERS:
        raise ValueError(f"unknown video codec {codec!r}; choose from {list(_ENCODERS)}")
    import av

    h, w = image_bgr.shape[:2]
    padded = cv2.copyMakeBorder(image_bgr, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE)
    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as container:
        stream = container.add_stream(_ENCODERS[codec], rate=max(1, int(round(fps))))
        stream.width, stream.height = padded.shape[1], padded.shape[0]
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(bitrate_mbps * 1e6)
        stream.options = {"preset": "ultrafast", "tune": "zerolatency"}
        if codec == "h265":
            stream.options = {**stream.options, "x265-params": "log-level=none"}
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
    4:2:0 chroma in most; JPEG frames (quality 70-95) in a fifth, video at 15-60 Mb/s (sports
    cameras) in two fifths, H.265 in two of five of those, H.264 in the rest; the sports cameras'
    rolling shutter reads out in 5-20 ms, one in ten of the other cameras' in 5-15 ms."""
    codec = str(rng.choice(["none", "jpeg", "h264", "h264"], p=[0.4, 0.2, 0.2, 0.2]))
    look = CameraLook(
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
    # drawn after the mix above, so that its draws stay what they were
    sports = codec == "h264"
    if sports and rng.random() < 0.4:
        look = dataclasses.replace(look, codec="h265")
    readout = float(rng.uniform(5, 20)) if sports else (float(rng.uniform(5, 15)) if rng.random() < 0.1 else 0.0)
    return dataclasses.replace(look, readout_ms=readout)


def camera_looks(name: str, cameras: int, scene_seed: int, fps: float, readout_ms: float | None = None,
                 codec: str | None = None) -> list[CameraLook] | None:
    """Per camera the :data:`CAMERA_LOOKS` ``name`` (``ideal``: None), seeded by the scene, with
    every camera's rolling-shutter ``readout_ms`` and ``codec`` set where given (on an ``ideal``
    look, a look with only those)."""
    looks = None if name == "ideal" else [lab_camera_look(np.random.default_rng([scene_seed, 11, c]), fps)
                                          for c in range(cameras)]
    if readout_ms is None and codec is None:
        return looks
    out = []
    for look in looks or [CameraLook(fps=fps)] * cameras:
        if readout_ms is not None:
            look = dataclasses.replace(look, readout_ms=float(readout_ms))
        if codec is not None:  # a video codec codes 4:2:0
            look = dataclasses.replace(look, codec=cast(Codec, codec), chroma_420=look.chroma_420 or codec in _ENCODERS)
        out.append(look)
    return out
