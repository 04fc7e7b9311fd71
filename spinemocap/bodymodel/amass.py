"""AMASS motion files (``.npz``) in both layouts, read into one :class:`AmassMotion`.

- SMPL+H layout: ``poses`` (N, 156) axis-angle (root 3, body 63, hands 90), ``betas``, ``trans``
  (N, 3) m, ``gender``, ``mocap_framerate``.
- SMPL-X layout: ``root_orient`` (N, 3), ``pose_body`` (N, 63), ``pose_hand`` (N, 90),
  ``pose_jaw`` (N, 3), ``pose_eye`` (N, 6), ``trans``, ``betas``, ``gender``,
  ``mocap_frame_rate``.

Values stay in AMASS's own frame and units (metres, Z up as AMASS ships them); see
:meth:`AmassMotion.body_pose_vector` for the pose vector of the SMPL backends.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..fileio import InputError


@dataclass
class AmassMotion:
    """One AMASS sequence: ``root_orient`` (N, 3), ``pose_body`` (N, 63) (21 body joints),
    ``pose_hand`` (N, 90), ``pose_jaw`` (N, 3) (zeros for SMPL+H), ``trans`` (N, 3) m,
    ``betas`` (B,), ``gender``, ``fps`` and ``layout`` ('smplh' | 'smplx')."""

    root_orient: np.ndarray
    pose_body: np.ndarray
    pose_hand: np.ndarray
    pose_jaw: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    gender: str
    fps: float
    layout: str

    @property
    def n_frames(self) -> int:
        return len(self.trans)


def _text(value) -> str:
    value = np.asarray(value)
    text = value.item() if value.shape == () else value.ravel()[0]
    return text.decode() if isinstance(text, bytes) else str(text)


def load_amass(path: str | os.PathLike) -> AmassMotion:
    """Read an AMASS ``.npz`` of either layout (see the module docstring)."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
        keys = set(data.files)
    except (OSError, ValueError) as exc:
        raise InputError(path, f"not a readable .npz file ({exc})") from exc

    def need(*names: str) -> None:
        missing = [n for n in names if n not in keys]
        if missing:
            raise InputError(path, f"AMASS file lacks {missing} (has {sorted(keys)})")

    gender = _text(data["gender"]) if "gender" in keys else "neutral"
    if "poses" in keys:
        need("poses", "trans", "betas", "mocap_framerate")
        poses = np.asarray(data["poses"], float)
        if poses.ndim != 2 or poses.shape[1] < 66:
            raise InputError(path, f"'poses' has shape {poses.shape}; expected (N, 156) SMPL+H axis-angle")
        n = len(poses)
        hands = poses[:, 66:156] if poses.shape[1] >= 156 else np.zeros((n, 90))
        motion = AmassMotion(poses[:, :3], poses[:, 3:66], hands, np.zeros((n, 3)), np.asarray(data["trans"], float),
                             np.asarray(data["betas"], float).ravel(), gender, float(data["mocap_framerate"]), "smplh")
    elif "root_orient" in keys:
        need("root_orient", "pose_body", "trans", "betas", "mocap_frame_rate")
        n = len(data["root_orient"])
        motion = AmassMotion(np.asarray(data["root_orient"], float), np.asarray(data["pose_body"], float),
                             np.asarray(data["pose_hand"], float) if "pose_hand" in keys else np.zeros((n, 90)),
                             np.asarray(data["pose_jaw"], float) if "pose_jaw" in keys else np.zeros((n, 3)),
                             np.asarray(data["trans"], float), np.asarray(data["betas"], float).ravel(), gender,
                             float(data["mocap_frame_rate"]), "smplx")
    else:
        raise InputError(path, "neither the SMPL+H ('poses') nor the SMPL-X ('root_orient', 'pose_body') AMASS "
                               f"layout (keys: {sorted(keys)})")
    for name in ("root_orient", "pose_body", "trans"):
        if len(getattr(motion, name)) != motion.n_frames:
            raise InputError(path, f"'{name}' has {len(getattr(motion, name))} frames, 'trans' {motion.n_frames}")
    if motion.pose_body.shape[1] != 63:
        raise InputError(path, f"body pose has {motion.pose_body.shape[1]} values per frame; expected 63")
    return motion
