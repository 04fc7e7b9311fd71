"""Where the viewers' outputs go: ``<results folder>/view/`` holds one ``<camera>.mp4`` per
camera, ``all_cameras.mp4`` (the grid) and ``tape3d.html`` (the 3D viewer). A batch trial's
results folder is its output folder, so the report finds them there."""

from __future__ import annotations

import os
from pathlib import Path

VIEW_FOLDER = "view"
GRID_NAME = "all_cameras.mp4"
VIEWER_NAME = "tape3d.html"


def view_folder(results_folder: str | os.PathLike) -> Path:
    """The viewers' folder of a results folder."""
    return Path(results_folder) / VIEW_FOLDER


def view_outputs(results_folder: str | os.PathLike) -> dict[str, Path]:
    """The viewers' files present for a results folder: ``grid`` (all cameras), ``viewer`` (3D
    HTML) and ``camera:<file stem>`` per camera video, in that order."""
    folder = view_folder(results_folder)
    found: dict[str, Path] = {}
    if (folder / GRID_NAME).is_file():
        found["grid"] = folder / GRID_NAME
    if (folder / VIEWER_NAME).is_file():
        found["viewer"] = folder / VIEWER_NAME
    if folder.is_dir():
        for video in sorted(folder.glob("*.mp4")):
            if video.name != GRID_NAME:
                found[f"camera:{video.stem}"] = video
    return found
