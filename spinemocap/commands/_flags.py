"""The library's wording on the command line: messages of the library and the application name
parameters (the :class:`~spinemocap.fileio.InputError` convention: `name` or `name=value` in
backticks); a command's user reads the flags of the command being run instead.

:func:`with_flags` rewrites one text for given parsers; :func:`show_flags_of` makes the running
command's parsers the ones :func:`shown` (text a command prints), :class:`FlagNames` (log records)
and the CLI's warnings use."""

from __future__ import annotations

import argparse
import logging
import re
from typing import Sequence

# Errors of the library name the parameter (InputError's source); on the command line they name its
# flag: the flag whose destination is the parameter, else the one this table gives.
PARAMETER_FLAGS = {"backend": "--ba", "sources": "--videos", "model_type": "--model", "mapping": "--map",
                   "named": "--video", "offsets": "--offset", "predict": "--no-predict"}
# A parameter named inside a problem text (see InputError): `name` or `name=value`.
PARAMETER_MENTION = re.compile(r"`([A-Za-z_]\w*)(?:=([^`\s]+))?`")

# The parsers of the command being run (empty outside the CLI: texts stay as the library wrote them).
_running: list[argparse.ArgumentParser] = []


def invoked_parsers(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[argparse.ArgumentParser]:
    """The parser and the sub-command parsers ``args`` went through, outermost first."""
    chain = [parser]
    while True:
        subs = [a for a in chain[-1]._actions if isinstance(a, argparse._SubParsersAction)]
        chosen = getattr(args, subs[0].dest, None) if subs else None
        if not subs or chosen not in subs[0].choices:
            return chain
        chain.append(subs[0].choices[chosen])


def flag_of(parameter: str, parsers: Sequence[argparse.ArgumentParser]) -> str | None:
    """The long flag of ``parameter`` among the options of ``parsers`` (None: not an option there)."""
    flags = {action.dest: long[0] for p in parsers for action in p._actions
             if (long := [o for o in action.option_strings if o.startswith("--")])}
    if parameter in flags:
        return flags[parameter]
    alias = PARAMETER_FLAGS.get(parameter)
    return alias if alias in flags.values() else None


def with_flags(problem: str, parsers: Sequence[argparse.ArgumentParser]) -> str:
    """``problem`` as a command-line user reads it: each parameter it names (`name` or
    `name=value`) written as the flag of the options of ``parsers``: ``--flag`` (a value True or
    False: the flag alone, PARAMETER_FLAGS naming the flag that turns an option off) or ``--flag
    value`` (quotes dropped). A parameter without a flag there stays as written."""
    def rendered(mention: re.Match[str]) -> str:
        name, value = mention.groups()
        flag = flag_of(name, parsers)
        if flag is None:
            return mention.group(0)
        if value is None or value in ("True", "False"):
            return flag
        return f"{flag} {value.strip(chr(39) + chr(34))}"

    return PARAMETER_MENTION.sub(rendered, problem)


def shown(text: str) -> str:
    """``text`` (written by the library or the application) :func:`with_flags` of the command
    being run (see :func:`show_flags_of`); unchanged when none is."""
    return with_flags(text, _running)


class FlagNames(logging.Filter):
    """A log handler's filter: a record whose message names parameters gets the message
    :func:`shown` (its arguments merged in). Passes every record."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        rendered = shown(message)
        if rendered != message:
            record.msg, record.args = rendered, None
        return True


def show_flags_of(parsers: Sequence[argparse.ArgumentParser]) -> None:
    """Make ``parsers`` (the command being run, :func:`invoked_parsers`) the ones :func:`shown`
    uses, and put one :class:`FlagNames` on each handler of the root logger."""
    _running[:] = parsers
    for handler in logging.getLogger().handlers:
        if not any(isinstance(f, FlagNames) for f in handler.filters):
            handler.addFilter(FlagNames())
