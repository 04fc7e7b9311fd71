"""Writing a body fit: the summary's RMS over the markers (trunk markers apart), flags for markers
the body cannot explain and frames without a fit, every file written and read back."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from spinemocap.bodymodel.fit import BodyFit
from spinemocap.bodymodel.results import MARKER_FLAG_MM, write_fit


def _fit() -> BodyFit:
    residual = np.array([[1.0, 3.0, 30.0], [1.0, np.nan, 30.0], [1.0, 3.0, 30.0]])
    return BodyFit(model_name="anny", labels=["C7", "LASI", "RKNE"], vertices=np.array([10, 20, 30]),
                   shape=np.zeros(4), offsets=np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 2.0]]),
                   poses=np.zeros((3, 6)), residual_mm=residual, flagged=np.array([False, True, False]))


def test_the_summary_and_files_of_a_fit(tmp_path):
    summary = write_fit(tmp_path / "fit", _fit(), np.array([10, 11, 12]), 100.0, "walk.c3d", ("pelvis",))
    assert summary.per_marker_rms_mm == {"C7": 1.0, "LASI": 3.0, "RKNE": 30.0}
    assert summary.markers_flagged == ["RKNE"] and 30.0 > MARKER_FLAG_MM
    assert summary.frames_without_fit == [11] and summary.offset_mm["C7"] == pytest.approx(5.0)
    assert "C7" in summary.trunk_markers and "RKNE" not in summary.trunk_markers
    trunk = [k for k, label in enumerate(summary.markers) if label in summary.trunk_markers]
    assert summary.trunk_marker_rms_mm == pytest.approx(np.sqrt(np.nanmean(_fit().residual_mm[:, trunk] ** 2)))
    assert summary.marker_rms_mm == pytest.approx(np.sqrt(np.nanmean(_fit().residual_mm ** 2)))
    written = json.loads((tmp_path / "fit" / "summary.json").read_text())
    assert written["markers_flagged"] == ["RKNE"] and written["first_frame"] == 10
    assert written == summary.to_dict() and list(written)[-1] == "note" and "tape_dots" not in written
    with np.load(tmp_path / "fit" / "body.npz") as body:
        assert body["time"].tolist() == [0.1, 0.11, 0.12] and body["labels"].tolist() == ["C7", "LASI", "RKNE"]
    rows = (tmp_path / "fit" / "residuals.csv").read_text().splitlines()
    assert rows[0] == "frame,label,residual_mm" and "11,LASI," in rows and len(rows) == 10
    assert (tmp_path / "fit" / "residuals.png").stat().st_size > 1000


def test_a_fit_with_the_tape_laid_adds_its_files_after_the_note(tmp_path):
    summary = write_fit(tmp_path / "fit", _fit(), np.array([10, 11, 12]), 100.0, "walk.c3d", ("pelvis",))
    laid = replace(summary, tape_dots=str(tmp_path / "fit" / "tape_dots.c3d"), tape_row_levels=["L5", "L4"])
    laid.write(tmp_path / "fit")
    written = json.loads((tmp_path / "fit" / "summary.json").read_text())
    assert list(written)[-3:] == ["note", "tape_dots", "tape_row_levels"]
    assert written["tape_row_levels"] == ["L5", "L4"] and written["marker_rms_mm"] == summary.marker_rms_mm
