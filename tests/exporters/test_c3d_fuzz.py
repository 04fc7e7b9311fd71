"""Damaged C3D files end in the project's InputError naming the file, or in
data that passes validation (finite coordinates within a sane bound, NaN exactly where missing,
consistent shapes); absurd, NaN and infinite coordinates are read as missing with a warning
naming the file and how many. Seeded fuzzing with tests/fuzzing.py."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from c3d_corpus import RawC3d, sample_points
from fuzzing import FuzzReport, case_count, cases, marker_table_problems, run_fuzz
from repo_paths import SHARED

import exporters
from exporters import ExportWarning
from exporters.c3d import MAX_ABS_MM, MAX_ABS_OTHER, read_c3d

NEXUS = SHARED / "data" / "vicon" / "walking01_plugin_gait_lower.c3d"


def small_seeds(folder: Path) -> dict[str, bytes]:
    """Small valid C3D files of every kind the reader handles (a few KB each)."""
    points, invalid = sample_points(12, 3)
    rng = np.random.default_rng(0)
    raws = {
        "intel-float-analog": RawC3d(points, invalid=invalid, analog=rng.normal(size=(12, 4, 2)), analog_rate=400.0),
        "intel-int": RawC3d(points, invalid=invalid, integer=True, scale=0.1),
        "dec-float": RawC3d(points, invalid=invalid, processor="dec", trial=(1, 12)),
        "mips-int-analog": RawC3d(points, invalid=invalid, processor="mips", integer=True, scale=0.1,
                                  analog=rng.integers(-99, 99, size=(12, 2, 2)), analog_rate=200.0),
        "rotations": RawC3d(points, invalid=invalid, rotations=np.tile(np.eye(4), (12, 1, 1, 1))),
    }
    seeds = {name: raw.to_bytes() for name, raw in raws.items()}
    table = exporters.read(raws["intel-int"].write(folder / "seed.c3d"))
    table.meta["point_types"] = {}
    seeds["ours"] = exporters.write(table, folder / "ours.c3d").read_bytes()
    return seeds


def _problems(table) -> list[str]:
    return marker_table_problems(table, MAX_ABS_MM, MAX_ABS_OTHER)


def _fuzz(seeds: dict[str, bytes], n: int, seed: int, folder: Path) -> FuzzReport:
    report = run_fuzz(cases(seeds, n, seed), folder, ".c3d", read_c3d, _problems,
                      allowed_warnings=(ExportWarning,))
    report.check()
    return report


def test_fuzz_c3d(tmp_path):
    report = _fuzz(small_seeds(tmp_path), case_count(400), seed=12, folder=tmp_path)
    assert report.accepted > 20 and report.refused > 20          # both outcomes are exercised


def test_fuzz_nexus_c3d(tmp_path):
    if not NEXUS.is_file():
        pytest.skip(f"{NEXUS} not available (shared reference data)")
    _fuzz({"nexus": NEXUS.read_bytes()}, case_count(30), seed=19, folder=tmp_path)


@pytest.mark.slow
def test_fuzz_c3d_10000(tmp_path):
    report = _fuzz(small_seeds(tmp_path), max(case_count(10_000), 10_000), seed=1012, folder=tmp_path)
    print(f"C3D fuzz: {report.total} cases, {report.accepted} accepted, {report.refused} refused, 0 failures")


@pytest.mark.slow
def test_fuzz_nexus_c3d_many(tmp_path):
    if not NEXUS.is_file():
        pytest.skip(f"{NEXUS} not available (shared reference data)")
    report = _fuzz({"nexus": NEXUS.read_bytes()}, max(case_count(500), 500), seed=1019, folder=tmp_path)
    print(f"Nexus C3D fuzz: {report.total} cases, {report.accepted} accepted, {report.refused} refused")


# ------------------------------------------------------------------------------- damaged samples
@pytest.mark.parametrize("value", [1e38, -3e38, np.nan, np.inf, 2e6])
def test_absurd_or_non_finite_coordinates_read_as_missing_with_a_warning(tmp_path, value):
    points, invalid = sample_points(20, 3)
    points[4, 1, 0] = value
    points[9, 2, 2] = value
    path = RawC3d(points, invalid=invalid).write(tmp_path / "damaged.c3d")
    with pytest.warns(ExportWarning, match=r"damaged\.c3d: 2 of 60 C3D samples have non-finite or absurd coordinates"):
        table = exporters.read(path)
    status = table.to_arrays().status
    assert status[4, 1] == "missing" and status[9, 2] == "missing"
    assert np.isnan(table.positions()[4, 1]).all()
    assert _problems(table) == []
    assert np.array_equal(np.isnan(table.positions()[..., 0]), invalid | (np.arange(20)[:, None] == 4) & [0, 1, 0]
                          | (np.arange(20)[:, None] == 9) & [0, 0, 1])


def test_damaged_scale_of_an_integer_file_leaves_every_sample_missing_with_warnings(tmp_path):
    points, invalid = sample_points(10, 2, gaps=False)
    data = bytearray(RawC3d(points, integer=True, scale=0.1).to_bytes())
    at = data.find(b"SCALE")
    assert at > 0
    start = at + len("SCALE") + 2 + 2          # name, offset to next, type, dimensions (0)
    data[start:start + 4] = np.float32(1e30).tobytes()
    (tmp_path / "scale.c3d").write_bytes(bytes(data))
    with pytest.warns(ExportWarning) as caught:
        table = exporters.read(tmp_path / "scale.c3d")
    messages = " | ".join(str(w.message) for w in caught)
    assert re.search(r"scale\.c3d: 20 of 20 C3D samples have non-finite or absurd", messages)
    assert re.search(r"scale\.c3d: markers with no valid sample", messages)
    assert set(table.to_arrays().status.ravel()) == {"missing"} and _problems(table) == []


def test_cli_refuses_a_cut_c3d_naming_it_and_flags_absurd_samples(tmp_path, capsys):
    from spinemocap.cli import main

    points, invalid = sample_points(200, 3)
    data = RawC3d(points, invalid=invalid).to_bytes()
    (tmp_path / "cut.c3d").write_bytes(data[: len(data) // 2])
    assert main(["-q", "export", str(tmp_path / "cut.c3d"), "--format", "csv", "--out", str(tmp_path / "a.csv")]) == 2
    err = capsys.readouterr().err
    assert "cut.c3d: truncated C3D" in err and "Traceback" not in err and not (tmp_path / "a.csv").exists()
    points[50:60, 0] = 1e38
    RawC3d(points, invalid=invalid).write(tmp_path / "absurd.c3d")
    with pytest.warns(ExportWarning, match=r"absurd\.c3d: 10 of 600 C3D samples have non-finite or absurd"):
        assert main(["-q", "export", str(tmp_path / "absurd.c3d"), "--format", "csv",
                     "--out", str(tmp_path / "b.csv")]) == 0
    assert np.isnan(exporters.read(tmp_path / "b.csv").positions()[50:60, 0]).all()
