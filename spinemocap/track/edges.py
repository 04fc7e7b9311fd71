"""Stage 2: the edge cloud E (paper section 3): candidate point pairs whose length lies in the
tape's solid-edge length range (th3, th4) = :meth:`TapeGraph.solid_length_bounds_mm`, i.e. the
rest lengths widened by the tape's stretch tolerance."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..tape import TapeSpec
from .config import EdgeConfig
from .types import CandidateCloud, EdgeCloud


def edge_bounds(tape: TapeSpec, config: EdgeConfig) -> tuple[float, float]:
    th3, th4 = tape.graph.solid_length_bounds_mm()
    return (config.th3_mm if config.th3_mm is not None else th3,
            config.th4_mm if config.th4_mm is not None else th4)


def build_edges(cloud: CandidateCloud, tape: TapeSpec, config: EdgeConfig | None = None) -> EdgeCloud:
    """All point pairs (i < j) with th3 < |p_i - p_j| < th4 (mm)."""
    config = config or EdgeConfig()
    th3, th4 = edge_bounds(tape, config)
    if len(cloud) < 2:
        return EdgeCloud(edges=np.zeros((0, 2), np.int64), lengths=np.zeros(0))
    pairs = cKDTree(cloud.points).query_pairs(th4, output_type="ndarray").astype(np.int64)
    if not len(pairs):
        return EdgeCloud(edges=np.zeros((0, 2), np.int64), lengths=np.zeros(0))
    lengths = np.linalg.norm(cloud.points[pairs[:, 0]] - cloud.points[pairs[:, 1]], axis=1)
    keep = (lengths > th3) & (lengths < th4)
    if config.drop_shared_blob:
        bi, bj = cloud.blob_ids[pairs[:, 0]], cloud.blob_ids[pairs[:, 1]]
        keep &= ~((bi >= 0) & (bi == bj)).any(axis=1)
    order = np.lexsort((pairs[keep, 1], pairs[keep, 0]))
    return EdgeCloud(edges=pairs[keep][order], lengths=lengths[keep][order])
