"""Batch over a study (process pool, real Dask LocalCluster), resumability, bad trials, report."""

import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from repo_paths import SHARED

from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.app.batch import discover, run_batch
from spinemocap.app.report import write_report
from spinemocap.cli import main
from spinemocap.tape import TapeSpec

TAPE = TapeSpec(n_rows=9)
LEVELS_TOML = '[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n'


def _write_trial(folder: Path, peak_flexion: float, n_frames: int = 30, gap_rows=()) -> None:
    """Exact tape dots (groundtruth.npz) for a lumbar flexion of ``peak_flexion`` over
    S1..T12/L1 (rows 1..7, 0..150 mm) on a 10 deg/100 mm kyphotic background; ``gap_rows``
    hidden in frames 5..24 (a long occlusion)."""
    write_bent_capture(folder, TAPE, peak_flexion, n_frames, fps=50.0, hidden_rows=tuple(gap_rows),
                       hidden_frames=slice(5, 25))


@pytest.fixture()
def study(tmp_path):
    root = tmp_path / "study"
    for s, subject in enumerate(("S01", "S02")):
        (root / subject).mkdir(parents=True)
        (root / subject / "levels.toml").write_text(LEVELS_TOML)
        for c, condition in enumerate(("pre", "post")):
            _write_trial(root / subject / condition / "trial01", 20.0 + 10 * c + 5 * s)
    return root


def test_batch_on_dask_localcluster_then_report(study, tmp_path):
    from distributed import LocalCluster

    # problem trials beside the good ones: no capture, a level map naming rows the tape lacks,
    # and markers with a long gap
    (study / "S01" / "pre" / "trial02").mkdir()
    _write_trial(study / "S02" / "pre" / "trial02", 25.0)
    (study / "S02" / "pre" / "trial02" / "levels.toml").write_text('[levels]\nS1 = 1\n"T12/L1" = 7\nT7 = 12\n')
    _write_trial(study / "S02" / "post" / "trial02", 25.0, gap_rows=(6, 7, 8))
    out = tmp_path / "out"
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        result = run_batch(study, out, source="groundtruth", scheduler=cluster.scheduler_address, progress=False)
    by_key = {t.summary.key: t.summary for t in result.trials}
    assert len(by_key) == 7
    assert "no capture.toml" in by_key["S01/pre/trial02"].reason
    assert "T7 is mapped to row 12" in by_key["S02/pre/trial02"].reason
    assert {k for k, t in by_key.items() if t.status != "ok"} == {"S01/pre/trial02", "S02/pre/trial02"}
    # every good trial: lumbar flexion follows the applied peak (the background bend adds 15 deg);
    # 3 % of the angle is what the spline loses at the curvature step placed exactly at T12/L1
    for key, peak in {"S01/pre/trial01": 20, "S01/post/trial01": 30, "S02/pre/trial01": 25}.items():
        stats = by_key[key].stats
        assert stats["lumbar_flexion_rom"] == pytest.approx(peak, abs=0.03 * peak)
        assert stats["lumbar_flexion_max"] == pytest.approx(peak + 15, abs=0.03 * (peak + 15))
        assert np.isfinite(stats["thoracic_flexion_rom"])  # upper level: the map's top (T10)
        assert by_key[key].analysis.completeness_pct == 100.0
    gap = by_key["S02/post/trial02"]
    assert gap.status == "ok" and gap.analysis.completeness_pct < 80
    (reason, frames), = gap.notes["lumbar"].items()
    assert frames == 20 and "T12/L1" in reason
    angles = pd.read_csv(out / "S02/post/trial02/angles.csv")
    assert angles["lumbar_flexion"][5:25].isna().all() and angles["lumbar_flexion"][:5].notna().all()
    log = (out / "batch.log").read_text()
    assert "S01/pre/trial02 failed: " in log and "lumbar angles NaN in 20 frames" in log

    paths = write_report(out)
    page = paths["html"].read_text()
    assert page.count("data:image/png;base64,") >= 6  # group plot + one per analysed trial
    assert "no capture.toml in this trial folder" in page and "T7 is mapped to row 12" in page
    assert "tape rows near T12/L1" in page
    summary = pd.read_csv(paths["csv"])
    xlsx = pd.read_excel(paths["xlsx"], sheet_name=None)
    assert set(xlsx) == {"trials", "by_subject", "by_condition", "problems"}
    assert np.allclose(xlsx["trials"]["flexion_rom_deg"], summary["flexion_rom_deg"], atol=1e-3, equal_nan=True)
    by_condition = pd.read_csv(paths["by_condition"]).set_index("condition")
    ok = summary[summary["status"] == "ok"]
    assert by_condition.loc["post", "n_trials"] == 3 and by_condition.loc["pre", "n_failed"] == 2
    assert by_condition.loc["pre", "flexion_rom_deg_mean"] == pytest.approx(
        ok[ok["condition"] == "pre"]["flexion_rom_deg"].mean(), abs=1e-3)


def test_batch_resumes_and_reprocesses_only_stale_trials(study, tmp_path):
    out = tmp_path / "out"
    first = run_batch(study, out, source="groundtruth", workers=2, progress=False)  # process pool
    assert len(first.processed) == 4 and not first.failed
    assert not list(out.rglob(".*.tmp"))  # atomic writes leave no temporaries
    # an interrupted batch: one trial never finished (no summary); another's input changed since
    (out / "S01/pre/trial01/summary.json").unlink()
    earlier = time.time() - 100  # the results predate a change of the ground truth
    os.utime(out / "S02/post/trial01/summary.json", (earlier, earlier))
    os.utime(study / "S02/post/trial01/groundtruth.npz", (earlier + 50, earlier + 50))
    second = run_batch(study, out, source="groundtruth", workers=1, progress=False)
    assert sorted(t.summary.key for t in second.processed) == ["S01/pre/trial01", "S02/post/trial01"]
    assert len(second.trials) == 4 and not second.failed
    third = run_batch(study, out, source="groundtruth", workers=1, progress=False)
    assert third.processed == []


def test_failed_trial_is_retried_and_others_untouched(study, tmp_path):
    out = tmp_path / "out"
    bad = study / "S01/post/trial01/groundtruth.npz"
    bad.write_bytes(b"not an npz")
    result = run_batch(study, out, source="groundtruth", workers=1, progress=False)
    (failed,) = result.failed
    assert failed.summary.key == "S01/post/trial01" and len(result.trials) == 4
    assert json.loads((out / "S01/post/trial01/summary.json").read_text())["status"] == "failed"
    _write_trial(study / "S01" / "post" / "trial01", 30.0)  # fixed: a failed trial is never "up to date"
    again = run_batch(study, out, source="groundtruth", workers=1, progress=False)
    assert [t.summary.key for t in again.processed] == ["S01/post/trial01"] and not again.failed


def test_manifest_discovery_and_cli(study, tmp_path, capsys):
    manifest = tmp_path / "manifest.csv"
    manifest.write_text("path,subject,condition\nstudy/S01/pre/trial01,A,fast\nstudy/S02/post/trial01,B,slow\n"
                        "study/nowhere,C,slow\n")
    trials = discover(manifest)
    assert [(t.subject, t.condition, t.trial) for t in trials][:2] == [("A", "fast", "trial01"), ("B", "slow", "trial01")]
    assert "no capture.toml" in trials[2].problem
    out = tmp_path / "out"
    code = main(["-q", "batch", str(manifest), "--out", str(out), "--source", "groundtruth",
                 "--workers", "1", "--levels", str(study / "S01" / "levels.toml"), "--report"])
    text = capsys.readouterr().out
    assert code == 1 and "2 ok" in text and "FAILED C/slow/nowhere" in text
    assert (out / "report.html").is_file() and (out / "A/fast/trial01/angles.csv").is_file()
    assert main(["report", str(tmp_path / "missing")]) == 2  # clean InputError, no traceback


def test_pelvis_from_a_vicon_c3d_named_in_the_manifest(tmp_path):
    c3d = SHARED / "data" / "vicon" / "walking01_plugin_gait_lower.c3d"
    if not c3d.is_file():
        pytest.skip("shared Vicon data not available")
    _write_trial(tmp_path / "study" / "S01" / "walk" / "trial01", 20.0)
    (tmp_path / "study" / "S01" / "levels.toml").write_text(LEVELS_TOML)
    manifest = tmp_path / "manifest.csv"
    manifest.write_text(f"path,subject,condition,c3d\nstudy/S01/walk/trial01,S01,walk,{c3d}\n")
    result = run_batch(manifest, tmp_path / "out", source="groundtruth", workers=1, progress=False)
    (outcome,) = result.trials
    trial = outcome.summary
    assert trial.status == "ok" and trial.analysis.pelvis_from == "c3d"
    angles = pd.read_csv(tmp_path / "out" / "S01/walk/trial01/angles.csv")
    # the subject walks into the volume: the trial's first samples lack pelvis markers -> NaN
    # with the reason; afterwards the pelvis angles exist and move with the gait
    missing = angles["pelvis_tilt"].isna()
    assert 0 < missing.sum() < len(angles) and (angles.loc[missing, "pelvis_note"] == "pelvis markers missing").all()
    assert trial.notes["pelvis"] == {"pelvis markers missing": int(missing.sum())}
    assert np.ptp(angles.loc[~missing, "pelvis_rotation"]) > 0.5


def test_angles_command_on_one_marker_file(tmp_path, capsys):
    import exporters
    from spinemocap.markers import MarkerTable

    _write_trial(tmp_path / "S01" / "x" / "t1", 30.0, gap_rows=(6, 7, 8))
    with np.load(tmp_path / "S01/x/t1/groundtruth.npz") as data:
        table = MarkerTable.from_arrays(list(data["labels"]), data["dots"], fps=50.0)
    exporters.write(table, tmp_path / "trial.trc")
    (tmp_path / "levels.toml").write_text(LEVELS_TOML)
    assert main(["angles", str(tmp_path / "trial.trc"), "--levels", str(tmp_path / "levels.toml")]) == 0
    text = capsys.readouterr().out
    assert "lumbar angles NaN in 20 frames: tape rows near T12/L1" in text
    angles = pd.read_csv(tmp_path / "trial_angles.csv")
    assert np.nanmax(angles["lumbar_flexion"]) - np.nanmin(angles["lumbar_flexion"]) > 10
    assert (tmp_path / "trial_angles.png").stat().st_size > 1000
