"""The virtual Vicon's geometry: cameras on a ring, markers seen by the cameras they face and
that the body does not hide, tape markers on the tape's 2-dot rows with one on each side."""

from __future__ import annotations

import numpy as np

from spinemocap.bodymodel.virtual_vicon import (
    ViconCameraRing,
    cameras_seeing,
    default_tape_rows,
    interleave_rows,
    tape_marker_layout,
)
from spinemocap.tape import TapeSpec


def test_the_ring_of_cameras():
    centres = ViconCameraRing(n_cameras=4, radius_mm=3000.0, heights_mm=(2000.0, 1000.0), start_deg=0.0).centres(
        np.array([100.0, 0.0, 900.0]))
    np.testing.assert_allclose(centres, [[3100, 0, 2000], [100, 3000, 1000], [-2900, 0, 2000], [100, -3000, 1000]],
                               atol=1e-9)


def test_a_marker_is_seen_by_the_cameras_it_faces_and_nothing_hides():
    cameras = np.array([[0.0, -3000.0, 1000.0], [0.0, 3000.0, 1000.0], [3000.0, 0.0, 1000.0]])
    markers = np.array([[0.0, -100.0, 1000.0], [0.0, 100.0, 1000.0]])
    normals = np.array([[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]])

    def nothing(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        return np.zeros(len(starts), bool)

    def wall_at_x_1000(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        return (starts[:, 0] < 1000) & (ends[:, 0] > 1000)

    # facing within 100 deg: the front camera and the side one (90 deg), not the one behind
    assert cameras_seeing(markers, normals, cameras, nothing, 100.0).tolist() == [2, 2]
    assert cameras_seeing(markers, normals, cameras, nothing, 80.0).tolist() == [1, 1]
    assert cameras_seeing(markers, normals, cameras, wall_at_x_1000, 100.0).tolist() == [1, 1]


def test_tape_markers_sit_on_two_dot_rows_beside_the_tape():
    spec = TapeSpec(n_rows=9)
    rows = default_tape_rows(spec)
    assert len(rows) == 3 and all((spec.graph.row == r).sum() == 2 for r in rows)
    labels, centres, sides = tape_marker_layout(spec, rows, beside_mm=15.0)
    assert labels[:3] == [f"VT_R{rows[0] + 1:02d}", f"VT_R{rows[0] + 1:02d}L", f"VT_R{rows[0] + 1:02d}R"]
    assert (centres[:, 0] == 0).all() and np.allclose(sides[:, 1, 0], spec.width_mm / 2 + 15.0)
    assert np.allclose(sides[:, :, 1], centres[:, 1:2])
    merged = interleave_rows(np.array([[0.0, 0, 0]]), np.array([[-1.0, 0, 0], [1.0, 0, 0]]))
    assert merged.tolist() == [[0, 0, 0], [-1, 0, 0], [1, 0, 0]]
