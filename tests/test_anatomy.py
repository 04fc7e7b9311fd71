"""The generic thoracolumbar anthropometry: every level T1..S1 in order along the column, the
trends of the cited tables (bodies and discs growing toward the lumbar spine, the lumbar
segments the most mobile in flexion), and the model's distances built from them."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.anatomy import ANATOMY, centre_spacing, skin_depth

LEVELS = [f"T{k}" for k in range(1, 13)] + [f"L{k}" for k in range(1, 6)] + ["S1"]


def test_every_level_from_t1_to_s1_in_order():
    assert list(ANATOMY) == LEVELS
    assert [v.region for v in ANATOMY.values()] == ["thoracic"] * 12 + ["lumbar"] * 5 + ["sacral"]
    s1 = ANATOMY["S1"]
    assert (s1.disc_below, s1.flexion_extension_rom, s1.lateral_rom, s1.axial_rom, s1.mass_share) == (0, 0, 0, 0, 0)


def test_the_published_trends_hold():
    thoracic = [ANATOMY[f"T{k}"] for k in range(1, 13)]
    heights = np.array([v.body_height for v in thoracic])
    assert (np.diff(heights) > 0).all() and 13 <= heights[0] <= 16 and 21 <= heights[-1] <= 25
    discs = np.array([ANATOMY[name].disc_below for name in LEVELS[:-1]])
    assert (np.diff(discs[:12]) >= 0).all() and (discs[12:] >= 9).all() and (discs[:11] <= 6.5).all()
    lumbar_rom = [ANATOMY[f"L{k}"].flexion_extension_rom for k in range(1, 6)]
    assert min(lumbar_rom) > max(v.flexion_extension_rom for v in thoracic[:9])
    assert 0 < sum(v.mass_share for v in ANATOMY.values()) < 100


@pytest.mark.parametrize("upper, lower", [("T1", "T2"), ("T12", "L1"), ("L5", "S1")])
def test_centre_spacing_spans_half_of_each_body_and_the_disc(upper, lower):
    a, b = ANATOMY[upper], ANATOMY[lower]
    assert centre_spacing(upper, lower) == pytest.approx(a.body_height / 2 + a.disc_below + b.body_height / 2)
    assert centre_spacing(upper, lower) > a.disc_below


def test_skin_depth_reaches_the_body_centre_behind_the_spinous_process():
    for name, v in ANATOMY.items():
        assert v.posterior < skin_depth(name) == pytest.approx(v.posterior + v.body_depth / 2)
    assert skin_depth("L3") > skin_depth("T3")
