"""``summary.json`` of ``spinemocap opensim``: the typed summaries written as JSON and read back
(no OpenSim run: the summaries are built by hand)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest

from spinemocap.fileio import InputError, strict_json
from spinemocap.opensim.summary import (
    NO_SLIP,
    Depth,
    LabModelSummary,
    Placement,
    SkinModelSummary,
    SlipSummary,
    SpineModelSummary,
    read_summary,
)

COMMON = dict(frames=12, fps=12.0, marker_rms_mm=0.8, marker_rms_mm_max=1.4, ms_per_frame=35.5,
              flagged_frames=[3, 7], flag_reasons={"marker RMS > 4 mm": 1, "a marker > 10 mm off": 2}, warnings=[],
              driven_joints=["L4_L5", "L3_L4"], markers_by_body={"L4": ["R01L", "R01R"], "L3_skin": ["R03C"]},
              facing_error_deg=2.5, marker_weights={"R01L": 1.0, "R01R": 0.25, "R03C": 0.8})


def _spine(**changes) -> SpineModelSummary:
    slip = SlipSummary(model="each row above the pinned ones slips", from_tape="held", held_share=0.9167,
                       pinned_rows=["R01", "R02"], prior="Gaussian, SD 25 mm; clamped to +/-80 mm",
                       prior_weight_per_m2=0.0016, estimate_weight_per_m2=0.1111, at_peak_mm={"R03_skin_slip": -4.2})
    summary = SpineModelSummary(
        **COMMON, marker_rms_observed_mm=0.6, marker_max_mm=3.1, welded_joints=["S1_L5"],
        couplers=[("L3_L4_lateral_bending", "L4_L5_lateral_bending", 0.8571)], coordinates=["L4_L5_extension"],
        markers_not_placed=["R13L"], levels_mapped=["S1", "T12"], scale_to_generic=0.97,
        placement=Placement(lateral_median_mm=2.0, lateral_max_mm=6.5, depth_median_mm=4.0, depth_max_mm=9.0,
                            vertical_median_mm=1.5),
        region_ranges_deg={"lumbar_flexion": (-1.5, 16.0)}, ik_accuracy=1e-7, ik_accuracy_note="",
        ik="OpenSim InverseKinematicsSolver frame by frame", opensim_version="4.6",
        depth=Depth(scale_on_published=1.0, source="published depths", depth_mm={"L3": 62.5}),
        skin_model=SkinModelSummary(row_tilt="as measured", tilt_correction_max_deg={"R01": 0.4}, slip=slip))
    return replace(summary, **changes)


def _lab() -> LabModelSummary:
    return LabModelSummary(**COMMON, model="lab.osim", bodies_map={"L4": "lumbar4", "L3": "lumbar3"})


@pytest.mark.parametrize("summary", [
    _spine(), _spine(skin_model=SkinModelSummary(row_tilt="as measured", tilt_correction_max_deg=None, slip=None)),
    _lab()], ids=["spine model", "rigid skin", "lab model"])
def test_a_summary_reads_back_equal_from_its_dict_and_its_file(summary, tmp_path):
    assert type(summary).from_dict(summary.to_dict(), "summary.json") == summary
    (tmp_path / "summary.json").write_text(strict_json(summary.to_dict()))
    assert read_summary(tmp_path / "summary.json") == summary  # a lab model's is told by its bodies_map


def test_the_file_keeps_its_keys_in_order():
    data = _spine().to_dict()
    assert list(data) == [
        "frames", "fps", "marker_rms_mm", "marker_rms_mm_max", "marker_rms_observed_mm", "marker_max_mm",
        "ms_per_frame", "flagged_frames", "flag_reasons", "warnings", "driven_joints", "welded_joints", "couplers",
        "coordinates", "markers_by_body", "markers_not_placed", "marker_weights", "levels_mapped", "scale_to_generic",
        "facing_error_deg", "placement", "region_ranges_deg", "ik_accuracy", "ik_accuracy_note", "ik",
        "opensim_version", "units", "signs", "depth", "skin_model"]
    assert data["couplers"] == [{"dependent": "L3_L4_lateral_bending", "independent": "L4_L5_lateral_bending",
                                 "ratio": 0.8571}]
    assert data["region_ranges_deg"] == {"lumbar_flexion": [-1.5, 16.0]}
    assert data["units"] == {"angles": "deg", "marker errors": "mm", "trc": "m"}
    assert list(_lab().to_dict()) == [
        "frames", "fps", "model", "bodies_map", "marker_rms_mm", "marker_rms_mm_max", "ms_per_frame",
        "flagged_frames", "flag_reasons", "warnings", "driven_joints", "markers_by_body", "facing_error_deg",
        "marker_weights", "units"]
    rigid = _spine(skin_model=SkinModelSummary(row_tilt="as measured", tilt_correction_max_deg=None, slip=None))
    assert rigid.to_dict()["skin_model"] == {"row_tilt": "as measured", "slip": NO_SLIP}


def test_nan_is_written_as_null_and_read_back_as_nan(tmp_path):
    (tmp_path / "summary.json").write_text(strict_json(_spine(marker_rms_observed_mm=math.nan).to_dict()))
    assert json.loads((tmp_path / "summary.json").read_text())["marker_rms_observed_mm"] is None
    summary = read_summary(tmp_path / "summary.json")
    assert isinstance(summary, SpineModelSummary) and math.isnan(summary.marker_rms_observed_mm)


@pytest.mark.parametrize("path", [("marker_rms_mm",), ("skin_model", "slip", "from_tape"), ("depth", "depth_mm")])
def test_a_missing_key_is_an_input_error_naming_the_file_and_the_key(tmp_path, path):
    data = _spine().to_dict()
    inner = data
    for key in path[:-1]:
        inner = inner[key]
    del inner[path[-1]]
    file = tmp_path / "summary.json"
    file.write_text(strict_json(data))
    with pytest.raises(InputError, match=rf"{path[-1]}.*run `spinemocap opensim` again") as caught:
        read_summary(file)
    assert caught.value.source == str(file)


def test_a_file_that_is_no_summary_is_an_input_error_naming_it(tmp_path):
    for text in ("[1, 2]", "{not json"):
        (tmp_path / "summary.json").write_text(text)
        with pytest.raises(InputError) as caught:
            read_summary(tmp_path / "summary.json")
        assert caught.value.source == str(tmp_path / "summary.json")
    with pytest.raises(InputError, match="from_tape"):
        data = _spine().to_dict()
        data["skin_model"]["slip"]["from_tape"] = "sometimes"
        SpineModelSummary.from_dict(data, tmp_path / "summary.json")
