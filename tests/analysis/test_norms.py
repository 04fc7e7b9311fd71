"""Published lumbar range-of-motion references: every value carries its source, subjects' age and
sex come from capture.toml, the report places (never diagnoses) each subject's values."""

from __future__ import annotations

import html
import re

import numpy as np
import pandas as pd
import pytest
import tomllib

from spinemocap.analysis.norms import MOVEMENTS, load_norms, norms_path, subject_profile
from spinemocap.app.report import REFERENCE_COLUMNS, _reference_html, _view_links, reference_table
from spinemocap.app.trial_summary import TrialSummary
from spinemocap.camera import Camera, Rig
from spinemocap.capture import Capture
from spinemocap.fileio import InputError
from spinemocap.tape import TapeSpec


def test_every_shipped_value_carries_its_citation_and_method():
    raw = tomllib.loads(norms_path().read_text())
    keys = {s["key"] for s in raw["source"]}
    assert raw["reference"] and all(entry["source"] in keys for entry in raw["reference"])
    norms = load_norms()
    assert len(norms.values) == len(raw["reference"])
    for value in norms.values:
        assert value.source.citation.strip() and value.source.method.strip() and value.source.differs.strip()
        assert value.quote.strip() and value.statistic.strip() and value.scope in ("band", "pooled")
        # the figures appear in the source's words that the file quotes
        for figure in {value.low_deg, value.high_deg}:
            assert f"{figure:g}" in value.quote, (value.source.key, value.movement, figure)
    assert {v.movement for v in norms.values} == set(MOVEMENTS)
    assert all(f.source.key in keys and f.text.strip() for f in norms.findings)
    # every movement has a pooled span, the fallback for a subject no band covers
    assert {v.movement for v in norms.values if v.scope == "pooled" and v.sex == "any"} == set(MOVEMENTS)
    # a band quotes its source's table row and names the table
    for band in (v for v in norms.values if v.scope == "band"):
        assert re.search(r"\bTable \d+", band.statistic + " " + band.quote), (band.source.key, band.movement)


# A norms file with age bands per sex beside a pooled span: test data (made-up figures, each
# quoted in its entry's words), not published values.
BANDED = """
[[source]]
key = "example"
citation = "Example source (test data)."
method = "Test method."
differs = "Test difference."

[[reference]]
movement = "flexion"
source = "example"
sex = "any"
age_min = 16
age_max = 90
scope = "pooled"
low_deg = 40.0
high_deg = 70.0
statistic = "pooled span"
quote = "flexion 40-70 deg over all ages"

[[reference]]
movement = "flexion"
source = "example"
sex = "female"
age_min = 20
age_max = 39
scope = "band"
low_deg = 52.0
high_deg = 68.0
statistic = "Table 2, mean +- 2 SD"
quote = "women 20-39 years: 60 (4) deg, i.e. 52-68"

[[reference]]
movement = "flexion"
source = "example"
sex = "male"
age_min = 20
age_max = 39
scope = "band"
low_deg = 55.0
high_deg = 71.0
statistic = "Table 2, mean +- 2 SD"
quote = "men 20-39 years: 63 (4) deg, i.e. 55-71"

[[reference]]
movement = "flexion"
source = "example"
sex = "any"
age_min = 60
age_max = 90
scope = "band"
low_deg = 30.0
high_deg = 50.0
statistic = "Table 3, range"
quote = "60-90 years, both sexes: 30-50 deg"
"""


def test_age_and_sex_select_the_band_and_the_pooled_span_is_the_fallback(tmp_path):
    path = tmp_path / "banded.toml"
    path.write_text(BANDED)
    norms = load_norms(path)

    def first(age, sex):
        return norms.for_subject("flexion", age, sex)[0]

    woman, man = first(25.0, "female"), first(25.0, "male")
    assert (woman.scope, woman.sex, woman.low_deg, woman.high_deg) == ("band", "female", 52.0, 68.0)
    assert (man.scope, man.sex, man.low_deg, man.high_deg) == ("band", "male", 55.0, 71.0)
    assert woman.applies_to() == "female, 20-39 years (age band)"
    assert [v.scope for v in norms.for_subject("flexion", 25.0, "female")] == ["band", "pooled"]
    # ages count in completed years, both ends included: 20, 39 and 39.5 are in "20-39", 19.9 and 40 not
    assert first(20.0, "female").scope == first(39.0, "female").scope == first(39.5, "female").scope == "band"
    assert first(19.9, "female").scope == first(40.0, "female").scope == "pooled"
    # no band for 45-year-olds, nor for a 25-year-old of unknown sex: the pooled span applies
    for age, sex in ((45.0, "female"), (45.0, "male"), (25.0, None)):
        fallback = first(age, sex)
        assert (fallback.scope, fallback.sex, fallback.low_deg, fallback.high_deg) == ("pooled", "any", 40.0, 70.0)
        assert fallback.applies_to() == "both sexes, 16-90 years (pooled)"
    # a band for both sexes applies whatever the sex, and before the pooled span
    assert (first(70.0, "male").low_deg, first(70.0, None).low_deg) == (30.0, 30.0)
    # an unknown age gets no band, only the pooled span
    assert [v.scope for v in norms.for_subject("flexion", None, "female")] == ["pooled"]
    assert norms.for_subject("flexion", 95.0, "female") == []  # outside every value
    # the band's figures are in its quoted words, as for the shipped file
    for value in norms.values:
        assert all(f"{figure:g}" in value.quote for figure in (value.low_deg, value.high_deg))


def test_a_value_without_a_known_source_is_refused(tmp_path):
    raw = norms_path().read_text().replace('source = "troke2001"', 'source = "nobody2020"', 1)
    path = tmp_path / "norms.toml"
    path.write_text(raw)
    with pytest.raises(InputError, match="norms.toml.*nobody2020"):
        load_norms(path)
    path.write_text(norms_path().read_text().replace("low_deg = 40.0", "low_deg = 90.0", 1))
    with pytest.raises(InputError, match="low_deg <= high_deg"):
        load_norms(path)
    path.write_text(norms_path().read_text().replace('scope = "pooled"', 'scope = "decade"', 1))
    with pytest.raises(InputError, match="scope 'decade'"):
        load_norms(path)
    path.write_text(norms_path().read_text().replace('scope = "pooled"\n', "", 1))
    with pytest.raises(InputError, match="missing or unknown key 'scope'"):
        load_norms(path)
    # a band must name the source's table its figures were read from
    path.write_text(BANDED.replace('statistic = "Table 3, range"', 'statistic = "range read off Figure 2"'))
    with pytest.raises(InputError, match=r"norms\.toml.*flexion any 60-90 from example.*Table 2"):
        load_norms(path)


def test_placement_and_subject_profile():
    flexion = load_norms().for_subject("flexion", 30.0, "female")[0]
    assert (flexion.place(flexion.low_deg - 0.1), flexion.place(flexion.high_deg), flexion.place(flexion.high_deg + 1)) \
        == ("below", "within", "above")
    assert flexion.place(float("nan")) == "no value"
    assert load_norms().for_subject("flexion", 130.0, None) == []  # no source covers that age
    rotation = load_norms().for_subject("axial_rotation", None, None)[0]
    assert rotation.place(1.0) == "median only"  # one median is no range to fall outside of
    assert subject_profile({"age": 41, "sex": "M"}).sex == "male"
    bad = subject_profile({"age": -3, "sex": "other"})
    assert bad.age is None and bad.sex is None and len(bad.problems) == 2


def _summary(key: str, subject: str, capture) -> TrialSummary:
    """A tracked trial's summary as the batch writes it (only its identity matters here)."""
    return TrialSummary(key=key, subject=subject, condition="flex", trial=key.rsplit("/", 1)[-1],
                        capture=str(capture), source="tracked", status="ok", reason="", out_dir=str(capture))


def _trial_row(key: str, subject: str, **values) -> dict:
    row = {"key": key, "subject": subject, "status": "ok"}
    row.update({column: np.nan for _, column, _ in REFERENCE_COLUMNS})
    row.update(values)
    return row


def _capture_with_subject(folder, subject: dict) -> str:
    """A capture folder (manifest and a one-camera rig) whose [subject] table is ``subject``."""
    camera = Camera.look_at("cam1", (0.0, -2000.0, 1000.0), (0.0, 0.0, 1000.0), (640, 480), 800.0)
    Capture(root=folder, name=folder.name, fps=50.0, n_frames=1, rig=Rig([camera]), tape=TapeSpec(),
            subject=subject).save()
    return str(folder)


def test_reference_table_from_trials(tmp_path):
    captures = {name: _capture_with_subject(tmp_path / name, subject) for name, subject in
                (("a", {"id": "S01", "age": 34, "sex": "female"}), ("b", {"id": "S02"}),
                 ("c", {"id": "S01", "age": 35}))}
    trials = pd.DataFrame([
        _trial_row("S01/flex/1", "S01", flexion_from_neutral_deg=35.0, extension_from_neutral_deg=12.0,
                   lateral_right_from_neutral_deg=31.0),
        _trial_row("S01/flex/2", "S01", flexion_from_neutral_deg=52.0),
        _trial_row("S02/flex/1", "S02", flexion_from_neutral_deg=80.0),
    ])
    results = [_summary("S01/flex/1", "S01", captures["a"]), _summary("S02/flex/1", "S02", captures["b"]),
               _summary("S01/flex/2", "S01", captures["c"])]
    table = reference_table(trials, results)
    norms = load_norms()
    assert set(table["source"]) <= set(norms.sources) and (table["source"] != "").all()
    s01 = table[table["subject"] == "S01"].set_index(["movement", "direction"])
    assert s01.loc[("flexion", "forward"), "value_deg"] == 52.0  # the larger of its two trials
    assert s01.loc[("flexion", "forward"), "trial"] == "S01/flex/2"
    assert s01.loc[("flexion", "forward"), "placement"] == "within"
    assert s01.loc[("lateral bending", "right"), "placement"] == "above"
    assert s01.loc[("lateral bending", "left"), "placement"] == "no value"
    assert (s01["age"] == 34).all() and (s01["sex"] == "female").all()
    assert "gives age 35" in s01["metadata_notes"].iloc[0]
    s02 = table[table["subject"] == "S02"].set_index(["movement", "direction"])
    assert s02.loc[("flexion", "forward"), "placement"] == "above" and (s02["sex"] == "not given").all()
    page = _reference_html(table)
    for source in norms.sources.values():
        assert source.key in page
    assert page.count("class=\"warn\"") + page.count("class='warn'") >= 3  # two rows marked and the note's word
    assert "diagnos" in page and "abnormal" not in page


def test_view_links_point_to_the_trials_outputs(tmp_path):
    trial = tmp_path / "S01" / "flex" / "t1"
    (trial / "view").mkdir(parents=True)
    for name in ("all_cameras.mp4", "tape3d.html", "cam 1.mp4"):
        (trial / "view" / name).write_bytes(b"x")
    links = _view_links(trial, tmp_path)
    assert 'href="S01/flex/t1/view/all_cameras.mp4"' in links and 'href="S01/flex/t1/view/tape3d.html"' in links
    assert 'href="S01/flex/t1/view/cam%201.mp4"' in links
    assert "spinemocap view" in _view_links(tmp_path / "other", tmp_path)


def test_report_shows_the_band_it_used_and_marks_a_value_outside_it(tmp_path):
    path = tmp_path / "banded.toml"
    path.write_text(BANDED)
    banded = load_norms(path)
    captures = {name: _capture_with_subject(tmp_path / name, subject) for name, subject in
                (("a", {"id": "W25", "age": 25, "sex": "female"}), ("b", {"id": "M25", "age": 25, "sex": "male"}),
                 ("c", {"id": "U45", "age": 45}))}
    # 70 deg: above the women's band (52-68) but inside the men's (55-71) and the pooled span (40-70)
    trials = pd.DataFrame([_trial_row(f"{s}/flex/1", s, flexion_from_neutral_deg=70.0) for s in ("W25", "M25", "U45")])
    results = [_summary(f"{s}/flex/1", s, captures[c])
               for s, c in (("W25", "a"), ("M25", "b"), ("U45", "c"))]
    table = reference_table(trials, results, banded)
    flexion = table[table["movement"] == "flexion"].set_index("subject")
    assert flexion.loc["W25", "reference_applies_to"] == "female, 20-39 years (age band)"
    assert (flexion.loc["W25", "reference_low_deg"], flexion.loc["W25", "placement"]) == (52.0, "above")
    assert flexion.loc["M25", "reference_applies_to"] == "male, 20-39 years (age band)"
    assert flexion.loc["M25", "placement"] == "within"
    assert flexion.loc["U45", "reference_applies_to"] == "both sexes, 16-90 years (pooled)"
    assert flexion.loc["U45", "placement"] == "within"
    assert (flexion["source"] == "example").all()
    assert set(table.loc[table["movement"] != "flexion", "placement"]) == {"no reference"}  # the file has none
    page = _reference_html(table, banded)
    rows = re.findall(r"<tr[^>]*>.*?</tr>", page, flags=re.S)
    woman = [r for r in rows if "W25" in r and ">flexion<" in r]
    man = [r for r in rows if "M25" in r and ">flexion<" in r]
    assert len(woman) == len(man) == 1
    assert "warn" in woman[0] and "female, 20-39 years (age band)" in woman[0] and "example" in woman[0]
    assert "warn" not in man[0] and "male, 20-39 years (age band)" in man[0]


@pytest.mark.parametrize(("age", "sex"), [(25, "female"), (52.5, "male"), (70, None)])
def test_shipped_file_gives_each_subject_the_most_specific_span_and_marks_a_value_outside_it(tmp_path, age, sex):
    norms = load_norms()
    raw = tomllib.loads(norms_path().read_text())["reference"]
    # what the shipped file holds for this subject, most specific first
    expected = {m: norms.for_subject(m, float(age), sex)[0] for m in ("flexion", "extension")}
    for value in expected.values():
        # the file's own entries, read without the loader: a band of the subject's completed years
        # and sex (or both sexes) wins wherever one is entered, one sex before both
        bands = [e for e in raw if e["movement"] == value.movement and e["scope"] == "band"
                 and e["sex"] in (sex, "any") and e["age_min"] <= int(age) <= e["age_max"]]
        assert (value.scope == "band") == bool(bands)
        if any(e["sex"] == sex for e in bands):
            assert value.sex == sex
    capture = _capture_with_subject(tmp_path / "s", {"id": "S", "age": age} | ({"sex": sex} if sex else {}))
    flexion_outside = expected["flexion"].high_deg + 10.0
    extension_inside = (expected["extension"].low_deg + expected["extension"].high_deg) / 2
    trials = pd.DataFrame([_trial_row("S/flex/1", "S", flexion_from_neutral_deg=flexion_outside,
                                      extension_from_neutral_deg=extension_inside)])
    table = reference_table(trials, [_summary("S/flex/1", "S", capture)])
    rows = table.set_index("movement")
    for movement, value in expected.items():
        row = rows.loc[movement]
        assert (row["age"], row["sex"]) == (float(age), sex or "not given")
        assert row["reference_applies_to"] == value.applies_to() and row["source"] == value.source.key
        assert (row["reference_low_deg"], row["reference_high_deg"]) == (value.low_deg, value.high_deg)
    assert (rows.loc["flexion", "placement"], rows.loc["extension", "placement"]) == ("above", "within")
    page = _reference_html(table)
    flexion_row = [r for r in re.findall(r"<tr[^>]*>.*?</tr>", page, flags=re.S) if ">flexion<" in r]
    assert len(flexion_row) == 1 and "warn" in flexion_row[0] and "above the published span" in flexion_row[0]
    assert expected["flexion"].applies_to() in flexion_row[0]
    for value in expected.values():
        assert html.escape(value.source.citation) in page
    assert "no diagnosis" in page and "abnormal" not in page
