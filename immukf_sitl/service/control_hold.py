"""How wrong a held servo output may be: the controls' uncertainty between their samples.

The model flies on the controls (paper eq. 1) and predicts the accelerometers from them
(eq. 2). An autopilot sends its servo outputs at 10-25 Hz, where the filter steps at 100 Hz,
so between two samples the model holds the last one while the surfaces keep moving. In a roll
reversal at 10 Hz that hold is tens of gyro sigmas of model error, and the zero mode of an
unrelated channel (a lateral accelerometer that reads near zero anyway) wins the bank.

:class:`ControlHold` treats what a control did since its last sample as unknown: a random walk
from the sample, ``u(t) = u_k + w``, ``Var w = q (t - t_k)``. Its intensity ``q`` is measured
from the stream itself: a random walk's increments between samples ``dt`` apart have
``E[du^2] = q dt``, so each new sample gives ``du^2 / dt``, and ``q`` is the mean of the last
:data:`INCREMENTS` of them (the manoeuvre the aircraft is in now; a quiet cruise gives a small
``q``, a reversal a large one). The filter turns the variance into process noise and output
noise through the model's own sensitivity to each control
(:meth:`~immukf_sitl.service.filters.AircraftEstimator.step`). A stream whose samples arrive
with the IMU's (the sim's native 100 Hz) has an age of zero and adds nothing.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: increments whose mean is the random walk's intensity: the last two intervals (0.2 s at
#: 10 Hz), the shortest mean that does not forget a reversal's first increment at once
INCREMENTS = 2


class ControlHold:
    """The last servo sample's controls, and the variance of their error since.

    Parameters
    ----------
    increments : int
        Increments averaged into the random walk's intensity.
    """

    def __init__(self, increments: int = INCREMENTS) -> None:
        self._rates: deque[np.ndarray] = deque(maxlen=increments)
        self.controls: np.ndarray | None = None
        self.time_s: float | None = None

    def add(self, time_s: float, controls: np.ndarray) -> None:
        """A new sample of the controls at ``time_s`` (s): it is what acts from now on."""
        if self.controls is not None and self.time_s is not None and time_s > self.time_s:
            self._rates.append((controls - self.controls) ** 2 / (time_s - self.time_s))
        self.controls = controls
        self.time_s = time_s

    def reset(self) -> None:
        """Forget the stream (a new flight)."""
        self._rates.clear()
        self.controls = None
        self.time_s = None

    @property
    def intensity(self) -> np.ndarray | None:
        """``q`` of each control (its unit^2 / s); None before two samples."""
        if not self._rates:
            return None
        return np.mean(self._rates, axis=0)

    def variance(self, t_s: float) -> np.ndarray | None:
        """``Var`` of each held control's error at ``t_s`` (None: nothing known or nothing held)."""
        q = self.intensity
        if q is None or self.time_s is None or t_s <= self.time_s:
            return None
        return q * (t_s - self.time_s)
