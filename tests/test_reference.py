"""A reference object of known geometry fixes ``--refine-rig``'s world frame (issue 11).

The refinement on the tape's dots alone keeps the given rig's world frame (no residual sees
it, see test_rig_gauge); a reference object's markers at known world positions, held as control
points, pin it. Pixels here are exact projections (+ noise) through the true rig and the given
rigs the studio's own calibration error, so no rendering is needed, except for the studio's
L-frame itself (rendered, then found where its pose projects)."""

from __future__ import annotations

import numpy as np
import pytest
from test_rig_gauge import pixels_of, sequence, triangulated
from test_track_stages import rig_behind

from spinemocap.app.reference import pose_doubt
from spinemocap.camera import Rig
from spinemocap.fileio import InputError
from spinemocap.reference import ReferenceObject
from spinemocap.synth.lab_errors import perturb_rig
from spinemocap.track.rig_refine import ControlPoints, ReferenceFitError, RigRefineConfig, refine_rig

# the L-frame upright beside the tape of test_track_stages (tape centre (0, 800, 1000), back
# facing +Y toward the cameras): short arm toward the body, long arm up, markers facing the cameras
POSE = (np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]), np.array([380.0, 950.0, 880.0]))


def lframe() -> ReferenceObject:
    return ReferenceObject.lframe(*POSE)


def control_of(rig: Rig, reference: ReferenceObject, noise_px: float = 0.05, seed: int = 0) -> ControlPoints:
    """The reference's markers where ``rig`` (the truth) sees them, with blob noise."""
    rng = np.random.default_rng(seed)
    pixels = rig.project(reference.world_mm) + rng.normal(0, noise_px, (len(rig), reference.n_markers, 2))
    return ControlPoints(reference.labels, reference.world_mm, pixels, reference.name)


def mean_error(rig: Rig, pixels: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(triangulated(rig, pixels) - truth, axis=2).mean())


def test_the_reference_pins_the_world_frame_of_a_perturbed_rig():
    """Over seeded 2 px studio calibrations: without the reference the refined dots keep the given
    rig's world frame (2.2-2.7 mm here); with it they are near where the true rig puts them (its own
    error on the same noisy pixels, 0.16 mm; measured 0.25-0.32: the frame is exact at the reference,
    the sweep reaches 0.5 m from it), the report says the frame came from the reference and fits
    to a blob's noise."""
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    reference = lframe()
    control = control_of(true_rig, reference)
    floor = mean_error(true_rig, pixels, poses)  # the pixels' noise through the true rig
    without, with_reference = [], []
    for seed in range(3):
        given = perturb_rig(true_rig, poses.reshape(-1, 3), 2.0, np.random.default_rng([seed, 3]))[0]
        start = triangulated(given, pixels)
        plain = refine_rig(given, pixels, start, 100.0, RigRefineConfig())
        pinned = refine_rig(given, pixels, start, 100.0, RigRefineConfig(), control)
        without.append(mean_error(plain.rig, pixels, poses))
        with_reference.append(mean_error(pinned.rig, pixels, poses))
        frame = pinned.extra["world_frame"]
        assert frame["source"] == "reference" and plain.extra["world_frame"]["source"] == "given rig"
        assert frame["fit_rms_px"] < 0.15 and not frame["bad_markers"] and frame["observations"] == 4 * 5
        assert pinned.extra["frame_uncertainty_mm"] == frame["fit_rms_mm"] < 0.2
    assert np.mean(without) > 3 * floor  # the given rig's frame error, kept by the dots-only refinement
    assert np.mean(with_reference) < 0.2 * np.mean(without)
    assert max(with_reference) < 2.5 * floor


def test_a_wrong_design_is_an_error_that_names_the_marker():
    """One marker 8 mm from where the file says (a design typed wrong): the refined rig cannot
    fit it, and the error names it instead of bending the rig to it."""
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    truth = lframe()
    wrong = ReferenceObject(truth.name, truth.labels, truth.markers_mm + [[0, 0, 0], [0, 0, 0], [8.0, 0, 0], [0, 0, 0],
                                                                       [0, 0, 0]], 14.0, *POSE)
    seen = control_of(true_rig, truth)
    control = ControlPoints(wrong.labels, wrong.world_mm, seen.pixels, wrong.name)
    given = perturb_rig(true_rig, poses.reshape(-1, 3), 2.0, np.random.default_rng([0, 3]))[0]
    with pytest.raises(ReferenceFitError, match=r"markers \['REF3'\]"):
        refine_rig(given, pixels, triangulated(given, pixels), 100.0, RigRefineConfig(), control)


def test_too_few_markers_seen_is_an_error():
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    control = control_of(true_rig, lframe())
    control.pixels[1:, 2:] = np.nan  # markers 3-5 seen by one camera only
    with pytest.raises(ReferenceFitError, match="only 2 markers seen by >= 2 cameras"):
        refine_rig(true_rig, pixels, poses, 100.0, RigRefineConfig(), control)


def test_a_pose_shifted_as_a_whole_fits_but_is_doubted():
    """A pose 15 mm off moves the world with it (the markers fit perfectly): what shows it is how
    far the reference's frame lies from the given rig's, against the given rig's own residuals."""
    true_rig = rig_behind()
    poses = sequence()
    pixels = pixels_of(true_rig, poses)
    truth = lframe()
    shifted = ReferenceObject.lframe(POSE[0], POSE[1] + [15.0, 0.0, 0.0])
    seen = control_of(true_rig, truth)
    given = perturb_rig(true_rig, poses.reshape(-1, 3), 1.0, np.random.default_rng([1, 3]))[0]
    start = triangulated(given, pixels)
    good = refine_rig(given, pixels, start, 100.0, RigRefineConfig(), seen)
    assert pose_doubt(good) is None
    moved = refine_rig(given, pixels, start, 100.0, RigRefineConfig(),
                       ControlPoints(shifted.labels, shifted.world_mm, seen.pixels, shifted.name))
    assert moved.extra["world_frame"]["fit_rms_px"] < 0.15  # no residual sees a shifted pose
    message = pose_doubt(moved)
    assert message is not None and "check its pose" in message


def test_reference_file_round_trip_and_bad_designs(tmp_path):
    path = tmp_path / "reference.toml"
    lframe().to_toml(path)
    back = ReferenceObject.from_toml(path)
    assert back.labels == lframe().labels and np.allclose(back.world_mm, lframe().world_mm)
    path.write_text('[reference]\nlabels = ["A", "B", "C"]\nmarker_diameter_mm = 14.0\n'
                    'markers_mm = [[0, 0, 0], [100, 0, 0], [250, 0, 0]]\n')
    with pytest.raises(InputError, match="reference.toml.*one line"):
        ReferenceObject.from_toml(path)
    path.write_text('[reference]\nlabels = ["A", "B"]\nmarker_diameter_mm = 14.0\nmarkers_mm = [[0, 0, 0], [100, 0, 0]]\n')
    with pytest.raises(InputError, match="at least 3 markers"):
        ReferenceObject.from_toml(path)

