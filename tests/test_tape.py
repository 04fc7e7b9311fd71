import math

import numpy as np
import pytest

from spinemocap.fileio import InputError
from spinemocap.tape import TapeSpec, edge_neighbour_sets


def hand_count(n_rows):
    """Count solid edges by walking the rows as one would on paper."""
    sizes = [2 if r % 2 == 0 else 3 for r in range(n_rows)]
    within = sum(s - 1 for s in sizes)
    between = sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))
    return within + between


@pytest.mark.parametrize("n_rows", [1, 3, 5, 9, 13, 21])
def test_target_edge_count_matches_eq1_and_graph(n_rows):
    spec = TapeSpec(n_rows=n_rows)
    eq1 = math.floor(n_rows / 2) * 2 + math.ceil(n_rows / 2) + (n_rows - 1) * 6
    assert spec.n_target_edges == eq1 == hand_count(n_rows)
    assert len(spec.graph.solid_edges) == eq1


def test_paper_tapes():
    assert TapeSpec(n_rows=9).n_dots == 22  # 22 dots on 20 x 5 cm
    assert TapeSpec(n_rows=13).n_dots == 32  # artificial experiment
    assert TapeSpec(n_rows=9).length_mm == pytest.approx(225.0)


def test_labels_from_sacral_end():
    g = TapeSpec(n_rows=5).graph
    assert g.labels[:5] == ("R01L", "R01R", "R02L", "R02C", "R02R")
    assert g.labels[-2:] == ("R05L", "R05R")
    assert g.index("R02C") == 3


def test_neighbour_bounds_match_paper_range():
    """Eq. 4-5 bound |Omega_e| (selected neighbours) to 6..12 on the tape's own graph."""
    g = TapeSpec(n_rows=9).graph
    sizes = [len(s) for s in g.edge_neighbours()]
    assert min(sizes) == 6 and max(sizes) == 12


def test_dashed_edges_and_lengths():
    spec = TapeSpec(n_rows=5, row_pitch_mm=25, column_spacing_mm=15)
    g = spec.graph
    dashed = {(g.labels[i], g.labels[j]) for i, j in g.dashed_edges}
    assert ("R02L", "R02R") in dashed and ("R01L", "R03L") in dashed and ("R02C", "R04C") in dashed
    lengths = dict(zip(map(tuple, g.edges.tolist()), g.rest_length_mm))
    assert lengths[(g.index("R01L"), g.index("R01R"))] == pytest.approx(15.0)
    assert lengths[(g.index("R01L"), g.index("R03L"))] == pytest.approx(50.0)
    lo, hi = g.solid_length_bounds_mm()
    assert lo == pytest.approx(15 * 0.85) and hi == pytest.approx(np.hypot(25, 22.5) * 1.15)
    assert g.transverse[: 2 * 1 + 2 * 2 + 1].all()  # within-row edges come first


def test_neighbour_sets_small_graph():
    sets = edge_neighbour_sets(np.array([[0, 1], [1, 2], [2, 3]]))
    assert [s.tolist() for s in sets] == [[1], [0, 2], [1]]


@pytest.mark.parametrize("bad", [{"n_rows": 0}, {"n_rows": 4}, {"width_mm": 20}, {"dot_diameter_mm": 20}])
def test_invalid_specs_rejected(bad):
    with pytest.raises(ValueError):
        TapeSpec(**bad)


def test_toml_round_trip_and_errors(tmp_path):
    spec = TapeSpec(n_rows=13, row_pitch_mm=20.0)
    spec.to_toml(tmp_path / "tape.toml")
    assert TapeSpec.from_toml(tmp_path / "tape.toml") == spec
    (tmp_path / "bad.toml").write_text("[tape]\nn_rowz = 3\n")
    with pytest.raises(InputError, match="bad.toml.*n_rowz"):
        TapeSpec.from_toml(tmp_path / "bad.toml")


@pytest.mark.parametrize("n_rows", [5, 9, 13])
def test_min_spacing_is_the_closest_pair_of_dots(n_rows):
    graph = TapeSpec(n_rows=n_rows).graph
    uv = graph.uv_mm
    pairs = np.linalg.norm(uv[:, None] - uv[None], axis=2) + np.diag(np.full(len(uv), np.inf))
    assert graph.min_spacing_mm == pytest.approx(pairs.min())
