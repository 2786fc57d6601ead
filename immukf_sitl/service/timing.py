"""Wall-time statistics of the filter step and the service's lag, computed one way everywhere."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TimingStats:
    """Mean, median and 99th percentile of a series of durations (us); None when empty."""

    mean: float | None = None
    median: float | None = None
    p99: float | None = None

    @classmethod
    def of(cls, values_us: Iterable[float]) -> TimingStats:
        """The statistics of ``values_us``."""
        arr = np.fromiter(values_us, float)
        if arr.size == 0:
            return cls()
        return cls(float(arr.mean()), float(np.median(arr)), float(np.percentile(arr, 99)))

    @classmethod
    def from_json(cls, data: dict | None) -> TimingStats:
        """Back from :meth:`to_json` (e.g. the ``--json`` object of ``serve``)."""
        data = data or {}
        return cls(data.get("mean"), data.get("median"), data.get("p99"))

    def to_json(self) -> dict[str, float | None]:
        """``{"mean", "median", "p99"}``."""
        return {"mean": self.mean, "median": self.median, "p99": self.p99}
