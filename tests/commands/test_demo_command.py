"""``spinemocap demo``'s steps: the report step lists the angle report and tables it wrote; a
step that needs the capture before it is made says so."""

from __future__ import annotations

import shutil

import pytest

from spinemocap.commands.demo import STEPS, DemoContext, step_report, step_synthesize


def test_the_steps_run_in_order_and_the_report_comes_last():
    assert STEPS[0] is step_synthesize and STEPS[-1] is step_report


def test_the_report_step_writes_and_lists_its_outputs(tiny_capture, tracked, tmp_path, capsys):
    with pytest.raises(RuntimeError, match="synthesize step has not run"):
        DemoContext(out=tmp_path).synthesized()
    ctx = DemoContext(out=tmp_path, capture_dir=tiny_capture)
    shutil.copytree(tracked, tmp_path / "tracked")
    ctx.report("tracked markers (table)", tmp_path / "tracked" / "markers.csv")
    step_report(ctx)
    labels = dict(ctx.outputs)
    assert labels["angle report"].suffix == ".html" and labels["angle report"].is_file()
    assert labels["angle tables"].suffix == ".xlsx" and labels["angle tables"].is_file()
    assert str(labels["angle report"]) in capsys.readouterr().out
