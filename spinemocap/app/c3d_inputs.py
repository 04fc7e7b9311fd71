"""Domain inputs that arrive as C3D files, read with the one C3D reader (``exporters.read``) and
handed to the domain packages as marker tables (calibration and analysis depend on core only)."""

from __future__ import annotations

import os

import numpy as np

import exporters
from calibration.wand import ViconWand, WandSpec, vicon_wand_from_table

from ..analysis.frames import pelvis_markers
from ..markers import MarkerTable


def read_vicon_wand(path: str | os.PathLike, wand: WandSpec) -> ViconWand:
    """The wand markers of a Vicon C3D (see :func:`calibration.wand.vicon_wand_from_table`)."""
    return vicon_wand_from_table(exporters.read(path, format="c3d"), wand, source=path)


def write_vicon_wand_c3d(path: str | os.PathLike, points_mm: np.ndarray, rate: float, wand: WandSpec) -> None:
    """Write wand markers (J, 5, 3) mm, NaN = missing, as a C3D (as Nexus would export a labelled
    wand wave)."""
    exporters.write(MarkerTable.from_arrays(list(wand.labels), points_mm, rate), path)


def read_pelvis_c3d(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Pelvis marker trajectories of a C3D (see :func:`spinemocap.analysis.frames.pelvis_markers`)."""
    return pelvis_markers(exporters.read(path, format="c3d"), source=str(path))
