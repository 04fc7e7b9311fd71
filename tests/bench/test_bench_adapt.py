"""The adaptation benchmark's scoring: the detector's dot recall and precision against the true
dot centres (every ``step``-th frame), the tracked error of ``track`` against the ground truth, and
the table and JSON it reports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spinemocap.bench.adapt import (
    AdaptNumbers,
    AdaptRow,
    DetectionScore,
    TrackingFailure,
    TrackingScore,
    describe,
    detection_scores,
    format_table,
    save,
    tracking_scores,
)
from spinemocap.capture import Capture

pytest.importorskip("pyvista")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from spinemocap.synth import SynthConfig, write_capture

    return write_capture(SynthConfig.preset("tiny", frames=2), tmp_path_factory.mktemp("adapt") / "capture",
                         progress=False)


def test_the_shipped_detector_scores_high_on_the_studio_it_learnt_and_step_picks_the_frames(tiny):
    capture = Capture.open(tiny)
    every = detection_scores(capture, None, step=1)
    first = detection_scores(capture, None, step=2)  # frame 0 alone
    assert every.recall >= 0.9 and every.precision >= 0.9
    assert every.recall == pytest.approx(every.dots_found / (every.dots_found + every.dots_missed))
    visible = int(np.asarray(capture.groundtruth()["visible"]).sum())
    scored = every.dots_found + every.dots_missed
    assert 0.8 * visible <= scored <= visible  # visible dots, less those within half a dot of a border
    assert 0 < first.dots_found + first.dots_missed < scored


def test_the_shifted_look_is_one_the_starting_weights_handle_poorly(tmp_path):
    # the benchmark starts from the studio-only weights: on red tape on darker skin they find
    # fewer dots than the default weights, which learnt that tape
    from spinemocap.bench.adapt import SHIFTED
    from spinemocap.detect.detector import STUDIO_WEIGHTS, shipped_weights_path
    from spinemocap.synth import SynthConfig, write_capture

    root = write_capture(SynthConfig.preset("tiny", frames=6, **SHIFTED), tmp_path / "red", progress=False)
    start = detection_scores(Capture.open(root), shipped_weights_path(STUDIO_WEIGHTS), step=1)
    default = detection_scores(Capture.open(root), None, step=1)
    assert start.recall < 0.9 <= default.recall


def test_tracking_scores_and_the_report_of_a_row(tiny, tmp_path):
    tracking = tracking_scores(tiny, tmp_path / "tracked")
    assert tracking.mean_mm < 2.0 and tracking.swaps == 0 and tracking.unsolved_frames == 0
    assert 0.0 < tracking.observed_share <= 1.0
    assert (tmp_path / "tracked" / "markers.csv").is_file()
    assert isinstance(tracking, TrackingScore)
    row = AdaptRow("unseen", "shipped", DetectionScore(0.5, 0.75, 3, 3, 1), tracking)
    failed = AdaptRow("unseen", "adapted", row.detection, TrackingFailure("no tape found"))
    numbers = AdaptNumbers({"tape_colour": "red"}, "tiny", 4, 2, "start.pt", {"epochs": 1}, {"frames": 4}, "x86_64",
                           1.0, [row, failed])
    table = format_table(numbers)
    assert "| unseen | shipped | 0.500 | 0.750 |" in table and "no tape found | - | - | all" in table
    assert "recall 0.500" in describe(row) and describe(failed).endswith("no tape found")
    save(numbers, tmp_path / "out" / "adapt.json")
    written = json.loads((tmp_path / "out" / "adapt.json").read_text())
    assert list(written["rows"][0]) == ["capture", "weights", "recall", "precision", "dots_found", "dots_missed",
                                        "false_dots", "tracking"]
    assert written["rows"][0]["recall"] == 0.5 and written["rows"][1]["tracking"] == {"error": "no tape found"}
    assert written["rows"][0]["tracking"]["swaps"] == tracking.swaps and written["wall_s"] == 1.0
