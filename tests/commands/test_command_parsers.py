"""Every command module registers a parser whose help renders, whose leaf commands have a handler,
and whose texts speak of the product only (no issue numbers or development history)."""

from __future__ import annotations

import argparse
import re

import pytest

from spinemocap import cli

HISTORY_WORDS = re.compile(r"\b(issues?|branch|legacy|sprint|round \d+)\b", re.IGNORECASE)


def command_parsers() -> list[argparse.ArgumentParser]:
    return list(cli._subparsers(cli.build_parser()))


def is_leaf(parser: argparse.ArgumentParser) -> bool:
    return not any(isinstance(action, argparse._SubParsersAction) for action in parser._actions)


def test_every_command_module_adds_a_command():
    parser = cli.build_parser()
    registering = [m for m in cli._command_modules() if hasattr(m, "register") or hasattr(m, "register_bench")]
    assert len(registering) >= 20, f"only {len(registering)} command modules register a command"
    names = {p.prog.split(" ", 1)[1] for p in cli._subparsers(parser)}
    for expected in ("track", "view", "detector adapt", "bench long-capture", "bench adapt", "capture init"):
        assert expected in names, f"`spinemocap {expected}` is not registered"


@pytest.mark.parametrize("parser", command_parsers(), ids=lambda p: p.prog)
def test_each_command_has_a_handler_and_a_product_help_text(parser):
    text = parser.format_help()
    assert parser.prog in text
    if is_leaf(parser):
        assert callable(parser.get_default("func")), f"`{parser.prog}` has no handler"
    words = HISTORY_WORDS.findall(text)
    # `:legacy` is a ChArUco board layout's name (OpenCV's), not history
    words = [w for w in words if not (w.lower() == "legacy" and ":legacy" in text)]
    assert not words, f"`{parser.prog} --help` speaks of {words}"
