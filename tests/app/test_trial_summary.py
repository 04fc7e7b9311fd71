"""A trial's summary as a typed result: written and read back unchanged, a damaged one refused
by name, and a damaged cached one processed again rather than trusted."""

from __future__ import annotations

import json

import pytest
from test_analysis_batch import LEVELS_TOML, _write_trial

from spinemocap.app.batch import load_results, run_batch
from spinemocap.app.trial_summary import TrialOutcome, TrialSummary
from spinemocap.fileio import InputError, strict_json


@pytest.fixture()
def batch(tmp_path):
    root = tmp_path / "study"
    (root / "S01").mkdir(parents=True)
    (root / "S01" / "levels.toml").write_text(LEVELS_TOML)
    _write_trial(root / "S01" / "pre" / "trial01", 20.0, n_frames=12, gap_rows=(6, 7, 8))
    (root / "S01" / "pre" / "trial02").mkdir()  # no capture: a failed trial
    out = tmp_path / "out"
    return root, out, run_batch(root, out, source="groundtruth", workers=1, progress=False)


def test_summaries_read_back_write_the_same_json(batch):
    root, out, result = batch
    good, bad = result.trials
    assert isinstance(good, TrialOutcome) and good.summary.analysis is not None and not good.skipped
    assert bad.summary.status == "failed" and bad.summary.analysis is None and "capture.toml" in bad.summary.reason
    assert good.summary.notes["lumbar"]  # the hidden rows leave NaN lumbar angles with their reason
    for summary in load_results(out):
        written = (out / summary.key / "summary.json").read_text()
        assert strict_json(summary.to_dict()) == written
    batch_json = json.loads((out / "batch.json").read_text())
    assert batch_json["trials"] == [json.loads(strict_json(t.to_dict())) for t in result.trials]
    assert [t["skipped"] for t in batch_json["trials"]] == [False, False]


def test_a_damaged_summary_is_refused_by_name_and_its_trial_processed_again(batch):
    root, out, _ = batch
    path = out / "S01/pre/trial01/summary.json"
    data = json.loads(path.read_text())
    del data["stats"]
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="summary.json.*not a trial summary.*KeyError: 'stats'"):
        load_results(out)
    with pytest.raises(InputError, match="not a trial summary"):
        TrialSummary.from_dict({**data, "stats": None}, path.parent)
    again = run_batch(root, out, source="groundtruth", workers=1, progress=False)
    assert [(t.summary.key, t.skipped) for t in again.trials if t.summary.ok] == [("S01/pre/trial01", False)]
    assert "stats" in json.loads(path.read_text())


@pytest.mark.parametrize("steps", [
    {"opensim": {"status": "ok", "marker_rms_mm": 1.25, "marker_rms_mm_max": None, "ms_per_frame": 3.5,
                 "flagged_frames": 2, "driven_joints": ["L1_L2", "L2_L3"], "out_dir": "/out/S01/opensim"},
     "view": {"status": "ok", "frames": 12, "seconds": 4.2}},
    {"opensim": {"status": "failed", "reason": "no OpenSim"}, "view": {"status": "failed", "reason": "no images"}},
])
def test_the_optional_steps_read_back_write_the_same_json(batch, steps):
    _, out, result = batch
    path = out / "S01/pre/trial01/summary.json"
    data = json.loads(path.read_text())
    with_steps = {**{k: data[k] for k in ("key", "subject", "condition", "trial", "capture", "source")}, **steps,
                  **{k: v for k, v in data.items() if k not in steps and k not in ("key", "subject", "condition",
                                                                                  "trial", "capture", "source")}}
    summary = TrialSummary.from_dict(with_steps, path.parent)
    assert summary.opensim is not None and summary.view is not None
    assert strict_json(summary.to_dict()) == strict_json(with_steps)
