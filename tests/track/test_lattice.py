"""The tape's local lattice checks on dots laid on a curved back (exact truth, no rendering)."""

from __future__ import annotations

import numpy as np
from tape_scenes import SPEC, tape_on_back

from spinemocap.track.lattice import affine_from_neighbours, crowded_labels, off_observed_lattice

GRAPH = SPEC.graph
LIMIT_MM = 0.5 * float(GRAPH.rest_length_mm.min())  # the tracker's default: half the smallest dot spacing


def _end_rows_a_column_aside() -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The dots with rows 1-10 and R11R observed on their own places and the top rows' only
    observed dots on their row neighbours' places (R12L on R12C's, R13L on R13R's).
    Returns (positions (D, 3) mm, observed (D,) bool, the two wrong dots' indices)."""
    dots = tape_on_back(SPEC)
    index = GRAPH.index
    observed = (GRAPH.row <= 9) | np.isin(np.arange(GRAPH.n_dots), [index(x) for x in ("R11R", "R12L", "R13L")])
    positions = dots.copy()
    positions[index("R12L")], positions[index("R13L")] = dots[index("R12C")], dots[index("R13R")]
    return positions, observed, [index("R12L"), index("R13L")]


def test_two_wrong_dots_side_by_side_do_not_bear_each_other_out():
    positions, observed, wrong = _end_rows_a_column_aside()
    # judged against every other observed dot at once, R13L pulls R12L's prediction toward it
    r12l = wrong[0]
    alone = affine_from_neighbours(GRAPH.uv_mm, positions, observed, np.array([r12l]), 20.0)[0]
    assert np.linalg.norm(positions[r12l] - alone) < LIMIT_MM
    off = off_observed_lattice(GRAPH.uv_mm, positions, observed, LIMIT_MM)
    assert off[wrong].all()
    assert not off[observed & ~np.isin(np.arange(GRAPH.n_dots), wrong)].any()  # the dots on their own places


def test_a_tape_on_its_own_places_is_borne_out_under_occlusion():
    """Every dot, an end's rows unseen, the middle rows unseen, a whole column unseen: nothing off."""
    dots = tape_on_back(SPEC)
    rows, column = GRAPH.row, GRAPH.uv_mm[:, 0]
    for observed in (np.ones(GRAPH.n_dots, bool), rows >= 3, rows <= 9, (rows <= 4) | (rows >= 7), column > -10.0,
                     column < 10.0):
        assert not off_observed_lattice(GRAPH.uv_mm, dots, observed, LIMIT_MM).any()


def test_upper_rows_labelled_a_column_aside_crowd_the_model_s_own_dots():
    """Rows 10-13 observed a column to the right (each dot on its right neighbour's place), their
    right-hand dots left where the model put them (inferred): every edge length to row 9 is kept
    (a staggered tape), but two labels sit on one dot."""
    dots = tape_on_back(SPEC)
    index, rows = GRAPH.index, GRAPH.row
    positions, observed = dots.copy(), np.ones(GRAPH.n_dots, bool)
    moved = []
    for row in range(10, 14):
        names = [n for n in ("L", "C", "R") if f"R{row:02d}{n}" in GRAPH.labels]
        for left, right in zip(names, names[1:]):
            positions[index(f"R{row:02d}{left}")] = dots[index(f"R{row:02d}{right}")]
            moved.append(index(f"R{row:02d}{left}"))
        observed[index(f"R{row:02d}R")] = False  # the model's own dot for the column taken
    crowded = crowded_labels(positions, observed, rows, LIMIT_MM)
    np.testing.assert_array_equal(crowded, rows >= 9)  # rows R10-R13 (0-based 9-12) moved, whole
    assert len(moved) >= 6
    assert not crowded_labels(dots, observed, rows, LIMIT_MM).any()  # every dot on its own place
    assert not crowded_labels(positions, observed, rows, 0.0).any()  # 0 turns the check off
