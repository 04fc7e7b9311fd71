"""A benchmark result's JSON object: fields in declaration order, nested results as objects."""

from __future__ import annotations

import json
from dataclasses import dataclass

import pytest

from spinemocap.bench.records import JsonRecord


@dataclass(frozen=True)
class _Inner(JsonRecord):
    mean_mm: float
    swaps: int


@dataclass(frozen=True)
class _Outer(JsonRecord):
    name: str
    inner: _Inner
    per_case: dict[str, float]
    rows: list[_Inner]


def test_a_record_is_written_in_field_order_with_nested_records_as_objects():
    record = _Outer("lab", _Inner(0.5, 0), {"b": 2.0, "a": 1.0}, [_Inner(1.0, 1)])
    written = record.to_dict()
    assert list(written) == ["name", "inner", "per_case", "rows"]
    assert written["inner"] == {"mean_mm": 0.5, "swaps": 0}
    assert list(written["per_case"]) == ["b", "a"]
    assert written["rows"] == [{"mean_mm": 1.0, "swaps": 1}]
    assert json.loads(json.dumps(written)) == written
    with pytest.raises(AttributeError):
        record.name = "other"  # type: ignore[misc]  # frozen: a result is not edited after the fact
