"""Fault declaration from mode probabilities: threshold, dwell, clearing, settling time.

The IMM is decision free (paper, section 2.D); a user needs a decision. A fault mode is
declared when its probability stays at or above ``threshold`` for ``dwell_s`` *and* its failed
channels read what a zeroed sensor reads: over the last ``zero_window`` samples,
``sum z^2 / sigma^2`` within the ``zero_quantile`` of a chi-square with that many degrees of
freedom (the paper's fault is zero plus the sensor's noise). The filters' probabilities weigh a
channel against the model's prediction of it; on a real airframe in turbulence that model is
wrong by more than the sensor noise, and a mode that ignores the channel the model explains
worst wins, whatever the channel reads. A healthy channel whose true value sits within about a
noise sigma of zero for the whole window passes the test too: there the probabilities decide
alone. It is cleared
when its probability stays below ``clear_threshold`` for ``clear_dwell_s`` *and* the declared
channels have shown they are alive: at least ``alive_samples`` readings more than
``alive_sigmas`` noise sigmas from zero since the declaration. A zeroed sensor reads zero plus
its noise, beyond 5 sigma once in about 1.7 million samples (4.8 h at 100 Hz), so a sensor that
stays dead is never cleared, nor replaced by another mode's declaration, whatever the
probabilities do while it cannot be told from a healthy one (a y accelerometer in coordinated
flight, a q gyro on a straight leg). Nothing is
declared during the first ``settle_s`` after the estimator starts (its covariances are still
converging from the initial alignment).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from immukf_sitl.estimation.fault_modes import FaultMode


@dataclass(frozen=True)
class DetectorConfig:
    """Decision thresholds (docs/design/detection-and-tuning.md says why each)."""

    threshold: float = 0.9
    dwell_s: float = 0.2
    clear_threshold: float = 0.5
    clear_dwell_s: float = 5.0
    settle_s: float = 3.0
    alive_sigmas: float = 5.0
    alive_samples: int = 3
    zero_window: int = 20
    zero_quantile: float = 0.999

    def __post_init__(self) -> None:
        if not 0.0 < self.clear_threshold <= self.threshold < 1.0:
            raise ValueError(
                "detection thresholds: expected 0 < clear_threshold <= threshold < 1, got "
                f"{self.clear_threshold} and {self.threshold}"
            )
        if min(self.dwell_s, self.clear_dwell_s, self.settle_s) < 0.0:
            raise ValueError("detection dwell and settle times must be >= 0")
        if self.zero_window < 1 or not 0.0 < self.zero_quantile < 1.0:
            raise ValueError(
                "zero test: expected zero_window >= 1 and 0 < zero_quantile < 1, got "
                f"{self.zero_window} and {self.zero_quantile}"
            )


@dataclass(frozen=True)
class DetectionEvent:
    """A fault declared (``kind="detected"``) or cleared (``kind="cleared"``)."""

    kind: str
    mode: FaultMode
    t_s: float
    probability: float

    def to_json(self) -> dict[str, object]:
        """``{"kind", "mode", "t_s", "probability"}`` (mode by name, time to 0.1 ms)."""
        return {
            "kind": self.kind,
            "mode": self.mode.name,
            "t_s": round(self.t_s, 4),
            "probability": self.probability,
        }

    @classmethod
    def from_json(cls, data: dict) -> DetectionEvent:
        """Back from :meth:`to_json`."""
        return cls(
            data["kind"], FaultMode.from_name(data["mode"]), data["t_s"], data["probability"]
        )

    def text(self) -> str:
        """STATUSTEXT wording, at most 50 characters."""
        verb = "detected" if self.kind == "detected" else "cleared"
        return f"IMM: {self.mode.description} fault {verb}, p={self.probability:.2f}"[:50]


class FaultDetector:
    """Turns a stream of mode probabilities into detection and clearing events.

    Parameters
    ----------
    modes : sequence of FaultMode
        The IMM's modes, in the order of the probability vectors; the fault-free mode may be
        among them (it is never declared).
    config : DetectorConfig
    start_s : float
        Time the estimator started (the settling period counts from it).
    """

    def __init__(self, modes: Sequence[FaultMode], config: DetectorConfig, start_s: float):
        self.modes = tuple(modes)
        self.config = config
        self.start_s = start_s
        self.declared: FaultMode | None = None
        self._above_since: dict[int, float] = {}
        self._below_since: float | None = None
        self._alive = 0  # readings of the declared channels beyond the noise since declared
        self._recent: deque[np.ndarray] = deque(maxlen=config.zero_window)
        # chi-square limits for 1 .. zero_window readings
        dof = np.arange(1, config.zero_window + 1)
        self._zero_limit = chi2.ppf(config.zero_quantile, dof)

    def reads_zero(self, mode: FaultMode) -> bool:
        """Whether every failed channel of ``mode`` read zero plus noise over the window.

        Over the readings there are when fewer than ``zero_window`` have been seen (the
        detector's first samples); True with none (the probabilities decide alone).
        """
        n = len(self._recent)
        if n == 0:
            return True
        failed = mode.healthy_mask == 0.0
        energy = np.sum(np.square(np.array(self._recent)), axis=0)
        return bool(np.all(energy[failed] <= self._zero_limit[n - 1]))

    def update(
        self,
        t_s: float,
        probabilities: np.ndarray,
        imu: np.ndarray | None = None,
        imu_sigmas: np.ndarray | None = None,
    ) -> list[DetectionEvent]:
        """Feed the probabilities at ``t_s``; returns the events this sample caused.

        ``imu`` (the six readings) and ``imu_sigmas`` (their noise sigmas) show whether a
        declared channel is alive; without them a declared fault clears on the probabilities
        alone.
        """
        cfg = self.config
        events: list[DetectionEvent] = []
        if len(self.modes) < 2:  # a single filter (UKF-1/2/3) has nothing to decide between
            return events
        if imu is not None and imu_sigmas is not None:
            n = len(imu_sigmas)
            self._recent.append(np.asarray(imu, dtype=float)[:n] / np.asarray(imu_sigmas))
        if self.declared is not None and imu is not None and imu_sigmas is not None:
            readings = np.abs(np.asarray(imu)[: len(imu_sigmas)])
            mask = self.declared.healthy_mask == 0.0
            if np.any(readings[mask] > cfg.alive_sigmas * np.asarray(imu_sigmas)[mask]):
                self._alive += 1
        for j, mode in enumerate(self.modes):
            if mode.bits == 0:
                continue
            if probabilities[j] >= cfg.threshold:
                self._above_since.setdefault(j, t_s)
            else:
                self._above_since.pop(j, None)
        alive = imu_sigmas is None or self._alive >= cfg.alive_samples
        if self.declared is not None:
            j = self.modes.index(self.declared)
            p = float(probabilities[j])
            if p < cfg.clear_threshold:
                if self._below_since is None:
                    self._below_since = t_s
                if t_s - self._below_since >= cfg.clear_dwell_s and alive:
                    events.append(DetectionEvent("cleared", self.declared, t_s, p))
                    self.declared = None
                    self._below_since = None
            else:
                self._below_since = None
        if t_s - self.start_s < cfg.settle_s:
            return events
        if self.declared is not None and not alive:
            # a declared channel that has not read beyond its noise is still dead: no other
            # single fault replaces it (a dead q gyro on a straight leg let a y mode lead)
            return events
        for j, since in sorted(self._above_since.items(), key=lambda kv: -probabilities[kv[0]]):
            mode = self.modes[j]
            if mode == self.declared or t_s - since < cfg.dwell_s or not self.reads_zero(mode):
                continue
            if self.declared is not None:
                events.append(
                    DetectionEvent(
                        "cleared",
                        self.declared,
                        t_s,
                        float(probabilities[self.modes.index(self.declared)]),
                    )
                )
            self.declared = mode
            self._below_since = None
            self._alive = 0
            events.append(DetectionEvent("detected", mode, t_s, float(probabilities[j])))
            break
        return events
