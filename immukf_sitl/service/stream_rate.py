"""The rate a stream really arrives at, from its own timestamps.

Autopilots send their IMU at anything from 2 Hz (a telemetry radio) to 1 kHz (a log), and
their servo outputs and GPS at their own rates. The pipeline judges each stream against its
own measured interval (a servo output is stale after a few of its own intervals, not after a
fixed time) and says when the IMU is too slow for detection. :class:`StreamRate` is the median
interval of the last samples: a median ignores the odd dropped or doubled sample that a mean
would follow.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: intervals kept (half a second of a 100 Hz stream; 15 s of a 3 Hz one)
WINDOW = 50
#: intervals needed before the rate is reported
MIN_INTERVALS = 5
#: the median is recomputed every this many samples (it moves slowly; the add is per sample)
REFRESH = 10


class StreamRate:
    """Median interval of a stream's last :data:`WINDOW` samples.

    Parameters
    ----------
    window : int
        Intervals kept.
    """

    def __init__(self, window: int = WINDOW) -> None:
        self._intervals: deque[float] = deque(maxlen=window)
        self._last_s: float | None = None
        self._median_s: float | None = None
        self._since_refresh = 0

    def add(self, time_s: float) -> None:
        """One sample's time (s); a time not after the last is ignored."""
        if self._last_s is not None and time_s > self._last_s:
            self._intervals.append(time_s - self._last_s)
            self._since_refresh += 1
            if self._median_s is None or self._since_refresh >= REFRESH:
                self._refresh()
        if self._last_s is None or time_s > self._last_s:
            self._last_s = time_s

    def _refresh(self) -> None:
        self._since_refresh = 0
        if len(self._intervals) >= MIN_INTERVALS:
            self._median_s = float(np.median(self._intervals))

    def reset(self) -> None:
        """Forget the stream (a new flight)."""
        self._intervals.clear()
        self._last_s = None
        self._median_s = None
        self._since_refresh = 0

    @property
    def interval_s(self) -> float | None:
        """Median interval (s); None before :data:`MIN_INTERVALS` intervals."""
        return self._median_s

    @property
    def rate_hz(self) -> float | None:
        """Samples per second (1 / the median interval); None before it is known."""
        return None if self._median_s is None else 1.0 / self._median_s


def averaged_var_scale(samples: int, interval_s: float | None, step_s: float) -> float:
    """The noise variance of the mean of ``samples`` readings over one sample at ``step_s``.

    A sensor of a given white-noise density has, per sample, a variance in proportion to its
    rate: a reading every ``interval_s`` has ``step_s / interval_s`` times the variance of one
    every ``step_s`` (the spec sheet's ``R`` is per filter step). The mean of ``samples`` of
    them divides that by ``samples``. At 250 Hz a 10 ms step holds 2 or 3 readings: 1.25 and
    0.83 of ``R``, where a fixed ``R`` would be wrong by a quarter every other step. One
    sample, or an unknown interval, is the sensor's own ``R`` (1).
    """
    if samples <= 1 or interval_s is None or interval_s <= 0.0:
        return 1.0
    return step_s / (interval_s * samples)
