"""Declaring and releasing channels one at a time over a bank re-based on what is declared.

The untrusted bank holds seven modes about the declared set ``D``
(:func:`~immukf_sitl.estimation.fault_modes.bank_modes`): slot 0 believes ``D``, slot
``1 + i`` believes that channel ``i`` changed state, a further failure when ``i`` is not in
``D``, a recovery when it is. A declaration or a release changes ``D`` by one channel, and the
service re-bases the bank on the new set (:meth:`AircraftEstimator.rebased`). So a second and a
third failure are told apart from the first ones (the paper's future work, "multiple failure
scenarios"), at most seven filters run at any time, and a declared channel never masks another
channel's failure: the mode ``D + c`` is always in the bank.

- **Declare** channel ``c`` not in ``D`` when slot ``D + c`` stays at or above ``threshold``
  for ``dwell_s`` *and* the channel shows a failure: over the :class:`SignatureWindow` it reads
  zero plus noise, or the offset the slot learnt for it is beyond its uncertainty (the
  chi-square quantile ``signature_quantile`` either way), or the slot has seen it read zero or
  hold still where it should have moved (its weights of dead and stuck at least the quantile).
- **Release** channel ``c`` in ``D`` when slot ``D - c`` (the recovery) stays above
  ``1 - clear_threshold`` for ``clear_dwell_s`` *and* the channel has shown life relative to the
  way it was named to fail: at least ``alive_samples`` readings that agree with the base
  filter's prediction of the channel (within 3 sigma) while the named failure would have read
  more than ``alive_sigmas`` sigmas of that prediction away from it (a zero: the prediction
  itself; stuck: the held value; a bias: the bias; a gain: ``(g - 1)`` times the prediction),
  so that the reading tells the two apart. A sensor stuck near the true value agrees with it
  for as long as the aircraft holds still, which is not life; where the prediction is loose (a
  gyro in turbulence) a stuck or zeroed channel is rarely released. The count decays with
  time constant ``clear_dwell_s``: life shown long ago says little of the sensor now.
- **Cannot isolate**: when slot 0 stays below ``1 - threshold`` for ``dwell_s`` while no other
  slot reaches ``threshold`` (the evidence is split between channels), an ``unisolated`` event
  names the channels in doubt, once until a declaration or until slot 0 recovers.

Nothing is declared during the first ``settle_s`` after the estimator starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation.fault_modes import IMU_CHANNELS, N_IMU, FaultMode, bank_modes
from immukf_sitl.service.detection import DetectionEvent, DetectorConfig, SignatureWindow

#: a reading within this many sigmas of the base filter's prediction agrees with it
AGREE_SIGMAS = 3.0


@dataclass(frozen=True)
class NamedFailure:
    """How a declared channel was named to fail, for its life test (size in its unit)."""

    kind: str | None
    size: float | None
    t_s: float


def failed_reading(failure: NamedFailure, prediction: float) -> float | None:
    """What a channel failed as named would read when the healthy one reads ``prediction``.

    None where the kind has no reading model (noise, spikes, drift): its life is agreement
    alone. Not named yet: NaN, no reading shows life (it is not known what to tell it from).
    """
    kind, size = failure.kind, failure.size
    if kind is None:
        return math.nan
    if kind == "zero":
        return 0.0
    if size is None or not math.isfinite(size):
        return None
    if kind == "stuck":
        return size
    if kind == "bias":
        return prediction + size
    if kind == "scale":
        return size * prediction
    return None


class DeclaredSetDetector:
    """Turns a re-based bank's probabilities into declarations and releases (module docstring).

    Parameters
    ----------
    config : DetectorConfig
    start_s : float
        Time the estimator started (the settling period counts from it).
    declared : FaultMode or None
        What is declared already (a restarted detector keeps it).
    """

    signature = "untrusted"

    def __init__(
        self, config: DetectorConfig, start_s: float, declared: FaultMode | None = None
    ) -> None:
        self.config = config
        self.start_s = start_s
        self._bits = 0 if declared is None else declared.bits
        self.modes = bank_modes(self.declared)
        self._since: dict[int, float] = {}  # slot -> when it crossed its level
        self._base_low_since: float | None = None
        self._unisolated_said = False
        self._window = SignatureWindow(config)
        self._life: dict[int, float] = {}  # declared channel -> decayed count of life
        self._failure: dict[int, NamedFailure] = {}
        for channel in range(N_IMU):
            if self._bits >> channel & 1:
                self._start_latch(channel)
        self._last_t_s: float | None = None

    @property
    def declared(self) -> FaultMode | None:
        """The declared set (None: nothing)."""
        return FaultMode(self._bits) if self._bits else None

    def named(self, channel: int, kind: str, size: float | None, t_s: float) -> None:
        """How declared ``channel`` was named to fail (its life is judged against it)."""
        if self._bits >> channel & 1:
            self._failure[channel] = NamedFailure(kind, size, t_s)

    def _change(self, channel: int) -> None:
        """Declare or release ``channel``; the bank re-bases on the new set."""
        self._bits ^= 1 << channel
        self.modes = bank_modes(self.declared)
        self._since.clear()
        self._base_low_since = None
        self._unisolated_said = False
        self._window.forget_residuals()
        self._life.pop(channel, None)
        self._failure.pop(channel, None)
        if self._bits >> channel & 1:
            self._start_latch(channel)

    def _start_latch(self, channel: int) -> None:
        """A declared channel starts with no life shown and its failure not yet named."""
        self._life[channel] = 0.0
        self._failure[channel] = NamedFailure(None, None, -math.inf)

    def _after(self) -> FaultMode:
        """The declared set as an event's ``declared_after`` (fault-free when empty)."""
        return FaultMode(self._bits)

    def _update_life(
        self,
        t_s: float,
        imu: np.ndarray,
        imu_sigmas: np.ndarray,
        innovations: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """Decay every declared channel's life and count this reading if it shows it."""
        dt = 0.0 if self._last_t_s is None else max(t_s - self._last_t_s, 0.0)
        decay = math.exp(-dt / self.config.clear_dwell_s) if self.config.clear_dwell_s else 0.0
        nu, var = innovations
        for channel in list(self._life):
            z = float(imu[channel])
            life = self._life[channel] * decay
            if math.isfinite(z):
                prediction = z - float(nu[0, channel])
                agrees = abs(nu[0, channel]) <= AGREE_SIGMAS * math.sqrt(var[0, channel])
                failed = failed_reading(self._failure[channel], prediction)
                apart = self.config.alive_sigmas * math.sqrt(var[0, channel])
                if agrees and (failed is None or abs(prediction - failed) > apart):  # NaN: no
                    life += 1.0
            self._life[channel] = life

    def update(
        self,
        t_s: float,
        probabilities: np.ndarray,
        imu: np.ndarray | None = None,
        imu_sigmas: np.ndarray | None = None,
        innovations: tuple[np.ndarray, np.ndarray] | None = None,
        failure_weights: np.ndarray | None = None,
    ) -> list[DetectionEvent]:
        """Feed the bank's probabilities at ``t_s`` (slot order of :attr:`modes`).

        ``imu`` and ``imu_sigmas`` feed the zero test; ``innovations`` (each slot's residuals
        of its own prediction of each channel and their variances, ``(7, 6)`` each) feed the
        inconsistency test and the life test; ``failure_weights`` ``(7, 6, 3)`` (how each slot
        believes each channel failed: dead, stuck, offset) the stuck test. Returns the events
        of this sample: at most one declaration or release, after which :attr:`modes` is the
        re-based bank's.
        """
        cfg = self.config
        readings = None
        if imu is not None and imu_sigmas is not None:
            readings = np.asarray(imu, dtype=float)[:N_IMU] / np.asarray(imu_sigmas)[:N_IMU]
        residuals = None if innovations is None else innovations[0] ** 2 / innovations[1]
        self._window.push(readings, residuals)
        if imu is not None and imu_sigmas is not None and innovations is not None:
            self._update_life(t_s, np.asarray(imu, dtype=float), imu_sigmas, innovations)
        self._last_t_s = t_s
        for j in range(1, N_IMU + 1):
            channel = j - 1
            release = bool(self._bits >> channel & 1)
            level = 1.0 - cfg.clear_threshold if release else cfg.threshold
            if probabilities[j] >= level:
                self._since.setdefault(j, t_s)
            else:
                self._since.pop(j, None)
        for j, since in sorted(self._since.items(), key=lambda kv: -probabilities[kv[0]]):
            channel = j - 1
            if not self._bits >> channel & 1:
                continue
            alive = imu_sigmas is None or self._life.get(channel, 0.0) >= cfg.alive_samples
            if t_s - since >= cfg.clear_dwell_s and alive:
                mode = FaultMode(1 << channel)
                self._change(channel)
                p = float(probabilities[j])
                return [DetectionEvent("cleared", mode, t_s, p, declared_after=self._after())]
        if t_s - self.start_s < cfg.settle_s:
            return []
        for j, since in sorted(self._since.items(), key=lambda kv: -probabilities[kv[0]]):
            channel = j - 1
            if self._bits >> channel & 1 or t_s - since < cfg.dwell_s:
                continue
            failed = np.arange(N_IMU) == channel
            if (
                self._window.reads_zero(failed)
                or self._window.reads_inconsistent(j, failed)
                or self._seen_dead_or_stuck(failure_weights, j, channel)
            ):
                mode = FaultMode(1 << channel)
                self._change(channel)
                p = float(probabilities[j])
                return [DetectionEvent("detected", mode, t_s, p, declared_after=self._after())]
        return self._unisolated(t_s, probabilities)

    def _seen_dead_or_stuck(self, weights: np.ndarray | None, j: int, channel: int) -> bool:
        """Whether slot ``j`` has seen its channel read zero or hold still where it should not.

        Its weights of dead and stuck together at least ``signature_quantile``: they move only
        on readings the reference predicts away from zero or from the held value.
        """
        if weights is None:
            return False
        return bool(
            weights[j, channel, 0] + weights[j, channel, 1] >= self.config.signature_quantile
        )

    def _unisolated(self, t_s: float, probabilities: np.ndarray) -> list[DetectionEvent]:
        """An ``unisolated`` event once the base mode has lost and no channel has won."""
        cfg = self.config
        doubt = 1.0 - cfg.threshold
        if probabilities[0] >= doubt or np.max(probabilities[1:]) >= cfg.threshold:
            self._base_low_since = None
            if probabilities[0] >= doubt:
                self._unisolated_said = False
            return []
        if self._base_low_since is None:
            self._base_low_since = t_s
        if self._unisolated_said or t_s - self._base_low_since < cfg.dwell_s:
            return []
        self._unisolated_said = True
        in_doubt = [IMU_CHANNELS[j - 1] for j in range(1, N_IMU + 1) if probabilities[j] >= doubt]
        if not in_doubt:
            return []
        return [
            DetectionEvent(
                "unisolated",
                FaultMode.from_channels(in_doubt),
                t_s,
                float(1.0 - probabilities[0]),
            )
        ]
