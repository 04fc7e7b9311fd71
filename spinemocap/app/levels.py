"""The row-to-level map of a capture (which tape row lies over which vertebra), from wherever
the lab put it: the one place the application layer looks it up (batch, OpenSim, viewers)."""

from __future__ import annotations

import os
from pathlib import Path

from ..analysis.levels import LevelMap
from ..capture import MANIFEST, Capture
from ..fileio import InputError, read_toml


def find_level_map(capture: Capture, trial_file: str | os.PathLike | None = None,
                   batch_file: str | os.PathLike | None = None) -> tuple[LevelMap, str]:
    """The capture's row-to-level map and where it came from, first found wins: ``trial_file``,
    ``levels.toml`` in the capture folder, ``[levels]`` in capture.toml, ``levels.toml`` two
    folders up (the subject's), ``batch_file``, the synthetic ground truth's ``row_levels``."""
    n_rows = capture.tape.n_rows
    folder = capture.root
    candidates = [trial_file, folder / "levels.toml"]
    for path in candidates[:2]:
        if path and Path(path).is_file():
            return LevelMap.from_toml(path, n_rows), str(path)
    section = read_toml(folder / MANIFEST).get("levels")
    if section:
        return LevelMap(dict(section), n_rows, source=str(folder / MANIFEST)), str(folder / MANIFEST)
    for path in (folder.parent.parent / "levels.toml", batch_file):
        if path and Path(path).is_file():
            return LevelMap.from_toml(path, n_rows), str(path)
    row_levels = capture.row_levels()
    if row_levels is not None:
        return (LevelMap.from_row_levels(row_levels, n_rows, source=str(capture.groundtruth_path)),
                f"{capture.groundtruth_path} (row_levels)")
    raise InputError(folder, "no row-to-level map: put levels.toml in the trial or subject "
                     "folder, a [levels] table in capture.toml, or pass `levels`")
