"""The ``anny`` backend (the default): Apache-2.0 parametric human from PyPI, works offline.

anny's native output is in metres, Z up, facing ``-Y`` (the studio's axes): vertices are only
scaled to mm. Shape = anny's six phenotype values in [0, 1] (:data:`PHENOTYPE_KEYS`). Pose:
``local-ref`` deltas (world-aligned rotation vectors about each bone's head) for the bones of
:data:`POSE_BONES`; all other bones (fingers, toes, twist bones, face) keep their rest pose.
"""

from __future__ import annotations

import logging

import numpy as np

from ..skin import anny_model, vertex_normals
from .base import (
    CANONICAL_JOINTS,
    BodyModel,
    RestBody,
    SurfaceAnchors,
    apply_global,
    rotvec_to_matrix,
)

log = logging.getLogger(__name__)

PHENOTYPE_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")
POSE_BONES = (
    "spine05", "spine04", "spine03", "spine02", "spine01", "neck01", "head",
    "clavicle.L", "upperarm01.L", "lowerarm01.L", "wrist.L",
    "clavicle.R", "upperarm01.R", "lowerarm01.R", "wrist.R",
    "upperleg01.L", "lowerleg01.L", "foot.L", "upperleg01.R", "lowerleg01.R", "foot.R",
)
SPINE_CHAIN = ("spine05", "spine04", "spine03", "spine02", "spine01", "neck01")  # heads: S1 ... C7
# Canonical joint -> the anny bone whose head it is (pelvis: between the hips; head_top: the
# top of the skull vertices; hand: middle-finger base).
_JOINT_BONES = {
    "hip_L": "upperleg01.L", "hip_R": "upperleg01.R", "knee_L": "lowerleg01.L", "knee_R": "lowerleg01.R",
    "ankle_L": "foot.L", "ankle_R": "foot.R", "toe_L": "toe3-1.L", "toe_R": "toe3-1.R",
    "spine_base": "spine05", "neck_base": "neck01", "head": "head",
    "shoulder_L": "upperarm01.L", "shoulder_R": "upperarm01.R", "elbow_L": "lowerarm01.L",
    "elbow_R": "lowerarm01.R", "wrist_L": "wrist.L", "wrist_R": "wrist.R",
    "hand_L": "finger3-1.L", "hand_R": "finger3-1.R",
}


class AnnyModel(BodyModel):
    """anny behind the :class:`~spinemocap.bodymodel.base.BodyModel` interface."""

    name = "anny"
    pose_joints = POSE_BONES
    shape_names = PHENOTYPE_KEYS
    shape_bounds = (0.0, 1.0)

    def __init__(self) -> None:
        import torch

        self._torch = torch
        self.model = anny_model()
        self.bone_labels = list(self.model.bone_labels)
        self._pose_bones = torch.tensor([self.bone_labels.index(b) for b in POSE_BONES])
        self._weights = self.model.vertex_bone_weights.double()  # (V, K)
        self._bones = self.model.vertex_bone_indices.long()  # (V, K)
        self._faces = np.asarray(self.model.faces.numpy(), dtype=np.int64)
        self._rest_cache: dict[tuple, dict] = {}

    @property
    def faces(self) -> np.ndarray:
        return self._faces

    def default_shape(self) -> np.ndarray:
        return np.full(len(PHENOTYPE_KEYS), 0.5)

    # ------------------------------------------------------------------ rest model
    def _rest_model(self, shape) -> dict:
        """anny's rest model (float64 torch, metres). A torch ``shape`` is differentiated
        through; a numpy shape is fixed and its rest model cached (the fit's pose stage)."""
        torch = self._torch
        if isinstance(shape, torch.Tensor):
            return self._compute_rest(shape)
        key = tuple(np.round(np.asarray(shape, float), 12))
        if key not in self._rest_cache:
            with torch.no_grad():
                self._rest_cache = {key: self._compute_rest(torch.tensor(key, dtype=torch.float64))}
        return self._rest_cache[key]

    def _compute_rest(self, shape) -> dict:
        pheno = {k: shape[i : i + 1].float() for i, k in enumerate(PHENOTYPE_KEYS)}
        coeffs = self.model.get_phenotype_blendshape_coefficients(**pheno)
        rest = self.model.get_rest_model(coeffs)
        return {"vertices": rest["rest_vertices"][0].double(), "bone_poses": rest["rest_bone_poses"][0].double()}

    def rest(self, shape: np.ndarray | None = None) -> RestBody:
        """The body at the zero pose (anny's reference pose: standing, arms down), which is
        what :meth:`points` and :meth:`vertices` return for a zero pose vector."""
        torch = self._torch
        shape = self.default_shape() if shape is None else np.asarray(shape, float)
        pheno = {k: torch.tensor([float(v)]) for k, v in zip(PHENOTYPE_KEYS, shape)}
        with torch.no_grad():
            out = self.model(pose_parameters=torch.eye(4).repeat(1, len(self.bone_labels), 1, 1),
                             phenotype_kwargs=pheno, pose_parameterization="local-ref")
        vertices = out["vertices"][0].double().numpy() * 1000.0
        heads = out["bone_poses"][0, :, :3, 3].double().numpy() * 1000.0
        joints = {name: heads[self.bone_labels.index(bone)] for name, bone in _JOINT_BONES.items()}
        joints["pelvis"] = self._pelvis(self._rest_model(shape))
        near_axis = np.linalg.norm(vertices[:, :2] - joints["head"][:2], axis=1) < 30
        joints["head_top"] = vertices[near_axis][np.argmax(vertices[near_axis, 2])]
        assert set(joints) == set(CANONICAL_JOINTS)
        chain = np.array([heads[self.bone_labels.index(b)] for b in SPINE_CHAIN])
        return RestBody(vertices, self._faces, joints, vertex_normals(vertices, self._faces), chain)

    # ------------------------------------------------------------------ posing
    def _bone_transforms(self, pose, rest_bone_poses):
        """(F, J, 4, 4) skinning transforms (metres) for torch poses (F, P)."""
        torch = self._torch
        F = pose.shape[0]
        J = rest_bone_poses.shape[0]
        rotations = rotvec_to_matrix(pose[:, 6:].reshape(F, len(POSE_BONES), 3))
        delta = torch.eye(4, dtype=pose.dtype).repeat(F, J, 1, 1)
        delta[:, self._pose_bones, :3, :3] = rotations
        transforms, _ = self.model.get_bone_transforms(
            delta, rest_bone_poses.to(pose.dtype).expand(F, J, 4, 4), pose_parameterization="local-ref")
        return transforms

    def points(self, pose, shape, anchors: SurfaceAnchors):
        """Sparse path; an anchor's offset is given in the zero pose (:meth:`rest`) and turns
        with the blended rotation of its vertex relative to the zero pose."""
        torch = self._torch
        pose = torch.as_tensor(pose, dtype=torch.float64)
        rest = self._rest_model(shape)
        idx = torch.as_tensor(np.asarray(anchors.vertices), dtype=torch.long)
        offsets = torch.as_tensor(anchors.offsets, dtype=torch.float64)
        zero = torch.zeros(1, pose.shape[1], dtype=torch.float64)
        blended = self._blended(torch.cat([pose, zero]), rest, idx)  # (F + 1, M, 3, 4)
        p = rest["vertices"][idx]  # (M, 3) m
        skinned = (blended[:-1, :, :, :3] @ p[None, :, :, None])[..., 0] + blended[:-1, :, :, 3]
        turn = blended[:-1, :, :, :3] @ torch.linalg.inv(blended[-1, :, :, :3])  # (F, M, 3, 3)
        moved = skinned * 1000.0 + (turn @ offsets[None, :, :, None])[..., 0]
        return apply_global(moved, pose, self._pelvis(rest))

    def _blended(self, pose, rest: dict, idx):
        """(F, M, 3, 4) skinning-weight blend of the bone transforms of vertices ``idx``."""
        T = self._bone_transforms(pose, rest["bone_poses"])[:, self._bones[idx]]  # (F, M, K, 4, 4)
        w = self._weights[idx]
        return (w[None, :, :, None, None] * T[..., :3, :]).sum(2)

    def _pelvis(self, rest: dict) -> np.ndarray:
        heads = rest["bone_poses"][:, :3, 3].detach().numpy() * 1000.0
        return (heads[self.bone_labels.index("upperleg01.L")] + heads[self.bone_labels.index("upperleg01.R")]) / 2

    def vertices(self, pose: np.ndarray, shape: np.ndarray | None = None, batch: int = 32) -> np.ndarray:
        torch = self._torch
        shape = self.default_shape() if shape is None else np.asarray(shape, float)
        pose = np.atleast_2d(np.asarray(pose, float))
        rest = self._rest_model(shape)
        pheno = {k: torch.tensor([float(v)]) for k, v in zip(PHENOTYPE_KEYS, shape)}
        out = []
        with torch.no_grad():
            for start in range(0, len(pose), batch):
                chunk = torch.as_tensor(pose[start : start + batch])
                F = len(chunk)
                delta = torch.eye(4).repeat(F, len(self.bone_labels), 1, 1)
                delta[:, self._pose_bones, :3, :3] = rotvec_to_matrix(chunk[:, 6:].reshape(F, -1, 3)).float()
                verts = self.model(pose_parameters=delta, phenotype_kwargs=pheno,
                                   pose_parameterization="local-ref")["vertices"].double() * 1000.0
                out.append(apply_global(verts, chunk, self._pelvis(rest)).float().numpy())
        return np.concatenate(out)
