"""The base of the benchmarks' results: a frozen dataclass written as one JSON object."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class JsonRecord:
    """A result written as one JSON object: ``to_dict()`` gives its fields in declaration order,
    nested dataclasses as objects, lists and dicts as they are."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
