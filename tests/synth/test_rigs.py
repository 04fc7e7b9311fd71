"""The studio's camera arcs: every camera on its layout's arc and elevation, looking at the
target, the focal length following the image width, and no lens distortion when none is asked."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.synth.rigs import LAYOUTS, ArcLayout, arc_rig

TARGET = np.array([0.0, 800.0, 1150.0])


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_cameras_stand_on_the_arc_and_look_at_the_target(name):
    layout = LAYOUTS[name]
    n = 4
    rig = arc_rig(layout, n, (640, 400), TARGET, distortion=1.0, rng=np.random.default_rng(0))
    offsets = np.array([cam.center - TARGET for cam in rig])
    np.testing.assert_allclose(np.linalg.norm(offsets[:, :2], axis=1), layout.radius_mm, rtol=1e-9)
    azimuths = np.degrees(np.arctan2(offsets[:, 0], offsets[:, 1]))
    np.testing.assert_allclose(azimuths, np.linspace(-layout.arc_deg / 2, layout.arc_deg / 2, n), atol=1e-9)
    elevations = np.degrees(np.arctan2(offsets[:, 2], np.linalg.norm(offsets[:, :2], axis=1)))
    expected = [layout.elevations_deg[k % len(layout.elevations_deg)] for k in range(n)]
    np.testing.assert_allclose(elevations, expected, atol=1e-9)
    for cam in rig:
        assert cam.K[0, 0] == pytest.approx(layout.focal_px * 640 / layout.reference_width_px)
        # the target seen near the image centre (the principal point is off by <= 1 %)
        assert np.abs(cam.project(TARGET[None])[0] - np.array([319.5, 199.5])).max() <= 0.011 * 640
        assert np.abs(cam.dist).max() > 0


def test_no_distortion_gives_pinhole_cameras():
    rig = arc_rig(LAYOUTS["tiny"], 1, (480, 360), TARGET, distortion=0.0, rng=np.random.default_rng(1))
    assert len(rig) == 1 and (rig[0].dist == 0).all()
    assert rig[0].center[0] == pytest.approx(0.0) and rig[0].center[1] > TARGET[1]  # straight behind (+Y)


def test_a_rig_needs_a_camera():
    with pytest.raises(ValueError, match="at least one camera"):
        arc_rig(ArcLayout(60.0, 1000.0, (10.0,), 1000.0, 640), 0, (640, 480), TARGET, 0.0, np.random.default_rng(0))
