"""OpenSim's IK driven frame by frame (spinemocap/opensim/tools.py): the coordinate goals' weights
and the clamped ranges."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

MARKERS = 6  # on one body that slides along ground's x


def _slider_model(path: Path, range_mm: float | None = None) -> Path:
    """A body on a slider along x (coordinate ``slide``, m) carrying :data:`MARKERS` markers;
    ``range_mm``: the slide clamped to +/- that range."""
    import opensim as osim

    model = osim.Model()
    model.setName("slider")
    body = osim.Body("block", 1.0, osim.Vec3(0), osim.Inertia(1))
    model.addBody(body)
    joint = osim.SliderJoint("slider", model.getGround(), body)
    joint.updCoordinate().setName("slide")
    if range_mm is not None:
        joint.updCoordinate().setRangeMin(-range_mm / 1000.0)
        joint.updCoordinate().setRangeMax(range_mm / 1000.0)
        joint.updCoordinate().set_clamped(True)
    model.addJoint(joint)
    for m in range(MARKERS):
        model.addMarker(osim.Marker(f"M{m}", body, osim.Vec3(0.0, 0.05 * m, 0.02 * (m % 2))))
    model.finalizeConnections()
    model.printToXML(str(path))
    return path


@pytest.mark.parametrize(("goal_sd_mm", "missing"), [(2.0, 0), (5.0, 0), (2.0, 2)])
def test_a_coordinate_goal_of_sd_s_weighs_as_a_prior_of_sd_s_against_the_markers(tmp_path, goal_sd_mm, missing):
    pytest.importorskip("opensim")
    from spinemocap.opensim.tools import OBSERVED_SD_MM, CoordinateGoal, quiet_opensim, solve_ik

    quiet_opensim()
    model = _slider_model(tmp_path / "slider.osim")
    shift_mm = 8.0  # every marker seen 8 mm along x from the model's; the goal holds the slide at 0
    static = np.array([[0.0, 50.0 * m, 20.0 * (m % 2)] for m in range(MARKERS)])
    positions = (static + [shift_mm, 0.0, 0.0])[None]
    positions[0, :missing] = np.nan  # missing samples carry no weight
    weights = np.ones((1, MARKERS))  # each marker observed, SD OBSERVED_SD_MM
    goal = CoordinateGoal(np.zeros(1), np.full(1, (OBSERVED_SD_MM / goal_sd_mm) ** 2))
    solution = solve_ik(model, [f"M{m}" for m in range(MARKERS)], np.zeros(1), positions, weights,
                        accuracy=1e-9, restart=False, goals={"slide": goal})
    # Gaussian posterior mean of the slide: MARKERS measurements of SD OBSERVED_SD_MM and a prior of SD goal_sd_mm
    precision_markers, precision_goal = (MARKERS - missing) / OBSERVED_SD_MM**2, 1.0 / goal_sd_mm**2
    expected_mm = shift_mm * precision_markers / (precision_markers + precision_goal)
    slide_mm = 1000.0 * solution.values[0, solution.coordinates.index("slide")]
    assert slide_mm == pytest.approx(expected_mm, abs=0.01 * shift_mm)


@pytest.mark.parametrize(("shift_mm", "expected_mm"), [(3.0, 3.0), (8.0, 5.0), (-8.0, -5.0)])
def test_a_clamped_coordinate_is_solved_freely_inside_its_range_and_held_at_its_end_outside(
        tmp_path, shift_mm, expected_mm):
    pytest.importorskip("opensim")
    from spinemocap.opensim.tools import quiet_opensim, solve_ik

    quiet_opensim()
    model = _slider_model(tmp_path / "slider.osim", range_mm=5.0)
    static = np.array([[0.0, 50.0 * m, 20.0 * (m % 2)] for m in range(MARKERS)])
    positions = np.stack([static, static + [shift_mm, 0.0, 0.0]])  # the static pose, then the shift
    solution = solve_ik(model, [f"M{m}" for m in range(MARKERS)], np.arange(2.0), positions,
                        np.ones((2, MARKERS)), accuracy=1e-9)
    slide_mm = 1000.0 * solution.values[:, solution.coordinates.index("slide")]
    assert slide_mm[0] == pytest.approx(0.0, abs=0.01)
    assert slide_mm[1] == pytest.approx(expected_mm, abs=0.01)
    assert solution.marker_rms_mm[1] == pytest.approx(abs(shift_mm - expected_mm), abs=0.01)
