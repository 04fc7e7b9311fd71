"""Cross-validation: on a synthetic studio trial with a virtual Vicon (own clock and frame), the
clock offset (< 1 ms) and transform (< 1 mm) are recovered and the angles agree; agreement
statistics on known series."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spinemocap.crossval.agreement import agreement, cmc, icc_2_1


def test_agreement_statistics_on_known_series():
    rng = np.random.default_rng(0)
    truth = 10 * np.sin(np.linspace(0, 6, 400))
    a = truth + 1.0 + rng.normal(0, 0.5, truth.shape)
    stats = agreement(a, truth)
    assert stats.bias == pytest.approx(1.0, abs=0.1)
    assert stats.loa_high - stats.loa_low == pytest.approx(2 * 1.96 * 0.5, rel=0.1)
    assert stats.rmse == pytest.approx(np.sqrt(1.0 + 0.25), rel=0.05)
    assert 0.9 < stats.icc < 1.0 and 0.95 < stats.cmc < 1.0 and stats.n == len(truth)
    assert stats.to_dict()["rmse_deg"] == stats.rmse and agreement(a, truth, "mm").to_dict()["bias_mm"] == stats.bias
    empty = agreement(np.array([np.nan, 1.0]), np.array([2.0, np.nan]))  # no finite pair
    assert empty.n == 0 and np.isnan(empty.rmse)
    assert icc_2_1(truth, truth) == pytest.approx(1.0) and cmc(truth, truth) == pytest.approx(1.0)
    assert icc_2_1(truth, -truth) < 0  # opposite waveforms do not agree
    assert np.isnan(cmc(truth, -truth))  # within-instant variance above the total: no real CMC


# on this trial (0.1 mm dot noise): RMSE 1.08 / 1.07 / 0.52 deg, ICC >= 0.976;
# the Vicon's three triads resolve the midline's tangent only coarsely
LUMBAR_RMSE_DEG = {"lumbar_flexion": 1.5, "lumbar_lateral": 2.0, "lumbar_rotation": 1.2}


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    """A 2 s studio trial (no rendering): exact dots + 0.1 mm noise, and its virtual Vicon."""
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from spinemocap.app.virtual_vicon import record_scene
    from spinemocap.synth import SynthConfig
    from spinemocap.synth.scene import build_scene

    config = SynthConfig.preset("tiny", frames=60, fps=30.0, rows=9)
    scene = build_scene(config)
    dots = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])  # the studio's truth (skin strain on)
    dots += np.random.default_rng(1).normal(0.0, 0.1, dots.shape)
    from spinemocap.bodymodel.virtual_vicon import ViconSetup

    vicon = record_scene(scene, ViconSetup(gap_share=0.02))  # the Vicon's ring sees every marker here: add dropouts
    return scene, dots, vicon


def test_crossval_recovers_clock_offset_and_transform(trial):
    from spinemocap.crossval.compare import cross_validate

    scene, dots, vicon = trial
    assert vicon.setup.rate_hz == 200.0 and np.isnan(vicon.positions).any()  # own rate, with gaps
    result = cross_validate(scene.times, dots, scene.labels, scene.tape, vicon.time_s, vicon.positions,
                            vicon.labels)
    a, s = result.alignment, vicon.setup
    assert abs(a.offset_s - s.clock_offset_s) < 1e-3
    points = dots.reshape(-1, 3)
    assert np.linalg.norm(a.to_vicon(points) - (points @ s.R.T + s.t), axis=1).max() < 1.0
    # angles, like with like: the analysis's definitions on both sides (tape: spinemocap angles on
    # the dots; Vicon: the same levels' frames from the triads beside the tape), from neutral
    from spinemocap.analysis.levels import LevelMap
    from spinemocap.app.crossval import COMPARED, crossval_angles

    levels = LevelMap.from_row_levels(scene.tape_on_skin.row_levels, scene.tape.n_rows)
    crossval_angles(result, scene.times, dots, scene.labels, scene.tape, levels)
    angles = result.summary.angles
    assert set(angles) == set(COMPARED)
    for stats in angles.values():
        assert {"rmse_deg", "bias_deg", "loa_low_deg", "loa_high_deg", "icc", "cmc"} <= set(stats.to_dict())
    convention = result.summary.angle_convention
    assert convention is not None
    assert "T12/L1 relative to S1" in convention["definition"]
    assert "VT_R05L/R" in convention["vicon_frames"]["T12/L1"]
    for name in ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation"):  # 15-20 deg of motion
        assert angles[name].rmse < LUMBAR_RMSE_DEG[name] and angles[name].icc > 0.95, name
    # without the sacral triad the Plug-in Gait pelvis stands in for S1 (its offset removed by the neutral)
    keep = [k for k, label in enumerate(vicon.labels) if not label.startswith("VT_R01")]
    no_sacral = cross_validate(scene.times, dots, scene.labels, scene.tape, vicon.time_s, vicon.positions[:, keep],
                               [vicon.labels[k] for k in keep])
    crossval_angles(no_sacral, scene.times, dots, scene.labels, scene.tape, levels)
    assert "Plug-in Gait pelvis" in (no_sacral.summary.angle_convention or {})["vicon_frames"]["S1"]
    for name in ("lumbar_flexion", "lumbar_lateral", "lumbar_rotation"):  # ICC 0.80 / 0.93 / 0.90
        assert no_sacral.summary.angles[name].icc > 0.75, name
    # a wrong clock is found: shifting the Vicon clock by 100 ms shifts the estimate by 100 ms
    shifted = cross_validate(scene.times, dots, scene.labels, scene.tape, vicon.time_s + 0.1, vicon.positions,
                             vicon.labels)
    assert abs(shifted.alignment.offset_s - (s.clock_offset_s + 0.1)) < 1e-3


def test_crossval_command_writes_its_outputs(trial, tmp_path):
    import exporters
    from spinemocap.cli import main
    from spinemocap.markers import MarkerTable

    scene, dots, vicon = trial
    capture = tmp_path / "capture"
    from spinemocap.capture import Capture

    Capture(root=capture, name="trial", fps=scene.fps, n_frames=scene.n_frames, rig=scene.rig, tape=scene.tape).save()
    from spinemocap.analysis.levels import LevelMap

    levels = LevelMap.from_row_levels(scene.tape_on_skin.row_levels, scene.tape.n_rows)
    (capture / "levels.toml").write_text("[levels]\n" + "".join(f'"{k}" = {v}\n' for k, v in levels.rows.items()))
    exporters.write(MarkerTable.from_arrays(scene.labels, dots, scene.fps), tmp_path / "tracked.c3d")
    first = round(vicon.time_s[0] * vicon.setup.rate_hz)
    exporters.write(MarkerTable.from_arrays(vicon.labels, vicon.positions, vicon.setup.rate_hz, first_frame=first),
                    tmp_path / "vicon.c3d")
    # a body-model reference in the Vicon frame and clock (here: the exact dots, as a perfect body fit
    # would give them, sampled on the Vicon clock)
    exact = np.array([scene.frame_dots(f) for f in range(scene.n_frames)])
    s = vicon.setup
    ref_first = 10
    reference = MarkerTable.from_arrays(scene.labels, exact @ s.R.T + s.t, scene.fps, first_frame=ref_first)
    reference.data["time"] = (reference.data["frame"] - ref_first) / scene.fps + s.clock_offset_s
    exporters.write(MarkerTable(reference.data, reference.meta), tmp_path / "tape_dots.csv")  # time column kept
    out = tmp_path / "cv"
    assert main(["crossval", str(tmp_path / "tracked.c3d"), str(tmp_path / "vicon.c3d"), "--capture", str(capture),
                 "--out", str(out), "--reference", str(tmp_path / "tape_dots.csv")]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["clock_offset_s"] - vicon.setup.clock_offset_s) < 1e-3
    assert summary["reference"]["dot_distance_mean_mm"] < 0.5  # tracked noise is 0.1 mm per axis
    assert summary["angles"]["lumbar_flexion"]["icc"] > 0.95  # the capture's levels.toml, analysis angles
    assert set(summary["reference"]["angles"]) == set(summary["angles"])
    merged = exporters.read(out / "merged.c3d")
    assert {"VICON_VT_R01", "R01L", "REF_R01L"} <= set(merged.labels)
    assert "<img src=\"data:image/png;base64," in (out / "report.html").read_text()


def test_synth_vicon_hook_writes_a_c3d_nexus_tools_read(tmp_path):
    pytest.importorskip("torch")
    ezc3d = pytest.importorskip("ezc3d")
    from spinemocap.app.virtual_vicon import write_virtual_vicon
    from spinemocap.synth import SynthConfig

    np.savez(tmp_path / "groundtruth.npz", dots=np.zeros((4, 2, 3)))  # the studio's own truth, kept
    from spinemocap.bodymodel.virtual_vicon import ViconSetup

    config = SynthConfig.preset("tiny")
    vicon = write_virtual_vicon(config, tmp_path, ViconSetup(gap_share=0.05))  # (tiny: no occlusion, no wand wave)
    c3d = ezc3d.c3d(str(tmp_path / "vicon.c3d"))
    assert c3d["parameters"]["POINT"]["RATE"]["value"][0] == 200.0
    labels = c3d["parameters"]["POINT"]["LABELS"]["value"]
    assert labels == vicon.labels and {"LASI", "C7", "VT_R01", "VT_R01L"} <= set(labels)
    points = np.transpose(c3d["data"]["points"][:3], (2, 1, 0))  # (N, M, 3) mm, Vicon frame
    seen = np.isfinite(vicon.positions)
    np.testing.assert_allclose(points[seen], vicon.positions[seen], atol=0.01)
    truth = np.load(tmp_path / "groundtruth.npz")
    assert "dots" in truth.files and float(truth["vicon_clock_offset_s"]) == vicon.setup.clock_offset_s
    studio = truth["vicon_truth_studio_mm"]
    # Vicon = R studio + t + noise (0.2 mm)
    residual = (studio @ truth["vicon_R"].T + truth["vicon_t_mm"] - vicon.positions)[seen]
    assert np.abs(residual).max() < 1.5 and np.isnan(vicon.positions).any()


def test_transform_from_the_wand_calibrated_rig():
    """--rig-vicon: the same cameras' extrinsics in the rig and in the Vicon frame (as the wand
    writes it, camera coordinates in Vicon mm) give X_v = scale R X + t, the scale included."""
    from scipy.spatial.transform import Rotation

    from spinemocap.crossval.register import Alignment, transform_between_rigs

    rng = np.random.default_rng(3)
    R = Rotation.from_euler("xyz", [1.0, -2.0, 75.0], degrees=True).as_matrix()
    t = np.array([300.0, -900.0, 12.0])
    cams_R = [Rotation.random(random_state=k).as_matrix() for k in range(4)]
    cams_t = [rng.normal(0, 1000, 3) for _ in range(4)]
    scale = 0.9994  # the wand measured the rig 0.06 % small
    vicon_R = [Rc @ R.T for Rc in cams_R]
    vicon_t = [scale * tc - Rc @ R.T @ t for Rc, tc in zip(cams_R, cams_t)]
    R_est, t_est, scale_est = transform_between_rigs(cams_R, cams_t, vicon_R, vicon_t)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-6)
    assert abs(scale_est - scale) < 1e-9
    points = rng.normal(0, 500, (20, 3))
    alignment = Alignment(R_est, t_est, 0.0, 0.0, 0, "offset", scale_est)
    np.testing.assert_allclose(alignment.to_rig(alignment.to_vicon(points)), points, atol=1e-9)
    np.testing.assert_allclose(alignment.to_vicon(points), scale * points @ R.T + t, atol=1e-6)


def test_crossval_recovers_the_clock_and_frame_on_a_13_row_tape():
    """A 13-row tape (triads at R01, R07, R13), exact dots: the Vicon's tape markers sit where
    crossval expects them from the dots (the bench's trial: the studio's dots with skin strain, as
    the Vicon's markers ride the strained skin; unstrained dots would miss the triads by several
    mm and the clock by tens of ms), so offset < 1 ms and transform < 1 mm."""
    torch = pytest.importorskip("torch")
    torch.set_num_threads(1)
    from spinemocap.bench.bodyfit import crossval_trial
    from spinemocap.crossval.compare import cross_validate
    from spinemocap.crossval.tape_markers import tape_marker_points

    scene, dots, vicon = crossval_trial(0, rows=13, occlusion=False)
    s = vicon.setup
    names, expected = tape_marker_points(dots, scene.labels, scene.tape, vicon.labels,
                                         scene.tape.thickness_mm + s.marker_diameter_mm / 2)
    assert names == ["VT_R01", "VT_R07", "VT_R13"]
    studio_time = vicon.time_s - s.clock_offset_s
    for k, name in enumerate(names):  # 0.23 / 0.06 / 0.24 mm (end rows: the tape's curvature)
        j = vicon.labels.index(name)
        placed = np.stack([np.interp(scene.times, studio_time, vicon.truth_studio[:, j, c]) for c in range(3)], axis=1)
        assert np.sqrt(np.mean(np.sum((placed - expected[:, k]) ** 2, axis=1))) < 0.4, name
    result = cross_validate(scene.times, dots, scene.labels, scene.tape, vicon.time_s, vicon.positions, vicon.labels)
    a = result.alignment
    assert abs(a.offset_s - s.clock_offset_s) < 1e-3
    points = dots.reshape(-1, 3)
    assert np.linalg.norm(a.to_vicon(points) - (points @ s.R.T + s.t), axis=1).max() < 1.0


def test_tape_marker_points_on_a_curved_tape_at_every_row():
    """A tape bent round a 300 mm cylinder (across the tape = its axis): the expected centre marker
    is the surface point at the row plus the height along the radius, end rows included (a
    one-sided chord to the next row would tilt the normal by half a row: 0.37 mm at 9 mm)."""
    from spinemocap.crossval.tape_markers import tape_marker_points
    from spinemocap.tape import TapeSpec

    spec = TapeSpec(n_rows=9)
    graph, radius, height = spec.graph, 300.0, 9.0
    theta = graph.uv_mm[:, 1] / radius
    dots = np.column_stack([graph.uv_mm[:, 0], radius * np.sin(theta), radius * np.cos(theta)])[None]
    rows = [0, 4, 8]
    names, expected = tape_marker_points(dots, list(graph.labels), spec, [f"VT_R{r + 1:02d}" for r in rows], height)
    assert names == ["VT_R01", "VT_R05", "VT_R09"]
    angle = np.array(rows) * spec.row_pitch_mm / radius
    truth = (radius + height) * np.column_stack([np.zeros(3), np.sin(angle), np.cos(angle)])
    assert np.abs(expected[0] - truth).max() < 0.05
