"""``bench realism``'s goals judged from the cases: the verdicts of every shipped result recomputed
from its cases equal the ones it holds, and a case that swaps fails the zero-swap goal."""

from __future__ import annotations

import json

import pytest
from repo_paths import ROOT

from spinemocap.bench.realism import GoalVerdict, verdict

RESULTS = sorted((ROOT / "docs" / "results" / "realism").glob("realism_200_*.json"))


@pytest.mark.parametrize("path", RESULTS, ids=lambda p: p.stem)
def test_the_shipped_verdicts_are_recomputed_from_their_cases(path):
    numbers = json.loads(path.read_text())
    assert {goal: judged.to_dict() for goal, judged in verdict(numbers["cases"]).items()} == numbers["verdict"]


def test_a_swap_fails_the_goal_and_the_numbers_say_where():
    lab = {"case": "lab", "factor": "all", "studio": {"tape_tension": 0.15, "calibration_error_px": 0.5},
           "new": {"swaps": 3, "mean_mm": 0.7, "flagged_dot_share": 0.01}}
    judged = verdict([lab])
    assert judged["zero_swaps"] == GoalVerdict(False, by_case={"lab": 3}, judged_on="swaps")
    assert judged["zero_swaps"].to_dict() == {"met": False, "swaps": {"lab": 3}}
    assert judged["lab_mean_mm"].met and judged["lab_mean_mm"].numbers() == 0.7
    assert judged["flagged_dot_share"].to_dict() == {"met": True, "shares": {"lab": 0.01}}
