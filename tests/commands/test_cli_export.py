"""`export` never overwrites the tracker's result set unless told to (the manifest stays true);
commands taking tracked markers accept a results folder or a marker file; global flags after
the command."""

from __future__ import annotations

import json

import numpy as np
import pytest

import exporters
from spinemocap.app.results import RESULTS_MANIFEST, results_run_id, write_markers
from spinemocap.cli import build_parser, main
from spinemocap.markers import MarkerTable


@pytest.fixture
def results(tmp_path):
    rng = np.random.default_rng(0)
    positions = rng.normal(0, 100, (6, 4, 3)) + [0, 0, 1000]
    table = MarkerTable.from_arrays(["R01L", "R01R", "R02L", "R02C"], positions, fps=100.0)
    write_markers(table, tmp_path / "tracked")
    return tmp_path / "tracked"


def test_export_as_the_readme_shows_it_writes_beside_the_set_not_over_it(results, capsys):
    before = (results / "markers.trc").read_bytes()
    run_id = results_run_id(results)
    assert main(["export", str(results), "--format", "trc", "--units", "m", "--opensim-axes"]) == 0
    assert (results / "markers.trc").read_bytes() == before and results_run_id(results) == run_id
    written = results / "markers_opensim_m.trc"
    assert str(written) in capsys.readouterr().out
    table = exporters.read(written)
    assert table.n_frames == 6 and len(table.labels) == 4


def test_export_over_a_file_of_the_set_needs_force_and_keeps_the_manifest_true(results, capsys):
    target = results / "markers.trc"
    args = ["export", str(results / "markers.csv"), "--out", str(target), "--units", "m"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "file of the tracker's result set" in err and "--force" in err
    assert main([*args, "--force"]) == 0
    results_run_id(results)  # the manifest checks out against the replaced file
    manifest = json.loads((results / RESULTS_MANIFEST).read_text())
    assert "exported from markers.csv" in manifest["files"]["markers.trc"]["replaced"]
    assert exporters.read(target).n_frames == 6


def test_tracked_markers_are_taken_from_a_results_folder_or_a_file(results):
    from spinemocap.commands.export import find_markers

    assert find_markers(results) == results / "markers.csv"
    assert find_markers(results / "markers.c3d") == results / "markers.c3d"
    with pytest.raises(Exception, match="holds none of markers.csv"):
        find_markers(results.parent)


@pytest.mark.parametrize("command", [["export", "--list-formats"], ["capture", "init", "o", "--videos", "a",
                                                                    "--calibration", "c"]])
def test_global_flags_after_any_command(command):
    parser = build_parser()
    assert parser.parse_args([*command, "-v"]).verbose is True
    assert parser.parse_args(["-q", *command]).quiet is True
    assert parser.parse_args([*command, "--quiet"]).quiet is True


def test_python_warnings_print_without_their_source_line(monkeypatch, capsys):
    import warnings

    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)  # restored afterwards
    assert main(["export"]) == 2  # any command: here one refused at once
    text = warnings.formatwarning("a frame without a camera", UserWarning, "/x/spinemocap/app/run.py", 321)
    assert text == "spinemocap: warning: a frame without a camera\n"
