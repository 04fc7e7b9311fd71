"""``python -m spinemocap`` (spinemocap/__main__.py) is the CLI: its exit status is the command's."""

from __future__ import annotations

import runpy
import sys

import pytest

from spinemocap.version import __version__


def _run_as_main(monkeypatch, *argv: str) -> int:
    monkeypatch.setattr(sys, "argv", ["spinemocap", *argv])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_module("spinemocap", run_name="__main__")
    return int(exit_.value.code or 0)


def test_the_version_and_an_unknown_command(monkeypatch, capsys):
    assert _run_as_main(monkeypatch, "--version") == 0
    assert __version__ in capsys.readouterr().out
    assert _run_as_main(monkeypatch, "no-such-command") == 2
    assert "no-such-command" in capsys.readouterr().err
