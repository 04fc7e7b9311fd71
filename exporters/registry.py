"""Exporters by name: the built-in formats plus any found through the entry-point group
``spinemocap.exporters``.

A lab adds its own format without touching this code: in its own distribution's
``pyproject.toml``::

    [project.entry-points."spinemocap.exporters"]
    mylab = "mylab_formats:MyLabExporter"

The entry point may name an :class:`Exporter` subclass (instantiated without arguments), an
instance, or any object with ``write(table, path, **options)`` (and optionally ``read(path)``
and ``extensions``). :func:`write` always writes through a temporary file and renames it into
place, so even a plugin that writes straight to its ``path`` never leaves a half-written file.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import logging
import os
from pathlib import Path
from typing import Any, Iterable

import pandas as pd

from spinemocap.fileio import InputError, atomic_path
from spinemocap.markers import MarkerTable

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "spinemocap.exporters"

# name -> "module:attribute", imported lazily so ``available()`` never pays for c3d/pyarrow.
BUILTIN = {
    "trc": "exporters.trc:TrcExporter",
    "c3d": "exporters.c3d:C3dExporter",
    "csv": "exporters.tables:CsvExporter",
    "parquet": "exporters.tables:ParquetExporter",
}


class Exporter:
    """Base class for a marker file format. Subclasses set :attr:`name`, :attr:`extensions`
    and implement :meth:`write` (atomically, e.g. through :func:`spinemocap.fileio.atomic_path`)
    and :meth:`read` where the format can be read back. :attr:`options` names the keyword
    options ``write`` takes (the CLI checks its flags against it; None: not declared)."""

    name: str = ""
    extensions: tuple[str, ...] = ()
    description: str = ""
    options: tuple[str, ...] | None = None

    def write(self, table: MarkerTable, path: str | os.PathLike, **options: Any) -> Path:
        raise NotImplementedError

    def read(self, path: str | os.PathLike) -> MarkerTable:
        raise InputError(path, f"the {self.name!r} format cannot be read back")

    def write_parts(self, parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int,
                    **options: Any) -> Path:
        """Write a table given as consecutive ``parts`` (the same labels and meta, ``n_frames``
        frames in all) as :meth:`write` writes their concatenation. This default joins them
        first; formats that can write part by part (CSV, TRC, C3D) hold one part at a time."""
        return self.write(joined(parts, path), path, **options)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} {self.extensions}>"


def _load(target: Any, name: str) -> Any:
    """Turn what a registry entry points at (class, instance, "module:attr") into an exporter."""
    if isinstance(target, str):
        module, _, attr = target.partition(":")
        target = getattr(importlib.import_module(module), attr)
    if isinstance(target, type):
        target = target()
    if not callable(getattr(target, "write", None)):
        raise TypeError(f"exporter {name!r} ({target!r}) has no write(table, path, **options)")
    return target


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    return {ep.name.lower(): ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def available() -> list[str]:
    """Names of all exporters: built-in ones and those registered by entry point."""
    return sorted(set(BUILTIN) | set(_entry_points()))


def get(name: str) -> Any:
    """The exporter called ``name`` (case-insensitive). Built-in names win over plugins."""
    key = name.lower()
    if key in BUILTIN:
        return _load(BUILTIN[key], key)
    ep = _entry_points().get(key)
    if ep is None:
        raise InputError(None, f"unknown export format {name!r}; available: {', '.join(available())}")
    try:
        return _load(ep.load(), ep.name)
    except Exception as exc:  # a broken plugin must say which one it is
        raise InputError(f"entry point {ep.name} = {ep.value}", f"cannot load exporter: {exc}") from exc


def format_for_path(path: str | os.PathLike) -> str:
    """Exporter name for a file name, from its extension (``.trc`` -> ``trc``); built-in
    formats first, then plugins that declare ``extensions``."""
    suffix = Path(path).suffix.lower()
    for name in [*BUILTIN, *sorted(set(_entry_points()) - set(BUILTIN))]:
        try:
            extensions = tuple(getattr(get(name), "extensions", ()))
        except InputError as exc:  # a broken plugin must not break the built-in formats
            log.warning("%s", exc)
            continue
        if suffix in extensions:
            return name
    raise InputError(path, f"cannot tell the format from extension {suffix!r}; "
                           f"pass a format, one of {', '.join(available())}")


def write(table: MarkerTable, path: str | os.PathLike, format: str | None = None, **options: Any) -> Path:
    """Write ``table`` to ``path`` in ``format`` (default: from the extension), atomically."""
    path = Path(path)
    exporter = get(format or format_for_path(path))
    if isinstance(exporter, Exporter):  # ours write atomically themselves
        return Path(exporter.write(table, path, **options))
    with atomic_path(path) as tmp:  # a plugin without our base class: make it atomic anyway
        exporter.write(table, tmp, **options)
    return path


def write_parts(parts: Iterable[MarkerTable], path: str | os.PathLike, n_frames: int, format: str | None = None,
                **options: Any) -> Path:
    """:func:`write` of a table given as consecutive ``parts`` (the same labels and meta,
    ``n_frames`` frames in all): the same file, with one part in memory at a time where the format
    writes part by part (the built-in ones; a plugin without ``write_parts`` gets them joined)."""
    path = Path(path)
    exporter = get(format or format_for_path(path))
    if isinstance(exporter, Exporter):
        return Path(exporter.write_parts(parts, path, n_frames, **options))
    return write(joined(parts, path), path, format, **options)


def joined(parts: Iterable[MarkerTable], path: str | os.PathLike) -> MarkerTable:
    """One table of consecutive ``parts`` (the first part's meta); :class:`InputError` naming
    ``path`` where there is none."""
    tables = list(parts)
    if not tables:
        raise InputError(path, "marker table has no frames to write")
    return MarkerTable(pd.concat([t.data for t in tables], ignore_index=True), dict(tables[0].meta))


def read(path: str | os.PathLike, format: str | None = None) -> MarkerTable:
    """Read a marker file into a :class:`MarkerTable` (mm, lab frame Z up)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    exporter = get(format or format_for_path(path))
    if not callable(getattr(exporter, "read", None)):
        raise InputError(path, f"the {format or path.suffix!r} exporter cannot read files")
    return exporter.read(path)
