"""Names from another lab's folders (subjects, conditions, trials, failure reasons) reach the
report's HTML as text, never as markup."""

from __future__ import annotations

from test_analysis_batch import LEVELS_TOML, _write_trial

from spinemocap.app.batch import run_batch
from spinemocap.app.report import write_report

HOSTILE = "<script>alert(1)</script>"


def test_script_tags_in_folder_names_are_escaped_in_the_report(tmp_path):
    root = tmp_path / "study"
    subject = root / f"S01{HOSTILE.replace('/', '_')}"
    subject.mkdir(parents=True)
    (subject / "levels.toml").write_text(LEVELS_TOML)
    _write_trial(subject / "pre<b>" / "trial01", 20.0, n_frames=15)
    (subject / "pre<b>" / "trial02<img src=x onerror=alert(2)>").mkdir()       # no capture: a failed trial
    out = tmp_path / "out"
    run_batch(root, out, source="groundtruth", workers=1, progress=False)
    page = write_report(out)["html"].read_text()
    assert "<script>alert" not in page and "<img src=x" not in page and "pre<b>" not in page
    assert "&lt;script&gt;alert(1)&lt;_script&gt;" in page and "&lt;img src=x onerror=alert(2)&gt;" in page
    assert "pre&lt;b&gt;" in page
