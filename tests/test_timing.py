"""StageTimer: per-stage totals in ms into a caller's dict, one sample per block or add()."""

from __future__ import annotations

import time

import pytest

from spinemocap.timing import StageTimer


def test_blocks_and_added_times_accumulate_per_stage_in_the_callers_dict():
    totals: dict[str, float] = {"detect": 1.0}
    timer = StageTimer(totals)
    with timer("lp"):
        time.sleep(0.01)
    timer.add("lp", 5.0)
    timer.add("detect", 2.0)
    assert timer.totals is totals
    assert totals["detect"] == 3.0
    assert totals["lp"] >= 15.0  # 10 ms asleep + 5 ms added
    assert timer.mean_ms() == pytest.approx({"lp": totals["lp"] / 2, "detect": 2.0})


def test_a_block_that_raises_is_still_timed():
    timer = StageTimer()
    with pytest.raises(RuntimeError), timer("mrf2"):
        raise RuntimeError("stage failed")
    assert list(timer.samples) == ["mrf2"] and timer.totals["mrf2"] >= 0.0
