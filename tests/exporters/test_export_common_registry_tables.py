"""The exporters' shared checks, the registry and the CSV / Parquet tables, module by module:
units and rates checked, repeated labels kept apart, absurd samples read as missing with a
warning naming the file, formats found from extensions, tables round-tripped exactly."""

from __future__ import annotations

import numpy as np
import pytest

from exporters.common import ExportWarning, deduplicate_labels, drop_implausible, frame_rate, mm_per_unit
from exporters.registry import available, format_for_path, get, joined, write_parts
from exporters.tables import read_csv, read_parquet, write_csv, write_parquet
from spinemocap.fileio import InputError
from spinemocap.markers import MarkerTable

LABELS = ["R01L", "R01R", "R02C"]


def _table(n_frames: int = 5, first_frame: int = 0) -> MarkerTable:
    positions = np.arange(n_frames * 3 * 3, dtype=float).reshape(n_frames, 3, 3) + [0.0, 0.0, 1000.0]
    positions[2, 1] = np.nan
    return MarkerTable.from_arrays(LABELS, positions, fps=100.0, first_frame=first_frame)


def test_units_and_frame_rates_are_checked_naming_the_file():
    assert mm_per_unit(" M ", "f.trc") == 1000.0 and mm_per_unit("cm", None) == 10.0
    with pytest.raises(InputError, match="f.trc: unknown length units 'inch'"):
        mm_per_unit("inch", "f.trc")
    assert frame_rate(_table()) == 100.0
    with np.errstate(divide="ignore", invalid="ignore"):  # the table's times at 0 fps
        still = MarkerTable.from_arrays(LABELS, np.zeros((2, 3, 3)), fps=0.0)
    with pytest.raises(InputError, match="out.c3d: frame rate must be positive"):
        frame_rate(still, "out.c3d")


def test_repeated_labels_are_kept_apart_and_absurd_samples_dropped_with_a_warning():
    with pytest.warns(ExportWarning, match="in.csv: duplicate marker label"):
        assert deduplicate_labels(["A", "B", "A", "A_2"], "in.csv") == ["A", "B", "A_2", "A_2_2"]
    positions = np.zeros((2, 2, 3))
    positions[0, 0] = [1e9, 0.0, 0.0]
    positions[1, 1] = [np.nan, 0.0, 0.0]
    with pytest.warns(ExportWarning, match=r"in.trc: 2 of 4 samples"):
        kept = drop_implausible(positions, "in.trc")
    assert np.isnan(kept[0, 0]).all() and np.isnan(kept[1, 1]).all() and (kept[0, 1] == 0).all()
    assert positions[0, 0, 0] == 1e9  # the caller's array is not changed


def test_the_registry_finds_formats_by_name_and_extension():
    assert {"trc", "c3d", "csv", "parquet"} <= set(available())
    assert format_for_path("a/b/markers.TRC") == "trc" and format_for_path("m.parquet") == "parquet"
    assert type(get("CSV")) is type(get("csv"))
    with pytest.raises(InputError, match="unknown export format 'xls'"):
        get("xls")
    with pytest.raises(InputError, match="markers.xyz.*cannot tell the format"):
        format_for_path("markers.xyz")


@pytest.mark.parametrize("write, read, name", [(write_csv, read_csv, "m.csv"), (write_parquet, read_parquet, "m.parquet")])
def test_tables_round_trip_exactly(write, read, name, tmp_path):
    table = _table()
    back = read(write(table, tmp_path / name))
    assert back.labels == table.labels and back.fps == table.fps
    np.testing.assert_array_equal(back.positions(), table.positions())


def test_a_table_written_in_parts_reads_back_as_the_whole(tmp_path):
    whole = _table(6)
    parts = [MarkerTable.from_arrays(LABELS, whole.positions()[k:k + 3], fps=100.0, first_frame=k) for k in (0, 3)]
    path = write_parts(parts, tmp_path / "m.csv", n_frames=6)
    np.testing.assert_array_equal(read_csv(path).positions(), whole.positions())
    np.testing.assert_array_equal(joined(iter(parts), path).positions(), whole.positions())


def test_a_one_frame_csv_reads_back_with_its_frame_rate_from_its_frame_and_time(tmp_path):
    one = MarkerTable.from_arrays(LABELS, np.ones((1, 3, 3)), fps=50.0, first_frame=7)
    back = read_csv(write_csv(one, tmp_path / "one.csv"))
    assert back.fps == 50.0 and back.n_frames == 1
    np.testing.assert_array_equal(back.to_arrays().positions, one.to_arrays().positions)
    first = MarkerTable.from_arrays(LABELS, np.ones((1, 3, 3)), fps=50.0)  # frame 0 at 0 s: no rate to read
    with pytest.raises(InputError, match="first.csv: .*frame rate"):
        read_csv(write_csv(first, tmp_path / "first.csv"))
