"""Real C3D files written by Vicon Nexus (../shared/data/vicon): our reader agrees with ezc3d,
and what we write carries the parameters Nexus writes, with the same types."""

import warnings
from pathlib import Path

import c3d as c3dlib
import numpy as np
import pytest
from repo_paths import SHARED

import exporters

# ../shared beside the checkout; SPINEMOCAP_SHARED points elsewhere (e.g. from a git worktree)
VICON = SHARED / "data" / "vicon"
FILES = ["walking01_plugin_gait_lower.c3d", "running_cluster01.c3d", "golf_static.c3d"]


def vicon_file(name: str) -> Path:
    path = VICON / name
    if not path.is_file():
        pytest.skip(f"{path} not available (shared reference data)")
    return path


@pytest.mark.parametrize("name", FILES)
def test_vicon_files_read_like_ezc3d(name):
    ezc3d = pytest.importorskip("ezc3d")
    path = vicon_file(name)
    table = exporters.read(path)
    c = ezc3d.c3d(str(path))
    labels = list(c["parameters"]["POINT"]["LABELS"]["value"])
    points = c["data"]["points"][:3].transpose(2, 1, 0)               # (F, D, 3), NaN = gap
    assert table.labels == labels
    assert table.fps == c["header"]["points"]["frame_rate"]
    assert table.frames[0] == c["header"]["points"]["first_frame"]
    assert table.n_frames == points.shape[0]
    assert table.meta["subject"] == c["parameters"]["SUBJECTS"]["NAMES"]["value"][0]
    ours = table.positions()
    assert np.array_equal(np.isnan(ours), np.isnan(points))           # the same gaps
    assert np.array_equal(ours[~np.isnan(ours)], points[~np.isnan(points)])  # the same float32 values
    assert table.completeness()["missing"] == pytest.approx(np.isnan(points[..., 0]).mean())


def test_vicon_walking_has_gaps_and_angles_typed():
    table = exporters.read(vicon_file("walking01_plugin_gait_lower.c3d"))
    assert table.completeness()["missing"] > 0.05                     # the file has real gaps
    assert table.meta["point_types"]["LHipAngles"] == "angle"
    assert "LASI" in table.labels and "LASI" not in table.meta["point_types"]


def _params(path):
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3dlib.Reader(handle)
        return {(g, p): (param.bytes_per_element, len(param.dimensions))
                for g, group in reader.group_items() for p, param in group.param_items()}


def test_our_c3d_has_nexus_parameters_with_nexus_types(tmp_path):
    nexus = _params(vicon_file("running_cluster01.c3d"))
    table = exporters.read(vicon_file("running_cluster01.c3d")).select(labels=["C7", "T10", "CLAV", "STRN", "RBAK"])
    ours = _params(exporters.write(table, tmp_path / "trunk.c3d"))
    for group in ("TRIAL", "SUBJECTS", "MANUFACTURER", "POINT"):
        written = {key: kind for key, kind in ours.items() if key[0] == group}
        assert written, group
        for key, kind in written.items():
            if key in nexus:
                assert kind == nexus[key], key                         # same type and rank as Nexus
            else:
                assert key in {("POINT", "LONG_FRAMES")}, f"{key} is not a parameter Nexus writes"
    expected = {k for k in nexus if k[0] in ("TRIAL", "SUBJECTS", "MANUFACTURER")}
    assert expected <= set(ours)                                       # every Nexus TRIAL/SUBJECTS/MANUFACTURER one


def test_vicon_reexport_reads_back_identically(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    table = exporters.read(vicon_file("walking01_plugin_gait_lower.c3d"))
    path = exporters.write(table, tmp_path / "walking.c3d")
    c = ezc3d.c3d(str(path))
    points = c["data"]["points"][:3].transpose(2, 1, 0)
    assert list(c["parameters"]["POINT"]["LABELS"]["value"]) == table.labels
    assert np.array_equal(points, table.positions(), equal_nan=True)
    assert c["header"]["points"]["first_frame"] == table.frames[0]
    back = exporters.read(path)
    assert np.array_equal(back.to_arrays().status, table.to_arrays().status)


def test_vicon_markers_to_opensim_trc_with_gaps(tmp_path):
    osim = pytest.importorskip("opensim")
    table = exporters.read(vicon_file("walking01_plugin_gait_lower.c3d"))
    markers = table.select(labels=[l for l in table.labels if l not in table.meta["point_types"]])
    path = exporters.write(markers, tmp_path / "walking.trc", units="m", opensim_axes=True)
    trc = osim.TimeSeriesTableVec3(str(path))
    assert list(trc.getColumnLabels()) == markers.labels
    flat = trc.flatten()
    matrix = flat.getMatrix()
    values = np.array(matrix.to_numpy(), copy=True).reshape(trc.getNumRows(), -1, 3)
    assert np.array_equal(np.isnan(values), np.isnan(markers.positions()))
    assert np.isnan(values).any()


def test_vectorised_decoder_matches_c3d_package_with_analog_data():
    from c3d_corpus import assert_matches_c3d_package

    path = vicon_file("walking01_plugin_gait_lower.c3d")   # 30 analog channels x 10 per frame
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert c3dlib.Reader(handle).analog_used > 0
    assert_matches_c3d_package(path)


@pytest.mark.parametrize("name", FILES)
def test_export_vicon_file_to_csv(tmp_path, name):
    from spinemocap.cli import main

    path = vicon_file(name)
    assert main(["-q", "export", str(path), "--format", "csv", "--out", str(tmp_path / "m.csv")]) == 0
    back, table = exporters.read(tmp_path / "m.csv"), exporters.read(path)
    assert sorted(back.labels) == sorted(table.labels) and np.array_equal(back.frames, table.frames)
    order = [back.labels.index(label) for label in table.labels]         # (CSV rows come sorted by label)
    assert np.allclose(back.positions()[:, order], table.positions(), rtol=1e-12, equal_nan=True)
