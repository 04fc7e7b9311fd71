"""Calibration file formats, picked by file name.

=================  ==================================  ===========
extension          format                              read/write
=================  ==================================  ===========
``.toml``          our rig TOML (:meth:`Rig.to_toml`)   read/write
``.toml``          Pose2Sim / Anipose calibration       read/write (``fmt="pose2sim"``; sniffed on read)
``.qca.txt``       Qualisys QTM export                  read
``.xcp``           Vicon Nexus camera calibration       read/write
=================  ==================================  ===========
"""

from __future__ import annotations

import os
from pathlib import Path

from spinemocap.camera import Rig
from spinemocap.fileio import InputError, read_toml, reading

from .pose2sim import is_pose2sim, read_pose2sim, rig_from_pose2sim, write_pose2sim
from .qualisys import read_qca
from .vicon import read_xcp, write_xcp

FORMATS = ("spinemocap", "pose2sim", "qualisys", "vicon")


def detect_format(path: str | os.PathLike) -> str:
    name = Path(path).name.lower()
    if name.endswith(".qca.txt"):
        return "qualisys"
    if name.endswith(".xcp"):
        return "vicon"
    if name.endswith(".toml"):
        return "toml"
    raise InputError(path, "unknown calibration format; expected .toml (ours or Pose2Sim/Anipose), "
                     ".qca.txt (Qualisys) or .xcp (Vicon)")


def read_rig(path: str | os.PathLike) -> Rig:
    """Read any supported calibration file as a :class:`Rig` (mm, world -> camera)."""
    fmt = detect_format(path)
    with reading(path, "calibration"):
        if fmt == "qualisys":
            return read_qca(path)
        if fmt == "vicon":
            return read_xcp(path)
        data = read_toml(path)
        return rig_from_pose2sim(data, path) if is_pose2sim(data) else Rig.from_dict(data, source=str(path))


def write_rig(rig: Rig, path: str | os.PathLike, fmt: str | None = None) -> None:
    """Write ``rig``; ``fmt`` ("spinemocap" or "pose2sim" for .toml) defaults to ours."""
    kind = detect_format(path)
    if kind == "qualisys":
        raise InputError(path, "writing Qualisys .qca.txt is not supported (read only)")
    if kind == "vicon":
        write_xcp(rig, path)
    elif fmt == "pose2sim":
        write_pose2sim(rig, path)
    elif fmt in (None, "spinemocap"):
        rig.to_toml(path)
    else:
        raise InputError(path, f"format {fmt!r} cannot be written as .toml (use spinemocap or pose2sim)")


__all__ = ["read_rig", "write_rig", "detect_format", "read_qca", "read_xcp", "write_xcp",
           "read_pose2sim", "write_pose2sim", "FORMATS"]
