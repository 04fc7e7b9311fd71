"""End to end: `spinemocap track` on a tiny synthetic capture written to disk."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from spinemocap.cli import main
from spinemocap.markers import STATUSES

pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from spinemocap.synth import SynthConfig, write_capture

    root = tmp_path_factory.mktemp("track_e2e")
    return write_capture(SynthConfig.preset("tiny", frames=3), root / "capture", progress=False)


@pytest.fixture(scope="module")
def tracked(capture, tmp_path_factory):
    out = tmp_path_factory.mktemp("track_out")
    # the classical tape detector: real segmentation and dot finding from the rendered images
    code = main(["track", str(capture), "--out", str(out), "--detector", "classical", "--no-progress"])
    assert code == 0
    return out


def test_track_writes_labelled_markers_close_to_ground_truth(capture, tracked):
    table = pd.read_csv(tracked / "markers.csv")
    assert list(table.columns[:9]) == ["frame", "time", "label", "x", "y", "z", "status", "n_views", "residual"]
    gt = np.load(capture / "groundtruth.npz")
    labels = [str(x) for x in gt["labels"]]
    assert sorted(table["label"].unique()) == sorted(labels)
    assert set(table["status"]) <= set(STATUSES)
    truth = gt["dots"]
    rows = table.set_index(["frame", "label"])
    errors = [np.linalg.norm(rows.loc[(f, lab), ["x", "y", "z"]].to_numpy(float) - truth[f, d])
              for f in range(truth.shape[0]) for d, lab in enumerate(labels)]
    assert np.max(errors) < 3.0  # every dot, labelled correctly, within a few mm
    observed = table[table["status"] == "observed"]
    assert len(observed) >= 0.9 * len(table) and (observed["n_views"] >= 2).all()
    assert (tracked / "markers.trc").is_file() and (tracked / "markers.c3d").is_file()


def test_track_prints_accuracy_for_synthetic_captures(capture, tmp_path, capsys):
    code = main(["track", str(capture), "--out", str(tmp_path), "--detector", "mask", "--mode", "paper",
                 "--frames", "1:2", "--no-progress"])
    assert code == 0
    out = capsys.readouterr().out
    assert "accuracy vs ground truth" in out and "label swaps 0" in out
    table = pd.read_csv(tmp_path / "markers.csv")
    assert set(table["frame"]) == {1}


def test_track_reports_bad_input_cleanly(tmp_path, capture, capsys):
    assert main(["track", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2
    assert "capture folder not found" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("[lp]\nno_such_key = 1\n")
    assert main(["track", str(capture), "--out", str(tmp_path / "o"), "--config", str(bad)]) == 2
    assert "no_such_key" in capsys.readouterr().err
    assert main(["track", str(capture), "--out", str(tmp_path / "o"), "--detector", "mask", "--frames", "7:9"]) == 2
    assert "selects no frame" in capsys.readouterr().err


def test_track_refine_rig_writes_the_refined_rig_with_its_residuals(capture, tmp_path, capsys):
    import json

    from spinemocap.camera import Rig

    code = main(["track", str(capture), "--out", str(tmp_path), "--detector", "mask", "--refine-rig",
                 "--no-progress"])
    assert code == 0
    out = capsys.readouterr().out
    assert "rig refined on" in out and "no frame flagged" in out
    report = json.loads((tmp_path / "rig_refine.json").read_text())
    assert report["after_px"]["all"] <= report["before_px"]["all"] + 1e-9
    assert len(Rig.from_toml(tmp_path / "rig_refined.toml")) == 3
    table = pd.read_csv(tmp_path / "markers.csv")
    assert {"confidence", "stretch"} <= set(table.columns)
    assert table["confidence"].between(0, 1).all()


def test_calibration_warning_points_to_the_refinement_once_refined(capture, tmp_path):
    from spinemocap.app.run import track_capture_result
    from spinemocap.track.rig_check import REFINE_ADVICE
    from spinemocap.track.rig_refine import RigRefineConfig

    result = track_capture_result(capture, tmp_path, detector="mask", progress=False, refine=RigRefineConfig())
    # this capture's rig is good: give it the warning a 2 px rig gets
    result.calibration_warning = f"calibration: camera(s) cam1 reproject the capture's own dots with 2.10 px RMS; {REFINE_ADVICE}"
    refined = result.summary()
    assert REFINE_ADVICE not in refined and "the rig was refined on these dots (--refine-rig" in refined
    assert result.quality().calibration_warning in refined
    result.refinement = None  # not refined: the advice stays
    assert REFINE_ADVICE in result.summary()
