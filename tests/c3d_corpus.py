"""A C3D corpus the project writes itself, byte by byte, for the variants the ``c3d`` package
cannot write: DEC and SGI/MIPS processors, integer data, header / POINT:FRAMES / TRIAL fields
that disagree, rotation sections, 0-point files, more than 65535 frames, no padding.

:func:`write_raw_c3d` follows the C3D specification (c3d.org, "The C3D File Format User Guide"):
a 512-byte header, the parameter section (groups and parameters), then per frame the point words
(x, y, z, fourth word = residual byte | camera mask << 8, -1 when invalid) and the analog samples,
and, when there are rotations, a rotation section (ezc3d's layout: per rotation a column-major 4x4
matrix and a reliability, as floats) starting at ROTATION:DATA_START.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

PROCESSOR = {"intel": 84, "dec": 85, "mips": 86}


def encode_floats(values, processor: str) -> bytes:
    """32-bit floats as the processor stores them (DEC: the value x 4 with the 16-bit words
    swapped, the DEC F-float layout)."""
    values = np.asarray(values, np.float64).ravel()
    if processor == "mips":
        return values.astype(">f4").tobytes()
    if processor == "dec":
        raw = (values * 4.0).astype("<f4").view(np.uint8).reshape(-1, 4)
        return raw[:, [2, 3, 0, 1]].tobytes()
    return values.astype("<f4").tobytes()


def encode_ints(values, processor: str) -> bytes:
    """16-bit signed integers in the processor's byte order."""
    return np.asarray(values).astype(">i2" if processor == "mips" else "<i2").tobytes()


@dataclass
class Param:
    """One parameter: ``kind`` -1 char, 1 byte, 2 int16, 4 float; ``dims`` Fortran order."""

    name: str
    kind: int
    dims: tuple[int, ...]
    data: bytes


def int_param(name: str, values, processor: str) -> Param:
    values = np.atleast_1d(values)
    return Param(name, 2, () if np.ndim(values) == 1 and len(values) == 1 else (len(values),),
                 encode_ints(values, processor))


def float_param(name: str, values, processor: str) -> Param:
    values = np.atleast_1d(values)
    return Param(name, 4, () if len(values) == 1 else (len(values),), encode_floats(values, processor))


def str_param(name: str, values: list[str] | str) -> Param:
    if isinstance(values, str):
        return Param(name, -1, (len(values),), values.encode())
    width = max([len(v) for v in values] + [1])
    return Param(name, -1, (width, len(values)), b"".join(v.ljust(width).encode() for v in values))


def parameter_section(groups: dict[str, list[Param]], processor: str) -> bytes:
    """The parameter section (without its 4-byte lead), ending with a zero-length name."""
    short = ">h" if processor == "mips" else "<h"
    out = b""
    for gid, (gname, params) in enumerate(groups.items(), start=1):
        name = gname.encode()
        out += struct.pack("bb", len(name), -gid) + name + struct.pack(short, 3) + b"\x00"
        for p in params:
            name = p.name.encode()
            body = struct.pack("bB", p.kind, len(p.dims)) + bytes(p.dims) + p.data + b"\x00"
            out += struct.pack("bb", len(name), gid) + name + struct.pack(short, 2 + len(body)) + body
    return out + b"\x00\x00"


def pad(data: bytes) -> bytes:
    return data + b"\x00" * (-len(data) % 512)


@dataclass
class RawC3d:
    """A C3D file to write. ``points`` (F, P, 3) in ``units``; ``invalid`` (F, P) samples are
    written as 0, 0, 0 with the fourth word -1; ``residual_bytes``/``cameras`` (F, P) fill the
    fourth word of the others. Frame fields default to the consistent values; set them to
    write files whose fields disagree (``None`` leaves a field out)."""

    points: np.ndarray
    labels: list[str] | None = None
    rate: float = 100.0
    processor: str = "intel"
    integer: bool = False
    scale: float = 0.01          # |POINT:SCALE|: mm per count (integer data), residual units per count
    units: str = "mm"
    invalid: np.ndarray | None = None
    residual_bytes: np.ndarray | None = None
    cameras: np.ndarray | None = None
    analog: np.ndarray | None = None           # (F, samples per frame, channels)
    analog_rate: float | None = None
    rotations: np.ndarray | None = None        # (F, R, 4, 4)
    first_frame: int = 1
    header_first: int | None = None            # default first_frame (saturated at 65535)
    header_last: int | None = None             # default first + F - 1 (saturated at 65535)
    point_frames: int | None = -1              # -1: F (65535 when larger), None: no POINT:FRAMES
    point_frames_float: bool = False
    long_frames: int | None = None
    trial: tuple[int, int] | None = None       # TRIAL:ACTUAL_START_FIELD / END_FIELD
    pad_data: bool = True
    extra_groups: dict[str, list[Param]] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.points.shape[0])

    def expected_positions(self) -> np.ndarray:
        """What a reader should return: (F, P, 3), NaN where invalid, integer data quantised."""
        pos = np.asarray(self.points, np.float64).copy()
        if self.integer:
            pos = np.round(pos / self.scale).astype(np.int16).astype(np.float64) * np.float64(np.float32(self.scale))
        else:
            pos = pos.astype(np.float32).astype(np.float64)
        if self.invalid is not None:
            pos[self.invalid] = np.nan
        return pos

    # ------------------------------------------------------------------ writing
    def _groups(self, data_block: int, rotation_block: int) -> dict[str, list[Param]]:
        proc, F = self.processor, self.n_frames
        P = self.points.shape[1]
        labels = self.labels or [f"M{i:03d}" for i in range(P)]
        point = [int_param("USED", P, proc), int_param("DATA_START", data_block, proc),
                 float_param("SCALE", self.scale if self.integer else -self.scale, proc),
                 float_param("RATE", self.rate, proc), str_param("LABELS", labels),
                 str_param("DESCRIPTIONS", [""] * P), str_param("UNITS", self.units)]
        if self.point_frames is not None:
            frames = min(F, 65535) if self.point_frames == -1 else self.point_frames
            point.append(float_param("FRAMES", frames, proc) if self.point_frames_float
                         else Param("FRAMES", 2, (), encode_ints(np.uint16(frames).view(np.int16), proc)))
        if self.long_frames is not None:
            point.append(float_param("LONG_FRAMES", self.long_frames, proc))
        C = 0 if self.analog is None else self.analog.shape[2]
        analog = [int_param("USED", C, proc), float_param("RATE", self.analog_rate or 0.0, proc)]
        if C:
            analog += [str_param("LABELS", [f"A{i}" for i in range(C)]), float_param("GEN_SCALE", 1.0, proc),
                       float_param("SCALE", np.ones(C), proc), int_param("OFFSET", np.zeros(C, int), proc),
                       str_param("UNITS", ["V"] * C)]
        groups = {"POINT": point, "ANALOG": analog}
        if self.trial is not None:
            groups["TRIAL"] = [Param(key, 2, (2,), encode_ints(np.array([v % 65536, v // 65536], np.uint16)
                                                                .view(np.int16), proc))
                               for key, v in (("ACTUAL_START_FIELD", self.trial[0]),
                                              ("ACTUAL_END_FIELD", self.trial[1]))]
        if self.rotations is not None:
            R = self.rotations.shape[1]
            groups["ROTATION"] = [int_param("USED", R, proc), int_param("DATA_START", rotation_block, proc),
                                  int_param("RATIO", 1, proc), float_param("RATE", self.rate, proc),
                                  str_param("LABELS", [f"R{i}" for i in range(R)])]
        groups.update(self.extra_groups)
        return groups

    def _frames(self) -> bytes:
        proc, F = self.processor, self.n_frames
        P = self.points.shape[1]
        invalid = np.zeros((F, P), bool) if self.invalid is None else np.asarray(self.invalid, bool)
        res = np.ones((F, P), int) if self.residual_bytes is None else np.asarray(self.residual_bytes)
        cams = np.full((F, P), 3) if self.cameras is None else np.asarray(self.cameras)
        fourth = np.where(invalid, -1, (res & 0xFF) | ((cams & 0x7F) << 8))
        words = np.zeros((F, P, 4))
        if self.integer:
            words[..., :3] = np.round(self.points / self.scale)
        else:
            words[..., :3] = self.points
        words[invalid, :3] = 0
        words[..., 3] = fourth
        rows = words.reshape(F, 4 * P)
        if self.analog is not None:
            rows = np.concatenate([rows, self.analog.reshape(F, -1)], axis=1)
        return encode_ints(rows, proc) if self.integer else encode_floats(rows, proc)

    def _rotations(self) -> bytes:
        assert self.rotations is not None
        F, R = self.rotations.shape[:2]
        values = np.concatenate([self.rotations.transpose(0, 1, 3, 2).reshape(F, R, 16),
                                 np.ones((F, R, 1))], axis=2)       # column-major matrix, reliability
        return encode_floats(values, self.processor)

    def to_bytes(self) -> bytes:
        proc, F = self.processor, self.n_frames
        P = self.points.shape[1]
        frames = self._frames()
        size_guess = len(parameter_section(self._groups(0, 0), proc)) + 4
        param_blocks = -(-size_guess // 512)
        data_block = 2 + param_blocks
        frame_bytes = pad(frames) if self.pad_data or self.rotations is not None else frames
        rotation_block = data_block + len(frame_bytes) // 512
        params = parameter_section(self._groups(data_block, rotation_block), proc)
        section = pad(bytes([1, 0x50, param_blocks, PROCESSOR[proc]]) + params)
        assert len(section) == 512 * param_blocks
        C = 0 if self.analog is None else self.analog.shape[2]
        per_frame = 0 if self.analog is None else self.analog.shape[1]
        first = min(self.first_frame, 65535) if self.header_first is None else self.header_first
        last = min(self.first_frame + F - 1, 65535) if self.header_last is None else self.header_last
        end = ">" if proc == "mips" else "<"
        head = struct.pack(end + "BBHHHHH", 2, 0x50, P, C * per_frame, first, last, 0)
        head += encode_floats([self.scale if self.integer else -self.scale], proc)
        head += struct.pack(end + "HH", data_block, per_frame)
        head += encode_floats([self.rate], proc)
        head = head.ljust(512, b"\x00")
        out = head + section + frame_bytes
        if self.rotations is not None:
            out += pad(self._rotations())
        return out

    def write(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_bytes(self.to_bytes())
        return path


def sample_points(n_frames: int = 30, n_points: int = 4, seed: int = 0, gaps: bool = True):
    """Marker-like trajectories (mm, around the lab origin at 1 m height) and a gap mask."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None]
    points = rng.normal(size=(1, n_points, 3)) * 200 + [0, 0, 1000] + 5 * np.sin(t / 7.0 + rng.random(3))
    invalid = np.zeros((n_frames, n_points), bool)
    if gaps and n_frames > 8:
        invalid[3:7, 0] = True
        invalid[-1, n_points - 1] = True
    return points, invalid


def assert_matches_c3d_package(path: str | Path) -> None:
    """Our reader's positions, residuals and view counts equal the ``c3d`` package's
    frame-by-frame decoder (invalid samples: NaN / missing)."""
    import warnings

    import c3d as c3dlib

    import exporters

    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = np.stack([p for _, p, _ in c3dlib.Reader(handle).read_frames(check_nan=True)])
    arrays = exporters.read(path).to_arrays()
    invalid = frames[..., 3] < 0
    assert np.array_equal(np.isnan(arrays.positions[..., 0]), invalid)
    assert np.array_equal(arrays.positions[~invalid], frames[..., :3][~invalid])
    assert np.allclose(arrays.residual[~invalid], frames[..., 3][~invalid], rtol=1e-6)
    views = np.array([int(c).bit_count() for c in frames[..., 4].ravel()]).reshape(invalid.shape)
    assert np.array_equal(arrays.n_views[~invalid], views[~invalid])
