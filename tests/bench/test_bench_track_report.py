"""``bench track``'s result: the accuracy beside the paper's numbers on screen, every number in the
JSON and the per-frame error plot beside it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spinemocap.app.run import TrackQuality
from spinemocap.bench.track import GOAL_MM, PAPER_ERROR_MM, TrackBenchResult, TrackBenchRun, format_report
from spinemocap.markers import MarkerTable
from spinemocap.tape import TapeSpec
from spinemocap.track.evaluate import evaluate_tracking

QUALITY = TrackQuality(flagged_frames=[2], flags={"lp_relaxed": 1}, stretch_along=(1.1, 1.2, 1.3), stretch_across=1.0,
                       gate_px=2.5, rig_rms_px={"cam1": 0.5}, calibration_warning=None, missing_cameras={})


def test_a_run_one_millimetre_off_is_reported_and_saved(tmp_path):
    tape = TapeSpec(n_rows=5)
    rng = np.random.default_rng(0)
    dots = np.stack([np.c_[tape.graph.uv_mm, np.zeros(len(tape.labels))] + rng.normal(0, 5, 3) for _ in range(4)])
    groundtruth = {"labels": np.array(tape.labels), "dots": dots,
                   "visible": np.ones((4, 3, len(tape.labels)), bool)}
    table = MarkerTable.from_arrays(tape.labels, dots + [1.0, 0.0, 0.0], fps=50.0)
    accuracy = evaluate_tracking(table, groundtruth, float(tape.graph.rest_length_mm.min()))
    run = TrackBenchRun(preset="tiny", occlusion="light", balls=3, mode="sequence", realism="lab", quality=QUALITY,
                        detector="mask", cameras=3, rows=5, wall_s=1.0, tape_thickness_mm=0.8,
                        routes={"full": 4}, frames_failed_before_gap_fill=0, lp_relaxed_frames=0,
                        paper={"error_mm": PAPER_ERROR_MM["light"]}, goal_mm=GOAL_MM["light"])
    result = TrackBenchResult(accuracy, run, table, groundtruth)
    assert result.numbers["mean_error_mm"] == pytest.approx(1.0) and result.numbers["label_swaps"] == 0
    report = format_report(result)
    assert "Table 1" in report and "Table 2 (occlusion 'light'" in report and "1.00" in report
    assert [line.split()[-1] for line in report.splitlines() if "flagged frames" in line] == ["1"]
    plot = result.save(tmp_path / "track.json")
    saved = json.loads((tmp_path / "track.json").read_text())
    assert saved["goal_mm"] == 2.5 and saved["mean_error_mm"] == pytest.approx(1.0) and saved["routes"] == {"full": 4}
    assert saved["quality"] == {"flagged_frames": [2], "flags": {"lp_relaxed": 1}, "stretch_along": [1.1, 1.2, 1.3],
                                "stretch_across": 1.0, "gate_px": 2.5, "rig_rms_px": {"cam1": 0.5},
                                "calibration_warning": None, "missing_cameras": {}}
    assert list(saved).index("quality") == list(saved).index("realism") + 1  # the run's fields in their order
    assert plot == tmp_path / "track.png" and plot.stat().st_size > 1000
