"""The studio benchmark's visibility histogram and atomic-write timing; the tape-free set's
region share and the lattice test on random wall bars and tapes."""

from __future__ import annotations

import numpy as np

from spinemocap.bench.synth import time_atomic_writes, views_histogram
from spinemocap.bench.tape_free import largest_region_share, score_lattice


def test_views_histogram_counts_dot_frames_by_cameras_seeing_them():
    visible = np.zeros((2, 3, 4), bool)  # frames, cameras, dots
    visible[0, :, 0] = True              # seen by all 3
    visible[0, :2, 1] = True             # by 2
    visible[1, 0, 2] = True              # by 1
    assert views_histogram(visible).tolist() == [1, 1, 1, 5]


def test_atomic_writes_are_timed_and_land(tmp_path):
    numbers = time_atomic_writes(tmp_path / "w", files=120, size=1000)
    assert numbers.files == 120 and numbers.first_100_cpu_ms >= 0 and numbers.last_100_cpu_ms >= 0
    assert list(numbers.to_dict()) == ["files", "bytes", "first_100_cpu_ms", "last_100_cpu_ms"]
    assert len(list((tmp_path / "w").iterdir())) == 120


def test_the_largest_region_and_the_lattice_test():
    mask = np.zeros((10, 10), bool)
    mask[:2, :5] = True
    mask[5:9, 5:9] = True
    assert largest_region_share(mask) == 0.16 and largest_region_share(np.zeros((3, 3), bool)) == 0.0
    lattice = score_lattice(20)
    assert lattice.cases == 20 and lattice.tapes_accepted > lattice.wall_bars_accepted
    assert 0.5 < lattice.tape_dots_kept <= 1.0
    assert list(lattice.to_dict()) == ["cases", "wall_bars_accepted", "tapes_accepted", "tape_dots_kept"]


def test_a_tape_free_summary_counts_false_dots_and_keeps_the_worst_images():
    from spinemocap.bench.tape_free import MAX_REGION_SHARE, TapeFreeScore

    score = TapeFreeScore()
    empty = np.zeros((10, 10), bool)
    region = empty.copy()
    region[:5, :5] = True  # a quarter of the image
    score.add("clean", np.zeros((0, 2)), empty, 2.0)
    score.add("wall", np.ones((3, 2)), region, 4.0)
    summary = score.summary()
    assert (summary.images, summary.false_dots, summary.images_with_dots) == (2, 3, 1)
    assert summary.false_dots_per_100_images == 150.0 and summary.largest_region_share == 0.25
    assert summary.images_with_region_above_goal == int(0.25 > MAX_REGION_SHARE) and not summary.goal_met
    assert summary.worst == [("wall", 3, 0.25)] and summary.ms_per_image == 3.0
    assert list(summary.to_dict()) == ["images", "false_dots", "false_dots_per_100_images", "images_with_dots",
                                       "largest_region_share", "images_with_region_above_goal", "goal_met",
                                       "ms_per_image", "worst"]
