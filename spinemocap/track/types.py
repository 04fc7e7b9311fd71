"""Data passed between tracker stages. World coordinates in mm, image coordinates in px."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

#: How the LP chose a frame's edges: at Eq. 1's edge count, at a relaxed (lower) count, not run
#: (``skipped``: the frame was carried from the last one) or not yet (empty).
LpStatus = Literal["optimal", "relaxed", "skipped", ""]
#: How a frame was solved: ``full`` (LP + MRFs), ``carried`` (the previous frame's solution
#: explained it), ``failed`` (no solution).
FrameRoute = Literal["full", "carried", "failed"]


@dataclass
class CandidateCloud:
    """3D candidate points (paper: the point cloud P).

    ``points``: (N, 3) mm; ``normals``: (N, 3) unit, negative mean viewing direction of the
    cameras used; ``blob_ids``: (N, C) index of the blob used in each camera, -1 where the camera
    did not contribute; ``residual``: (N,) RMS reprojection error in px over contributing views;
    ``pixels``: (N, C, 2) the blobs' distorted pixel centres (NaN where unused; for the rig's
    bundle adjustment on tracked dots)."""

    points: np.ndarray
    normals: np.ndarray
    blob_ids: np.ndarray
    residual: np.ndarray
    pixels: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @property
    def n_views(self) -> np.ndarray:
        return (self.blob_ids >= 0).sum(axis=1)


@dataclass
class EdgeCloud:
    """Point pairs whose length lies in (th3, th4): ``edges`` (M, 2) indices into the candidate
    points, ``lengths`` (M,) mm."""

    edges: np.ndarray
    lengths: np.ndarray

    def __len__(self) -> int:
        return len(self.edges)


@dataclass
class FeasibleSet:
    """The LP's selected edges and the points they touch (paper: the feasibility set F).

    ``points``/``normals``: (K, 3); ``edges``: (L, 2) indices into ``points``; ``source_index``:
    (K,) index of each point in the candidate cloud; ``n_target``: edge count finally required
    (after relaxation); ``n_target_initial``: Eq. 1's value; ``status``: ``optimal`` at Eq. 1's
    count, else ``relaxed``; ``time_limited``: a solve behind this set (or behind the count it
    settled on) stopped at the LP's time limit, so the set is the best found in time, not proven
    optimal (:mod:`spinemocap.track.lp`)."""

    points: np.ndarray
    normals: np.ndarray
    edges: np.ndarray
    source_index: np.ndarray
    n_target: int
    n_target_initial: int
    status: LpStatus = "optimal"
    time_limited: bool = False

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class MRFResult:
    """Output of an MRF stage: ``positions`` (D, 3) mm in tape-label order; ``energy_history``
    per iteration (lower is better); ``extra`` stage-specific arrays (e.g. MRF1's ``d``)."""

    positions: np.ndarray
    energy_history: list[float] = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    @property
    def energy(self) -> float:
        return self.energy_history[-1] if self.energy_history else float("nan")
