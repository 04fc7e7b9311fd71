"""``bench realism``'s goals judged from the cases: the verdicts of every shipped result recomputed
from its cases equal the ones it holds, and a case that swaps fails the zero-swap goal."""

from __future__ import annotations

import json

import pytest
from repo_paths import ROOT

from spinemocap.bench.realism import CaseResult, GoalVerdict, RefinedScore, RefinementFailure, TrackerScore, verdict

RESULTS = sorted((ROOT / "docs" / "results" / "realism").glob("realism_200_*.json"))


@pytest.mark.parametrize("path", RESULTS, ids=lambda p: p.stem)
def test_the_shipped_verdicts_are_recomputed_from_their_cases(path):
    numbers = json.loads(path.read_text())
    cases = [CaseResult.from_dict(row) for row in numbers["cases"]]
    assert {goal: judged.to_dict() for goal, judged in verdict(cases).items()} == numbers["verdict"]


def test_a_swap_fails_the_goal_and_the_numbers_say_where():
    score = TrackerScore(mean_mm=0.7, p95_mm=1.5, swaps=3, flagged_frames=1, flagged_dot_share=0.01,
                         vouched_mean_mm=0.6, vouched_swaps=0, flags={}, unsolved_frames=0, stretch_along=None,
                         gate_px=2.0, ms_per_frame=10.0)
    lab = CaseResult("lab", "all", {"tape_tension": 0.15, "calibration_error_px": 0.5}, new=score, peer=score)
    judged = verdict([lab])
    assert judged["zero_swaps"] == GoalVerdict(False, by_case={"lab": 3}, judged_on="swaps")
    assert judged["zero_swaps"].to_dict() == {"met": False, "swaps": {"lab": 3}}
    assert judged["lab_mean_mm"].met and judged["lab_mean_mm"].numbers() == 0.7
    assert judged["flagged_dot_share"].to_dict() == {"met": True, "shares": {"lab": 0.01}}


def test_a_case_writes_its_json_keys_in_order_and_reads_back_the_same():
    score = TrackerScore(mean_mm=0.4, p95_mm=0.9, swaps=0, flagged_frames=2, flagged_dot_share=0.02,
                         vouched_mean_mm=0.35, vouched_swaps=0, flags={"stretch": 2}, unsolved_frames=0,
                         stretch_along=[1.0, 1.1, 1.2], gate_px=1.5, ms_per_frame=40.0)
    refined = RefinedScore(score, rig_rms_before_px=2.0, rig_rms_after_px=0.3, frame_uncertainty_mm=1.2,
                           shape_mm=0.3, world_frame="reference", reference_fit_px=0.2, reference_fit_mm=0.1,
                           given_frame_offset_mm=4.0)
    case = CaseResult("calibration 2.0 px + reference", "calibration", {"calibration_error_px": 2.0, "reference": True},
                      new=score, peer=score, new_refined=refined,
                      new_refined_without_reference=RefinementFailure("too few dots"))
    written = case.to_dict()
    assert list(written) == ["case", "factor", "studio", "new", "new_refined_without_reference", "new_refined", "peer"]
    assert written["new_refined_without_reference"] == {"error": "too few dots"}
    assert list(written["new_refined"])[len(written["new"]):] == [
        "rig_rms_before_px", "rig_rms_after_px", "frame_uncertainty_mm", "shape_mm", "world_frame",
        "reference_fit_px", "reference_fit_mm", "given_frame_offset_mm"]
    in_given_frame = RefinedScore(score, 2.0, 0.3, 1.2, 0.3, "given rig").to_dict()
    assert "reference_fit_px" not in in_given_frame and in_given_frame["world_frame"] == "given rig"
    assert CaseResult.from_dict(json.loads(json.dumps(written))) == case
    assert verdict([case])["refined_2px_reference_mean_mm"].numbers() == 0.4
