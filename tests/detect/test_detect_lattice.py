"""The tape's lattice test: tape dots kept, lines, rings and isolated spots dropped, with their regions."""

import numpy as np
import pytest

from spinemocap.detect import Detector
from spinemocap.detect.drawn import draw_sample
from spinemocap.detect.lattice import lattice_dots, tape_regions
from spinemocap.synth.rooms import paint_room


def tape_lattice(rows: int = 7, spacing: float = 15.0, pitch: float = 25.0) -> np.ndarray:
    """Dot centres (mm) of a tape: rows alternating 2 and 3 dots, 2-dot rows at the ends."""
    out = []
    for j in range(rows):
        xs = (-spacing / 2, spacing / 2) if j % 2 == 0 else (-spacing, 0.0, spacing)
        out += [(x, j * pitch) for x in xs]
    return np.array(out)


def seen(points_mm: np.ndarray, px_per_mm: float, angle_deg: float, squash: float, shear: float) -> np.ndarray:
    """An affine view: rotated, foreshortened across by ``squash``, sheared, scaled, shifted."""
    a = np.radians(angle_deg)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    affine = rotation @ np.array([[squash, shear], [0.0, 1.0]]) * px_per_mm
    return points_mm @ affine.T + [400.0, 300.0]


@pytest.mark.parametrize("angle, squash, shear", [(0, 1.0, 0.0), (30, 0.5, 0.2), (80, 0.8, -0.3), (-45, 1.0, 0.0)])
def test_every_dot_of_a_tape_seen_from_any_side_is_on_the_lattice(angle, squash, shear):
    uv = seen(tape_lattice(), 1.3, angle, squash, shear)
    found = lattice_dots(uv)
    assert found.corner.all() and found.middle[[3, 8, 13]].all()  # the middles of the 3-dot rows
    assert found.staggered.all()  # every row of three lies between rows of two
    # two rows cut out of the tape by an occluder still form the lattice, but show no stagger
    cut = lattice_dots(uv[:5])
    assert cut.corner.all() and cut.middle.sum() == 1 and not cut.staggered.any()
    assert lattice_dots(uv[:7]).staggered.all()  # three rows do


def test_lines_rings_and_isolated_spots_are_not_on_a_lattice():
    line = np.c_[np.arange(12) * 17.0, np.full(12, 50.0)]  # screw heads on a rail, gaps of blinds
    assert not lattice_dots(line).corner.any()
    for n in (6, 8, 10, 12, 16, 20, 24, 32, 40):  # the LED ring round a motion-capture camera's lens
        a = 2 * np.pi * np.arange(n) / n
        for squash in (1.0, 0.6):  # seen face-on and obliquely
            ring = np.c_[100 + 30 * np.cos(a), 100 + 30 * squash * np.sin(a)]
            rings = [ring]
            if squash == 1.0:  # two staggered rings, face-on (seen obliquely, they form a local lattice)
                rings.append(np.r_[ring, np.c_[100 + 38 * np.cos(a + np.pi / n), 100 + 38 * np.sin(a + np.pi / n)]])
            for dots in rings:
                found = lattice_dots(dots)
                assert not (found.corner.any() and found.middle.any()), (n, squash, len(dots))
                kept, keep = tape_regions(np.ones((200, 200), bool), dots)
                assert not keep.any() and not kept.any()
    assert not lattice_dots(np.zeros((0, 2))).corner.any() and len(lattice_dots(np.ones((3, 2))).middle) == 3


def test_tape_regions_keep_the_tape_and_drop_the_rest():
    mask = np.zeros((600, 900), bool)
    uv_tape = seen(tape_lattice(), 1.3, 90, 1.0, 0.0) + [-50.0, 0.0]  # along x, around (400, 300)
    lo, hi = uv_tape.min(axis=0).astype(int) - 12, uv_tape.max(axis=0).astype(int) + 12
    mask[lo[1]:hi[1], lo[0]:hi[0]] = True
    line = np.c_[np.arange(8) * 15.0 + 100, np.full(8, 40.0)]
    mask[32:49, 90:215] = True  # a rail with its screws
    mask[500:520, 700:760] = True  # a dark patch without dots
    uv = np.concatenate([uv_tape, line])
    kept, keep = tape_regions(mask, uv)
    assert keep[:len(uv_tape)].all() and not keep[len(uv_tape):].any()
    assert kept[lo[1]:hi[1], lo[0]:hi[0]].all()
    assert not kept[32:49, 90:215].any() and not kept[500:520, 700:760].any()
    assert mask[500:520, 700:760].all()  # the input is not changed


@pytest.fixture(scope="module")
def net():
    return Detector("net")


def test_the_network_finds_no_tape_in_a_lab_room_and_keeps_a_drawn_tape(net):
    # a treadmill with screw heads on its rail and motion-capture cameras with LED rings: the
    # network's regions there carry dots in lines and rings, which the lattice test drops
    room = paint_room((960, 540), seed=3, items=("treadmill", "strobe", "window", "wall_bars"))
    every = Detector("net", lattice=False)
    found = net.detect(room)
    assert len(found.uv) == 0 and not found.mask.any()
    crowded = net.detect(paint_room((960, 540), seed=3, items=("treadmill", "window"), people=2))
    assert len(crowded.uv) == 0  # other people's skin, hair and clothing edges are no tape
    sample = draw_sample(np.random.default_rng(5), size=(480, 360), px_per_mm=1.2)
    tape = net.detect(sample.image)
    plain = every.detect(sample.image)
    assert len(tape.uv) == len(plain.uv) >= len(sample.uv) - 1
    np.testing.assert_array_equal(tape.mask, plain.mask)


def test_two_lines_side_by_side_are_not_a_tape():
    # screw heads on a treadmill's rail found twice each (above and below their slot), or wall
    # bars with two gaps per rung: a grid two dots wide and many long
    for n in (4, 5, 8):  # (three long is a tape-like patch: rows of three)
        grid = np.array([(x * 34.0, y * 8.0) for x in range(n) for y in range(2)]) + 100
        found = lattice_dots(grid)
        assert found.corner.all() and not found.middle.any(), n


def test_a_small_piece_beside_the_tape_stays_and_one_far_away_goes():
    mask = np.zeros((600, 900), bool)
    uv_tape = seen(tape_lattice(5), 1.3, 90, 1.0, 0.0) + [-50.0, 0.0]
    lo, hi = uv_tape.min(axis=0).astype(int) - 12, uv_tape.max(axis=0).astype(int) + 12
    mask[lo[1]:hi[1], lo[0]:hi[0]] = True
    beside = np.array([[hi[0] + 20.0, 290.0], [hi[0] + 20.0, 310.0]])  # a 2-dot piece past a ball
    far = np.array([[850.0, 550.0], [850.0, 570.0]])
    for piece in (beside, far):
        y, x = piece[:, 1].astype(int), piece[:, 0].astype(int)
        mask[y.min() - 8:y.max() + 8, x.min() - 8:x.max() + 8] = True
    kept, keep = tape_regions(mask, np.concatenate([uv_tape, beside, far]))
    assert keep[:len(uv_tape) + 2].all() and not keep[-2:].any()
    assert kept[int(beside[0, 1]), int(beside[0, 0])] and not kept[int(far[0, 1]), int(far[0, 0])]
    # alone, the same small piece is not tape
    alone, keep_alone = tape_regions(mask, beside)
    assert not keep_alone.any() and not alone.any()


def wall_bars(gaps: int, rungs: int, pitch: float, missing: tuple[tuple[int, int], ...] = ()) -> np.ndarray:
    """The gaps of wall bars: ``gaps`` per rung (spacing 1), ``rungs`` rungs ``pitch`` apart."""
    return np.array([(i, j * pitch) for j in range(rungs) for i in range(gaps) if (i, j) not in missing], float)


@pytest.mark.parametrize("pitch", [0.6, 0.9, 1.4, 2.2])
@pytest.mark.parametrize("gaps", [3, 5])
def test_wall_bars_with_three_or_five_gaps_per_rung_are_not_a_tape(pitch, gaps):
    # rows of exactly three on every rung (a lattice like the tape's; with five gaps, every other
    # column is the tape's staggered lattice, but with dots between), with gaps missing where the
    # network did not mark them: a row of two beside a row of three, but no stagger
    patterns = ((), ((1, 3),), ((0, 5),), ((1, 3), (2, 6)), ((0, 2), (2, 5))) if gaps == 3 else ((),)
    for missing in patterns:  # (five gaps with some missing: kept at times, counted by the benchmark)
        for angle, squash, shear in ((0, 1.0, 0.0), (35, 0.6, 0.2), (100, 0.8, -0.3)):
            uv = seen(wall_bars(gaps, 8, pitch, missing), 30.0, angle, squash, shear)
            found = lattice_dots(uv)
            assert found.middle.any() and not found.staggered.any(), (missing, angle)
            kept, keep = tape_regions(np.ones((900, 900), bool), uv)
            assert not keep.any() and not kept.any()


def test_the_lattice_test_keeps_tapes_and_drops_most_wall_bars():
    # the benchmark's count over random views: every wall-bar grid the test keeps is a false tape
    from spinemocap.bench.tape_free import score_lattice

    score = score_lattice(40)
    assert score.tapes_accepted >= 0.75 * score.cases and score.tape_dots_kept >= 0.75
    assert score.wall_bars_accepted <= 0.25 * score.cases
