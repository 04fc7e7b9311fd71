"""A lab's format plugs in through the ``spinemocap.exporters`` entry-point group: we install
tests/export_plugin as a real distribution (a .dist-info with entry_points.txt on sys.path)
and use it through the registry and the CLI. Also the ``spinemocap export`` command."""

import importlib.metadata
import sys

import numpy as np
import pytest
from repo_paths import TESTS

import exporters
from spinemocap.cli import main
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable

PLUGIN_DIR = TESTS / "export_plugin"


@pytest.fixture
def lab_plugin(tmp_path, monkeypatch):
    """Install the plugin distribution the way pip would leave it: metadata beside the code."""
    site = tmp_path / "site"
    info = site / "lab_formats-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-formats\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[spinemocap.exporters]\nlabjson = lab_format_plugin:LabJsonExporter\n"
        "broken = lab_format_plugin_missing:Nothing\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.syspath_prepend(str(PLUGIN_DIR))
    yield
    sys.modules.pop("lab_format_plugin", None)


def table() -> MarkerTable:
    pos = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3) * 10
    pos[2, 1] = np.nan
    return MarkerTable.from_arrays(["R01L", "R01R"], pos, fps=60, first_frame=5)


def test_entry_point_plugin_is_found_and_used(lab_plugin, tmp_path):
    assert "labjson" in exporters.available()
    names = {ep.name for ep in importlib.metadata.entry_points(group=exporters.ENTRY_POINT_GROUP)}
    assert {"labjson", "broken"} <= names
    plugin = exporters.get("labjson")
    assert type(plugin).__module__ == "lab_format_plugin"
    path = exporters.write(table(), tmp_path / "out.labjson")           # chosen by its extension
    assert '"labels": ["R01L", "R01R"]' in path.read_text()
    back = exporters.read(path, format="labjson")
    assert back.frames.tolist() == [5, 6, 7, 8]
    assert np.allclose(back.positions(), table().positions(), equal_nan=True)


def test_broken_plugin_is_named_and_does_not_break_builtins(lab_plugin, tmp_path):
    with pytest.raises(InputError, match="entry point broken = lab_format_plugin_missing:Nothing"):
        exporters.get("broken")
    assert exporters.write(table(), tmp_path / "m.trc").is_file()


def test_plugin_failing_midway_leaves_previous_file(lab_plugin, tmp_path):
    path = exporters.write(table(), tmp_path / "out" / "out.labjson")
    before = path.read_text()
    bad = table()
    bad.meta["explode_after_half"] = True
    with pytest.raises(OSError, match="simulated disk full"):
        exporters.write(bad, path)
    assert path.read_text() == before
    assert [p.name for p in path.parent.iterdir()] == ["out.labjson"]


def test_cli_export_results_folder(tmp_path, capsys):
    pytest.importorskip("opensim")
    import opensim as osim

    results = tmp_path / "results"
    exporters.write(table(), results / "markers.csv")
    assert main(["export", str(results), "--format", "trc", "--units", "m", "--opensim-axes"]) == 0
    trc = osim.TimeSeriesTableVec3(str(results / "markers.trc"))
    assert list(trc.getColumnLabels()) == ["R01L", "R01R"] and trc.getTableMetaDataAsString("Units") == "m"
    assert "4 frames x 2 markers at 60 Hz" in capsys.readouterr().out
    assert main(["export", str(results / "markers.trc"), "-o", str(tmp_path / "x.c3d")]) == 0
    assert np.allclose(exporters.read(tmp_path / "x.c3d").positions(), table().positions(), atol=1e-3,
                       equal_nan=True)


def test_cli_export_with_plugin_and_bad_flags(lab_plugin, tmp_path, capsys):
    src = exporters.write(table(), tmp_path / "markers.csv")
    assert main(["export", str(src), "--format", "labjson"]) == 0
    assert (tmp_path / "markers.labjson").is_file()
    assert main(["export", str(src), "--format", "c3d", "--opensim-axes"]) == 2
    assert "--opensim-axes does not apply to the c3d format" in capsys.readouterr().err
    assert main(["export", str(src), "--format", "trc", "--forward=-y"]) == 2
    assert "--forward only applies with --opensim-axes" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "nothing")]) == 2
    assert main(["export", "--list-formats"]) == 0
    listing = capsys.readouterr().out
    assert "labjson" in listing and "broken     (cannot load" in listing
