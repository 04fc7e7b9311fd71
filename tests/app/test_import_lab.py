"""From a lab's own files to markers: MP4 videos of different lengths (H.264 where this PyAV has
it), one camera's calibration 8 rows taller than its video (an encoder's 1088 -> 1080 crop) and a
Qualisys calibration, through `capture init` alone, then `track`; and `batch` keeping complete
markers when only the analysis' inputs change."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from lab_recordings import write_mp4, write_qca

from spinemocap.capture import Capture
from spinemocap.cli import main
from spinemocap.fileio import write_toml

pytest.importorskip("pyvista")
pytest.importorskip("av")
FRAMES = 5
SERIALS = ["28513", "28514", "28515"]


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    from spinemocap.synth import SynthConfig, write_capture

    root = tmp_path_factory.mktemp("import_studio")
    return write_capture(SynthConfig.preset("tiny", frames=FRAMES), root / "capture", progress=False)


@pytest.fixture(scope="module")
def lab(studio, tmp_path_factory):
    """The studio's images as a lab would bring them: one MP4 per camera named after the camera's
    serial (the second one frame shorter), a QTM calibration whose second camera's sensor window
    is 8 rows taller than its video, and the tape roll's spec."""
    import cv2

    capture = Capture.open(studio)
    folder = tmp_path_factory.mktemp("lab")
    videos = []
    for k, name in enumerate(capture.camera_names):
        count = FRAMES - 1 if k == 1 else FRAMES
        images = [cv2.imread(str(studio / capture.image_pattern.format(camera=name, frame=f))) for f in range(count)]
        videos.append(write_mp4(folder / f"trial01_Miqus_{k + 1}_{SERIALS[k]}.mp4", images, capture.fps))
    calibration = write_qca(capture.rig, SERIALS, folder / "Calib.qca.txt", {capture.camera_names[1]: 8})
    write_toml(folder / "tape.toml", {"tape": capture.tape.to_dict()})
    return folder, videos, calibration


def test_a_labs_videos_and_qualisys_calibration_become_a_tracked_capture(studio, lab, tmp_path, capsys):
    folder, videos, calibration = lab
    out = tmp_path / "trial01"
    args = ["capture", "init", str(out), "--videos", *map(str, videos), "--calibration", str(calibration),
            "--tape", str(folder / "tape.toml")]
    assert main(args) == 2  # the crop is explained, never fixed silently
    err = capsys.readouterr().err
    assert "camera '28514': its recording is 480x360 px but the calibration says 480x368 px" in err
    assert "--fix-size crop" in err
    assert main([*args, "--fix-size", "crop"]) == 0
    printed = capsys.readouterr().out
    # the shorter camera is left out of the last frame, which the other two recorded
    assert f"3 cameras, {FRAMES} frames at 4 frames/s" in printed and "calibration fixed: camera '28514'" in printed

    capture = Capture.open(out)
    assert capture.camera_names == SERIALS and capture.n_frames == FRAMES and capture.media == "video"
    truth_rig = Capture.open(studio).rig
    np.testing.assert_allclose(capture.rig["28514"].K, truth_rig[1].K, rtol=1e-9)  # the principal point kept
    assert capture.rig["28514"].size == truth_rig[1].size

    results = tmp_path / "tracked"
    assert main(["track", str(out), "--out", str(results), "--detector", "classical", "--no-progress", "-q"]) == 0
    table = pd.read_csv(results / "markers.csv")
    gt = np.load(studio / "groundtruth.npz")
    labels = [str(x) for x in gt["labels"]]
    rows = table.set_index(["frame", "label"])
    errors = np.array([np.linalg.norm(rows.loc[(f, lab), ["x", "y", "z"]].to_numpy(float) - gt["dots"][f, d])
                       for f in range(FRAMES) for d, lab in enumerate(labels)])
    assert set(table["frame"]) == set(range(FRAMES))
    named = pd.read_csv(results / "markers.csv", dtype={"missing_cameras": str})   # names that look like numbers
    assert set(named.loc[named["frame"] == FRAMES - 1, "missing_cameras"]) == {SERIALS[1]}
    assert np.median(errors) < 1.5 and errors.max() < 4.0, errors  # every dot labelled right, mm


def test_batch_reuses_complete_markers_when_only_the_level_map_changed(studio, tmp_path):
    from spinemocap.app.batch import groundtruth_markers, run_batch
    from spinemocap.app.results import RESULTS_MANIFEST, write_markers

    trial = tmp_path / "study" / "S01" / "pre" / "trial01"
    shutil.copytree(studio, trial)
    out = tmp_path / "out"
    trial_out = out / "S01" / "pre" / "trial01"
    write_markers(groundtruth_markers(Capture.open(trial)), trial_out)  # a complete set, newer than the capture
    run_id = json.loads((trial_out / RESULTS_MANIFEST).read_text())["run_id"]
    first = run_batch(tmp_path / "study", out, workers=1, progress=False)
    assert [t.summary.status for t in first.trials] == ["ok"], first.trials
    levels = dict(zip(Capture.open(trial).row_levels() or [], range(1, 99)))
    write_toml(trial / "levels.toml", {"levels": {k: v for k, v in list(levels.items())[::2]}})
    again = run_batch(tmp_path / "study", out, workers=1, progress=False)
    (trial,) = again.trials
    assert trial.summary.status == "ok" and not trial.skipped  # analysed again
    assert trial.summary.analysis is not None and trial.summary.analysis.levels_from.endswith("levels.toml")
    assert json.loads((trial_out / RESULTS_MANIFEST).read_text())["run_id"] == run_id  # not tracked again
    summary = (trial_out / "summary.json").read_text()
    assert "NaN" not in summary and "Infinity" not in summary
