"""The world-frame benchmark's summary per calibration level: statistics of each gauge and how
often the refined rig beats the given one, stays within 1 mm, and the reference was used."""

from __future__ import annotations

from dataclasses import replace

import pytest

from spinemocap.bench.rig_gauge import (
    CalibrationGauges,
    GaugeRow,
    ReferenceGauge,
    ReferenceNotUsed,
    format_table,
    summarize,
)


def _row(level: float, given: float, refined: float, reference: float | None = None) -> GaugeRow:
    gauges = CalibrationGauges(given=given, refined=refined, residual_priors=1.2, cloud_gauge=9.0, closest_cameras=9.0,
                               refined_shape=0.3, frame_uncertainty=0.5, residual_priors_frame_uncertainty=0.6,
                               rig_rms_before_px=2.0, rig_rms_after_px=0.4,
                               with_reference=None if reference is None else ReferenceGauge(reference, 0.3, 0.3, 0.3, 12,
                                                                                             0.3, 0.4))
    return GaugeRow(seed=0, level_px=level, rig=0, gauges=gauges)


def test_summary_per_level_and_its_table():
    rows = [_row(2.0, 2.5, 0.8), _row(2.0, 3.0, 1.6), _row(1.0, 1.0, 1.1),
            _row(2.0, 2.0, 0.9, reference=0.33)]
    summary = summarize(rows)
    assert list(summary) == ["1", "2"]
    two = summary["2"]
    assert two["n"] == 3 and two["refined"]["mean"] == pytest.approx(1.1) and two["refined"]["max"] == 1.6
    assert two["refined_better_than_given"] == 3 and two["refined_at_most_1mm"] == 2
    assert two["refined_better_than_residual_priors"] == 2
    assert two["reference"]["n"] == 1 and two["reference_at_most_1mm"] == 1 and two["reference_not_used"] == 0
    assert summary["1"]["refined_better_than_given"] == 0 and "reference" not in summary["1"]
    table = format_table(summarize(rows))
    assert "| 2 px | 3 |" in table and "2 of 3 |" in table and "with the reference (L-frame)" in table


def test_a_row_writes_its_gauges_then_the_reference_or_why_it_was_not_used():
    used = _row(2.0, 2.0, 0.9, reference=0.33).to_dict()
    assert list(used)[:4] == ["seed", "level_px", "rig", "given"]
    assert list(used)[-7:] == ["reference", "reference_shape", "reference_fit_px", "reference_fit_mm",
                               "reference_observations", "given_frame_offset_mm", "reference_rig_rms_after_px"]
    plain = _row(2.0, 2.0, 0.9)
    failed = GaugeRow(0, 2.0, 1, replace(plain.gauges, with_reference=ReferenceNotUsed("too few markers seen")))
    assert list(plain.to_dict())[-1] == "rig_rms_after_px" and failed.to_dict()["reference_error"] == "too few markers seen"
    assert failed.value("reference") is None and failed.reference_error == "too few markers seen"
    summary = summarize([_row(2.0, 2.0, 0.9, reference=0.0), failed])["2"]
    assert summary["reference_at_most_1mm"] == 1 and summary["reference_not_used"] == 1
