"""Fault declaration from mode probabilities: threshold, dwell, signature, clearing, settling.

The IMM is decision free (paper, section 2.D); a user needs a decision. This module holds what
the two detectors share, :class:`DetectorConfig`, :class:`DetectionEvent` and the
:class:`SignatureWindow`, and the paper bank's detector, :class:`FaultDetector`. The bank
re-based on its declarations (untrusted modes) has its own,
:class:`~immukf_sitl.service.declared_set.DeclaredSetDetector`.

:class:`FaultDetector` runs over the paper's fixed bank of zero modes (fault-free and one mode
per channel). A fault mode is declared when its probability stays at or above ``threshold`` for
``dwell_s`` *and* its failed channel reads zero plus noise over the last ``signature_window``
samples (the sum of its squared readings in noise sigmas within the chi-square quantile
``signature_quantile``). The filters' probabilities weigh a channel against the model's
prediction of it; on a real airframe in turbulence that model is wrong by more than the sensor
noise, and a zero mode that ignores the channel the model explains worst would win, whatever
the channel reads. A healthy channel whose true value sits within about a noise sigma of zero
for the whole window passes the test too: there the probabilities decide alone.

A declaration is cleared when its probability stays below ``clear_threshold`` for
``clear_dwell_s`` and the declared channel has shown life: at least ``alive_samples`` readings
more than ``alive_sigmas`` noise sigmas from zero since the declaration. A zeroed sensor reads
beyond 5 sigma once in about 1.7 million samples (4.8 h at 100 Hz), so a declaration, which
cannot be told from a healthy channel while the true value is near zero, is never cleared nor
replaced while the sensor stays dead. Nothing is declared during the first ``settle_s`` after
the estimator starts (its covariances are still converging from the initial alignment).
"""

from __future__ import annotations

import dataclasses
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
    #: None: the filter model's (:attr:`~immukf_sitl.service.filter_models.FilterModel.settle_s`)
    settle_s: float | None = None
    alive_sigmas: float = 5.0
    alive_samples: int = 3
    signature_window: int = 20
    signature_quantile: float = 0.999

    def __post_init__(self) -> None:
        if not 0.0 < self.clear_threshold <= self.threshold < 1.0:
            raise ValueError(
                "detection thresholds: expected 0 < clear_threshold <= threshold < 1, got "
                f"{self.clear_threshold} and {self.threshold}"
            )
        settle_s = 0.0 if self.settle_s is None else self.settle_s
        if min(self.dwell_s, self.clear_dwell_s, settle_s) < 0.0:
            raise ValueError("detection dwell and settle times must be >= 0")
        if self.signature_window < 1 or not 0.0 < self.signature_quantile < 1.0:
            raise ValueError(
                "signature test: expected signature_window >= 1 and 0 < signature_quantile < 1,"
                f" got {self.signature_window} and {self.signature_quantile}"
            )

    def settling(self) -> float:
        """``settle_s``, which must have been resolved (:meth:`resolved`)."""
        if self.settle_s is None:
            raise ValueError("detector settle_s: resolve it against the filter model first")
        return self.settle_s

    def resolved(self, settle_s: float) -> DetectorConfig:
        """The configuration with ``settle_s`` given where it was left to the filter model."""
        return self if self.settle_s is not None else dataclasses.replace(self, settle_s=settle_s)


#: what a named failure's size is, per kind, for the STATUSTEXT (``{unit}``: the channel's)
_SIZE_WORDING = {
    "stuck": "stuck at {size:.3g} {unit}",
    "bias": "bias {size:+.3g} {unit}",
    "drift": "drift {size:+.3g} {unit}/s",
    "scale": "gain {size:.3g}",
    "noise": "noise x{size:.3g}",
    "spikes": "spikes {size:.3g} {unit}",
}


@dataclass(frozen=True)
class DetectionEvent:
    """A fault declared (``kind="detected"``), named (``"named"``) or cleared (``"cleared"``).

    A naming carries the failure's kind and size (:mod:`immukf_sitl.service.fault_naming`).
    ``"unisolated"``: the declared set no longer explains the sensors and no single channel
    more does; ``mode`` holds the channels in doubt.
    """

    kind: str
    mode: FaultMode
    t_s: float
    probability: float
    failure: str | None = None
    size: float | None = None
    #: every channel declared once the event took effect (None: ``mode`` if detected, else none)
    declared_after: FaultMode | None = None

    def to_json(self) -> dict[str, object]:
        """``{"kind", "mode", "t_s", "probability"}``, and what the event carries besides.

        ``failure`` and ``size`` when named, ``declared_after`` when the detector holds a set.
        """
        out: dict[str, object] = {
            "kind": self.kind,
            "mode": self.mode.name,
            "t_s": round(self.t_s, 4),
            "probability": self.probability,
        }
        if self.failure is not None:
            out["failure"] = self.failure
            out["size"] = self.size
        if self.declared_after is not None:
            out["declared_after"] = self.declared_after.name
        return out

    @classmethod
    def from_json(cls, data: dict) -> DetectionEvent:
        """Back from :meth:`to_json`."""
        return cls(
            data["kind"],
            FaultMode.from_name(data["mode"]),
            data["t_s"],
            data["probability"],
            data.get("failure"),
            data.get("size"),
            None if "declared_after" not in data else FaultMode.from_name(data["declared_after"]),
        )

    def text(self) -> str:
        """STATUSTEXT wording, at most 50 characters."""
        if self.kind == "named" and self.failure is not None:
            unit = "rad/s" if set(self.mode.channels) <= {"p", "q", "r"} else "m/s2"
            what = _SIZE_WORDING.get(self.failure, "reads {kind}")
            words = what.format(size=self.size, unit=unit, kind=self.failure)
            if self.failure == "zero":
                words = "reads zero"
            return f"IMM: {self.mode.description} {words}, p={self.probability:.2f}"[:50]
        if self.kind == "unisolated":
            what = " or ".join(self.mode.channels)
            return f"IMM: cannot isolate fault: {what}, p={self.probability:.2f}"[:50]
        verb = "detected" if self.kind == "detected" else "cleared"
        return f"IMM: {self.mode.description} fault {verb}, p={self.probability:.2f}"[:50]


class SignatureWindow:
    """The last ``signature_window`` readings and residuals, and the chi-square tests on them.

    ``readings`` are the six IMU channels in noise sigmas; ``residuals`` ``(r, 6)`` each mode's
    normalised squared residual of its own prediction of each channel. Both tests hold over the
    samples there are while fewer than the window have been seen, and pass with none (the
    probabilities decide alone).
    """

    def __init__(self, config: DetectorConfig) -> None:
        self._readings: deque[np.ndarray] = deque(maxlen=config.signature_window)
        self._residuals: deque[np.ndarray] = deque(maxlen=config.signature_window)
        dof = np.arange(1, config.signature_window + 1)
        self._limit = chi2.ppf(config.signature_quantile, dof)  # for 1 .. window samples

    def push(self, readings: np.ndarray | None, residuals: np.ndarray | None) -> None:
        """One step's normalised readings and residuals (either may be missing)."""
        if readings is not None:
            self._readings.append(np.asarray(readings, dtype=float))
        if residuals is not None:
            self._residuals.append(np.asarray(residuals, dtype=float))

    def forget_residuals(self) -> None:
        """Drop the residuals (the bank's modes changed: old rows mean other modes)."""
        self._residuals.clear()

    def reads_zero(self, failed: np.ndarray) -> bool:
        """Whether every channel of the boolean mask ``failed`` read zero plus noise."""
        n = len(self._readings)
        if n == 0:
            return True
        energy = np.sum(np.square(np.array(self._readings)), axis=0)
        return bool(np.all(energy[failed] <= self._limit[n - 1]))

    def offset_beyond(self, j: int, failed: np.ndarray) -> bool:
        """Whether a channel of ``failed`` holds mode ``j``'s learnt offset beyond its uncertainty.

        The residual of a channel a mode believes failed is its learnt offset, a state, so the
        window's samples are one estimate seen twenty times, not twenty draws: their *mean*
        ``e^2 / P_ee`` is held to the quantile of a chi-square with one degree of freedom
        (10.8 at 0.999). That is exact for a constant estimate and errs towards "consistent"
        for independent ones (whose sum the twenty-degree quantile would have judged).
        """
        n = len(self._residuals)
        if n == 0:
            return True
        mean = np.mean(np.array(self._residuals)[:, j, :], axis=0)
        return bool(np.any(mean[failed] > self._limit[0]))

    def base_inconsistent(self, failed: np.ndarray) -> bool:
        """Whether mode 0, which reads the channels of ``failed`` as healthy, cannot explain them.

        The sum of mode 0's normalised squared residuals on a channel over the window, its
        largest sample left out (one gust's tail is not a failure, as for the sustained test),
        beyond the chi-square quantile of one degree fewer than the samples: a reading that
        keeps leaving the healthy prediction, whatever its mean (a noisy channel's offset stays
        zero, so :meth:`offset_beyond` never sees it). Leaving the largest of ``n`` samples out
        makes the sum stochastically smaller than a chi-square of ``n - 1`` degrees, so the
        test errs towards "consistent". False with fewer than two samples.
        """
        n = len(self._residuals)
        if n < 2:
            return False
        base = np.array(self._residuals)[:, 0, :][:, failed]
        rest = np.sum(base, axis=0) - np.max(base, axis=0)
        return bool(np.any(rest > self._limit[n - 2]))


class FaultDetector:
    """The paper bank's decision: zero modes declared, cleared and latched (module docstring).

    Parameters
    ----------
    modes : sequence of FaultMode
        The IMM's modes, in the order of the probability vectors; the fault-free mode may be
        among them (it is never declared).
    config : DetectorConfig
    start_s : float
        Time the estimator started (the settling period counts from it).
    """

    signature = "zero"

    def __init__(self, modes: Sequence[FaultMode], config: DetectorConfig, start_s: float):
        config.settling()  # resolved against the filter model
        self.modes = tuple(modes)
        self.config = config
        self.start_s = start_s
        self.declared: FaultMode | None = None
        self._above_since: dict[int, float] = {}
        self._below_since: float | None = None
        self._alive = 0  # readings of the declared channels beyond the noise since declared
        self._window = SignatureWindow(config)

    def reads_zero(self, mode: FaultMode) -> bool:
        """Whether every failed channel of ``mode`` read zero plus noise over the window."""
        return self._window.reads_zero(mode.healthy_mask == 0.0)

    def update(
        self,
        t_s: float,
        probabilities: np.ndarray,
        imu: np.ndarray | None = None,
        imu_sigmas: np.ndarray | None = None,
        innovations: tuple[np.ndarray, np.ndarray] | None = None,
        failure_weights: np.ndarray | None = None,
        log_likelihoods: np.ndarray | None = None,
        outliers: np.ndarray | None = None,
        rest: tuple[np.ndarray, np.ndarray, int] | None = None,
    ) -> list[DetectionEvent]:
        """Feed the probabilities at ``t_s``; returns the events this sample caused.

        ``imu`` (the six readings) and ``imu_sigmas`` (their noise sigmas) feed the zero test
        and show whether a declared channel is alive; without them a declared fault clears on
        the probabilities alone. ``innovations`` and ``failure_weights`` are unused (the zero
        test reads the readings themselves), as are ``log_likelihoods``, ``outliers`` and
        ``rest``; they keep one signature for both detectors.
        """
        cfg = self.config
        events: list[DetectionEvent] = []
        if len(self.modes) < 2:  # a single filter (UKF-1/2/3) has nothing to decide between
            return events
        if imu is not None and imu_sigmas is not None:
            n = len(imu_sigmas)
            self._window.push(np.asarray(imu, dtype=float)[:n] / np.asarray(imu_sigmas), None)
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
        if t_s - self.start_s < cfg.settling():
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
