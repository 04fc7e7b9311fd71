"""``spinemocap bench opensim``: the IK methods a run picks and the headline over them (no OpenSim run)."""

from __future__ import annotations

import pytest

from spinemocap.bench.opensim import GOALS, IK_METHODS, SLIP_FROM_TAPE, format_table, headline
from spinemocap.fileio import InputError


def _scores(flexion: float, rms: float) -> dict:
    return {"flexion_rmse_deg": flexion, "flexion_r2": 0.99, "flexion_gain": 1.0, "crosstalk_rms_deg": 0.1,
            "marker_rms_mm": rms, "ms_per_frame": 10.0}


def test_the_headline_covers_the_methods_that_ran_and_judges_each_against_the_goals():
    runs = {"flexion/seed0": {"ik": _scores(1.2, 0.6), "ik_slip_from_tape": _scores(2.5, 0.9),
                              "geometric": {"flexion_rmse_deg": 3.0, "flexion_r2": 0.9, "ms_per_frame": 1.0}},
            "flexion/seed1": {"ik": _scores(1.9, 2.4), "ik_slip_from_tape": _scores(1.0, 0.7),
                              "geometric": {"flexion_rmse_deg": 1.5, "flexion_r2": 0.9, "ms_per_frame": 1.0}}}
    table = headline({"groundtruth": runs})["headline"]["groundtruth"]
    assert list(table) == ["ik", "ik_slip_from_tape", "geometric"]  # only what ran
    assert table["ik"]["flexion_rmse_deg_worst"] == 1.9 and table["ik"]["goals_met"]["flexion"]
    assert not table["ik"]["goals_met"]["marker_rms"]  # 2.4 mm over the 2 mm goal
    assert table["ik_slip_from_tape"]["flexion_rmse_deg_worst"] > GOALS["flexion_rmse_deg"]
    assert not table["ik_slip_from_tape"]["goals_met"]["flexion"]
    lines = format_table({"groundtruth": runs}).splitlines()
    assert len(lines) == 1 + 2 * 3 and any("ik_slip_from_tape" in line for line in lines)


def test_the_slip_from_tape_method_is_the_pipelines_option_of_that_name():
    from spinemocap.opensim import OpenSimSettings
    from spinemocap.opensim.pipeline import slip_from_tape

    settings = slip_from_tape()
    assert SLIP_FROM_TAPE["slip"].estimate_sd_mm == settings.slip.estimate_sd_mm == 3.0
    assert SLIP_FROM_TAPE["accuracy"] == settings.accuracy < OpenSimSettings().accuracy
    assert OpenSimSettings().slip.estimate_sd_mm is None and IK_METHODS["ik"] == {}


def test_an_unknown_method_is_a_clear_error():
    pytest.importorskip("opensim")
    from spinemocap.bench.opensim import run_opensim_benchmark

    with pytest.raises(InputError, match="ik_slip_from_tape"):
        run_opensim_benchmark(motions=["flexion"], methods=["ik", "fastest"], progress=False)
