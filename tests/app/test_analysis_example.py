"""The synthetic-study example runs end to end (renders 12 small captures: slow)."""

import subprocess
import sys

import pandas as pd
import pytest
from repo_paths import ROOT


@pytest.mark.slow
def test_synthetic_study_example(tmp_path):
    script = ROOT / "examples" / "synthetic_study.py"
    subprocess.run([sys.executable, str(script), "--out", str(tmp_path), "--frames", "4", "--fps", "2"],
                   check=True, timeout=1800)
    summary = pd.read_csv(tmp_path / "results" / "summary.csv")
    assert len(summary) == 12 and (summary["status"] == "ok").all()
    assert set(summary["subject"]) == {"S01", "S02", "S03"} and set(summary["condition"]) == {"flexion", "forehand"}
    flexion = summary[summary["condition"] == "flexion"]["flexion_rom_deg"]
    assert (flexion > 5).all()  # the flexion trials bend the lumbar spine
    page = (tmp_path / "results" / "report.html").read_text()
    assert "alt='range of motion by subject and condition'" in page
    assert page.count("alt='spine shape and segmental angles: ") == 12
    # the lumbar angle is the standard S1 -> T12/L1 and finite in every frame of every trial
    assert (summary["lumbar_valid_pct"] == 100).all()
    assert "T12/L1 relative to S1" in page
