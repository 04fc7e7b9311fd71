"""``spinemocap bench opensim``: the IK methods a run picks and the headline over them (no OpenSim run)."""

from __future__ import annotations

import pytest

from spinemocap.bench.opensim import GOALS, IK_METHODS, format_table, headline
from spinemocap.fileio import InputError


def _scores(flexion: float, rms: float) -> dict:
    return {"flexion_rmse_deg": flexion, "flexion_r2": 0.99, "flexion_gain": 1.0, "crosstalk_rms_deg": 0.1,
            "marker_rms_mm": rms, "ms_per_frame": 10.0}


def test_the_headline_covers_the_methods_that_ran_and_judges_each_against_the_goals():
    runs = {"flexion/seed0": {"ik": _scores(1.2, 0.6), "ik_slip_goal": _scores(2.5, 0.9),
                              "geometric": {"flexion_rmse_deg": 3.0, "flexion_r2": 0.9, "ms_per_frame": 1.0}},
            "flexion/seed1": {"ik": _scores(1.9, 2.4), "ik_slip_goal": _scores(1.0, 0.7),
                              "geometric": {"flexion_rmse_deg": 1.5, "flexion_r2": 0.9, "ms_per_frame": 1.0}}}
    table = headline({"groundtruth": runs})["groundtruth"]
    assert list(table) == ["ik", "ik_slip_goal", "geometric"]  # only what ran
    assert table["ik"].rmse_deg_worst == {"flexion": 1.9} and table["ik"].goals_met["flexion"]
    assert not table["ik"].goals_met["marker_rms"]  # 2.4 mm over the 2 mm goal
    assert table["ik_slip_goal"].rmse_deg_worst["flexion"] > GOALS["flexion_rmse_deg"]
    assert not table["ik_slip_goal"].goals_met["flexion"]
    assert table["ik"].to_dict() == {"flexion_rmse_deg_worst": 1.9, "marker_rms_mm_worst": 2.4,
                                     "goals_met": {"flexion": True, "marker_rms": False}}
    assert table["geometric"].marker_rms_mm_worst is None and "marker_rms" not in table["geometric"].goals_met
    lines = format_table({"groundtruth": runs}).splitlines()
    assert len(lines) == 1 + 2 * 3 and any("ik_slip_goal" in line for line in lines)


def test_the_slip_methods_are_the_pipelines_uses_of_the_tapes_slip():
    from spinemocap.opensim import OpenSimSettings
    from spinemocap.opensim.pipeline import SLIP_SOLVER, slip_solved_as

    assert IK_METHODS["ik"] == {} and OpenSimSettings() == slip_solved_as("held")  # the default holds the slips
    assert OpenSimSettings().slip.from_tape == "held"
    for method, use in (("ik_slip_goal", "goal"), ("ik_slip_from_markers", "off")):
        settings = slip_solved_as(use)
        assert IK_METHODS[method]["slip"] == settings.slip and settings.slip.from_tape == use
        assert (IK_METHODS[method]["accuracy"], IK_METHODS[method]["fresh_start_margin"]) == SLIP_SOLVER[use]
    assert SLIP_SOLVER["off"][0] > SLIP_SOLVER["held"][0]  # the markers-only slips at OpenSim's looser default


def test_an_unknown_method_is_a_clear_error():
    pytest.importorskip("opensim")
    from spinemocap.bench.opensim import run_opensim_benchmark

    with pytest.raises(InputError, match="ik_slip_from_markers") as unknown:
        run_opensim_benchmark(motions=["flexion"], methods=["ik", "fastest"], progress=False)
    assert unknown.value.source == "methods"  # the parameter; the command line shows --methods


def test_the_headline_plot_is_a_png_of_every_method_that_ran():
    from spinemocap.bench.opensim import OpenSimBenchReport, headline_plot_png

    runs = {"flexion/seed0": {"ik": _scores(1.2, 0.6), "ik_slip_goal": _scores(2.5, 0.9),
                              "geometric": {"flexion_rmse_deg": 3.0, "flexion_r2": 0.9, "ms_per_frame": 1.0}}}
    report = OpenSimBenchReport("x86_64", "2026-01-01", "lab", None, ["ik", "ik_slip_goal", "geometric"],
                                headline({"groundtruth": runs, "tracked": runs}), {"groundtruth": runs, "tracked": runs},
                                1.0)
    png = headline_plot_png(report)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_the_frames_without_a_flagged_marker_are_scored_apart_and_the_goals_judge_all_frames():
    import numpy as np

    from spinemocap.bench.opensim import score

    expected = np.zeros((6, 3))
    expected[:, 0] = np.linspace(0.0, 50.0, 6)
    measured = expected.copy()
    measured[3:5, 0] += 10.0  # the bend's peak off by 10 deg where the markers are flagged
    vouched = np.array([True, True, True, False, False, True])
    out = score(measured, expected, [0], vouched)
    assert out["flexion_rmse_deg_vouched"] == pytest.approx(0.0) and out["vouched_frames"] == 4
    assert out["flexion_rmse_deg"] == pytest.approx(np.sqrt(200.0 / 6))
    assert "flexion_rmse_deg_vouched" not in score(measured, expected, [0])
    runs = {"flexion/seed0": {"ik": {**_scores(out["flexion_rmse_deg"], 0.6), "flexion_rmse_deg_vouched": 0.0}}}
    row = headline({"tracked": runs})["tracked"]["ik"]
    assert row.rmse_deg_vouched_worst["flexion"] == 0.0 and list(row.numbers()) == [
        "flexion_rmse_deg_worst", "flexion_rmse_deg_vouched_worst", "marker_rms_mm_worst"]
    assert not row.goals_met["flexion"]  # the goal is judged on every frame


def test_the_ik_runs_take_the_depth_of_the_studio_bodys_own_joints():
    """The model's joint centres sit where the studio's spine bends: well short of the published
    depth on anny's joints, at it (within a few percent) on the anatomical joint depth."""
    from spinemocap.bench.analysis import studio_motion
    from spinemocap.bench.opensim import body_model_depth_scale

    scales = {}
    for depth in ("anny", "anatomical"):
        data = studio_motion("flexion", 2, 10.0, 13, joint_depth=depth)
        assert data.scene.body.joint_depth == depth
        scales[depth] = body_model_depth_scale(data, data.levels)
    assert scales["anny"] < 0.75 and 0.95 < scales["anatomical"] < 1.1, scales
