"""MRF1 (alignment to the feasible set), its template and the normal field."""

import numpy as np
import pytest

from spinemocap.tape import TapeSpec
from spinemocap.track.config import MRF1Config
from spinemocap.track.mrf1 import fit_mrf1
from spinemocap.track.normals import NormalField
from spinemocap.track.template import build_template, tape_frames
from spinemocap.track.types import FeasibleSet

TAPE = TapeSpec(n_rows=13).graph  # the paper's artificial tape: 13 rows, 32 dots


def bent_tape(uv):
    """Dots of a tape lying along +Z on a back curved both ways (outward normal ~ +Y, the
    subject's right = -X). Bending keeps arc lengths, so rest lengths hold to ~1 %."""
    u, v = uv[:, 0], uv[:, 1]
    theta, phi = (v - 150) / 600.0, u / 150.0
    x = -150 * np.sin(phi)
    y = -600 * (1 - np.cos(theta)) - 150 * (1 - np.cos(phi))
    z = 900 + 600 * np.sin(theta)
    return np.column_stack([x, y, z])


def feasible_from(true, rng, missing=4, noise_mm=0.5, normal=(0.0, 1.0, 0.0)):
    keep = np.ones(len(true), bool)
    keep[rng.choice(len(true), missing, replace=False)] = False
    pts = true[keep] + rng.normal(scale=noise_mm, size=(keep.sum(), 3))
    nrm = np.asarray(normal, float) + rng.normal(scale=0.15, size=(keep.sum(), 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    fs = FeasibleSet(points=pts, normals=nrm, edges=np.zeros((0, 2), int), source_index=np.arange(len(pts)),
                     n_target=0, n_target_initial=TAPE.spec.n_target_edges)
    return fs, keep


def upside_down(points, centre):
    """Rotate 180 degrees about the world X axis through ``centre`` (a handstand)."""
    rot = np.diag([1.0, -1.0, -1.0])
    return (points - centre) @ rot.T + centre


def test_tape_frames_give_outward_normal_and_handedness():
    true = bent_tape(TAPE.uv_mm)
    normal, across, along = tape_frames(true, TAPE)
    mid = TAPE.index("R08C")
    np.testing.assert_allclose(normal[mid], [0, 1, 0], atol=0.05)
    np.testing.assert_allclose(across[mid], [-1, 0, 0], atol=0.05)  # toward the subject's right
    np.testing.assert_allclose(along[mid], [0, 0, 1], atol=0.05)  # from the sacral end upward


def test_tape_frames_of_a_single_row_tape_are_one_orthonormal_frame_per_dot():
    """A one-row tape has no direction along it: each dot still gets one (3,) frame, unit and
    orthogonal, with ``across`` from L to R (shapes went wrong before: (D, 1, 3) along)."""
    graph = TapeSpec(n_rows=1).graph
    positions = np.array([[-20.0, 0.0, 0.0], [20.0, 0.0, 0.0]])[: len(graph.row)]
    normal, across, along = tape_frames(positions, graph)
    for frame in (normal, across, along):
        assert frame.shape == (len(graph.row), 3)
        np.testing.assert_allclose(np.linalg.norm(frame, axis=1), 1.0)
    np.testing.assert_allclose((normal * across).sum(axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose((normal * along).sum(axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(across, [[1.0, 0.0, 0.0]] * len(graph.row))


def test_normal_field_smooths_noisy_normals():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-100, 100, size=(200, 3))
    noisy = np.array([0, 0, 1.0]) + rng.normal(scale=0.4, size=(200, 3))
    field = NormalField(pts, noisy, radius_mm=40)
    raw_err = np.degrees(np.arccos((noisy / np.linalg.norm(noisy, axis=1, keepdims=True))[:, 2])).mean()
    out = field.at(rng.uniform(-80, 80, size=(20, 3)))
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)
    assert np.degrees(np.arccos(out[:, 2])).mean() < raw_err / 2


def test_template_labels_follow_up_then_previous():
    rng = np.random.default_rng(1)
    true = bent_tape(TAPE.uv_mm)
    fs, _ = feasible_from(true, rng)
    tmpl = build_template(fs.points, fs.normals, TAPE, up=[0, 0, 1])
    assert np.linalg.norm(tmpl.positions - true, axis=1).mean() < 4.0
    flipped = build_template(fs.points, fs.normals, TAPE, up=[0, 0, -1])  # head-down subject
    row1 = TAPE.row == 0
    assert flipped.positions[row1, 2].mean() > true[TAPE.row == TAPE.row.max(), 2].mean() - 5


def test_mrf1_recovers_the_tape_pose_with_missing_dots():
    rng = np.random.default_rng(2)
    true = bent_tape(TAPE.uv_mm)
    fs, keep = feasible_from(true, rng, missing=4, noise_mm=0.5)
    result = fit_mrf1(fs, TAPE, MRF1Config(), up=np.array([0, 0, 1.0]), rng=np.random.default_rng(0))
    err = np.linalg.norm(result.positions - true, axis=1)
    assert err[keep].mean() < 1.0  # observed dots sit on their (noisy, 0.5 mm) feasible points
    assert err.max() < 6.0  # every dot, also the 4 missing ones, keeps its label
    assert err[~keep].mean() < 4.0
    hist = np.array(result.energy_history)
    assert len(hist) == MRF1Config().iterations + 1
    # every step lowers the energy it is judged by (parameters such as the edge normals follow
    # the estimate, so consecutive history entries may differ by that refresh alone)
    assert np.all(hist[1:] <= np.array(result.extra["energy_baselines"]))
    assert np.all(np.diff(hist) < 0.01 * hist[0]) and hist[-1] < 0.8 * hist[0]
    assert result.extra["d"].shape == (TAPE.n_dots,)


def test_mrf1_labels_survive_a_handstand_through_previous():
    rng = np.random.default_rng(3)
    centre = np.array([0.0, 0.0, 1050.0])
    true = upside_down(bent_tape(TAPE.uv_mm), centre)  # sacral row now on top, normal -Y
    fs, keep = feasible_from(true, rng, missing=3, normal=(0.0, -1.0, 0.0))
    previous = true + rng.normal(scale=3.0, size=true.shape)  # last frame, a little off
    previous[5] = np.nan  # a dot missing last frame
    carried = fit_mrf1(fs, TAPE, MRF1Config(), up=np.array([0, 0, 1.0]), previous=previous,
                       rng=np.random.default_rng(0))
    assert np.linalg.norm(carried.positions - true, axis=1).max() < 6.0
    # without the previous frame, "row 1 is the lower end" labels the handstand backwards
    naive = fit_mrf1(fs, TAPE, MRF1Config(), up=np.array([0, 0, 1.0]), rng=np.random.default_rng(0))
    assert np.all(naive.positions[TAPE.row == 0, 2] < carried.positions[TAPE.row == 0, 2] - 200)


def test_mrf1_warm_start_uses_previous_positions():
    rng = np.random.default_rng(4)
    true = bent_tape(TAPE.uv_mm)
    fs, _ = feasible_from(true, rng)
    # the last frame: the body has since moved 9 mm and turned 3 degrees
    angle = np.radians(3.0)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    centre = true.mean(axis=0)
    previous = (true - centre) @ turn.T + centre + np.array([5.0, -3.0, 7.0])
    config = MRF1Config(warm_start=True, iterations=6)
    result = fit_mrf1(fs, TAPE, config, previous=previous, rng=np.random.default_rng(0))
    assert np.linalg.norm(result.extra["template"] - true, axis=1).mean() < 1.5  # aligned start
    assert np.linalg.norm(result.positions - true, axis=1).mean() < 1.0


def test_mrf1_rejects_an_empty_feasible_set():
    fs = FeasibleSet(points=np.zeros((1, 3)), normals=np.zeros((1, 3)), edges=np.zeros((0, 2), int),
                     source_index=np.zeros(1, int), n_target=0, n_target_initial=0)
    with pytest.raises(ValueError, match="at least 2 feasible points"):
        fit_mrf1(fs, TAPE)
