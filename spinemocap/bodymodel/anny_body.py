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
    PoseKernel,
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
    def _rest_model(self, shape, vertex_ids=None) -> dict:
        """anny's rest model (float64 torch, metres): ``vertices`` (V, 3) (only the rows
        ``vertex_ids`` are meaningful when given) and ``bone_poses`` (J, 4, 4). A torch ``shape``
        is differentiated through, on the ``vertex_ids`` only when given (the fit's shape stage);
        a numpy shape is fixed and its whole rest model cached (the fit's pose stage)."""
        torch = self._torch
        if isinstance(shape, torch.Tensor):
            return self._compute_rest(shape, vertex_ids)
        key = tuple(np.round(np.asarray(shape, float), 12))
        if key not in self._rest_cache:
            with torch.no_grad():
                self._rest_cache = {key: self._compute_rest(torch.tensor(key, dtype=torch.float64))}
        return self._rest_cache[key]

    def _compute_rest(self, shape, vertex_ids=None) -> dict:
        pheno = {k: shape[i : i + 1].float() for i, k in enumerate(PHENOTYPE_KEYS)}
        coeffs = self.model.get_phenotype_blendshape_coefficients(**pheno)
        if vertex_ids is None or not self._sparse_rest_supported():
            rest = self.model.get_rest_model(coeffs)
            return {"vertices": rest["rest_vertices"][0].double(), "bone_poses": rest["rest_bone_poses"][0].double()}
        return {"vertices": self._sparse_rest_vertices(coeffs, vertex_ids),
                "bone_poses": self._rest_bone_poses(coeffs)[0].double()}

    def _sparse_rest_supported(self) -> bool:
        """Whether anny builds its rest bones the way :meth:`_rest_bone_poses` repeats
        ("cached" orientations, anny 0.6)."""
        m = self.model
        return m.bone_orientation == "cached" and hasattr(m, "bone_orientation_blendshapes")

    def _sparse_rest_vertices(self, coeffs, vertex_ids) -> object:
        """(V, 3) rest vertices whose rows ``vertex_ids`` are blended (the others zero): the
        full blend of 13718 vertices x 136 blend shapes was most of the shape stage."""
        torch = self._torch
        idx = torch.as_tensor(np.asarray(vertex_ids), dtype=torch.long)
        m = self.model
        part = m.template_vertices[idx][None] + torch.einsum("cpd,bc->bpd", m.blendshapes[:, idx], coeffs)
        out = torch.zeros(m.template_vertices.shape, dtype=torch.float64)
        return out.index_put((idx,), part[0].double())

    def _rest_bone_poses(self, coeffs):
        """(1, J, 4, 4) rest bone poses: anny's ``_get_cached_rest_model`` without the vertices."""
        import roma

        m = self.model
        heads = m.template_bone_heads[None] + self._torch.einsum("cpd,bc->bpd", m.bone_heads_blendshapes, coeffs)
        M = m.bone_template_orientation_matrices[None] + self._torch.einsum(
            "ba,akij->bkij", coeffs, m.bone_orientation_blendshapes)
        orientation = roma.special_procrustes(M)
        if m.rest_orientation_refiner is not None:
            orientation = m.rest_orientation_refiner(orientation, heads)
        poses = roma.Rigid(linear=orientation, translation=heads).to_homogeneous()
        if m.root_identity_orientation:
            poses[:, 0, :3, :3] = self._torch.eye(3, dtype=poses.dtype)
        return poses

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
        rest = self._rest_model(shape, anchors.vertices)
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

    def pose_kernel(self, shape: np.ndarray, anchors: SurfaceAnchors) -> "AnnyPoseKernel":
        """The fast per-frame path for a fixed shape and fixed anchors: numpy forward kinematics
        over the posed bones only and an analytic pose Jacobian (see :class:`AnnyPoseKernel`)."""
        rest = self._rest_model(np.asarray(shape, float))
        return AnnyPoseKernel(self, rest, anchors)

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


def _rodrigues(rotvecs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) rotation vectors -> (N, 3, 3) matrices R and (N, 3, 3) right Jacobians J_r, with
    R(w + d) ~ R(w) exp([J_r(w) d]x) (series near zero)."""
    theta2 = (rotvecs * rotvecs).sum(-1)[:, None, None]
    small = theta2 < 1e-10
    safe2 = np.where(small, 1.0, theta2)
    safe = np.sqrt(safe2)
    a = np.where(small, 1 - theta2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24, (1 - np.cos(safe)) / safe2)
    c = np.where(small, 1 / 6 - theta2 / 120, (safe - np.sin(safe)) / (safe2 * safe))
    K = _skew(rotvecs)
    KK = K @ K
    eye = np.eye(3)
    return eye + a * K + b * KK, eye - b * K + c * KK


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices."""
    K = np.zeros(v.shape + (3,))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


class AnnyPoseKernel(PoseKernel):
    """anny's sparse path for one shape and fixed anchors, in numpy, with its analytic Jacobian:
    the per-frame pose stage of the marker fit.

    anny's ``local-ref`` forward kinematics (``anny.utils.kinematics.forward_kinematic``): a bone
    c of parent p with rest pose P_c = [R_c | h_c] and reference orientation U_c has the posed
    pose W_c = W_p K_c, K_c = [U_p^T D_c U_c | U_p^T q_c] (q_c: its reference head offset), the
    root's W_0 = I, and skins with T_c = W_c P_c^-1. Only the :data:`POSE_BONES` have a delta D_c,
    so every other bone the anchors need is its nearest posed ancestor's W times a constant, and
    only the 21 posed bones are chained per call (bones that move no anchor are skipped).

    Jacobian: turning bone j's rotation vector w_j by d turns D_j into D_j exp([J_r(w_j) d]x),
    i.e. every bone of j's subtree about j's posed head by the world vector V_j U_j^T J_r(w_j) d
    (V_j: W_j's rotation). A skinned anchor moves by that rotation applied to the part of its
    blend coming from the subtree. The global rotation and translation follow
    :func:`~spinemocap.bodymodel.base.apply_global`. Units: mm, radians; float64.
    """

    def __init__(self, model: AnnyModel, rest: dict, anchors: SurfaceAnchors):
        parents = [int(p) for p in model.model.bone_parents]
        bone_poses = rest["bone_poses"].detach().numpy()
        R, h = bone_poses[:, :3, :3], bone_poses[:, :3, 3]
        reference = model.model.reference_bone_orientations
        U = R if reference is None else reference.double().numpy()
        A = np.concatenate([np.eye(3)[None], U[1:] @ R[1:].transpose(0, 2, 1)])
        parent = np.array([0] + parents[1:])
        q = np.einsum("nij,nj->ni", A[parent], h - h[parent])
        self._posed = [model.bone_labels.index(b) for b in POSE_BONES]
        self._Up_t = U[parent[self._posed]].transpose(0, 2, 1)
        self._Uj = U[self._posed]
        self._Kt = np.einsum("nij,nj->ni", self._Up_t, q[self._posed])
        vertices = np.asarray(anchors.vertices)
        weights = model._weights[vertices].numpy()  # (M, K)
        bones = model._bones[vertices].numpy()  # (M, K)
        used = sorted({int(b) for b, w in zip(bones.ravel(), weights.ravel()) if w > 0})
        # constant K_c (4 x 4) of every bone; posed bones get theirs per call from D_c
        Kc = np.zeros((len(parents), 4, 4))
        Kc[:, :3, :3] = U[parent].transpose(0, 2, 1) @ U
        Kc[:, :3, 3] = np.einsum("nji,nj->ni", U[parent], q)
        Kc[:, 3, 3] = 1.0
        self._K = Kc
        posed_set = set(self._posed)

        def anchor_of(bone: int) -> tuple[int, np.ndarray]:
            """(nearest posed ancestor-or-self or -1 for the root, constant W_anchor^-1 W_bone)."""
            chain = np.eye(4)
            while bone not in posed_set and bone != 0:
                chain = Kc[bone] @ chain
                bone = parent[bone]
            return (-1 if bone == 0 and 0 not in posed_set else self._posed.index(bone)), chain

        self._posed_parent = [anchor_of(parents[j]) for j in self._posed]  # W_j = W_a C K_j(D_j)
        assert all(a < i for i, (a, _) in enumerate(self._posed_parent)), "POSE_BONES must be in tree order"
        used_anchor = [anchor_of(b) for b in used]
        self._used_anchor = np.array([a for a, _ in used_anchor])
        self._used_const = np.array([c for _, c in used_anchor])
        P_inv = np.zeros((len(used), 4, 4))
        P_inv[:, :3, :3] = R[used].transpose(0, 2, 1)
        P_inv[:, :3, 3] = -np.einsum("nji,nj->ni", R[used], h[used])
        P_inv[:, 3, 3] = 1.0
        self._used_const = self._used_const @ P_inv  # T_c = W_a (C_c P_c^-1)
        column = {b: i for i, b in enumerate(used)}
        self._weights = np.where(weights > 0, weights, 0.0)
        self._columns = np.array([[column.get(int(b), 0) for b in row] for row in bones])
        # in_subtree[m, k, j]: anchor m's k-th influence lies in posed bone j's subtree
        descends = np.zeros((len(parents), len(self._posed)), bool)
        for c in range(len(parents)):
            b = c
            while True:
                if b in posed_set:
                    descends[c, self._posed.index(b)] = True
                if b == 0:
                    break
                b = parent[b]
        in_subtree = descends[bones] & (weights > 0)[..., None]  # (M, K, J)
        self._subtree = in_subtree.transpose(0, 2, 1).astype(float)  # (M, J, K)
        self._subtree_weight = self._subtree @ self._weights[..., None]  # (M, J, 1)
        rest_points = rest["vertices"][vertices].detach().numpy()  # (M, 3) m
        blend0 = self._blend(self._transforms(np.zeros(len(self._posed) * 3))[2])
        offsets = np.asarray(anchors.offsets, float)
        offsets_rest = np.einsum("mij,mj->mi", np.linalg.inv(blend0[:, :, :3]), offsets)  # blend-frame offsets
        # each anchor as a homogeneous point in mm that every bone transform (in m) moves:
        # T (1000 p + u) with the translation scaled by 1000
        self._anchor_h = np.concatenate([1000.0 * rest_points + offsets_rest, np.full((len(rest_points), 1), 1000.0)],
                                        axis=1)[:, None, :, None]  # (M, 1, 4, 1)
        self._pelvis = model._pelvis(rest)

    def _transforms(self, joint_rotvecs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Posed poses W_j (J, 4, 4) of the posed bones, their deltas' right Jacobians (J, 3, 3)
        and the skinning transforms T_c (B, 4, 4) of the used bones (metres)."""
        D, Jr = _rodrigues(joint_rotvecs.reshape(-1, 3))
        rotations = self._Up_t @ D @ self._Uj  # K_j's rotation (J, 3, 3)
        W = np.empty((len(self._posed) + 1, 4, 4))
        W[-1] = np.eye(4)  # index -1: the root, W_0 = I
        K = np.zeros((4, 4))
        K[3, 3] = 1.0
        for i, (a, C) in enumerate(self._posed_parent):
            K[:3, :3], K[:3, 3] = rotations[i], self._Kt[i]
            W[i] = W[a] @ C @ K
        return W[:-1], Jr, W[self._used_anchor] @ self._used_const

    def _blend(self, T: np.ndarray) -> np.ndarray:
        """(M, 3, 4) skinning-weight blend of the used bones' transforms for each anchor."""
        return np.einsum("mk,mkij->mij", self._weights, T[self._columns, :3, :])

    def __call__(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Anchors (M, 3) mm (studio frame) for one pose vector (P,), and d anchors / d pose
        (M, 3, P)."""
        pose = np.asarray(pose, float)
        W, Jr, T = self._transforms(pose[6:])
        contrib = self._weights[..., None] * (T[self._columns, :3, :] @ self._anchor_h)[..., 0]  # (M, K, 3) mm
        local = contrib.sum(1)
        # subtree parts of each anchor about each posed bone's head (M, J, 3)
        lever = self._subtree @ contrib - 1000.0 * self._subtree_weight * W[:, :3, 3]
        axes = W[:, :3, :3] @ self._Uj.transpose(0, 2, 1) @ Jr  # (J, 3, 3) world turn per unit rotvec
        joint_jac = -_skew(lever) @ axes[None]  # (M, J, 3, 3)
        Rg, Jg = _rodrigues(pose[None, 3:6])
        Rg, Jl = Rg[0], Jg[0].T
        centred = (local - self._pelvis) @ Rg.T
        M = len(local)
        jac = np.empty((M, 3, len(pose)))
        jac[:, :, 0:3] = np.eye(3)
        jac[:, :, 3:6] = -_skew(centred) @ Jl
        jac[:, :, 6:] = (Rg @ joint_jac).transpose(0, 2, 1, 3).reshape(M, 3, -1)
        return centred + self._pelvis + pose[:3], jac
