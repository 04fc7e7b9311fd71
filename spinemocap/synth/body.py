"""The synthetic athlete: an ``anny`` body with a chosen phenotype, posed through its spine bones.

World frame of the studio (mm, Z up): the subject stands with the feet on ``z = 0``, the pelvis
above the origin, facing ``-Y`` (so the back, and the tape, face ``+Y``); the subject's left is
``+X``. These are anny's own axes, translated so the soles touch the floor.

Spine motion is applied to ``spine05`` ... ``spine01`` (sacral to thoracic) with anny's
``local-ref`` pose parameterisation, where each bone's delta rotation is expressed in world-aligned
axes about the bone's head. Each of the five bones takes one fifth of the commanded angles; the
angles recorded as ground truth are measured back from the posed skeleton (see
:func:`spine_angles_from_rotation`), so they are exact even where the per-bone split composes to
slightly different totals.

Where the spine bends under the skin (:data:`JointDepth`): at anny's own joints, or at joints
moved forward to the published depth of the vertebral bodies, where the rigid part of the back
skin's lengthening in flexion (depth x angle) takes a real back's share and the skin's slide over
the vertebrae is the smaller rest.
"""

from __future__ import annotations

import copy
import logging
import math
from typing import Literal

import numpy as np

from ..anatomy import VERTEBRAE, centre_spacing, skin_depth
from ..skin import SURFACE_LEVELS, anny_model, cast_onto_skin, surface_level_heights

log = logging.getLogger(__name__)

SPINE_BONES = ("spine05", "spine04", "spine03", "spine02", "spine01")
PHENOTYPE_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")
ANGLE_NAMES = ("flexion", "lateral_bending", "axial_rotation")

#: Where the studio's spine bends under the skin: ``anny`` (anny's own joints, 28-40 mm under the
#: back skin, shallower than a real back's vertebral bodies) or ``anatomical`` (each spine joint
#: moved forward to the published skin-to-vertebral-body depth of its level, 53-76 mm on a generic
#: adult, scaled to the body; :meth:`Body.anatomical_joint_depths`).
JointDepth = Literal["anny", "anatomical"]
JOINT_DEPTHS: tuple[JointDepth, ...] = ("anny", "anatomical")
# the anthropometry table's column from the sacrum up, and the surface levels it lacks
ANATOMY_LEVELS = tuple(reversed(VERTEBRAE))
ANATOMY_ALIAS = {"S2": "S1", "C7": "T1"}

# Vertebral levels from the sacrum (S2) to the vertebra prominens (C7): the core's one level table,
# placed on anny from published surface anatomy by :func:`spinemocap.skin.surface_level_heights`
# (see :meth:`Body.level_heights`), as the body models place theirs.
LEVELS = SURFACE_LEVELS


def rotation_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rotation_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rotation_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotation_from_spine_angles(angles_deg) -> np.ndarray:
    """World rotation for [flexion, lateral bending, axial rotation] in degrees.

    Cardan sequence X-Y-Z in the body frame (X = subject's left, Y = backward, Z = up):
    flexion about X (positive bends the head forward, toward -Y), lateral bending about Y with its
    sign flipped (positive bends toward the subject's right, -X), axial rotation about Z (positive
    turns to the subject's left, counter-clockwise seen from above).
    """
    f, lat, r = np.radians(np.asarray(angles_deg, float))
    return rotation_x(f) @ rotation_y(-lat) @ rotation_z(r)


def spine_angles_from_rotation(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotation_from_spine_angles`: (3, 3) rotation -> (3,) degrees."""
    # R = Rx(a) Ry(b) Rz(c): R[0,2] = sin b, R[1,2] = -sin a cos b, R[2,2] = cos a cos b,
    # R[0,1] = -cos b sin c, R[0,0] = cos b cos c.
    b = math.asin(max(-1.0, min(1.0, R[0, 2])))
    a = math.atan2(-R[1, 2], R[2, 2])
    c = math.atan2(-R[0, 1], R[0, 0])
    return np.degrees([a, -b, c])


class Body:
    """An anny body of one phenotype: rest mesh, spine chain and posing. Lengths in mm."""

    def __init__(self, phenotype: dict[str, float] | None = None, joint_depth: JointDepth = "anny"):
        import torch

        if joint_depth not in JOINT_DEPTHS:
            raise ValueError(f"unknown joint depth {joint_depth!r} (choose from {list(JOINT_DEPTHS)})")
        # a body that moves its joints edits its own copy of the shared model (50 MB, 0.2 s)
        self.model = anny_model() if joint_depth == "anny" else copy.deepcopy(anny_model())
        self.phenotype = {k: 0.5 for k in PHENOTYPE_KEYS}
        self.phenotype.update(phenotype or {})
        self.joint_depth = joint_depth
        self.bone_labels = list(self.model.bone_labels)
        self._spine_index = [self.bone_labels.index(b) for b in SPINE_BONES]
        self._torch = torch
        self._top = self.bone_labels.index(SPINE_BONES[-1])
        self._set_rest()
        if joint_depth == "anatomical":
            # the rest mesh moves by ~1-2 mm when the joints do, so a second pass meets the target
            for _ in range(2):
                self._deepen_spine_joints(np.maximum(self.anatomical_joint_depths() - self.spine_joint_depths(), 0.0))

    def _set_rest(self) -> None:
        """The rest pose from the model as it stands: mesh, faces, bone heads (mm, studio frame)."""
        # The neutral pose (identity deltas = anny's reference pose, arms down) is the "rest"
        # pose of the studio: the tape is laid on it and angles are measured from it.
        with self._torch.no_grad():
            out = self._forward(np.zeros((1, 3)))
        neutral = out["vertices"][0].double().numpy() * 1000.0
        self.floor_offset = np.array([0.0, 0.0, -neutral[:, 2].min()])
        self.rest_vertices = neutral + self.floor_offset  # (V, 3) mm
        self.faces = np.asarray(self.model.faces.numpy(), dtype=np.int64)  # (T, 3)
        heads = out["bone_poses"][0, :, :3, 3].double().numpy() * 1000.0 + self.floor_offset
        self.rest_bone_heads = {name: heads[i] for i, name in enumerate(self.bone_labels)}
        self._neutral_top = out["bone_poses"][0, self._top, :3, :3].double().numpy()

    def _deepen_spine_joints(self, forward_mm: np.ndarray) -> None:
        """Move the heads of :data:`SPINE_BONES` forward (``-Y``) by ``forward_mm`` (5,) mm in the
        model's template, so that the spine bends about them, and rebuild the rest pose."""
        heads = self.model.template_bone_heads.clone()  # metres
        heads[self._spine_index, 1] -= self._torch.as_tensor(forward_mm / 1000.0, dtype=heads.dtype)
        self.model.template_bone_heads = heads
        self._set_rest()

    # ------------------------------------------------------------------ posing
    def _pose_parameters(self, angles_deg: np.ndarray):
        """(F, 3) commanded spine angles -> (F, B, 4, 4) local-ref deltas."""
        F = len(angles_deg)
        P = np.tile(np.eye(4), (F, len(self.bone_labels), 1, 1))
        share = np.asarray(angles_deg, float) / len(SPINE_BONES)
        for f in range(F):
            D = rotation_from_spine_angles(share[f])
            for i in self._spine_index:
                P[f, i, :3, :3] = D
        return self._torch.as_tensor(P, dtype=self._torch.float32)

    def _forward(self, angles_deg: np.ndarray):
        pheno = {k: self._torch.tensor([float(v)]) for k, v in self.phenotype.items()}
        return self.model(
            pose_parameters=self._pose_parameters(angles_deg),
            phenotype_kwargs=pheno,
            pose_parameterization="local-ref",
        )

    def pose(self, angles_deg: np.ndarray, batch: int = 64) -> tuple[np.ndarray, np.ndarray]:
        """Pose the body for (F, 3) commanded [flexion, lateral, rotation] angles (degrees).

        Returns ``vertices`` (F, V, 3) float32 mm in the studio frame and the applied angles
        (F, 3) degrees measured from the posed skeleton: the rotation of ``spine01`` from its
        neutral orientation (the pelvis does not move), decomposed as in :func:`rotation_from_spine_angles`.
        """
        angles_deg = np.atleast_2d(np.asarray(angles_deg, float))
        verts, applied = [], []
        with self._torch.no_grad():
            for start in range(0, len(angles_deg), batch):
                out = self._forward(angles_deg[start : start + batch])
                v = out["vertices"].double().numpy() * 1000.0 + self.floor_offset
                verts.append(v.astype(np.float32))
                W = out["bone_poses"][:, self._top, :3, :3].double().numpy()
                for Wf in W:
                    applied.append(spine_angles_from_rotation(Wf @ self._neutral_top.T))
        return np.concatenate(verts), np.array(applied)

    # ------------------------------------------------------------------ anatomy
    def spine_chain(self) -> np.ndarray:
        """(K, 3) rest positions (mm) of anny's spine joints from the ``spine05`` head (pelvis) to
        the ``neck01`` head (cervico-thoracic junction)."""
        names = list(SPINE_BONES) + ["neck01"]
        return np.array([self.rest_bone_heads[n] for n in names])

    def spine_joint_depths(self) -> np.ndarray:
        """(5,) depth (mm) of each :data:`SPINE_BONES` head under the back skin at rest: from the
        joint backward (``+Y``) to the first skin met coming from behind."""
        heads = np.array([self.rest_bone_heads[n] for n in SPINE_BONES])
        behind = heads + np.array([0.0, 100.0, 0.0])  # the ray runs from 200 mm behind the joint to it
        _, hits = cast_onto_skin(self.rest_vertices, self.faces, behind, np.tile([0.0, -1.0, 0.0], (len(heads), 1)))
        return hits[:, 1] - heads[:, 1]

    def anatomical_joint_depths(self) -> np.ndarray:
        """(5,) published skin-to-vertebral-body-centre depth (mm, :func:`spinemocap.anatomy.skin_depth`)
        of the vertebra at each :data:`SPINE_BONES` head's rest height (S2 counts as S1, C7 as T1),
        scaled to this body by its S1-T1 height over the generic column's S1-T1 centre distance."""
        heights = self.level_heights()
        generic = sum(centre_spacing(upper, lower) for lower, upper in zip(ANATOMY_LEVELS[:-1], ANATOMY_LEVELS[1:]))
        scale = (heights["T1"] - heights["S1"]) / generic
        names = [ANATOMY_ALIAS.get(level, level) for level in
                 (self.nearest_level(self.rest_bone_heads[n][2]) for n in SPINE_BONES)]
        return scale * np.array([skin_depth(name) for name in names])

    def level_heights(self) -> dict[str, float]:
        """Rest height z (mm) of each vertebral level in :data:`LEVELS`: S2 at the PSIS, C7 at
        the cervico-thoracic junction (anny's ``neck01`` head), the levels between spread by
        typical segment heights (:func:`spinemocap.skin.surface_level_heights`)."""
        heads = self.rest_bone_heads
        return surface_level_heights(heads["upperleg01.L"], heads["upperleg01.R"], heads["neck01"])

    def junction_height(self, lower: str, upper: str) -> float:
        """Rest height (mm) of the junction between two adjacent levels, e.g. ``("L1", "T12")``."""
        heights = self.level_heights()
        return 0.5 * (heights[lower] + heights[upper])

    def nearest_level(self, z_mm: float) -> str:
        heights = self.level_heights()
        return min(heights, key=lambda name: abs(heights[name] - z_mm))

