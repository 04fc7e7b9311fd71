"""The studio's realism: taping tension, calibration and sync errors, skin strain (Schober), the
taut strip from the sacrum, motions that reach the limits and the realism levels. Measured from
the ground truth and the written files."""

from __future__ import annotations

import numpy as np
import pytest

from spinemocap.capture import Capture
from spinemocap.synth import SynthConfig, build_scene, write_capture


def test_tape_tension_spreads_the_dots_on_the_skin_but_not_the_spec(tmp_path):
    """20 % tension: the rows sit ~20 % farther apart than the roll's spec (uneven by a few
    percent along the tape), the width keeps the spec, capture.toml keeps the roll's spec."""
    config = SynthConfig.preset("tiny", frames=1, rows=9, tape_tension=0.2, seed=3, motion="neutral")
    out = write_capture(config, tmp_path / "cap", progress=False)
    gt = np.load(out / "groundtruth.npz")
    spec = Capture.open(out).tape
    assert spec.row_pitch_mm == 25.0 and spec.n_rows == 9  # what a lab enters: the roll's spec
    assert float(gt["tape_tension"]) == 0.2
    assert abs(gt["laid_stretch"].mean() - 1.2) < 0.01
    assert 0.01 < gt["laid_stretch"].max() - gt["laid_stretch"].min() < 0.12  # uneven by a few percent
    stretch = gt["row_stretch"][0]
    assert abs(stretch.mean() - 1.2) < 0.02, stretch  # measured between the rendered dots
    np.testing.assert_allclose(stretch, gt["laid_stretch"], atol=0.02)
    np.testing.assert_allclose(gt["width_stretch"][0], 1.0, atol=0.04)  # tension acts along the tape
    # the same seed without tension lays the spec exactly
    plain = build_scene(SynthConfig.preset("tiny", frames=1, rows=9, seed=3, motion="neutral"))
    np.testing.assert_allclose(plain.groundtruth["row_stretch"][0], 1.0, atol=0.01)


def test_calibration_error_writes_a_rig_off_by_the_asked_rms_and_keeps_the_truth(tmp_path):
    """The written rig.toml reprojects the true dots with ~1.5 px RMS per camera; the images and
    the ground truth's uv come from the true rig stored in groundtruth.npz."""
    from spinemocap.camera import Camera, Rig

    config = SynthConfig.preset("tiny", frames=2, calibration_error_px=1.5, seed=2)
    out = write_capture(config, tmp_path / "cap", progress=False)
    gt = np.load(out / "groundtruth.npz")
    written = Capture.open(out).rig
    true_rig = Rig([Camera(name, K, d, R, t, cam.size) for name, K, d, R, t, cam in
                    zip(gt["camera_names"], gt["rig_K"], gt["rig_dist"], gt["rig_R"], gt["rig_t"], written)])
    for f in range(2):
        np.testing.assert_allclose(true_rig.project(gt["dots"][f]), gt["uv"][f], atol=1e-6)
    dots = gt["dots"].reshape(-1, 3)
    for c, cam in enumerate(written):
        error = cam.project(dots) - true_rig[c].project(dots)
        rms = np.sqrt(np.mean(np.sum(error**2, axis=1)))
        assert 1.2 < rms < 1.8, (cam.name, rms)
        assert abs(gt["calibration_rms_px"][c] - 1.5) < 0.01
        # rotations, centres and focal lengths all moved
        assert not np.allclose(cam.R, true_rig[c].R, atol=1e-7)
        assert np.linalg.norm(cam.center - true_rig[c].center) > 1e-3
        assert cam.K[0, 0] != true_rig[c].K[0, 0]
    # without the option the written rig is the true one
    exact = build_scene(SynthConfig.preset("tiny", frames=1, seed=2))
    assert exact.calibrated_rig is exact.rig and not exact.groundtruth["calibration_rms_px"].any()


def test_sync_error_renders_each_camera_at_its_own_clock():
    """2 ms RMS of clock offsets (zero mean): each camera's uv is the projection of the dots at
    its own time; in the forehand's fast swing that differs from the nominal time's projection."""
    config = SynthConfig.preset("tiny", frames=2, fps=1 / 0.425, motion="forehand", sync_error_ms=2.0, seed=4)
    scene = build_scene(config)
    offsets = scene.groundtruth["sync_offset_s"]
    assert abs(np.sqrt(np.mean(offsets**2)) - 0.002) < 1e-9 and abs(offsets.mean()) < 1e-12
    frame = 1
    for c, cam in enumerate(scene.rig):
        own = cam.project(scene.posed_tape(frame, offset_s=float(offsets[c])).dots())
        np.testing.assert_allclose(scene.groundtruth["uv"][frame, c], own, atol=1e-9)
    nominal = scene.rig.project(scene.groundtruth["dots"][frame])
    assert np.abs(nominal - scene.groundtruth["uv"][frame]).max() > 0.3
    scene.close()


# ---------------------------------------------------------------------- skin strain
def _row_centres(tape_on_skin, dots: np.ndarray) -> np.ndarray:
    labels = tape_on_skin.spec.labels
    n = tape_on_skin.spec.n_rows
    left = [labels.index(f"R{r + 1:02d}L") for r in range(n)]
    right = [labels.index(f"R{r + 1:02d}R") for r in range(n)]
    return 0.5 * (dots[left] + dots[right]), dots[left], dots[right]


@pytest.fixture(scope="module")
def strained():
    """The default studio body and tape, posed at a few angles, with one subject's skin."""
    scene = build_scene(SynthConfig.preset("tiny", frames=1, motion="neutral", seed=1))
    angles = np.array([[0.0, 0, 0], [70.0, 0, 0], [35.0, 0, 0], [-25.0, 0, 0], [0, 30.0, 0]])
    vertices, _ = scene.body.pose(angles)
    ideal = SynthConfig.preset("tiny", frames=1, realism="ideal")
    return scene, angles, vertices.astype(float), ideal


def _lengths(scene, vertices, angles, skin):
    tos = scene.tape_on_skin
    out = []
    for v, a in zip(vertices, angles):
        centres, left, right = _row_centres(tos, tos.pose(v, None, skin, a).dots())
        out.append((np.linalg.norm(np.diff(centres, axis=0), axis=1), np.linalg.norm(np.diff(left, axis=0), axis=1),
                    np.linalg.norm(np.diff(right, axis=0), axis=1), np.linalg.norm(right - left, axis=1)))
    return out


def test_lumbar_skin_grows_within_the_schober_range_at_full_flexion(strained):
    """Modified Schober: the 15 cm of tape from S1 (six 25 mm row gaps) lengthen by about a third
    (>= 4.5 cm, here 30-40 % by subject) at full flexion, about half that at half flexion, shorten
    in extension; across the tape less; the convex side stretches in lateral bending."""
    scene, angles, vertices, ideal = strained
    assert scene.tape_on_skin.row_levels[0] == "S1"
    rest, full, half, extension, lateral = _lengths(scene, vertices, angles, scene.skin)

    def schober(lengths):  # growth of the six lowest row gaps (15 cm at rest) against standing
        return lengths[0][:6].sum() / rest[0][:6].sum() - 1

    growth = schober(full)
    assert 0.30 <= growth <= 0.42, growth  # 4.5-6.3 cm over 15 cm
    assert abs(growth - scene.skin.lumbar_gain) < 0.03
    assert 0.4 < schober(half) / growth < 0.6  # proportionally less at smaller angles
    assert -0.15 < schober(extension) < -0.03  # compression in extension
    # less transversally, less over the thorax (the last rows, above T12/L1)
    width_growth = full[3][:6].mean() / rest[3][:6].mean() - 1
    assert 0.02 < width_growth < 0.5 * growth
    assert full[0][-1] / rest[0][-1] - 1 < 0.75 * growth
    # lateral bending to the right: the left (convex) side lengthens, the right side shortens
    left, right = lateral[1].sum() / rest[1].sum(), lateral[2].sum() / rest[2].sum()
    assert left > 1.01 and right < 0.99 and left - right > 0.025, (left, right)
    # per subject: another seed has other figures
    from spinemocap.synth.skin_strain import SkinStrain

    assert SkinStrain.for_subject(2).lumbar_gain != scene.skin.lumbar_gain
    # the ideal studio keeps anny's own (small) skin stretch only
    assert ideal.skin_strain == 0
    plain = _lengths(scene, vertices, angles, SkinStrain.for_subject(1, scale=ideal.skin_strain))
    assert schober(plain[1]) < 0.15


def test_rendered_tape_and_groundtruth_follow_the_skin_strain():
    """At full flexion the rendered holes sit where the (strained) ground truth puts the dots."""
    config = SynthConfig.preset("tiny", frames=2, fps=1 / 1.5, motion="flexion", seed=1, noise=0.0)
    scene = build_scene(config)
    gt = scene.groundtruth
    assert abs(scene.angles_deg[1, 0] - 70) < 2
    assert gt["row_stretch"][1][:6].mean() > 1.25  # strained far beyond anny's own stretch
    import cv2

    rendered = scene.render(1)
    hits = total = 0
    for c, (image, mask) in enumerate(zip(rendered.images, rendered.masks)):
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        for d in np.flatnonzero(gt["visible"][1, c]):
            u, v = np.round(gt["uv"][1, c, d]).astype(int)
            total += 1
            hits += bool(gray[v, u] > 80 and mask[v, u])
    scene.close()
    assert total > 20 and hits == total


# ---------------------------------------------------------------------- the taut strip from S1
@pytest.mark.parametrize("phenotype", [{}, {"gender": 1.0, "height": 1.0, "weight": 0.8},
                                       {"gender": 0.0, "height": 0.0, "muscle": 0.9}])
def test_default_tape_starts_at_s1_bridges_the_cleft_and_passes_t12_l1(phenotype):
    """Laid from S1 as a taut strip, the tape bridges the gluteal cleft: every solid dot distance
    keeps the rest spacing within 3 % (the first studio squeezed row 1 by 75-94 % there), and the
    default row count puts at least two rows above T12/L1 on each body."""
    scene = build_scene(SynthConfig.preset("tiny", frames=1, motion="neutral", phenotype=phenotype))
    tos, body = scene.tape_on_skin, scene.body
    graph = tos.spec.graph
    rest = tos.pose(body.rest_vertices).dots()
    solid = graph.edges[graph.solid]
    ratio = np.linalg.norm(rest[solid[:, 0]] - rest[solid[:, 1]], axis=1) / graph.rest_length_mm[graph.solid]
    assert np.abs(ratio - 1).max() < 0.03, ratio
    assert tos.row_levels[0] == "S1"
    centres = _row_centres(tos, rest)[0]
    above = centres[:, 2] > body.junction_height("L1", "T12")
    assert above.sum() >= 2 and above[-2:].all()
    assert abs(centres[0, 2] - body.level_heights()["S1"]) < 5
    scene.close()


def test_vertebral_levels_follow_surface_anatomy():
    """S2 at the PSIS (from the hip joints, Bell et al.), C7 at the cervico-thoracic junction; the
    iliac-crest line (L4/L5) then falls 6-8 cm above the PSIS line, T7 near the inferior angle of
    the scapula (about 13-16 cm below C7 on an adult of anny's height)."""
    from spinemocap.synth.scene import cached_body

    body = cached_body(())
    levels = body.level_heights()
    assert abs(levels["C7"] - body.rest_bone_heads["neck01"][2]) < 1e-6
    assert 60 <= body.junction_height("L5", "L4") - levels["S2"] <= 80
    assert 110 <= levels["C7"] - levels["T7"] <= 160
    assert list(levels) == sorted(levels, key=levels.get)


# ---------------------------------------------------------------------- realism levels and motions
def test_realism_levels_set_the_unset_fields():
    lab = SynthConfig.preset("tiny", realism="lab")
    assert (lab.skin_strain, lab.tape_tension, lab.calibration_error_px, lab.sync_error_ms) == (1.0, 0.15, 0.5, 1.0)
    assert lab.noise > 2.0
    ideal = SynthConfig.preset("tiny", realism="ideal")
    assert (ideal.skin_strain, ideal.tape_tension, ideal.calibration_error_px, ideal.sync_error_ms) == (0, 0, 0, 0)
    default = SynthConfig.preset("tiny")
    assert default.realism == "skin" and default.skin_strain == 1.0 and default.tape_tension == 0.0
    assert default.tape_start == "S1"
    assert SynthConfig.preset("tiny", realism="lab", tape_tension=0.3).tape_tension == 0.3  # a field wins
    with pytest.raises(ValueError, match="unknown realism level"):
        SynthConfig.preset("tiny", realism="hollywood")


def test_motions_reach_full_flexion_and_the_forehand_swings_early():
    from spinemocap.synth.motions import spine_motion
    from spinemocap.synth.skin_strain import FULL_FLEXION_DEG

    t = np.arange(0, 3.0, 0.01)
    assert abs(spine_motion("flexion", t)[:, 0].max() - FULL_FLEXION_DEG) < 0.1
    speed = np.abs(np.diff(spine_motion("forehand", t)[:, 2])) / 0.01
    fast = t[1:][speed > 500]
    assert len(fast) and fast.min() < 0.5  # the fast phase lies in the first 50 frames at 100 fps


def test_groundtruth_places_s1_and_t12_l1_on_the_tape():
    """level_rows: S1 at row 1 of the default tape, T12/L1 at least two rows below its last row."""
    scene = build_scene(SynthConfig.preset("tiny", frames=1, motion="neutral"))
    gt = scene.groundtruth
    rows = dict(zip([str(x) for x in gt["level_names"]], gt["level_rows"]))
    n = scene.tape.n_rows
    assert abs(rows["S1"] - 1) < 0.1
    assert 1 < rows["T12/L1"] < n - 1  # rows n - 1 and n lie above it
    assert rows["S1"] < rows["L5/S1"] < rows["L5"] < rows["L4"]  # ordered along the tape
    assert np.isnan(rows["C7"])  # off this tape
    scene.close()


def test_default_capture_has_a_finite_s1_to_t12_l1_lumbar_angle_over_full_flexion():
    """The default studio tape starts at S1, so the standard lumbar angle S1 -> T12/L1
    is finite in every frame of a full flexion, lordotic at rest and growing with the flexion."""
    from spinemocap.analysis.angles import compute_angles
    from spinemocap.analysis.levels import LevelMap
    from spinemocap.markers import MarkerTable

    scene = build_scene(SynthConfig.preset("tiny", frames=7, fps=2.0, motion="flexion"))
    gt = scene.groundtruth
    levels = LevelMap.from_row_levels([str(x) for x in gt["row_levels"]], scene.tape.n_rows)
    table = compute_angles(MarkerTable.from_arrays(scene.labels, gt["dots"], fps=2.0), scene.tape, levels).table
    flexion = table["lumbar_flexion"].to_numpy(float)
    assert np.isfinite(flexion).all()
    assert flexion[0] < 0  # standing: lumbar lordosis
    peak = int(np.argmax(gt["angles_deg"][:, 0]))
    assert gt["angles_deg"][peak, 0] > 65 and flexion[peak] - flexion[0] > 15
    scene.close()


def test_every_start_from_s2_to_t1_can_be_laid_and_only_impossible_ones_are_refused():
    """Default rows from any start S2..T1 lie flat (the taut strip bridges the cleft at S2); a
    5-row tape from T1 would run onto the head: refused with the room there is."""
    from spinemocap.synth.body import LEVELS
    from spinemocap.synth.scene import cached_tape_on_skin

    for start in LEVELS[:-1]:  # S2 .. T1
        tape = cached_tape_on_skin((), None, start)
        assert tape.row_levels[0] == start and tape.spec.n_rows >= 3
    with pytest.raises(ValueError, match=r"5-row tape .* starting at T1 does not fit .*\(\d+ mm of midline above T1"):
        cached_tape_on_skin((), 5, "T1")


def test_studio_envelope_benchmark_shows_the_lab_beyond_the_ideal_studio(tmp_path):
    """``bench studio``'s envelope: at full flexion the lab tape stretches ~40-60 % against its spec
    between rows, the ideal studio (the peer) only by anny's own few percent."""
    from spinemocap.bench.synth import plot_envelope, realism_envelope

    rows = realism_envelope(levels=("ideal", "lab"), motions=("flexion",), frames=3, fps=1 / 0.75, progress=False)
    ideal, lab = rows
    assert ideal.row_stretch_max < 1.15 and 1.4 < lab.row_stretch_max < 1.7
    assert abs(lab.calibration_rms_px - 0.5) < 0.01 and abs(lab.sync_rms_ms - 1.0) < 1e-6
    assert lab.schober_growth_mm > 45 > ideal.schober_growth_mm  # >= 5 cm over 15 cm of skin (x tension)
    plot_envelope(rows, 1 / 0.75, tmp_path / "envelope.png")
    assert (tmp_path / "envelope.png").stat().st_size > 1000
