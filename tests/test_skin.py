"""Skin binding on a mesh: barycentric weights reproduce the point, bound points follow a moved
mesh, normals point out of the surface; the S2 level from the hip centres (Bell et al.)."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.skin import (
    HJC_BELOW_ASIS_IAD,
    HJC_LATERAL_IAD,
    PSIS_ABOVE_ASIS_MM,
    SURFACE_LEVELS,
    SkinBinding,
    barycentric,
    psis_height,
    surface_level_heights,
    vertex_normals,
)

# a unit square in z = 0 of two triangles, normals +z
VERTICES = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0], [0.0, 10.0, 0.0]])
FACES = np.array([[0, 1, 2], [0, 2, 3]])


def test_barycentric_weights_reproduce_points_and_clip_into_the_triangle():
    corners = VERTICES[FACES[[0, 0]]]
    points = np.array([[7.0, 2.0, 0.0], [20.0, -5.0, 0.0]])
    w = barycentric(corners, points)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", w[:1], corners[:1]), points[:1], atol=1e-12)
    assert (w >= 0).all()  # the outside point is clipped into the triangle


def test_bound_points_follow_the_mesh_and_float_along_its_normal():
    normals = vertex_normals(VERTICES, FACES)
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (4, 1)))
    binding = SkinBinding(np.array([0, 1]), np.array([[0.2, 0.3, 0.5], [1 / 3, 1 / 3, 1 / 3]]), np.array([2.0, 0.0]))
    rest = binding.points(VERTICES, FACES)
    np.testing.assert_allclose(rest[0], [8.0, 5.0, 2.0])
    moved = VERTICES + [100.0, -50.0, 30.0]
    track = binding.sequence(np.stack([VERTICES, moved]), FACES)
    np.testing.assert_allclose(track[1] - track[0], np.tile([100.0, -50.0, 30.0], (2, 1)))


def test_the_psis_and_the_levels_between_it_and_c7():
    left, right = np.array([90.0, 0.0, 900.0]), np.array([-90.0, 0.0, 900.0])
    inter_asis = 90.0 / HJC_LATERAL_IAD
    assert psis_height(left, right) == pytest.approx(900.0 + HJC_BELOW_ASIS_IAD * inter_asis + PSIS_ABOVE_ASIS_MM)
    heights = surface_level_heights(left, right, np.array([0.0, 30.0, 1500.0]))
    assert list(heights) == list(SURFACE_LEVELS)
    values = np.array(list(heights.values()))
    assert values[0] == pytest.approx(psis_height(left, right)) and values[-1] == pytest.approx(1500.0)
    assert (np.diff(values) > 0).all()
