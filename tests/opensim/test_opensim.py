"""spinemocap opensim: the spine model, MarkerPlacer and inverse kinematics on studio markers.

Skipped without the optional ``opensim`` package (except the test of the message that says how to
install it). Studio data: ground-truth dots of a short ``mixed`` motion (no rendering)."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable

FRAMES = 12
FPS = 12.0  # the mixed motion's first second: ~16 deg flexion, ~27 deg lateral bending


def test_missing_opensim_says_how_to_install(monkeypatch, tmp_path):
    from spinemocap.app.opensim import opensim_capture

    monkeypatch.setitem(sys.modules, "opensim", None)
    with pytest.raises(InputError, match=r"pip install 'spinemocap\[opensim\]'"):
        opensim_capture(tmp_path, tmp_path, tmp_path / "out")


def test_a_lab_model_needs_its_body_map(tmp_path, capsys):
    pytest.importorskip("opensim")
    from spinemocap.cli import main

    assert main(["opensim", str(tmp_path), "--capture", str(tmp_path), "--out", str(tmp_path / "out"),
                 "--model", str(tmp_path / "lab.osim")]) == 2
    assert "--model: a lab model needs both" in capsys.readouterr().err


try:
    import opensim as osim
except ImportError:  # the extra is optional: everything below needs it
    osim = None
needs_opensim = pytest.mark.skipif(osim is None, reason="opensim not installed: pip install 'spinemocap[opensim]'")


@pytest.fixture(scope="module")
def studio():
    import torch

    from spinemocap.bench.analysis import studio_motion

    torch.set_num_threads(1)
    return studio_motion("mixed", FRAMES, FPS, 13)


def _run(studio, tmp_path, markers=None, up=None, facing=None, levels=None, **settings):
    from spinemocap.opensim import OpenSimSettings, run_opensim

    settings.setdefault("depth_scale", 0.5)
    settings.setdefault("static_frames", 1)  # the neutral first frame (the motion starts at once)
    return run_opensim(markers or studio.markers, studio.tape, levels or studio.levels,
                       studio.up if up is None else up, studio.facing if facing is None else facing,
                       tmp_path / "out", settings=OpenSimSettings(**settings))


@pytest.fixture(scope="module")
def base_run(studio, tmp_path_factory):
    return _run(studio, tmp_path_factory.mktemp("base"))


@pytest.fixture(scope="module")
def fitted_run(studio, tmp_path_factory):
    """The command's defaults: the published joint-centre depths, the skin model on."""
    return _run(studio, tmp_path_factory.mktemp("fitted"), depth_scale=1.0)


@needs_opensim
def test_built_model_loads_and_initialises(studio, base_run):
    from spinemocap.opensim.geometry import CHAIN, HEAD_NECK
    from spinemocap.opensim.model import joint_name

    result = base_run
    model = osim.Model(str(result.out_dir / "model.osim"))
    state = model.initSystem()
    names = [model.getCoordinateSet().get(i).getName() for i in range(model.getNumCoordinates())]
    # the spine's coordinates, then one skin slip per row above the two pinned ones
    assert names == result.plan.coordinates + [f"R{r:02d}_skin_slip" for r in range(3, 14)]
    assert list(result.summary.skin_model.slip.at_peak_mm) == names[-11:]
    bodies = [model.getBodySet().get(i).getName() for i in range(model.getBodySet().getSize())]
    spine = [b for b in bodies if not b.endswith("_skin")]
    assert spine[:3] == ["pelvis", "sacrum", "L5"] and spine[-2:] == ["T1", "head_neck"]
    assert [b for b in bodies if b.endswith("_skin")] == [f"R{r:02d}_skin" for r in range(3, 14)]
    assert model.getMarkerSet().getSize() == len(studio.labels)
    # joints outside the taped span are welds: coordinates only between the vertebrae under the
    # tape's first and last rows (the studio lays the tape from S1 by default: then L5/S1 is driven)
    chain = [*CHAIN, HEAD_NECK]
    lowest, highest = chain.index(studio.row_levels[0]), chain.index(studio.row_levels[-1])
    joints = [joint_name(chain[k], chain[k - 1]) for k in range(1, len(chain))]
    assert result.summary.driven_joints == joints[lowest:highest]
    assert result.summary.welded_joints == joints[:lowest] + joints[highest:]
    assert highest < len(chain) - 1 and joints[highest] in result.summary.welded_joints  # the tape ends below T1
    model.realizePosition(state)
    # the setups are OpenSim's own and name one marker task per placed marker
    for setup in ("setup_scale.xml", "setup_ik.xml"):
        tasks = ET.parse(result.out_dir / setup).getroot().iter("IKMarkerTask")
        assert sorted(t.get("name") for t in tasks) == sorted(studio.labels)
    osim.ScaleTool(str(result.out_dir / "setup_scale.xml"))
    osim.InverseKinematicsTool(str(result.out_dir / "setup_ik.xml"))


@needs_opensim
def test_markers_land_on_the_vertebra_of_the_level_map(studio, tmp_path):
    from spinemocap.analysis.levels import LevelMap
    from spinemocap.opensim.tools import marker_locations

    levels = LevelMap({"L4": 1, "L1": 10, "T10": 13}, 13)  # L3 at row 4, L2 at 7, T12 11, T11 12
    result = _run(studio, tmp_path, levels=levels, slip=None)  # rigid: every marker on its vertebra's body
    placed = marker_locations(result.out_dir / "model.osim", studio.labels)
    expected = {"R01L": "L4", "R02C": "L4", "R04C": "L3", "R06R": "L2", "R08L": "L2", "R10C": "L1",
                "R12C": "T11", "R13R": "T10"}
    assert {label: placed[label][0] for label in expected} == expected
    # on the back of the spine: behind the body centre, beside the midline by the tape's column
    assert all(placed[label][1][0] < -15 for label in expected)
    assert placed["R04C"][1][2] == pytest.approx(0.0, abs=3.0)
    assert placed["R06R"][1][2] > 10 and placed["R08L"][1][2] < -10


@needs_opensim
def test_ik_on_a_studio_capture_meets_the_marker_rms_bound(fitted_run):
    from spinemocap.opensim.summary import read_summary
    from spinemocap.opensim.tools import read_storage

    result = fitted_run
    s = result.summary
    assert s.marker_rms_mm <= 2.0 and s.marker_rms_mm_max <= 3.0
    assert read_summary(result.out_dir / "summary.json") == s  # the file says what the run returned
    assert s.depth.scale_on_published == 1.0 and s.depth.depth_mm["L3"] > 50
    angles = result.angles
    # the mixed motion bends forward: lumbar + thoracic flexion (project sign) grows from the static
    # pose (frame 0)
    total = angles["lumbar_flexion"] + angles["thoracic_flexion"]
    assert total.iloc[0] == pytest.approx(0.0, abs=1.0) and total.max() > 5.0
    header = (result.out_dir / "spine_angles.csv").read_text().splitlines()[0]
    assert "angles deg" in header and "mm" in header
    times, _, _, degrees = read_storage(result.out_dir / "ik.mot")
    assert degrees and len(times) == FRAMES
    assert (result.out_dir / "spine_angles.png").stat().st_size > 10_000


def _turn(points: np.ndarray, degrees: float) -> np.ndarray:
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(points, float) @ R.T


@needs_opensim
def test_turning_the_capture_about_the_vertical_leaves_the_angles_unchanged(studio, base_run, tmp_path):
    base = base_run
    turned_markers = MarkerTable.from_arrays(studio.labels, _turn(studio.dots, 130.0), fps=FPS)
    turned = _run(studio, tmp_path / "b", markers=turned_markers, facing=_turn(studio.facing, 130.0))
    # the command's default: each row's slip held at the tape's, so that IK solves the rotations only.
    # The two worlds differ by rounding alone; the solver stops on absolute tolerances along directions
    # the markers hardly see, so the angles agree within the stated bound (0.5 deg in every frame),
    # not to rounding (with the slips solved around a goal at the tape's they were 1.5 deg apart here)
    assert base.summary.skin_model.slip.from_tape == "held"
    columns = [c for c in base.angles.columns if c.startswith(("lumbar_", "thoracic_"))]
    np.testing.assert_allclose(turned.angles[columns].to_numpy(), base.angles[columns].to_numpy(), atol=0.5)
    assert turned.summary.marker_rms_mm == pytest.approx(base.summary.marker_rms_mm, abs=0.01)


@pytest.fixture(scope="module")
def declared_30_deg_off(studio, tmp_path_factory):
    """The command's defaults with ``facing`` declared 30 deg off the data."""
    return _run(studio, tmp_path_factory.mktemp("turned30"), facing=_turn(studio.facing, 30.0), depth_scale=1.0)


@needs_opensim
def test_a_subject_standing_a_little_turned_gets_its_own_sagittal_plane(studio, fitted_run, declared_30_deg_off):
    from spinemocap.opensim.tools import marker_locations

    # The command's defaults on the studio's default back (skin strain on). The two runs pose the
    # same problem in ground frames 30 deg apart; the placed markers below are the solver-free check.
    turned = declared_30_deg_off
    assert turned.summary.facing_error_deg == pytest.approx(30.0, abs=1.0)
    # the model is built in the tape's own sagittal plane: every marker lands at the same place on
    # the same vertebra whichever facing was declared
    labels = list(fitted_run.summary.marker_weights)
    placed = marker_locations(fitted_run.out_dir / "model.osim", labels)
    placed_turned = marker_locations(turned.out_dir / "model.osim", labels)
    assert {k: v[0] for k, v in placed_turned.items()} == {k: v[0] for k, v in placed.items()}
    np.testing.assert_allclose([placed_turned[k][1] for k in labels], [placed[k][1] for k in labels], atol=0.05)


@needs_opensim
def test_a_declared_facing_30_deg_off_gives_the_same_region_angles(fitted_run, declared_30_deg_off):
    columns = [c for c in fitted_run.angles.columns if c.startswith(("lumbar_", "thoracic_"))]
    np.testing.assert_allclose(declared_30_deg_off.angles[columns].to_numpy(), fitted_run.angles[columns].to_numpy(),
                               atol=0.5)


@needs_opensim
@pytest.mark.parametrize("facing", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
def test_a_facing_wrong_for_the_data_is_a_clear_error(studio, tmp_path, facing):
    with pytest.raises(InputError, match=r"facing does not match the data.*subject faces about \[-?0\.0\d, -1\.00"):
        _run(studio, tmp_path, facing=facing)
    assert not (tmp_path / "out").exists()


@needs_opensim
def test_missing_samples_are_excluded_not_zero(studio, tmp_path):
    dots = studio.dots.copy()
    status = np.full(dots.shape[:2], "observed", dtype=object)
    holes = [(3, 5), (4, 5), (6, 20), (FRAMES - 1, 31)]  # after the static frames
    for f, d in holes:
        dots[f, d] = np.nan
    status[2:, 12] = "inferred"
    markers = MarkerTable.from_arrays(studio.labels, dots, fps=FPS, status=status)
    # holes after the static frames
    result = _run(studio, tmp_path, markers=markers, static_frames=2)
    table = osim.TimeSeriesTableVec3(str(result.out_dir / "markers_opensim.trc"))
    labels = list(table.getColumnLabels())
    for f, d in holes:
        v = table.getRowAtIndex(f)[labels.index(studio.labels[d])]
        assert all(np.isnan([v[0], v[1], v[2]]))
    assert result.summary.marker_rms_mm <= 2.0  # zeros would put a marker a metre off
    weights = result.summary.marker_weights
    # an inferred sample without a confidence weighs 0.6^2 (the tracker's confidence of an inferred dot)
    # over its position variance against an observed dot's
    from spinemocap.opensim.tools import INFERRED_SD_MM, OBSERVED_SD_MM

    inferred = 0.36 * (OBSERVED_SD_MM / INFERRED_SD_MM) ** 2
    assert weights[studio.labels[5]] == 1.0 and weights[studio.labels[12]] == pytest.approx(
        (2 + inferred * (FRAMES - 2)) / FRAMES, abs=1e-3)
    ik = ET.parse(result.out_dir / "setup_ik.xml").getroot()
    task = next(t for t in ik.iter("IKMarkerTask") if t.get("name") == studio.labels[12])
    assert float(task.find("weight").text) == pytest.approx(weights[studio.labels[12]], abs=1e-3)


def _columns_off(studio, frame: int, rows: tuple[int, ...]) -> MarkerTable:
    """The studio's markers with ``rows`` of ``frame`` seen a row's width to the right (rows
    labelled two columns off)."""
    dots = studio.dots.copy()
    for row in rows:
        columns = [d for d, label in enumerate(studio.labels) if label.startswith(f"R{row:02d}")]
        left, right = studio.labels.index(f"R{row:02d}L"), studio.labels.index(f"R{row:02d}R")
        dots[frame, columns] += dots[frame, right] - dots[frame, left]
    return MarkerTable.from_arrays(studio.labels, dots, fps=FPS)


@needs_opensim
def test_a_frame_whose_markers_ik_cannot_fit_keeps_its_neighbours_posture_and_is_flagged(studio, base_run,
                                                                                         tmp_path):
    frame, columns = 6, [c for c in base_run.angles.columns if c.startswith(("lumbar_", "thoracic_"))]
    markers = _columns_off(studio, frame, (10, 11, 12))
    toward = _run(studio, tmp_path / "toward", markers=markers)
    alone = _run(studio, tmp_path / "alone", markers=markers, doubtful_prior_deg=0.0)
    assert alone.summary.flagged_frames == [frame] == toward.summary.flagged_frames
    assert "solved toward the neighbouring frames' posture" in toward.angles["flag"][frame]
    assert "neighbouring" not in alone.angles["flag"][frame]
    truth = base_run.angles[columns].to_numpy()[frame]
    error_toward = np.abs(toward.angles[columns].to_numpy()[frame] - truth).max()
    error_alone = np.abs(alone.angles[columns].to_numpy()[frame] - truth).max()
    assert error_toward < 0.5 * error_alone
    others = np.arange(FRAMES) != frame  # the frames IK fits are solved once, as without the prior
    np.testing.assert_array_equal(toward.angles[columns].to_numpy()[others], alone.angles[columns].to_numpy()[others])


@needs_opensim
def test_markers_on_a_lab_model(studio, base_run, tmp_path):
    from spinemocap.opensim.labmodel import run_lab_model
    from spinemocap.opensim.summary import LabModelSummary, read_summary

    lab = osim.Model(str(base_run.out_dir / "model_generic.osim"))  # stands in for a lab's model
    lab.updMarkerSet().clearAndDestroy()
    lab.setName("lab_spine")
    lab.printToXML(str(tmp_path / "lab.osim"))
    (tmp_path / "bodies.toml").write_text("[bodies]\nL4 = 'L4'\nL2 = 'L2'\nL1 = 'L1'\nT12 = 'T12'\nT10 = 'T10'\n"
                                          "T8 = 'T8'\nT6 = 'T6'\n")
    result = run_lab_model(studio.markers, studio.tape, studio.levels, studio.up, studio.facing,
                           tmp_path / "out", tmp_path / "lab.osim", tmp_path / "bodies.toml")
    s = result.summary
    assert s.marker_rms_mm <= 2.0
    assert isinstance(s, LabModelSummary) and read_summary(tmp_path / "out" / "summary.json") == s
    # rows over unmapped vertebrae go to the nearest mapped one: L3's rows onto L4 or L2, T11's onto T12/T10
    assert set(s.markers_by_body) == {"L4", "L2", "L1", "T12", "T10", "T8", "T6"}
    assert "L2_L3_extension" in result.angles.columns and (tmp_path / "out" / "setup_ik.xml").is_file()
    with pytest.raises(InputError, match="not in"):
        (tmp_path / "bad.toml").write_text("L4 = 'no_such_body'\n")
        run_lab_model(studio.markers, studio.tape, studio.levels, studio.up, studio.facing,
                      tmp_path / "out2", tmp_path / "lab.osim", tmp_path / "bad.toml")


@needs_opensim
def test_batch_with_opensim_shows_ik_beside_the_tape_angles(tmp_path):
    from spinemocap.analysis.bent_tape import write_bent_capture
    from spinemocap.app.batch import run_batch
    from spinemocap.app.report import write_report
    from spinemocap.tape import TapeSpec

    root = tmp_path / "study"
    write_bent_capture(root / "S01" / "pre" / "trial01", TapeSpec(n_rows=13), 30.0, n_frames=12, fps=12.0)
    (root / "S01" / "levels.toml").write_text('[levels]\nS1 = 1\n"T12/L1" = 7\nT9 = 13\n')
    result = run_batch(root, tmp_path / "out", source="groundtruth", workers=1, progress=False, opensim=True)
    trial = result.trials[0].summary
    assert trial.status == "ok" and trial.opensim is not None and trial.opensim.status == "ok", trial
    assert trial.opensim.marker_rms_mm <= 2.0
    ik = (tmp_path / "out" / "S01" / "pre" / "trial01" / "opensim" / "spine_angles.csv").read_text()
    assert "lumbar_flexion" in ik
    page = write_report(tmp_path / "out")["html"].read_text()
    assert "OpenSim IK: marker RMS" in page


@pytest.mark.slow
@needs_opensim
def test_a_tighter_ik_accuracy_reads_the_studio_twist_more_fully(tmp_path):
    # the studio's trunk twist (rotation motion, lab level, frames at 0, 0.75, 1.5, 2.25 s: the
    # twist's peaks either way and neutral): the IK solver stops at its accuracy short of the
    # optimum along a twist shared between the pelvis and the levels
    from spinemocap.analysis.levels import LevelMap
    from spinemocap.bench.analysis import expected_between_rows, studio_motion
    from spinemocap.bench.opensim import ik_angles
    from spinemocap.opensim import OpenSimSettings, run_opensim
    from spinemocap.opensim.tools import IK_ACCURACY

    data = studio_motion("rotation", 4, 4 / 3, 13, realism="lab")
    markers = MarkerTable.from_arrays(data.labels, data.dots, fps=4 / 3)
    lo, hi = data.rows
    expected = expected_between_rows(data.scene, markers, lo, hi)[:, 2]
    levels = LevelMap.from_row_levels(data.row_levels, 13)
    read = {}
    for accuracy in (IK_ACCURACY, 1e-6):
        settings = OpenSimSettings(static_frames=1, depth_scale=0.6, accuracy=accuracy)
        result = run_opensim(markers, data.tape, levels, data.up, data.facing, tmp_path / f"{accuracy:g}",
                             settings=settings)
        twist = ik_angles(result, lo, hi)[:, 2]
        peaks = np.abs(expected) > 5.0
        read[accuracy] = float(np.mean((twist - twist[0])[peaks] / expected[peaks]))
        assert result.summary.ik_accuracy == accuracy
    assert read[1e-6] > 0.8 and read[1e-6] > read[IK_ACCURACY] + 0.1


def test_only_short_runs_of_doubtful_frames_are_solved_toward_their_neighbours():
    from spinemocap.opensim.pipeline import SHORT_DOUBTFUL_RUN, short_doubtful_runs

    doubtful = np.zeros(20, bool)
    doubtful[[2, 4, 5]] = True  # runs of 1 and 2 frames between frames IK fits
    doubtful[9:9 + SHORT_DOUBTFUL_RUN + 1] = True  # a longer run: a deep bend fitted badly throughout
    doubtful[[0, 19]] = True  # at the trial's ends: a posture on one side only
    again = short_doubtful_runs(doubtful)
    np.testing.assert_array_equal(np.flatnonzero(again), [2, 4, 5])
    assert not short_doubtful_runs(np.ones(2, bool)).any()  # no frame to take a posture from
