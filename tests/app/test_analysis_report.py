"""The study report: new plots (ROM box/strip plots, spine picture, segmental angles), angles from
neutral (a static trial), an all-NaN trial stated with its reason, and the page as headless
Chromium draws it (skipped when no chromium is installed)."""

import base64
import re
import shutil
import subprocess

import cv2
import numpy as np
import pandas as pd
import pytest

from spinemocap.analysis.bent_tape import write_bent_capture
from spinemocap.app.batch import run_batch
from spinemocap.app.report import write_report
from spinemocap.tape import TapeSpec

TAPE = TapeSpec(n_rows=9)
LEVELS_TOML = '[levels]\nS1 = 1\n"T12/L1" = 7\nT10 = 9\n'
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run",
                  "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A small study of analytic bent-tape captures (ground-truth source): two subjects x two
    conditions, a static trial for S02, and one trial whose rows around T12/L1 are never seen."""
    tmp = tmp_path_factory.mktemp("study")
    root = tmp / "study"
    for s, subject in enumerate(("S01", "S02")):
        (root / subject).mkdir(parents=True)
        (root / subject / "levels.toml").write_text(LEVELS_TOML)
        for c, condition in enumerate(("pre", "post")):
            write_bent_capture(root / subject / condition / "trial01", TAPE, 20.0 + 10 * c + 5 * s, 20, fps=50.0)
    write_bent_capture(root / "S02" / "static" / "trial01", TAPE, 0.0, 10, fps=50.0)
    write_bent_capture(root / "S01" / "post" / "trial02", TAPE, 30.0, 20, fps=50.0, hidden_rows=(6, 7, 8),
                       hidden_frames=slice(0, 20))
    out = tmp / "out"
    result = run_batch(root, out, source="groundtruth", workers=1, progress=False)
    assert not result.failed
    return write_report(out, title="report test")


def _images(page: str) -> dict[str, np.ndarray]:
    """Every embedded PNG of the page by its alt text, decoded."""
    out = {}
    for alt, data in re.findall(r"<img alt='([^']*)' src='data:image/png;base64,([^']*)'>", page):
        out[alt] = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
    return out


def _drawn(image: np.ndarray) -> float:
    """Share of pixels that are neither white nor grey: the plotted lines, boxes and bars."""
    return float(np.mean((np.max(image, axis=2).astype(int) - np.min(image, axis=2)) > 40))


def test_report_has_the_new_plots_and_numbers_from_neutral(report):
    page = report["html"].read_text()
    images = _images(page)
    trials = ["S01/post/trial01", "S01/pre/trial01", "S02/post/trial01", "S02/pre/trial01", "S02/static/trial01"]
    assert "range of motion by subject and condition" in images
    for key in trials + ["S01/post/trial02"]:
        assert f"angles from neutral: {key}" in images and f"spine shape and segmental angles: {key}" in images
    for alt, image in images.items():
        assert image is not None and image.shape[1] >= 600, alt
        assert _drawn(image) > 0.002, alt  # something coloured was drawn (not an empty frame)
    # the tables: grouped short headers, numbers from neutral
    for words in ("Lumbar flexion (deg)", "flexion from neutral", "extension from neutral", "angle at neutral"):
        assert words in page
    summary = pd.read_csv(report["csv"]).set_index("key")
    # S02's static trial is its neutral: its own trials read from it; S01 has none: first frame
    assert summary.loc["S02/pre/trial01", "neutral_from"] == "static trial S02/static/trial01"
    assert summary.loc["S01/pre/trial01", "neutral_from"] == "first frame"
    # each capture flexes from its rest pose to its peak and back: flexion from neutral = peak,
    # no extension past neutral; the absolute angle at neutral is the tape's background bend
    for key, peak in {"S01/pre/trial01": 20, "S01/post/trial01": 30, "S02/pre/trial01": 25, "S02/post/trial01": 35}.items():
        assert summary.loc[key, "flexion_from_neutral_deg"] == pytest.approx(peak, rel=0.03)
        assert summary.loc[key, "extension_from_neutral_deg"] == pytest.approx(0.0, abs=0.3)
        assert summary.loc[key, "flexion_rom_deg"] == pytest.approx(peak, rel=0.03)
    assert summary.loc["S01/pre/trial01", "flexion_neutral_abs_deg"] == pytest.approx(
        summary.loc["S02/static/trial01", "flexion_neutral_abs_deg"], abs=0.1)


def test_report_says_why_a_trial_has_no_lumbar_angle(report):
    page = report["html"].read_text()
    assert "No lumbar angle in any frame: tape rows near T12/L1 (row 7) not seen." in page
    problems = pd.read_excel(report["xlsx"], sheet_name="problems")
    row = problems[(problems["key"] == "S01/post/trial02") & (problems["what"] == "no lumbar angle in any frame")]
    assert len(row) == 1 and "T12/L1" in row["reason"].iloc[0]
    summary = pd.read_csv(report["csv"]).set_index("key")
    assert summary.loc["S01/post/trial02", "status"] == "ok"
    assert np.isnan(summary.loc["S01/post/trial02", "flexion_from_neutral_deg"])
    images = _images(page)
    assert "spine shape and segmental angles: S01/post/trial02" in images  # still pictured, with the reason


@pytest.mark.skipif(shutil.which("chromium") is None, reason="no chromium (Debian: apt-get install chromium)")
def test_report_renders_its_plots_in_headless_chromium(report, tmp_path):
    shot = tmp_path / "page.png"
    subprocess.run(["chromium", *CHROMIUM_FLAGS, "--window-size=1280,3000", f"--screenshot={shot}",
                    report["html"].as_uri()], check=True, timeout=120, capture_output=True)
    page = cv2.imread(str(shot))
    assert page is not None and page.shape[:2] == (3000, 1280)
    # matplotlib's default blue (tab:blue, BGR 180 119 31) fills the box plots and the angle
    # curves: drawn images show it; a page whose images failed to load would not
    blue = np.all(np.abs(page.astype(int) - [180, 119, 31]) < 40, axis=2)
    rows_with_blue = np.flatnonzero(blue.sum(axis=1) > 3)
    assert blue.sum() > 2000 and rows_with_blue.size > 300
    # a plot sits at the top (ROM) and further down (per trial): blue spread over the page
    assert rows_with_blue.min() < 1200 and rows_with_blue.max() > 2000


def test_rom_plot_of_a_study_without_any_lumbar_angle_says_so():
    from spinemocap.app.report import _rom_plot

    trials = pd.DataFrame({"subject": ["S01", "S02"], "condition": ["pre", "pre"], "status": ["ok", "ok"],
                           "flexion_rom_deg": [np.nan, np.nan], "lateral_rom_deg": [np.nan, np.nan],
                           "rotation_rom_deg": [np.nan, np.nan]})
    image = cv2.imdecode(np.frombuffer(base64.b64decode(_rom_plot(trials)), np.uint8), cv2.IMREAD_COLOR)
    red = np.all(np.abs(image.astype(int) - [40, 39, 214]) < 60, axis=2)  # tab:red text, BGR
    assert red.sum() > 100  # "no value in any trial (see Problems)" in each panel
    assert _rom_plot(trials.assign(status="failed")) is None  # nothing analysed: no plot at all
