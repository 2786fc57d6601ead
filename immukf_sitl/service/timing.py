"""Wall-time statistics of the filter step and the service's lag, computed one way everywhere.

:class:`TimingStats` summarises a series; :func:`lag_statistics` adds the max and count the lag
needs; :class:`DurationHistogram` keeps quantiles of an unbounded series at a fixed memory cost,
and :class:`SimTimeWindows` reports them per window of sim time (``serve --json``'s ``windows``).
"""

from __future__ import annotations

import math
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


#: Sim time covered by each entry of ``windows`` in ``--json`` (s).
REPORT_WINDOW_S = 600.0


def lag_statistics(values_us: Iterable[float]) -> dict[str, float | int | None]:
    """Mean, median, p99 and max (us) and the count of a series of lags."""
    arr = np.fromiter(values_us, float)
    if arr.size == 0:
        return {"mean": None, "median": None, "p99": None, "max": None, "n": 0}
    return {
        **TimingStats.of(arr).to_json(),
        "max": float(arr.max()),
        "n": int(arr.size),
    }


class DurationHistogram:
    """Durations (us) counted in 1-us bins up to 100 ms: quantiles at a fixed memory cost."""

    BINS = 100_000

    def __init__(self) -> None:
        self.counts = np.zeros(self.BINS, dtype=np.int64)
        self.n = 0
        self.max_us = 0.0

    def add(self, value_us: float) -> None:
        """Count one duration (negative ones in the first bin, beyond 100 ms in the last)."""
        self.counts[min(max(int(value_us), 0), self.BINS - 1)] += 1
        self.n += 1
        self.max_us = max(self.max_us, value_us)

    def clear(self) -> None:
        """Forget everything (the memory is kept)."""
        self.counts.fill(0)
        self.n = 0
        self.max_us = 0.0

    def summary(self) -> dict[str, float | int | None]:
        """Median, p99 (lower edge of their 1-us bin), max and count."""
        if self.n == 0:
            return {"median": None, "p99": None, "max": None, "n": 0}
        cumulative = np.cumsum(self.counts)

        def quantile(q: float) -> float:
            return float(np.searchsorted(cumulative, q * self.n))

        return {
            "median": quantile(0.5),
            "p99": quantile(0.99),
            "max": round(self.max_us, 1),
            "n": self.n,
        }


class SimTimeWindows:
    """Step time and lag per window of sim time (``windows`` in ``--json``; the soak reads it).

    Parameters
    ----------
    window_s : float
        Sim time per window (s).
    """

    def __init__(self, window_s: float = REPORT_WINDOW_S) -> None:
        self.window_s = float(window_s)
        self.closed: list[dict] = []
        self._index: int | None = None
        self._step = DurationHistogram()
        self._lag = DurationHistogram()

    def add(self, t_s: float, step_us: float | None, lag_us: float | None) -> None:
        """Count one IMU sample's step time and lag (None: it had none) at sim time ``t_s``."""
        index = int(t_s // self.window_s) if math.isfinite(t_s) else -1
        if index != self._index:
            self._close()
            self._index = index
        if step_us is not None:
            self._step.add(step_us)
        if lag_us is not None:
            self._lag.add(lag_us)

    def _close(self) -> None:
        if self._index is not None and (self._step.n or self._lag.n):
            self.closed.append(self._entry())
        self._step.clear()
        self._lag.clear()

    def _entry(self) -> dict:
        start = (self._index or 0) * self.window_s
        return {
            "t_start_s": start,
            "t_end_s": start + self.window_s,
            "step_us": self._step.summary(),
            "lag_us": self._lag.summary(),
        }

    def report(self) -> list[dict]:
        """The closed windows and the current one (marked ``partial``)."""
        current = [{**self._entry(), "partial": True}] if self._index is not None else []
        return [*self.closed, *current]
