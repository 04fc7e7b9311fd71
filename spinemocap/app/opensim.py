"""The OpenSim workflow of a tracked capture: its marker results, its tape and level map, and the
subject's facing direction from ``capture.toml`` into :func:`spinemocap.opensim.run_opensim` (the
project's spine model) or :func:`spinemocap.opensim.labmodel.run_lab_model` (a lab's own model)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from ..analysis.levels import LevelMap
from ..capture import Capture
from ..fileio import InputError
from .levels import find_level_map
from .results import read_results

if TYPE_CHECKING:  # OpenSim loads only when the workflow runs
    from ..opensim.pipeline import OpenSimResult, OpenSimSettings
    from ..opensim.summary import LabModelSummary, SpineModelSummary

    #: A run on the project's spine model or on a lab's own model.
    AnyOpenSimResult = OpenSimResult[SpineModelSummary] | OpenSimResult[LabModelSummary]


def opensim_capture(results: str | os.PathLike, capture_dir: str | os.PathLike, out_dir: str | os.PathLike,
                    levels: str | os.PathLike | None = None, static: str | os.PathLike | None = None,
                    model: str | os.PathLike | None = None, bodies: str | os.PathLike | None = None,
                    settings: OpenSimSettings | None = None) -> tuple[AnyOpenSimResult, str]:
    """Place and solve the spine model on ``results`` (a results folder or marker file) of the
    capture at ``capture_dir``; files into ``out_dir``. ``levels``: a level-map TOML (default: the
    capture's, :func:`~spinemocap.app.levels.find_level_map`); ``static``: a static trial's results
    for the placement; ``model`` + ``bodies``: a lab's ``.osim`` model and its body map (both or
    neither); ``settings``: :class:`spinemocap.opensim.OpenSimSettings`.

    Returns ``(result, levels_from)``: the :class:`~spinemocap.opensim.pipeline.OpenSimResult`
    (its summary a :class:`~spinemocap.opensim.summary.LabModelSummary` with a lab model, else a
    :class:`~spinemocap.opensim.summary.SpineModelSummary`) and where the level map came from.
    Raises :class:`InputError` when OpenSim is not installed, when only one of ``model`` /
    ``bodies`` is given, or when ``capture.toml`` does not say where the subject faces."""
    from ..opensim import OpenSimSettings, require_opensim, run_opensim

    require_opensim()
    if (model is None) != (bodies is None):
        raise InputError("model", "a lab model needs both its .osim file (model) and its body map (bodies)")
    capture = Capture.open(capture_dir)
    markers = read_results(results)
    if levels:
        level_map, levels_from = LevelMap.from_toml(levels, capture.tape.n_rows), str(levels)
    else:
        level_map, levels_from = find_level_map(capture)
    facing = capture.subject.get("facing")
    if facing is None:
        raise InputError(Path(capture_dir) / "capture.toml", "[subject] facing is not set: OpenSim's forward axis "
                         "comes from it (e.g. facing = [0.0, -1.0, 0.0])")
    static_table = read_results(static) if static else None
    settings = settings or OpenSimSettings()
    if model is not None and bodies is not None:
        from ..opensim.labmodel import run_lab_model

        result: AnyOpenSimResult = run_lab_model(markers, capture.tape, level_map, capture.up, facing, out_dir,
                                                 model, bodies, static=static_table, settings=settings,
                                                 source=str(results))
    else:
        result = run_opensim(markers, capture.tape, level_map, capture.up, facing, out_dir, static=static_table,
                             settings=settings, source=str(results))
    return result, levels_from
