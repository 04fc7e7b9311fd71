"""Points on the tape that Vicon markers sit on, and segment angles from marker triads.

Virtual-Vicon/lab protocol (see ``spinemocap.bodymodel.virtual_vicon``): at chosen 2-dot rows a
marker ``VT_Rnn`` is stuck on the tape's centre line midway between the row's two dots, and
``VT_RnnL``/``VT_RnnR`` sit on the skin beside the tape. From the tracked dots, the centre marker
is at the row's dot midpoint plus the tape normal times (tape thickness + marker radius).
The tape normal at a row: ``across x along`` with ``across`` = right dot - left dot and
``along`` the tape's direction at the row from the row centres: the next row's centre - the
previous row's centre, and at an end row the one-sided second-order difference
``-3 c[r] + 4 c[r+1] - c[r+2]`` (mirrored at the top), so that the normal is the one at the
row, not at the midpoint of its first gap (outward from the back).

The beside markers give the Vicon side of the angle comparison (``spinemocap.app.crossval``).
"""

from __future__ import annotations

import re

import numpy as np

from ..tape import TapeSpec

TAPE_MARKER = re.compile(r"^(?:.*:)?VT_R(\d+)([LR]?)$")


def row_centres(positions: np.ndarray, spec: TapeSpec, labels: list[str]) -> np.ndarray:
    """(F, n_rows, 3) mean of each row's dots (NaN where a dot is missing)."""
    graph = spec.graph
    index = [labels.index(label) for label in graph.labels]
    dots = positions[:, index]
    return np.stack([dots[:, graph.row == r].mean(axis=1) for r in range(spec.n_rows)], axis=1)


def row_sides(positions: np.ndarray, spec: TapeSpec, labels: list[str], row: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) left and right dots of a row (the subject's left/right: labels ``L``/``R``)."""
    graph = spec.graph
    names = [graph.labels[i] for i in np.flatnonzero(graph.row == row)]
    left = next(n for n in names if n.endswith("L"))
    right = next(n for n in names if n.endswith("R"))
    return positions[:, labels.index(left)], positions[:, labels.index(right)]


def row_tangent(centres: np.ndarray, row: int) -> np.ndarray:
    """(F, 3) direction (not unit) of the tape at ``row`` from (F, n_rows, 3) row centres: central
    difference inside, second-order one-sided at the end rows; NaN on a one-row tape."""
    n = centres.shape[1]
    if 0 < row < n - 1:
        return centres[:, row + 1] - centres[:, row - 1]
    step = 1 if row == 0 else -1
    if n < 3:
        return np.full(centres[:, row].shape, np.nan)
    return step * (-3 * centres[:, row] + 4 * centres[:, row + step] - centres[:, row + 2 * step])


def tape_normal(positions: np.ndarray, spec: TapeSpec, labels: list[str], row: int) -> np.ndarray:
    """(F, 3) unit outward tape normal at a row (see module docstring)."""
    centres = row_centres(positions, spec, labels)
    along = row_tangent(centres, row)
    left, right = row_sides(positions, spec, labels, row)
    n = np.cross(right - left, along)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def tape_marker_points(positions: np.ndarray, labels: list[str], spec: TapeSpec, marker_labels: list[str],
                       height_mm: float) -> tuple[list[str], np.ndarray]:
    """The centre tape markers among ``marker_labels`` (``VT_Rnn``) and their expected (F, K, 3)
    positions from tracked dots (F, D, 3); ``height_mm`` = tape thickness + marker radius."""
    names, points = [], []
    centres = row_centres(positions, spec, labels)
    for name in marker_labels:
        match = TAPE_MARKER.match(name)
        if not match or match.group(2):
            continue
        row = int(match.group(1)) - 1
        if not 0 <= row < spec.n_rows or (spec.graph.row == row).sum() != 2:
            continue
        names.append(name)
        points.append(centres[:, row] + height_mm * tape_normal(positions, spec, labels, row))
    return names, (np.stack(points, axis=1) if points else np.zeros((len(positions), 0, 3)))
