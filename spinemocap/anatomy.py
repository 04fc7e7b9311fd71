"""Published thoracolumbar anthropometry the spine model is built from (generic adult, mm, degrees).

The numbers below were entered as rounded mid values of the cited tables (not copied from a
file); check them against the papers before relying on a single level's value. The model uses
their ratios along the column, and the tape scales them to the subject.

Every vertebra from T1 to L5 plus S1 (the sacral plateau) carries:

- ``body_height``: vertebral body height (mean of anterior and posterior), and ``disc_below``:
  height of the intervertebral disc under it. Thoracic bodies: approximate mid values of the
  tables of Panjabi MM, Takata K, Goel V et al. (1991) "Thoracic human vertebrae: quantitative
  three-dimensional anatomy", Spine 16(8):888-901 (posterior body height rising from ~14 mm at
  T1 to ~23 mm at T12). Lumbar bodies: Panjabi MM, Goel V, Oxland T et al. (1992) "Human lumbar
  vertebrae: quantitative three-dimensional anatomy", Spine 17(3):299-306 (~25-28 mm). Discs:
  thoracic 4-6 mm, lumbar 9-12 mm (typical adult values, lumbar as in Gilad I, Nissan M (1986)
  "A study of vertebra and disc geometric relations of the human cervical and lumbar spine",
  Spine 11(2):154-157).
  Only their ratios matter: the column is scaled to the subject by the tape (see
  :mod:`spinemocap.opensim.geometry`).
- ``body_depth`` and ``body_width``: upper end-plate depth and width (same Panjabi tables),
  used for the depth of the vertebral body centre under the skin and the display ellipsoids.
- ``posterior``: skin-to-vertebral-body-centre depth minus half the body depth, i.e. spinal
  canal depth (Panjabi 1991/1992: ~15 mm thoracic, ~17 mm lumbar) + lamina/spinous process to
  its tip (~25-30 mm) + soft tissue over the spinous process (~8-12 mm in lean adults). This is
  the least certain number here; the placement check reports how far the placed markers sit
  from it, and MarkerPlacer uses the measured static positions in any case.

Range of motion per motion segment, stored on the segment's upper vertebra (``L4`` = the
L4/L5 joint): representative values of White AA, Panjabi MM (1990) *Clinical
Biomechanics of the Spine*, 2nd ed. (their tables of representative thoracic and lumbar values):
flexion+extension, lateral bending to one side, axial rotation to one side. The lateral and
axial values are also the coupling ratios that share a region's lateral bending and axial
rotation between its joints (as the coordinate couplers of the published lumbar model of
Christophy M et al. (2012) Biomech Model Mechanobiol 11:19-34 and the thoracolumbar model of
Bruno AG et al. (2015) J Biomech Eng 137:081003 do).

Segment masses (for a valid model only: inverse kinematics does not use them): share of body
mass per vertebral level after Pearsall DJ, Reid JG, Livingston LA (1996) "Segmental inertial
parameters of the human trunk as determined from computed tomography", Ann Biomed Eng
24:198-210 (about 1.1 % per upper thoracic level rising to about 2.6 % per lower lumbar level).
"""

from __future__ import annotations

from dataclasses import dataclass

# cranial -> caudal order is anatomical reading order; the model chain runs caudal -> cranial.
VERTEBRAE = ("T1", "T2", "T3", "T4", "T5", "T6", "T7", "T8", "T9", "T10", "T11", "T12",
             "L1", "L2", "L3", "L4", "L5", "S1")


@dataclass(frozen=True)
class Vertebra:
    """Generic dimensions (mm) and the motion segment below it (deg); see the module docstring."""

    name: str
    body_height: float
    disc_below: float
    body_depth: float
    body_width: float
    posterior: float
    flexion_extension_rom: float  # of the motion segment between this vertebra and the one below
    lateral_rom: float  # one side, same segment
    axial_rom: float  # one side, same segment
    mass_share: float  # of body mass

    @property
    def region(self) -> str:
        """``thoracic``, ``lumbar`` or ``sacral`` by the vertebra's own name."""
        return {"T": "thoracic", "L": "lumbar", "S": "sacral"}[self.name[0]]


# ROM columns: the motion segment between this vertebra and the next caudal one (T1 -> T1/T2,
# T12 -> T12/L1, L5 -> L5/S1); S1 has none.
#                 name  height disc  depth width post  F/E  lat  axial mass%
_TABLE = [
    Vertebra("T1", 14.5, 4.0, 16.0, 28.0, 45.0, 4.0, 6.0, 9.0, 1.1),
    Vertebra("T2", 16.0, 4.0, 16.5, 27.0, 45.0, 4.0, 6.0, 8.0, 1.1),
    Vertebra("T3", 16.5, 4.0, 17.0, 26.5, 45.0, 4.0, 6.0, 8.0, 1.4),
    Vertebra("T4", 17.0, 4.5, 18.0, 26.5, 46.0, 4.0, 6.0, 8.0, 1.3),
    Vertebra("T5", 17.5, 4.5, 19.0, 27.5, 46.0, 4.0, 6.0, 8.0, 1.3),
    Vertebra("T6", 18.0, 4.5, 21.0, 29.0, 47.0, 5.0, 6.0, 8.0, 1.3),
    Vertebra("T7", 18.5, 5.0, 23.0, 31.0, 48.0, 6.0, 6.0, 8.0, 1.4),
    Vertebra("T8", 19.0, 5.0, 25.0, 33.0, 49.0, 6.0, 6.0, 7.0, 1.5),
    Vertebra("T9", 19.5, 5.5, 27.0, 35.0, 50.0, 6.0, 6.0, 4.0, 1.6),
    Vertebra("T10", 20.5, 6.0, 29.0, 38.0, 51.0, 9.0, 7.0, 2.0, 2.0),
    Vertebra("T11", 21.5, 6.5, 30.0, 41.0, 52.0, 12.0, 9.0, 2.0, 2.1),
    Vertebra("T12", 23.0, 8.0, 31.0, 43.0, 54.0, 12.0, 8.0, 2.0, 2.5),
    Vertebra("L1", 25.5, 9.5, 33.0, 43.0, 56.0, 12.0, 6.0, 2.0, 2.4),
    Vertebra("L2", 26.5, 10.5, 34.0, 45.0, 57.0, 14.0, 6.0, 2.0, 2.4),
    Vertebra("L3", 27.0, 11.0, 35.0, 48.0, 58.0, 15.0, 8.0, 2.0, 2.3),
    Vertebra("L4", 26.5, 11.5, 35.0, 50.0, 58.0, 16.0, 6.0, 2.0, 2.6),
    Vertebra("L5", 26.0, 11.0, 34.0, 52.0, 57.0, 17.0, 3.0, 1.0, 2.6),
    Vertebra("S1", 30.0, 0.0, 36.0, 50.0, 55.0, 0.0, 0.0, 0.0, 0.0),
]
ANATOMY: dict[str, Vertebra] = {v.name: v for v in _TABLE}


def centre_spacing(upper: str, lower: str) -> float:
    """Generic distance (mm) between the body centres of two adjacent vertebrae."""
    a, b = ANATOMY[upper], ANATOMY[lower]
    return 0.5 * a.body_height + a.disc_below + 0.5 * b.body_height


def skin_depth(name: str) -> float:
    """Generic depth (mm) of the vertebral body centre under the skin over the spinous process."""
    v = ANATOMY[name]
    return v.posterior + 0.5 * v.body_depth
