"""The one stage timer: wall time per named stage, in milliseconds."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class StageTimer:
    """Accumulates wall time per stage (ms).

    ``with timer("mrf1"): ...`` adds the block's time to ``totals["mrf1"]`` (``totals`` may be a
    caller's dict, e.g. a frame's ``stage_ms``) and records it as one sample; :meth:`add` records a
    time measured elsewhere; :meth:`mean_ms` is the mean per sample of each stage."""

    def __init__(self, totals: dict[str, float] | None = None):
        self.totals: dict[str, float] = {} if totals is None else totals
        self.samples: dict[str, list[float]] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(stage, 1000 * (time.perf_counter() - t0))

    def add(self, stage: str, ms: float) -> None:
        self.totals[stage] = self.totals.get(stage, 0.0) + ms
        self.samples.setdefault(stage, []).append(ms)

    def mean_ms(self) -> dict[str, float]:
        return {stage: sum(v) / len(v) for stage, v in self.samples.items()}
