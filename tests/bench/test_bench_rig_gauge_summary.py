"""The world-frame benchmark's summary per calibration level: statistics of each gauge and how
often the refined rig beats the given one, stays within 1 mm, and the reference was used."""

from __future__ import annotations

import pytest

from spinemocap.bench.rig_gauge import GAUGES, format_table, summarize


def _row(level: float, given: float, refined: float, **more: float) -> dict:
    row = {"level_px": level, "refined_shape": 0.3, "frame_uncertainty": 0.5, **{g: 9.0 for g in GAUGES}}
    row.update(given=given, refined=refined, residual_priors=1.2, **more)
    return row


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
    rows[3].update({key: 0.3 for key in ("reference_shape", "reference_fit_px", "reference_fit_mm",
                                         "given_frame_offset_mm")})
    table = format_table({"summary": summarize(rows)})
    assert "| 2 px | 3 |" in table and "2 of 3 |" in table and "with the reference (L-frame)" in table
