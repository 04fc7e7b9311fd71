"""The studio's L-frame: placed beside the tape where every marker of the ``artificial`` layout's
views falls inside at least two images (refused for a layout too narrow for it), and its bars
and pole built behind the markers, down to the floor."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.synth.reference import (
    MIN_CAMERAS,
    PLACEMENT_MM,
    STUDIO_ROTATION,
    reference_meshes,
    studio_reference,
)
from spinemocap.synth.rigs import LAYOUTS, arc_rig

TARGET = np.array([0.0, 120.0, 1150.0])


def _rig(layout: str, size: tuple[int, int]):
    return arc_rig(LAYOUTS[layout], 4, size, TARGET, distortion=0.0, rng=np.random.default_rng(0))


def test_the_lframe_stands_beside_the_tape_in_view_of_the_cameras():
    rig = _rig("artificial", (1024, 768))
    reference = studio_reference(TARGET, rig)
    np.testing.assert_allclose(reference.rotation, STUDIO_ROTATION)
    np.testing.assert_allclose(reference.world_mm[0], TARGET + PLACEMENT_MM)  # the corner marker
    seen = sum((cam.in_image(cam.project(reference.world_mm)) & (cam.depth(reference.world_mm) > 0)).astype(int)
               for cam in rig)
    assert (seen >= MIN_CAMERAS).all()


def test_a_layout_too_narrow_for_it_is_refused():
    with pytest.raises(ValueError, match="does not fit the views of this layout"):
        studio_reference(TARGET, _rig("tiny", (320, 240)))


def test_bars_behind_the_markers_and_a_pole_to_the_floor():
    reference = studio_reference(TARGET, _rig("artificial", (1024, 768)))
    meshes = reference_meshes(reference, floor_z_mm=0.0)
    np.testing.assert_array_equal(meshes.marker_centres, reference.world_mm)
    assert meshes.marker_radius == reference.marker_diameter_mm / 2
    facing = reference.rotation[:, 2]  # the side the markers face
    behind = (meshes.frame_vertices - reference.world_mm[0]) @ facing
    assert (behind <= -meshes.marker_radius + 1e-9).all()  # nothing of the frame in front of a marker
    assert meshes.frame_vertices[:, 2].min() == pytest.approx(0.0)
    assert meshes.frame_faces.min() == 0 and meshes.frame_faces.max() == len(meshes.frame_vertices) - 1
    # 4 bars of the markers' spanning tree (5 markers) and the pole: 12 triangles each
    assert meshes.frame_faces.shape == (5 * 12, 3)


def test_no_pole_when_the_frame_stands_on_the_floor():
    reference = studio_reference(TARGET, _rig("artificial", (1024, 768)))
    meshes = reference_meshes(reference, floor_z_mm=5000.0)
    assert meshes.frame_faces.shape == (4 * 12, 3)
