"""``spinemocap batch``, ``report`` and ``angles`` on a study of exact bending tapes: angles per
trial, a second run that finds them up to date, a failing trial that sets the exit status, the
report's pages and tables, one marker file's angles with its plot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import exporters
from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.commands import angles as angles_command
from spinemocap.commands import batch as batch_command
from spinemocap.commands import report as report_command
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec

TAPE = TapeSpec(n_rows=9)
LEVELS_TOML = '[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n'


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("study")
    for k, condition in enumerate(("pre", "post")):
        write_bent_capture(root / "S01" / condition / "trial01", TAPE, 20.0 + 10 * k, n_frames=12, fps=50.0)
    (root / "S01" / "levels.toml").write_text(LEVELS_TOML)
    return root


def test_batch_then_report(study, parse, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["-q", "batch", study, "--out", out, "--source", "groundtruth", "--workers", "1"]
    assert batch_command.run(parse(*argv)) == 0
    assert "2 trials: 2 ok (0 up to date), 0 failed" in capsys.readouterr().out
    peaks = [pd.read_csv(out / "S01" / c / "trial01" / "angles.csv")["lumbar_flexion"].max() for c in ("pre", "post")]
    assert peaks[1] - peaks[0] == pytest.approx(10.0, abs=1.5)  # the applied peaks differ by 10 deg
    assert batch_command.run(parse(*argv)) == 0
    assert "2 ok (2 up to date)" in capsys.readouterr().out
    assert report_command.run(parse("report", out, "--title", "Flexion study")) == 0
    printed = capsys.readouterr().out
    assert "Flexion study" in (out / "report.html").read_text()
    assert len(pd.read_csv(out / "summary.csv")) == 2 and str(out / "summary.xlsx") in printed


def test_a_failing_trial_sets_the_exit_status_and_is_named(study, parse, tmp_path, capsys):
    (study / "S02" / "pre" / "trial01").mkdir(parents=True)
    try:
        code = batch_command.run(parse("-q", "batch", study, "--out", tmp_path / "out", "--source", "groundtruth",
                                       "--workers", "1"))
    finally:
        (study / "S02" / "pre" / "trial01").rmdir()
    assert code == 1 and "FAILED S02/pre/trial01" in capsys.readouterr().out


def test_angles_of_one_marker_file(study, parse, tmp_path, capsys):
    with np.load(study / "S01" / "post" / "trial01" / "groundtruth.npz") as data:
        table = MarkerTable.from_arrays(list(data["labels"]), data["dots"], fps=50.0)
    exporters.write(table, tmp_path / "trial.c3d")
    out = tmp_path / "angles.csv"
    args = parse("angles", tmp_path / "trial.c3d", "--levels", study / "S01" / "levels.toml", "--out", out)
    assert angles_command.run_angles(args) == 0
    assert "lumbar flexion from neutral" in capsys.readouterr().out
    angles = pd.read_csv(out)
    assert len(angles) == 12 and np.nanmax(angles["lumbar_flexion"]) - np.nanmin(angles["lumbar_flexion"]) > 20
    assert out.with_suffix(".png").stat().st_size > 1000


def test_a_marker_file_without_tape_labels_is_refused_naming_it(parse, tmp_path):
    exporters.write(MarkerTable.from_arrays(["LASI", "RASI"], np.zeros((3, 2, 3)), fps=50.0), tmp_path / "pig.trc")
    (tmp_path / "levels.toml").write_text(LEVELS_TOML)
    with pytest.raises(InputError, match="pig.trc.*no tape labels"):
        angles_command.run_angles(parse("angles", tmp_path / "pig.trc", "--levels", tmp_path / "levels.toml"))
