"""A reference object of known geometry fixes ``--refine-rig``'s world frame.

The refinement on the tape's dots alone keeps the given rig's world frame (no residual sees
it, see test_rig_gauge); a reference object's markers at known world positions, held as control
points, pin it. Pixels here are exact projections (+ noise) through the true rig and the given
rigs the studio's own calibration error, so no rendering is needed, except for the studio's
L-frame itself (rendered, then found where its pose projects)."""

from __future__ import annotations

import numpy as np
import pytest
from tape_scenes import pixels_of, rig_behind, sequence, triangulated

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
    error on the same noisy pixels, 0.16 mm; 0.25-0.32 here: the frame is exact at the reference,
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
        frame = pinned.reference
        assert frame is not None and plain.reference is None
        assert frame.fit_rms_px < 0.15 and not frame.bad_markers and frame.observations == 4 * 5
        assert pinned.frame_uncertainty_mm == frame.fit_rms_mm < 0.2
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
    assert moved.reference is not None and moved.reference.fit_rms_px < 0.15  # no residual sees a shifted pose
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



def test_the_studio_renders_the_lframe_where_its_pose_projects(tmp_path):
    """The studio's L-frame is in the images for real: its markers are found, with the lab's 2 px
    rig saying where to look, near where the true rig projects its known pose (0.01-0.08
    px; a marker seen against the bright arm, whose edge is not in the image, is left out); the
    same scene without it shows no marker there. The capture folder carries
    its design and pose (reference.toml, named by capture.toml)."""
    from dataclasses import replace

    from spinemocap.app.run import capture_control_points
    from spinemocap.capture import Capture, to_grey
    from spinemocap.detect.reference import find_reference_markers
    from spinemocap.synth import SynthConfig, build_scene
    from spinemocap.synth.writer import write_capture

    config = SynthConfig.preset("artificial", frames=1, occlusion="none", realism="ideal",
                                calibration_error_px=2.0, reference=True)
    scene = build_scene(config)
    images = scene.render(0, with_masks=False).images
    plain = build_scene(replace(config, reference=False)).render(0, with_masks=False).images
    truth = scene.groundtruth
    errors, found_by = [], np.zeros(scene.reference.n_markers, int)
    for c, (image, without) in enumerate(zip(images, plain)):
        seen = truth["reference_visible"][0, c]
        assert seen.sum() >= 4
        found = find_reference_markers(image, scene.calibrated_rig[c], scene.reference)
        error = np.linalg.norm(found - truth["reference_uv"][c], axis=1)
        errors += list(error[seen & np.isfinite(error)])
        found_by += np.isfinite(error)
        at = np.round(truth["reference_uv"][c][seen]).astype(int)
        assert (to_grey(image)[at[:, 1], at[:, 0]] > 230).all()  # the bright markers
        assert (to_grey(image)[at[:, 1], at[:, 0]] != to_grey(without)[at[:, 1], at[:, 0]]).all()
        assert np.isnan(find_reference_markers(without, scene.calibrated_rig[c], scene.reference)).all()
    assert len(errors) >= 15 and (found_by >= 2).all() and max(errors) < 0.1, errors
    capture = Capture.open(write_capture(config, tmp_path / "cap", progress=False))
    assert capture.reference_file == "reference.toml"
    assert np.allclose(capture.reference().world_mm, scene.reference.world_mm)
    control, path = capture_control_points(capture, range(1))
    assert path == capture.root / "reference.toml" and control is not None and not control.problems()
    assert (np.isfinite(control.pixels).all(axis=2).sum(axis=0) >= 3).all()
    moved = capture.reference()
    moved.translation_mm = moved.translation_mm + [0.0, 0.0, 200.0]  # a pose 20 cm off: nothing where it says
    moved.to_toml(tmp_path / "moved.toml")
    with pytest.raises(InputError, match=r"moved.toml.*only 0 markers seen by >= 2 cameras"):
        capture_control_points(capture, range(1), tmp_path / "moved.toml")
    (capture.root / "reference.toml").unlink()  # capture.toml names a file that is not there
    with pytest.raises(InputError, match="capture.toml.*reference = 'reference.toml': no such file"):
        capture.reference()
    with pytest.raises(ValueError, match="does not fit the views"):
        build_scene(SynthConfig.preset("tiny", frames=1, reference=True))
