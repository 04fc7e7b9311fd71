"""The angle benchmark's agreement statistics and the batch benchmark's result."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.bench.analysis import BatchBenchResult, fit_stats


def test_fit_stats_of_a_biased_measurement():
    expected = np.linspace(0.0, 20.0, 21)
    measured = expected + 1.0
    measured[3] = np.nan
    stats = fit_stats(measured, expected)
    assert stats.rmse_deg == pytest.approx(1.0) and stats.bias_deg == pytest.approx(1.0)
    assert stats.loa_low_deg == pytest.approx(1.0) and stats.loa_high_deg == pytest.approx(1.0)
    assert stats.frames == 20 and stats.valid == pytest.approx(20 / 21)
    assert stats.r2 == pytest.approx(1 - 20 / np.sum((np.delete(expected, 3) - np.delete(expected, 3).mean()) ** 2))
    assert fit_stats(np.full(3, np.nan), np.zeros(3)).frames == 0


def test_the_batch_result_gives_rates_and_speed_ups():
    result = BatchBenchResult(trials=10, frames=100, workers=2, identical_results=True,
                              seconds={"serial": 8.0, "process_pool": 4.0, "dask_localcluster": 5.0})
    assert result.trials_per_s == {"serial": 1.25, "process_pool": 2.5, "dask_localcluster": 2.0}
    assert result.speedup_vs_serial["process_pool"] == 2.0
    numbers = result.to_dict()
    assert numbers["identical_results"] is True and numbers["speedup_vs_serial"]["dask_localcluster"] == 1.6
    assert set(numbers) == {"trials", "frames", "workers", "identical_results", "seconds", "trials_per_s",
                            "speedup_vs_serial"}
