"""The studio's fast ground truth and writes give the results of their plain references: visibility with
the cell locator built only on the triangles that can block a ray (all of a mesh's rays in one
query) equals the whole-mesh locator casting ray by ray; ``sphere_mesh`` from its cached template
equals the mesh built from scratch; atomic writes list a folder for stale temporaries once per
process and still remove what a killed writer left of the target they write."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from spinemocap.fileio import atomic_path, atomic_write
from spinemocap.synth import SynthConfig, build_scene
from spinemocap.synth import scene as scene_module
from spinemocap.synth.occluders import sphere_mesh


class WholeMeshCaster:
    """The ray caster as first written: a locator on the whole mesh, one segment at a time."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import pyvista as pv
        import vtk

        mesh = pv.PolyData(np.asarray(vertices, float), np.column_stack([np.full(len(faces), 3), faces]).ravel())
        self._locator = vtk.vtkStaticCellLocator()
        self._locator.SetDataSet(mesh)
        self._locator.BuildLocator()
        self._args = (vtk.reference(0.0), [0.0] * 3, [0.0] * 3, vtk.reference(0), vtk.reference(0))

    def blocked(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        out = np.array([bool(self._locator.IntersectWithLine(a, b, 0.0, *self._args)) for a, b in zip(starts, ends)],
                       dtype=bool)
        BLOCKED.append(out)
        return out


BLOCKED: list[np.ndarray] = []  # what the whole-mesh caster answered


@pytest.mark.parametrize("realism, occlusion, band", [("skin", "heavy", True), ("lab", "light", True)])
def test_visibility_equals_the_whole_mesh_locator_cast_ray_by_ray(monkeypatch, realism, occlusion, band):
    """Studio layout (6 cameras, small images), falling balls; ``skin``: all cameras on one clock
    (one mesh shared by all); ``lab``: every camera on its own clock; both with the sports-bra band
    (the body mesh hides some rays)."""
    config = SynthConfig.preset("studio", size=(640, 420), frames=12, seed=3, realism=realism,
                                occlusion=occlusion, band=band)
    scene = build_scene(config)
    frames = (4, 11)
    fast = [scene.frame_groundtruth(f)["visible"] for f in frames]
    monkeypatch.setattr(scene_module, "MeshRayCaster", WholeMeshCaster)
    BLOCKED.clear()
    first = [scene.frame_groundtruth(f)["visible"] for f in frames]
    assert len(np.unique(scene.sync_offsets_s)) == (len(scene.rig) if realism == "lab" else 1)
    for new, old in zip(fast, first):
        np.testing.assert_array_equal(new, old)
    seen, blocked = np.concatenate(first), np.concatenate(BLOCKED)
    assert 0.2 < seen.mean() < 0.95  # some dots hidden (body, balls, view angle), most seen
    assert blocked.any() and not blocked.all()  # the body hides some rays, not all


def _reference_sphere_mesh(centres: np.ndarray, radii: np.ndarray, resolution: int = 16):
    """``sphere_mesh`` as first written: template and connectivity rebuilt on every call."""
    import pyvista as pv

    unit = pv.Sphere(radius=1.0, theta_resolution=resolution, phi_resolution=resolution)
    base_pts = np.asarray(unit.points)
    base_faces = unit.faces.reshape(-1, 4)[:, 1:]
    n = len(centres)
    pts = (base_pts[None] * radii[:, None, None] + centres[:, None, :]).reshape(-1, 3)
    faces = (base_faces[None] + (np.arange(n) * len(base_pts))[:, None, None]).reshape(-1, 3)
    mesh = pv.PolyData(pts, np.column_stack([np.full(len(faces), 3), faces]).ravel())
    mesh.point_data.active_normals = np.tile(base_pts, (n, 1))
    return mesh


def test_sphere_mesh_from_the_cached_template_equals_the_mesh_built_from_scratch():
    rng = np.random.default_rng(0)
    for n in (40, 3, 700, 1, 120):  # the cached connectivity grows, then serves smaller sets
        centres, radii = rng.uniform(-500, 2500, (n, 3)), rng.uniform(9, 20, n)
        new, old = sphere_mesh(centres, radii), _reference_sphere_mesh(centres, radii)
        np.testing.assert_array_equal(new.points, old.points)
        np.testing.assert_array_equal(new.faces, old.faces)
        np.testing.assert_array_equal(new.point_data.active_normals, old.point_data.active_normals)
    assert sphere_mesh(np.zeros((0, 3)), np.zeros(0)).n_points == 0


def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def _leave_temp(folder: Path, target: str) -> Path:
    left = folder / f".~{target}.{_dead_pid()}.0123abcd.tmp"
    left.write_text("partial")
    return left


def test_atomic_writes_list_a_folder_once_and_still_remove_a_killed_writers_temporaries(tmp_path, monkeypatch):
    folder = tmp_path / "frames"
    folder.mkdir()
    left_a, left_b = _leave_temp(folder, "0000.png"), _leave_temp(folder, "0001.png")
    listings = []
    iterdir = Path.iterdir
    monkeypatch.setattr(Path, "iterdir", lambda self: listings.append(self) or iterdir(self))
    with atomic_write(folder / "0000.png", "wb") as handle:
        handle.write(b"a")
    assert not left_a.exists() and left_b.exists()  # only the written target's temporaries
    for i in range(1, 60):
        with atomic_path(folder / f"{i:04d}.png") as tmp:
            tmp.write_bytes(b"b")
    assert not left_b.exists() and listings == [folder]  # listed once for 60 writes
    assert sorted(os.listdir(folder)) == [f"{i:04d}.png" for i in range(60)]
    # another folder is listed on its own first write
    other = tmp_path / "masks"
    other.mkdir()
    left_c = _leave_temp(other, "0000.png")
    with atomic_write(other / "0000.png", "wb") as handle:
        handle.write(b"c")
    assert not left_c.exists() and (other / "0000.png").read_bytes() == b"c" and listings == [folder, other]
