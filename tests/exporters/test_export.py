"""Exporters checked by the real consumers: OpenSim's TRC reader, the c3d package and ezc3d.
Plus exact round trips, bad input and atomic writes."""

import warnings

import c3d as c3dlib
import numpy as np
import pytest

import exporters
from exporters import ExportWarning
from exporters.trc import lab_to_opensim
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable

LABELS = ["R01L", "R01R", "R02L", "R02C", "R02R"]


def sample_table(n_frames=40, first_frame=0, fps=100.0, seed=0) -> MarkerTable:
    """Tape-like markers around (0, 0, 1000) mm with a gap, inferred samples, views and residuals."""
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(n_frames, len(LABELS), 3)) * 80 + [0.0, 0.0, 1000.0]
    pos[5:9, 1] = np.nan                     # occluded marker: a gap
    pos[n_frames - 1, 4] = np.nan            # missing at the very end of a row
    status = np.where(rng.random(pos.shape[:2]) < 0.2, "inferred", "observed").astype(object)
    n_views = rng.integers(2, 7, size=pos.shape[:2])
    residual = rng.uniform(0.05, 2.0, size=pos.shape[:2])
    return MarkerTable.from_arrays(LABELS, pos, fps=fps, status=status, n_views=n_views, residual=residual,
                                   first_frame=first_frame, meta={"subject": "athlete01"})


# ------------------------------------------------------------------------------- TRC / OpenSim
def _opensim_table(path):
    osim = pytest.importorskip("opensim")
    table = osim.TimeSeriesTableVec3(str(path))
    flat = table.flatten()          # keep the SWIG owners alive while numpy copies the data
    matrix = flat.getMatrix()
    values = np.array(matrix.to_numpy(), copy=True).reshape(table.getNumRows(), -1, 3)
    meta = {k: table.getTableMetaDataAsString(k) for k in table.getTableMetaDataKeys()}
    return list(table.getColumnLabels()), np.array(table.getIndependentColumn()), values, meta


@pytest.mark.parametrize("units,opensim_axes", [("mm", False), ("m", True)])
def test_opensim_reads_our_trc_with_gaps(tmp_path, units, opensim_axes):
    table = sample_table()
    path = exporters.write(table, tmp_path / "markers.trc", units=units, opensim_axes=opensim_axes)
    labels, times, values, meta = _opensim_table(path)
    expected = table.positions() / (1000.0 if units == "m" else 1.0)
    if opensim_axes:
        expected = lab_to_opensim(expected)
        assert "rotated from lab Z up: X=+x, Y=+z, Z=-y" in meta["header"]
        assert np.allclose(values[..., 1], table.positions()[..., 2] / 1000.0, atol=1e-6, equal_nan=True)  # Y up
    else:
        assert "lab frame, Z up" in meta["header"]
    assert labels == LABELS
    assert meta["Units"] == units and float(meta["DataRate"]) == 100.0 and int(meta["NumFrames"]) == 40
    assert np.allclose(times, np.arange(40) / 100.0)
    assert np.array_equal(np.isnan(values), np.isnan(expected))       # gaps load as NaN, nothing else
    assert np.isnan(values[5:9, 1]).all() and np.isnan(values[39, 4]).all()
    assert np.allclose(values, expected, atol=0.6 * 10.0 ** -(6 if units == "m" else 3), equal_nan=True)


@pytest.mark.parametrize("options", [{}, {"units": "m", "opensim_axes": True, "forward": "-y"}])
def test_trc_round_trip_is_exact_to_written_precision(tmp_path, options):
    first = exporters.write(sample_table(first_frame=7), tmp_path / "a.trc", name="x.trc", **options)
    table = exporters.read(first)
    second = exporters.write(table, tmp_path / "b.trc", name="x.trc", **options)
    assert first.read_text() == second.read_text()
    assert table.frames[0] == 7 and table.meta["fps"] == 100.0
    assert np.allclose(table.positions(), sample_table().positions(), atol=5e-4, equal_nan=True)
    arrays = table.to_arrays()
    assert set(arrays.status[np.isnan(arrays.positions[..., 0])]) == {"missing"}
    assert set(arrays.status[~np.isnan(arrays.positions[..., 0])]) == {"observed"}


def test_we_read_trc_written_by_opensim(tmp_path):
    osim = pytest.importorskip("opensim")
    table = sample_table(n_frames=6)
    # OpenSim rewrites our file with its own writer (trailing tabs, 'nan', its header layout).
    # (Built from a file, not from Python lists: opensim's and ezc3d's SWIG string vectors
    # clash once both are loaded in one process.)
    loaded = osim.TimeSeriesTableVec3(str(exporters.write(table, tmp_path / "ours.trc")))
    osim.TRCFileAdapter.write(loaded, str(tmp_path / "osim.trc"))
    text = (tmp_path / "osim.trc").read_text()
    assert "nan" in text and "NaN" not in text
    back = exporters.read(tmp_path / "osim.trc")
    assert back.labels == LABELS and back.fps == 100.0 and back.meta["trc_axes"] == "as in file"
    assert np.allclose(back.positions(), table.positions(), atol=5e-4, equal_nan=True)
    assert back.to_arrays().status[5, 1] == "missing" and np.isnan(back.positions()[5:9, 1]).all()


def test_opensim_axes_are_a_proper_rotation():
    lab = np.eye(3)
    for forward in ("+x", "-x", "+y", "-y"):
        R = lab_to_opensim(lab, forward).T   # columns: images of lab x, y, z
        assert np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(R @ [0, 0, 1], [0, 1, 0])              # lab up -> OpenSim up (Y)
        f = {"+x": [1, 0, 0], "-x": [-1, 0, 0], "+y": [0, 1, 0], "-y": [0, -1, 0]}[forward]
        assert np.allclose(R @ f, [1, 0, 0])                      # facing direction -> OpenSim X


# ------------------------------------------------------------------------------- C3D
def _c3d_package_frames(path):
    with open(path, "rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3dlib.Reader(handle)
        frames = np.stack([p for _, p, _ in reader.read_frames(check_nan=False)])
        return reader, frames


def test_c3d_and_ezc3d_agree_with_our_writer(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    table = sample_table(first_frame=10)
    path = exporters.write(table, tmp_path / "markers.c3d")
    arrays = table.to_arrays()
    expected = arrays.positions.astype(np.float32).astype(float)   # float32 on disk
    missing = arrays.status == "missing"

    reader, frames = _c3d_package_frames(path)                        # (F, D, 5)
    assert [l.strip() for l in reader.point_labels] == LABELS
    assert reader.point_rate == 100.0 and reader.first_frame == 11 and reader.point_scale == pytest.approx(-0.01)
    assert np.array_equal(frames[..., 3] < 0, missing)                 # invalid = negative word
    assert np.array_equal(frames[..., :3][~missing], expected[~missing])
    res_byte = np.clip(np.rint(arrays.residual / 0.01), 1, 255)
    res_byte[arrays.status == "inferred"] = 0
    assert np.allclose(frames[..., 3][~missing], (res_byte * np.float32(0.01))[~missing], atol=1e-6)
    assert np.array_equal(frames[..., 4][~missing], ((1 << arrays.n_views) - 1)[~missing])

    c = ezc3d.c3d(str(path))
    points = c["data"]["points"][:3].transpose(2, 1, 0)               # (F, D, 3)
    assert list(c["parameters"]["POINT"]["LABELS"]["value"]) == LABELS
    assert c["header"]["points"]["frame_rate"] == 100.0 and c["header"]["points"]["first_frame"] == 10
    assert c["parameters"]["POINT"]["UNITS"]["value"] == ["mm"]
    assert np.array_equal(np.isnan(points).any(axis=2), missing)
    assert np.array_equal(points[~missing], expected[~missing])       # identical to the c3d package
    assert np.array_equal(points[~missing], frames[..., :3][~missing])
    for group, names in {"TRIAL": ["ACTUAL_START_FIELD", "ACTUAL_END_FIELD", "CAMERA_RATE"],
                         "SUBJECTS": ["USED", "NAMES", "MARKER_SETS", "IS_STATIC", "USES_PREFIXES"],
                         "MANUFACTURER": ["COMPANY", "SOFTWARE", "VERSION_LABEL"]}.items():
        assert set(names) <= set(c["parameters"][group])
    assert c["parameters"]["SUBJECTS"]["NAMES"]["value"] == ["athlete01"]
    assert list(c["parameters"]["TRIAL"]["ACTUAL_END_FIELD"]["value"]) == [50, 0]


def test_c3d_round_trip_keeps_status_views_and_residuals(tmp_path):
    table = sample_table()
    back = exporters.read(exporters.write(table, tmp_path / "m.c3d")).to_arrays()
    arrays = table.to_arrays()
    assert back.labels.tolist() == LABELS and back.frames.tolist() == arrays.frames.tolist()
    assert np.array_equal(back.status, arrays.status)
    observed = arrays.status == "observed"
    valid = arrays.status != "missing"
    assert np.array_equal(back.n_views[valid], arrays.n_views[valid])
    assert np.allclose(back.residual[observed], arrays.residual[observed], atol=0.005 + 1e-6)
    assert np.allclose(back.positions, arrays.positions, atol=1e-3, equal_nan=True)
    assert back.residual[arrays.status == "inferred"].max() == 0.0


def test_vectorised_decoder_matches_c3d_package(tmp_path):
    from c3d_corpus import assert_matches_c3d_package

    assert_matches_c3d_package(exporters.write(sample_table(), tmp_path / "m.c3d"))


def test_c3d_beyond_65535_frames(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    n = 70_000
    pos = np.zeros((n, 1, 3))
    pos[:, 0, 0] = np.arange(n)
    table = MarkerTable.from_arrays(["C7"], pos, fps=200.0)
    path = exporters.write(table, tmp_path / "long.c3d")
    c = ezc3d.c3d(str(path))
    assert c["data"]["points"].shape == (4, 1, n)
    assert np.array_equal(c["data"]["points"][0, 0], np.arange(n))
    assert list(c["parameters"]["TRIAL"]["ACTUAL_END_FIELD"]["value"]) == [n % 65536, n // 65536]
    back = exporters.read(path)
    assert back.n_frames == n and back.positions()[-1, 0, 0] == n - 1


def test_c3d_labels_fit_the_format_and_stay_unique(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    long = ["thoracolumbar_fascia_marker_left_A", "thoracolumbar_fascia_marker_left_B", "R01L"]
    table = MarkerTable.from_arrays(long, np.ones((3, 3, 3)), fps=50)
    with pytest.warns(ExportWarning, match="at most 30 characters"):
        path = exporters.write(table, tmp_path / "m.c3d")
    labels = list(ezc3d.c3d(str(path))["parameters"]["POINT"]["LABELS"]["value"])
    assert all(len(l) <= 30 for l in labels) and len(set(labels)) == 3 and labels[2] == "R01L"


def test_c3d_more_than_255_markers_use_labels2(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    labels = [f"D{i:03d}" for i in range(300)]
    table = MarkerTable.from_arrays(labels, np.random.default_rng(0).normal(size=(3, 300, 3)), fps=50)
    path = exporters.write(table, tmp_path / "many.c3d")
    c = ezc3d.c3d(str(path))
    point = c["parameters"]["POINT"]
    assert list(point["LABELS"]["value"]) + list(point["LABELS2"]["value"]) == labels
    back = exporters.read(path)
    assert back.labels == labels
    assert np.allclose(back.positions(), table.positions(), atol=1e-5)


def test_c3d_reference_markers_written_alongside(tmp_path):
    table = sample_table()
    truth = MarkerTable.from_arrays(LABELS, np.nan_to_num(table.positions()) + 1.0, fps=100,
                                    first_frame=2)          # covers frames 2..41: partly outside
    back = exporters.read(exporters.write(table, tmp_path / "m.c3d", reference=truth, reference_prefix="GT_"))
    assert back.labels == LABELS + ["GT_" + l for l in LABELS]
    ref = back.select(labels=["GT_R01L"]).positions()[:, 0]
    assert np.isnan(ref[:2]).all()                           # frames the reference lacks
    assert np.allclose(ref[2:], np.nan_to_num(table.positions())[:38, 0] + 1.0, atol=1e-3)
    assert back.meta["descriptions"]["GT_R01L"] == "reference marker R01L"


def test_c3d_meters(tmp_path):
    table = sample_table()
    path = exporters.write(table, tmp_path / "m.c3d", units="m")
    reader, frames = _c3d_package_frames(path)
    assert reader.get("POINT:UNITS").string_value.strip() == "m"
    ok = table.to_arrays().status != "missing"
    assert np.allclose(frames[..., :3][ok], table.positions()[ok] / 1000.0, rtol=1e-6)
    assert np.allclose(exporters.read(path).positions(), table.positions(), atol=1e-3, equal_nan=True)


# ------------------------------------------------------------------------------- tables
@pytest.mark.parametrize("name", ["m.csv", "m.parquet"])
def test_tables_keep_everything(tmp_path, name):
    table = sample_table(first_frame=3)
    back = exporters.read(exporters.write(table, tmp_path / name))
    for column in ("frame", "time", "label", "x", "y", "z", "n_views", "residual"):
        assert back.data[column].equals(table.data[column]), column
    assert (back.data["status"].astype(str) == table.data["status"].astype(str)).all()
    assert back.meta["fps"] == 100.0
    if name.endswith("parquet"):
        assert back.meta["subject"] == "athlete01"


# ------------------------------------------------------------------------------- bad input
def test_truncated_and_corrupt_c3d(tmp_path):
    good = exporters.write(sample_table(n_frames=200), tmp_path / "good.c3d").read_bytes()
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(good[: len(good) // 2])
    with pytest.raises(InputError, match=r"cut\.c3d.*truncated"):
        exporters.read(cut)
    junk = tmp_path / "junk.c3d"
    junk.write_bytes(b"\x02\x00" + bytes(range(256)) * 3)
    with pytest.raises(InputError, match=r"junk\.c3d"):
        exporters.read(junk)
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.c3d"):
        exporters.read(empty)


def test_c3d_unknown_units(tmp_path):
    data = bytearray(exporters.write(sample_table(), tmp_path / "m.c3d").read_bytes())
    at = data.find(b"UNITS")
    assert at > 0
    end = data.find(b"mm", at)
    data[end:end + 2] = b"ft"
    (tmp_path / "ft.c3d").write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"ft\.c3d.*unknown length units 'ft'"):
        exporters.read(tmp_path / "ft.c3d")


def _trc_lines(tmp_path):
    return exporters.write(sample_table(n_frames=5), tmp_path / "ok.trc").read_text().splitlines()


def test_trc_inconsistent_columns(tmp_path):
    lines = _trc_lines(tmp_path)
    lines[8] = "\t".join(lines[8].split("\t")[:-2])               # a row two fields short
    bad = tmp_path / "bad.trc"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"bad\.trc: line 9 has 15 columns.*need 17"):
        exporters.read(bad)
    lines = _trc_lines(tmp_path)
    lines[2] = lines[2].replace("\t5\tmm", "\t6\tmm")             # NumMarkers disagrees with the names
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="NumMarkers=6 but the names row has 5"):
        exporters.read(bad)


def test_trc_unknown_units_and_duplicates(tmp_path):
    lines = _trc_lines(tmp_path)
    bad = tmp_path / "units.trc"
    bad.write_text("\n".join([lines[0], lines[1], lines[2].replace("mm", "furlong")] + lines[3:]) + "\n")
    with pytest.raises(InputError, match=r"units\.trc: unknown length units 'furlong'"):
        exporters.read(bad)
    dup = tmp_path / "dup.trc"
    dup.write_text("\n".join(lines[:3] + [lines[3].replace("R01R", "R01L")] + lines[4:]) + "\n")
    with pytest.warns(ExportWarning, match=r"dup\.trc: duplicate marker label 'R01L'.*'R01L_2'"):
        table = exporters.read(dup)
    assert table.labels[:2] == ["R01L", "R01L_2"]


def test_nan_only_marker_warns(tmp_path):
    pos = np.ones((4, 2, 3))
    pos[:, 1] = np.nan
    table = MarkerTable.from_arrays(["R01L", "GONE"], pos, fps=10)
    for name in ("m.trc", "m.c3d", "m.csv"):
        with pytest.warns(ExportWarning, match=r"m\.\w+: markers with no valid sample.*GONE"):
            exporters.write(table, tmp_path / name)


def test_unknown_format_and_units(tmp_path):
    with pytest.raises(InputError, match="cannot tell the format from extension '.xyz'"):
        exporters.write(sample_table(), tmp_path / "m.xyz")
    with pytest.raises(InputError, match="unknown export format 'nope'"):
        exporters.get("nope")
    with pytest.raises(InputError, match="unknown length units 'inch'"):
        exporters.write(sample_table(), tmp_path / "m.trc", units="inch")


def test_failing_write_keeps_previous_file_and_leaves_no_temp(tmp_path, monkeypatch):
    path = exporters.write(sample_table(), tmp_path / "markers.c3d")
    before = path.read_bytes()

    def disk_full(self, handle):
        handle.write(b"\x00" * 1000)
        raise OSError("No space left on device")

    monkeypatch.setattr("exporters.c3d._BlockWriter._write_frames", disk_full)
    with pytest.raises(OSError, match="No space left"):
        exporters.write(sample_table(seed=1), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["markers.c3d"]


def test_integer_c3d_from_other_writers_reads_like_ezc3d(tmp_path):
    ezc3d = pytest.importorskip("ezc3d")
    writer = c3dlib.Writer(point_rate=50.0, point_scale=0.1)       # 16-bit integer data
    writer.set_point_labels(["A", "B"])
    frames = []
    for i in range(20):
        points = np.zeros((2, 5), np.float32)
        points[:, :3] = [[i, 2, 3], [4, 5, 6]]
        points[:, 3] = 0.3 if i != 4 else -1
        frames.append((points, np.zeros(0)))
    writer.add_frames(frames)
    with open(tmp_path / "int.c3d", "wb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        writer.write(handle)
    ours = exporters.read(tmp_path / "int.c3d").positions()
    theirs = ezc3d.c3d(str(tmp_path / "int.c3d"))["data"]["points"][:3].transpose(2, 1, 0)
    assert np.array_equal(np.isnan(ours), np.isnan(theirs)) and np.isnan(ours[4]).all()
    assert np.allclose(ours, theirs, rtol=1e-6, equal_nan=True)


def test_c3d_first_frame_beyond_65535_round_trips(tmp_path):
    table = MarkerTable.from_arrays(["A"], np.ones((5, 1, 3)), fps=100, first_frame=100_000)
    back = exporters.read(exporters.write(table, tmp_path / "late.c3d"))
    assert list(back.frames) == list(range(100_000, 100_005))
