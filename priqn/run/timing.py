"""Where a loop's wall time goes: named sections with accumulated seconds.

>>> clock = SectionClock()
>>> with clock("update"):
...     learner.update(batch)
>>> clock.totals()  # {"update": 1.23, ...} in first-use order

Costs two ``perf_counter`` calls per section; the training loop always keeps one and
records it in ``meta.json`` (``time_s``), which ``priqn bench train`` reads.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class SectionClock:
    """Accumulates wall seconds per named section (sections must not nest)."""

    def __init__(self) -> None:
        self._seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._seconds[name] = self._seconds.get(name, 0.0) + time.perf_counter() - t0

    def add(self, name: str, seconds: float) -> None:
        """Add time measured elsewhere (e.g. a sub-section inside another)."""
        self._seconds[name] = self._seconds.get(name, 0.0) + float(seconds)

    def totals(self) -> dict[str, float]:
        """Seconds per section, rounded to 0.1 ms."""
        return {k: round(v, 4) for k, v in self._seconds.items()}
