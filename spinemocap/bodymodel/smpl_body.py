"""SMPL, SMPL+H and SMPL-X through the optional ``smplx`` package (``pip install
spinemocap[smpl]``) and the user's own model files.

The model files are licence-gated (SMPL Model License, https://smpl.is.tue.mpg.de; SMPL+H via
https://mano.is.tue.mpg.de; SMPL-X License, https://smpl-x.is.tue.mpg.de): each user registers,
downloads them and passes their path (``--model-path``). Official ``.pkl`` files often hold
``chumpy`` objects, and ``chumpy`` does not build on current Python/numpy: use chumpy-free files
(the ``.npz`` releases, or ``.pkl`` files cleaned of chumpy).

Frames: SMPL's native frame is metres, Y up, facing ``+Z``, the subject's left ``+X``; the
backend returns mm in the studio frame (Z up, facing ``-Y``): ``x' = x, y' = -z, z' = y``.
The pose vector's joint rotations are SMPL's own axis-angle (in SMPL's frame, relative to the
parent) for the body joints; hands, jaw and eyes stay at zero (flat hands, closed jaw).
"""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..fileio import InputError
from ..skin import vertex_normals
from .base import (
    CANONICAL_JOINTS,
    BodyModel,
    RestBody,
    SurfaceAnchors,
    apply_global,
    rotvec_to_matrix,
)

# SMPL frame -> studio frame
SMPL_TO_STUDIO = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
SMPL_JOINTS = ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
               "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
               "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
               "left_wrist", "right_wrist", "left_hand", "right_hand")
_CANONICAL = {"pelvis": "pelvis", "hip_L": "left_hip", "hip_R": "right_hip", "knee_L": "left_knee",
              "knee_R": "right_knee", "ankle_L": "left_ankle", "ankle_R": "right_ankle", "toe_L": "left_foot",
              "toe_R": "right_foot", "spine_base": "pelvis", "neck_base": "neck", "head": "head",
              "shoulder_L": "left_shoulder", "shoulder_R": "right_shoulder", "elbow_L": "left_elbow",
              "elbow_R": "right_elbow", "wrist_L": "left_wrist", "wrist_R": "right_wrist"}
LICENCE = {
    "smpl": "SMPL Model License, https://smpl.is.tue.mpg.de",
    "smplh": "SMPL+H / MANO License, https://mano.is.tue.mpg.de",
    "smplx": "SMPL-X License, https://smpl-x.is.tue.mpg.de",
}


def _missing_files_error(model_type: str, model_path: str | os.PathLike | None) -> InputError:
    return InputError(
        model_path or "model_path",
        f"no {model_type.upper()} model file: these files are licence-gated ({LICENCE[model_type]}) and not "
        "shipped with spinemocap; register, download the model and give its path (model_path): the .npz/.pkl "
        "file or a folder holding smpl/, smplh/, smplx/ subfolders. Use chumpy-free files.")


def load_smplx_module(model_type: str, model_path: str | os.PathLike | None, gender: str = "neutral"):
    """The ``smplx`` torch module for the user's model file, with errors a user can act on."""
    if model_type not in LICENCE:
        raise InputError("model_type", f"unknown SMPL family model {model_type!r}; expected one of {list(LICENCE)}")
    try:
        import smplx
    except ImportError as exc:
        raise InputError("model_type", f"{model_type} needs the optional 'smplx' package: "
                                    "pip install 'spinemocap[smpl]'") from exc
    if model_path is None or not Path(model_path).exists():
        raise _missing_files_error(model_type, model_path)
    path = Path(model_path)
    ext = path.suffix.lstrip(".") if path.is_file() else "npz" if any(path.rglob("*.npz")) else "pkl"
    kwargs: dict[str, object] = {"gender": gender, "ext": ext}
    if model_type == "smpl":
        kwargs["vertex_ids"] = defaultdict(int)  # extra keypoints are not used here
    if model_type in ("smplh", "smplx"):
        kwargs["use_pca"] = False
    try:
        return smplx.create(str(path), model_type=model_type, **kwargs)
    except ModuleNotFoundError as exc:
        if "chumpy" in str(exc):
            raise InputError(path, "this model file holds chumpy objects and chumpy does not build here: "
                                   "use the chumpy-free .npz release or a .pkl cleaned of chumpy") from exc
        raise
    except (AssertionError, OSError, KeyError, ValueError, EOFError) as exc:
        if isinstance(exc, AssertionError) and "does not exist" in str(exc):
            raise _missing_files_error(model_type, model_path) from exc
        raise InputError(path, f"not a readable {model_type.upper()} model file ({type(exc).__name__}: {exc})") from exc


class SmplModel(BodyModel):
    """SMPL / SMPL+H / SMPL-X behind the :class:`~spinemocap.bodymodel.base.BodyModel` interface."""

    shape_bounds = None

    def __init__(self, model_type: str = "smpl", model_path: str | os.PathLike | None = None,
                 gender: str = "neutral", num_betas: int = 10):
        import torch

        self._torch = torch
        module = load_smplx_module(model_type, model_path, gender)
        self.name = model_type
        self.module = module
        self.v_template = module.v_template.double()
        self.shapedirs = module.shapedirs.double()[:, :, :num_betas]
        self.posedirs = module.posedirs.double()  # (P, V*3)
        self.J_regressor = module.J_regressor.double()
        self.parents = module.parents.long()
        self.weights = module.lbs_weights.double()
        self.n_joints = len(self.parents)
        self.shape_names = tuple(f"beta{i}" for i in range(self.shapedirs.shape[-1]))
        n_body = 23 if model_type == "smpl" else 21
        self.pose_joints = SMPL_JOINTS[1 : 1 + n_body]
        self._faces = np.asarray(module.faces, dtype=np.int64)
        self._A = torch.as_tensor(SMPL_TO_STUDIO)
        self._cache: dict[tuple, tuple] = {}

    @property
    def faces(self) -> np.ndarray:
        return self._faces

    def default_shape(self) -> np.ndarray:
        return np.zeros(len(self.shape_names))

    def _shaped(self, shape):
        """(V, 3) shaped template and (J, 3) joints, SMPL frame, metres."""
        torch = self._torch
        if not isinstance(shape, torch.Tensor):
            key = tuple(np.round(np.asarray(shape, float), 12))
            if key not in self._cache:
                self._cache = {key: self._shaped(torch.tensor(key, dtype=torch.float64))}
            return self._cache[key]
        v = self.v_template + torch.einsum("vdb,b->vd", self.shapedirs, shape.double())
        return v, self.J_regressor @ v

    def rest(self, shape: np.ndarray | None = None) -> RestBody:
        shape = self.default_shape() if shape is None else np.asarray(shape, float)
        v, J = (t.detach().numpy() for t in self._shaped(shape))
        vertices = v @ SMPL_TO_STUDIO.T * 1000.0
        joints_all = J @ SMPL_TO_STUDIO.T * 1000.0
        joints = {name: joints_all[SMPL_JOINTS.index(smpl)] for name, smpl in _CANONICAL.items()}
        for side in "LR":
            joints[f"hand_{side}"] = joints[f"wrist_{side}"] + 0.4 * (joints[f"wrist_{side}"] - joints[f"elbow_{side}"])
        near_axis = np.linalg.norm(vertices[:, :2] - joints["head"][:2], axis=1) < 30
        joints["head_top"] = vertices[near_axis][np.argmax(vertices[near_axis, 2])] if near_axis.any() else \
            joints["head"] + np.array([0.0, 0.0, 150.0])
        assert set(joints) == set(CANONICAL_JOINTS)
        chain = joints_all[[SMPL_JOINTS.index(n) for n in ("pelvis", "spine1", "spine2", "spine3", "neck")]]
        return RestBody(vertices, self._faces, joints, vertex_normals(vertices, self._faces), chain)

    def _full_rotations(self, pose):
        torch = self._torch
        F = pose.shape[0]
        body = pose[:, 6:].reshape(F, len(self.pose_joints), 3)
        rest = torch.zeros(F, self.n_joints - 1 - len(self.pose_joints), 3, dtype=pose.dtype)
        rotvecs = torch.cat([torch.zeros(F, 1, 3, dtype=pose.dtype), body, rest], dim=1)
        return rotvec_to_matrix(rotvecs)  # (F, J, 3, 3); the root stays identity (global applied after)

    def points(self, pose, shape, anchors: SurfaceAnchors):
        from smplx.lbs import batch_rigid_transform

        torch = self._torch
        pose = torch.as_tensor(pose, dtype=torch.float64)
        idx = torch.as_tensor(np.asarray(anchors.vertices), dtype=torch.long)
        v_shaped, J = self._shaped(shape)
        F = pose.shape[0]
        rot = self._full_rotations(pose)
        eye = torch.eye(3, dtype=torch.float64)
        pose_feature = (rot[:, 1:] - eye).reshape(F, -1)
        posedirs = self.posedirs.reshape(self.posedirs.shape[0], -1, 3)[:, idx]  # (P, M, 3)
        offsets = torch.as_tensor(anchors.offsets, dtype=torch.float64) @ self._A / 1000.0  # studio -> SMPL, m
        v = v_shaped[idx] + torch.einsum("fp,pmd->fmd", pose_feature, posedirs) + offsets
        _, A = batch_rigid_transform(rot, J.expand(F, -1, -1), self.parents, dtype=torch.float64)
        T = torch.einsum("mj,fjab->fmab", self.weights[idx], A)
        skinned = (T[..., :3, :3] @ v[..., None])[..., 0] + T[..., :3, 3]
        studio = skinned @ self._A.T * 1000.0
        pelvis = (J[0].detach() @ self._A.T * 1000.0).numpy()
        return apply_global(studio, pose, pelvis)

    def vertices(self, pose: np.ndarray, shape: np.ndarray | None = None) -> np.ndarray:
        torch = self._torch
        shape = self.default_shape() if shape is None else np.asarray(shape, float)
        all_vertices = SurfaceAnchors(np.arange(len(self.v_template)), np.zeros((len(self.v_template), 3)))
        with torch.no_grad():
            return self.points(torch.as_tensor(np.atleast_2d(pose)), shape, all_vertices).float().numpy()
