"""Command-line entry point ``spinemocap``.

Each sub-command lives in its own module under :mod:`spinemocap.commands`. A module defines
``register(subparsers)`` to add top-level commands and/or ``register_bench(subparsers)`` to add
``spinemocap bench NAME`` benchmarks; the handler is stored as ``func`` on the parser defaults
and returns an exit code (or None for 0).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
import warnings
from typing import Sequence

from . import commands
from .commands._flags import flag_of, invoked_parsers, show_flags_of, shown, with_flags
from .fileio import InputError
from .version import __version__

log = logging.getLogger("spinemocap")


def _command_modules():
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            yield importlib.import_module(f"{commands.__name__}.{info.name}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="spinemocap",
        description="3D spine motion capture from perforated kinesiology tape.",
    )
    parser.add_argument("--version", action="version", version=f"spinemocap {__version__}")
    add_global_flags(parser, False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    bench = sub.add_parser("bench", help="benchmarks that print and save speed/accuracy numbers")
    bench_sub = bench.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    for module in _command_modules():
        if hasattr(module, "register"):
            module.register(sub)
        if hasattr(module, "register_bench"):
            module.register_bench(bench_sub)
    for command in _subparsers(parser):  # the global flags also after a command's name
        add_global_flags(command, argparse.SUPPRESS)
    return parser


def error_text(exc: InputError, parsers: Sequence[argparse.ArgumentParser]) -> str:
    """The line ``main`` prints for ``exc`` (without the program's name): its source as the
    parameter's flag where it names one of ``parsers``' options, and its problem
    :func:`with_flags`."""
    problem = with_flags(exc.problem, parsers)
    source = (flag_of(exc.source, parsers) or exc.source) if exc.source else None
    return f"{source}: {problem}" if source else problem


def add_global_flags(parser: argparse.ArgumentParser, default) -> None:
    """``-v``/``--verbose`` and ``-q``/``--quiet`` on ``parser``; a command's copies default to
    ``argparse.SUPPRESS`` so that they do not undo the same flag given before the command."""
    flags = {"-v": ("--verbose", "debug logging"), "-q": ("--quiet", "warnings and errors only")}
    taken = {option for action in parser._actions for option in action.option_strings}
    for short, (long, text) in flags.items():
        names = [n for n in (short, long) if n not in taken]
        if len(names) == 2:  # a command that uses one of the names itself keeps its own meaning
            parser.add_argument(*names, action="store_true", default=default, help=text)


def _subparsers(parser: argparse.ArgumentParser):
    """Every command parser below ``parser`` (commands, their subcommands, benchmarks)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                yield child
                yield from _subparsers(child)


def plain_warning(message, category, filename, lineno, line=None) -> str:
    """A Python warning as a person reads it: the message, without the source file and line."""
    return f"spinemocap: warning: {shown(str(message))}\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    parsers = invoked_parsers(parser, args)
    show_flags_of(parsers)  # parameters named in printed, logged and warned texts read as flags
    warnings.formatwarning = plain_warning  # also in the batch's worker processes (forked from here)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"spinemocap: error: {error_text(exc, parsers)}", file=sys.stderr)
        return int(getattr(exc, "exit_code", 2))  # 2: bad input; a subclass may name its own status
    except KeyboardInterrupt:
        print("spinemocap: interrupted", file=sys.stderr)
        return 130
    finally:
        show_flags_of([])  # the command is over: the library's texts read as written again


if __name__ == "__main__":
    sys.exit(main())
