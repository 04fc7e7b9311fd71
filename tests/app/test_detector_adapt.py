"""``detector adapt``: labels rendered from tracked 3D dots, and the adapted weights a capture names."""

import json

import cv2
import numpy as np
import pytest

from spinemocap.app.adapt import frame_labels, spread, vouched_frames
from spinemocap.capture import Capture
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    from spinemocap.synth import SynthConfig
    from spinemocap.synth.writer import write_capture

    root = tmp_path_factory.mktemp("adapt") / "cap"
    # the exact rig (realism "skin"): a label's error is then the labelling's own
    return write_capture(SynthConfig.preset("tiny", frames=4, seed=5, realism="skin"), root, progress=False)


def test_labels_land_on_the_true_dots_and_cover_the_tape(capture_dir):
    capture = Capture.open(capture_dir)
    truth = capture.groundtruth()
    graph = capture.tape.graph
    surface = truth["dots"] + capture.tape.thickness_mm * truth["dot_normals"]  # the holes the cameras see
    checked = 0
    for frame in range(capture.n_frames):
        observed = np.ones(graph.n_dots, bool)
        observed[3] = False  # a dot the tracker only inferred: the surface is shaped without it
        for view in frame_labels(capture.rig, capture.tape, truth["dots"][frame], observed, frame):
            index = [graph.labels.index(label) for label in view.labels]
            assert 3 not in index
            seen = truth["visible"][frame, view.camera][index]
            true_uv = capture.rig[view.camera].project(surface[frame][index])
            error = np.linalg.norm(view.uv - true_uv, axis=1)
            assert seen.mean() > 0.9 and np.all(error[seen] < 0.3), (frame, view.camera, error.max())
            studio = cv2.imread(str(capture_dir / "masks" / capture.camera_names[view.camera] / f"{frame:06d}.png"), 0) > 127
            iou = (view.mask & studio).sum() / max((view.mask | studio).sum(), 1)
            assert iou > 0.85, (frame, view.camera, iou)
            checked += len(index)
    assert checked > 20


def test_vouched_frames_leave_out_flagged_and_partly_observed_frames():
    from spinemocap.tape import TapeSpec

    graph = TapeSpec().graph
    frames, d = 4, graph.n_dots
    positions = np.zeros((frames, d, 3))
    status = np.full((frames, d), "observed", dtype=object)
    confidence = np.ones((frames, d))
    confidence[1] = 0.5                       # a doubting flag: every dot of the frame at half confidence
    last_row = graph.row == graph.row.max()
    status[2, last_row] = "inferred"           # the last row unseen: its outline would be a guess
    confidence[2, last_row] = 0.6
    table = MarkerTable.from_arrays(graph.labels, positions, fps=50.0, status=status, confidence=confidence)
    assert vouched_frames(table, graph) == [0, 3]
    assert spread(list(range(10)), 3) == [0, 4, 9] and spread([1, 2], 5) == [1, 2]


def test_adapt_writes_weights_that_the_capture_names_and_tracking_uses(capture_dir, tmp_path, capsys):
    import shutil

    from spinemocap.app.run import track_capture_result
    from spinemocap.app.training_data import SynthDataSettings, generate_synthetic
    from spinemocap.cli import main
    from spinemocap.detect.segnet import load_weights

    studio = generate_synthetic(tmp_path / "studio", SynthDataSettings(scenes=1, frames_per_scene=1, layouts=("tiny",),
                                                                       sequence_frames=4), progress=False)
    capture_dir = shutil.copytree(capture_dir, tmp_path / "cap")
    out = tmp_path / "adapted"
    assert main(["detector", "adapt", str(capture_dir), "--out", str(out), "--studio", str(studio),
                 "--epochs", "1", "--steps", "2", "--batch", "2", "--crop", "64", "--use"]) == 0
    printed = capsys.readouterr().out
    assert "camera views labelled" in printed and "detector_weights names them" in printed
    meta = json.loads((out / "weights.json").read_text())
    assert meta["data"]["kind"] == "adapted" and meta["data"]["views"] > 0 and meta["data"]["dots"] > 0
    assert meta["command"].startswith("spinemocap detector adapt")
    load_weights(out / "weights.pt")
    capture = Capture.open(capture_dir)
    assert capture.detector_weights_path == (out / "weights.pt").resolve()
    result = track_capture_result(capture_dir, tmp_path / "tracked", frames="0:2", progress=False)
    assert result.table.meta["detector_weights"] == str((out / "weights.pt").resolve())


def test_a_capture_naming_missing_weights_is_refused(capture_dir, tmp_path):
    import shutil

    from spinemocap.capture import set_detector_weights

    copy = tmp_path / "cap"
    shutil.copytree(capture_dir, copy)
    set_detector_weights(copy, tmp_path / "gone.pt")
    with pytest.raises(InputError, match="detector_weights"):
        _ = Capture.open(copy).detector_weights_path
