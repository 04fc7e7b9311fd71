"""Skin strain under the tape: the back's skin lengthens in flexion, shortens in extension and
stretches on the convex side in lateral bending, more over the lumbar spine than the thorax.

anny's linear-blend skinning barely stretches the skin of the back (a 27 deg
``mixed`` motion stretched the tape by 3.2 % over its length), so the studio imposes the strain
of a real back on top of it: :class:`SkinStrain` gives the *total* strain of the skin relative
to standing, and :class:`spinemocap.synth.tape_on_skin.TapeOnSkin` slides the tape's material
points along anny's surface until their arc lengths follow it.

Source figures (the clinical tests they come from):

- Modified Schober test: 15 cm of skin marked over the lumbar spine from the lumbosacral junction
  up lengthen by 5 cm or more (>= 33 %) at full forward flexion in a healthy adult, less with age
  and back pain. Model: the lumbar skin (S1 .. L1) lengthens by ``lumbar_gain`` at full flexion,
  drawn per subject in :data:`LUMBAR_GAIN_RANGE` (4.5-6 cm over 15 cm: "about a third").
- The strain grows in proportion to the flexion angle ("proportionally less at smaller angles"):
  ``lumbar_gain * flexion / FULL_FLEXION_DEG``. :data:`FULL_FLEXION_DEG` is the studio's full
  forward flexion (the ``flexion`` motion's peak, toe touch): 70 deg between the pelvis and
  anny's ``spine01`` (lumbar flexion of ~50-60 deg plus the lower thorax).
- Extension shortens the skin: the Schober distance drops by about 1-2 cm of 15 cm at full
  extension (order of 10 %); model: ``-EXTENSION_SHORTENING * |angle| / FULL_EXTENSION_DEG``
  (modelling figure, the clinical extension measure is less standardised).
- Over the thorax the skin stretches much less (Ott's sign: 30 cm below C7 lengthen by 2-4 cm,
  7-13 %, at full flexion, against >= 33 % lumbar): the strain falls linearly from the lumbar
  value at L1 to ``thorax_ratio`` of it at T10 and above (per subject, :data:`THORAX_RATIO_RANGE`);
  the skin over the sacrum (below S1) does not stretch.
- Across the tape the skin stretches less: ``transverse_ratio`` (:data:`TRANSVERSE_RATIO_RANGE`)
  of the longitudinal strain (modelling figure).
- Lateral bending stretches the convex side and shortens the concave one like a bent beam:
  ``strain = offset * bend / LATERAL_BENDING_LENGTH_MM`` with the lateral offset from the
  midline (mm), the bend in radians and the lumbar length over which lateral bending happens
  (geometric figure, about +-6 % at the tape's edges for 30 deg).
- Axial rotation shears the skin; the model ignores it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FULL_FLEXION_DEG = 70.0
FULL_EXTENSION_DEG = 30.0
EXTENSION_SHORTENING = 0.10
LUMBAR_GAIN_RANGE = (0.30, 0.40)
THORAX_RATIO_RANGE = (0.20, 0.35)
TRANSVERSE_RATIO_RANGE = (0.20, 0.30)
LATERAL_BENDING_LENGTH_MM = 200.0
SCHOBER_SEGMENT_MM = 150.0  # the modified Schober test's lumbar segment, from the lumbosacral junction up


@dataclass(frozen=True)
class StrainRegions:
    """Where the strain profile changes along the tape's arc-length coordinate ``s`` (mm on the
    rest back): the lumbosacral junction (S1), the top of the lumbar spine (L1) and the thorax (T10)."""

    s_sacrum: float
    s_lumbar_top: float
    s_thorax: float


@dataclass(frozen=True)
class SkinStrain:
    """One subject's skin: the strain figures of the module docstring (``scale`` 0 turns it off)."""

    lumbar_gain: float = 0.35
    thorax_ratio: float = 0.27
    transverse_ratio: float = 0.25
    scale: float = 1.0

    @classmethod
    def for_subject(cls, seed: int, scale: float = 1.0) -> SkinStrain:
        """Per-subject figures drawn from the seed (ranges in the module docstring)."""
        rng = np.random.default_rng([int(seed), 5])
        return cls(lumbar_gain=float(rng.uniform(*LUMBAR_GAIN_RANGE)),
                   thorax_ratio=float(rng.uniform(*THORAX_RATIO_RANGE)),
                   transverse_ratio=float(rng.uniform(*TRANSVERSE_RATIO_RANGE)), scale=float(scale))

    @property
    def enabled(self) -> bool:
        return self.scale != 0

    def profile(self, s: np.ndarray, regions: StrainRegions) -> np.ndarray:
        """Weight (0..1) of the lumbar strain at arc lengths ``s`` (mm): 0 over the sacrum (ramping
        up over the 20 mm below S1), 1 from S1 to L1, falling to ``thorax_ratio`` at T10."""
        s = np.asarray(s, float)
        up = np.clip((s - regions.s_sacrum + 20.0) / 20.0, 0.0, 1.0)
        span = max(regions.s_thorax - regions.s_lumbar_top, 1.0)
        down = 1.0 - (1.0 - self.thorax_ratio) * np.clip((s - regions.s_lumbar_top) / span, 0.0, 1.0)
        return up * down

    def flexion_strain(self, flexion_deg: float) -> float:
        """Lumbar longitudinal strain at a sagittal angle (deg, flexion positive, extension negative)."""
        if flexion_deg >= 0:
            return self.scale * self.lumbar_gain * flexion_deg / FULL_FLEXION_DEG
        return -self.scale * EXTENSION_SHORTENING * (-flexion_deg) / FULL_EXTENSION_DEG

    def longitudinal(self, s: np.ndarray, u: np.ndarray, angles_deg: np.ndarray, regions: StrainRegions) -> np.ndarray:
        """Strain along the tape at (``s`` along, ``u`` across toward the subject's right) mm for
        [flexion, lateral bending (positive to the right), axial rotation] degrees."""
        weight = self.profile(s, regions)
        lateral = -np.asarray(u, float) * np.radians(angles_deg[1]) / LATERAL_BENDING_LENGTH_MM
        return np.maximum(weight * (self.flexion_strain(float(angles_deg[0])) + self.scale * lateral), -0.5)

    def transverse(self, s: np.ndarray, angles_deg: np.ndarray, regions: StrainRegions) -> np.ndarray:
        """Strain across the tape at arc lengths ``s`` (mm)."""
        return self.transverse_ratio * self.profile(s, regions) * self.flexion_strain(float(angles_deg[0]))
