"""A capture's reference object as control points for ``--refine-rig`` (application layer: joins
the marker finder of :mod:`spinemocap.detect.reference` and the refinement's
:class:`~spinemocap.track.rig_refine.ControlPoints`).

The object stands still, so its markers are searched for in a few frames spread over the capture
(:data:`REFERENCE_FRAMES`) and each camera's blob of a marker is the median over the frames that
found it: a ball passing in front of a marker in one frame, or a neighbour taken for it, moves
one sample, not the median. A camera's marker counts only when at least half of the frames found
it and those samples agree within :data:`MAX_SPREAD_PX` (median distance from their median).
"""

from __future__ import annotations

import warnings
from typing import Iterable, Sequence

import numpy as np

from ..camera import Rig
from ..capture import FrameSource
from ..detect.reference import SEARCH_PX, find_reference_markers
from ..reference import ReferenceObject
from ..track.rig_refine import ControlPoints, RigRefinement

REFERENCE_FRAMES = 12  # frames searched for the markers, spread over the capture
MAX_SPREAD_PX = 0.5  # a static marker's samples must agree this well (median distance to their median)
# the reference's world frame may differ from the given rig's by this many times the given rig's
# own frame uncertainty before the pose in the reference file is doubted
POSE_DOUBT_FACTOR = 3.0
POSE_DOUBT_MIN_MM = 3.0


def observe_reference(rig: Rig, reference: ReferenceObject, images: Iterable[Sequence[np.ndarray]],
                      search_px: float = SEARCH_PX) -> ControlPoints:
    """Control points of ``reference`` from frames ``images`` (each: one image per camera of
    ``rig``, the given rig: it says where to look); see module."""
    samples = np.stack([np.stack([find_reference_markers(image, cam, reference, search_px)
                                  for cam, image in zip(rig, frame)]) for frame in images])  # (F, C, N, 2)
    F = len(samples)
    found = np.isfinite(samples).all(axis=3)  # (F, C, N)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: markers never found
        median = np.nanmedian(samples, axis=0)  # (C, N, 2)
        spread = np.nanmedian(np.linalg.norm(samples - median[None], axis=3), axis=0)  # (C, N)
    keep = (found.sum(axis=0) >= max(1, (F + 1) // 2)) & (spread <= MAX_SPREAD_PX)
    median[~keep] = np.nan
    return ControlPoints(list(reference.labels), reference.world_mm, median, reference.name)


def source_images(source: FrameSource, frames: Sequence[int], count: int = REFERENCE_FRAMES):
    """The images of up to ``count`` frames of ``frames`` spread evenly over them."""
    frames = list(frames)
    picks = np.unique(np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int))
    for k in picks:
        yield source.read(frames[int(k)])


def pose_doubt(refinement: RigRefinement) -> str | None:
    """A warning when the reference's world frame lies farther from the given rig's than the given
    rig's own residuals make plausible (a pose in the reference file shifted as a whole fits the
    markers perfectly and moves the world with it), else None."""
    frame = refinement.reference
    if frame is None:
        return None
    offset = frame.given_frame_offset_mm
    expected = refinement.frame_uncertainty_from_residuals_mm
    limit = max(POSE_DOUBT_FACTOR * expected, POSE_DOUBT_MIN_MM)
    if np.isfinite(offset) and offset > limit:
        return (f"{frame.name}: the given rig places the reference's markers {offset:.1f} mm from where the reference "
                f"file says they are, more than its residuals make plausible (~{expected:.1f} mm, limit {limit:.1f} mm): "
                "the world frame now follows the reference file; check its pose (translation_mm, rotation)")
    return None

