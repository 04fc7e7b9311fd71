"""Shared inputs of the command tests: the CLI's parser, a tiny synthetic capture written by
``spinemocap synth`` and its tracking by ``spinemocap track`` (once per session)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import pytest

from spinemocap import cli
from spinemocap.commands import synth as synth_command
from spinemocap.commands import track as track_command

Parse = Callable[..., argparse.Namespace]


@pytest.fixture(scope="session")
def parse() -> Parse:
    """``parse("track", capture, "--out", out)``: the CLI's namespace for those arguments."""
    parser = cli.build_parser()
    return lambda *argv: parser.parse_args([str(a) for a in argv])


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory, parse: Parse) -> Path:
    """3 frames of the ``tiny`` preset (3 cameras 480x360, 9-row tape, ``lab`` realism, masks, ground truth)."""
    out = tmp_path_factory.mktemp("tiny") / "capture"
    assert synth_command.run_synth(parse("-q", "synth", out, "--preset", "tiny", "--frames", 3, "--no-progress")) == 0
    return out


@pytest.fixture(scope="session")
def tracked(tmp_path_factory, tiny_capture: Path, parse: Parse) -> Path:
    """The tiny capture tracked with the exact-mask detector: a results folder (markers.csv ...)."""
    out = tmp_path_factory.mktemp("tracked") / "results"
    args = parse("-q", "track", tiny_capture, "--out", out, "--detector", "mask", "--no-progress")
    assert track_command.run_track(args) == 0
    return out
