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
  chi-square quantile ``signature_quantile`` either way), or the slot has seen it fail in a way
  no offset explains: read zero or hold still where it should have moved, or read what no
  learnt offset fits (its weights of every way but the offset at least the quantile: dead,
  stuck, anything, noisy), or
  slot 0, which reads it as healthy, cannot explain it (its residuals over the window, the
  largest left out, beyond the quantile: a noise or a gain, whose learnt offset stays near
  zero). Save for the zero test, the failure must also be *sustained*: over the same window, the
  slot's log-likelihood ratio to slot 0 without its largest sample is at least
  ``ln(q / (1 - q))``, ``q = signature_quantile`` (6.9 nats: the window alone, from even odds,
  makes the mode ``q`` likely). A slot that learnt its offset is the base filter plus one
  more bias state, as good as the base, so nothing pulls its probability back; one gust the
  base's Gaussian tail prices at 5 sigma puts it near even odds, and small evidence then
  carries it over the threshold. A failing sensor keeps disagreeing with the base sample
  after sample. A spiking one disagrees a sample at a time: the slot keeps each spike out of
  its update as an outlier of the offset it learnt
  (:meth:`~immukf_sitl.estimation.fault_modes.DeadOrAnyEvidence.outlier_gate`). A spike is
  such an outlier on which the slot out-scores slot 0 by ``ln(q / (1 - q))`` in that one
  sample (a gust's 5-sigma tail costs the base about what the outlier costs the slot), or the
  sample that lifts the slot to the threshold by as much on its own (the first spike of a
  train, which no learnt offset yet calls an outlier); a *second* spike while the slot holds
  the threshold confirms the failure as the sustained test's "without its largest sample"
  does. One spike confirms itself when its sample alone puts the slot ``_REST_NATS`` ahead
  (the slow test's Markov bound, a one-sample ratio now) on the trusted channel slot 0 reads
  worst: no healthy sensor's tail gets there but by a chance the bound prices, and a step
  on another channel that some slot explains loosely leaves that channel worst.
- **Declare on a handed-over lead**: when the slots of new failures *together* hold
  ``threshold`` for ``dwell_s`` but the lead passes between them, the one whose
  log-likelihoods over the window beat slot 0's and each other slot's by ``ln(q / (1 - q))``
  stands for the dwell, its channel showing a failure as above. Two channels failing at once
  leave no slot right, and the lead flips between the slots that explain one of them each.
- **Release** channel ``c`` in ``D`` when, for ``clear_dwell_s``, slot ``D - c`` (the
  recovery) stays above ``1 - clear_threshold`` or the offset the base learnt for the channel
  stays within its uncertainty of zero while known to ``alive_sigmas`` noise sigmas (a channel
  read as healthy plus an offset of zero, and no outlier of it, is a healthy one, which the
  probabilities alone tell from the failed one only by the offset's uncertainty; not for a
  channel named noisy, whose failure is its spread and whose offset is zero throughout: it is
  released by the probabilities of the slot that reads it at its healthy noise), *and* the
  channel has shown life relative to the way it was named to fail. A failure defined by what
  the channel reads needs at least ``alive_samples`` readings more than ``alive_sigmas`` noise
  sigmas away from that (a zero: from zero; stuck: from the held value): a sensor stuck near
  the true value agrees with the other sensors for as long as the aircraft holds still, which
  is not life. A failure defined against the truth (bias, drift, gain, noise, spikes) shows
  its recovery in the probabilities and the offset above. Not named yet, nothing shows life.
  The count decays with time constant ``clear_dwell_s``: life shown long ago says little of
  the sensor now.
- **Declare slowly** channel ``c`` (while nothing is declared) when, over the GPS fixes of
  the last ``_REST_WINDOW_S``, slot ``c`` (which leaves the channel out and keeps a history
  of its own) predicts the fixes better than slot 0 by ``_REST_NATS`` beyond what the other
  slots typically gained at the same fixes, by ``ln(q / (1 - q))`` more than any other slot,
  and fits them itself (its normalised innovations squared within the chi-square quantile
  ``q``; :attr:`ImmEstimate.rest_ratios`). A slow failure (a drift) is followed by slot 0,
  whose rate and gust states move with the channel: slot ``c``'s probability stays at its
  floor, since it pays for the channel's unknown offset at every step, while the attitude and
  velocity slot 0 took from the channel show at the fixes. The fix alone: every slot but
  ``c`` reads ``c`` as slot 0 does, and on the IMU channels a jump of ``c`` favoured the slot
  that predicted ``c`` most loosely. Beyond the others (their median, when positive): a
  failed channel leaves one slot ahead alone, while a fix that most slots predict better says
  that slot 0's model erred (a turn in moderate air). The event's probability is
  ``1 - exp(-evidence)``, and the re-based bank believes the declared set (its base at 0.99).
  What the fixes declared, the fixes release: the re-based bank scores the slot that trusts
  the channel again on the GPS outputs alone (:attr:`declared_slowly`), since a slot that
  trusts a drifting channel moves its rate with it and explains its samples better than the
  base still learning its offset (it took the lead within 0.3 s and the estimate was lost).
  The fixes also arbitrate the probabilities: while the window puts a slot at ``_REST_NATS``
  ahead of the slot the probabilities lead, that one's declaration waits, and the slow test
  waits only for its own slot's lead (a drifting roll gyro and the lateral accelerometer run
  close at the fixes, and the IMU samples after a fix tipped the lead to the one behind).
- **Cannot isolate**: when slot 0 stays below ``1 - threshold`` for ``dwell_s`` while no other
  slot reaches ``threshold`` (the evidence is split between channels), an ``unisolated`` event
  names the channels in doubt, once until a declaration or until slot 0 recovers.

Nothing is declared during the first ``settle_s`` after the estimator starts.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from immukf_sitl.estimation.fault_modes import IMU_CHANNELS, N_IMU, FaultMode, bank_modes
from immukf_sitl.service.detection import DetectionEvent, DetectorConfig, SignatureWindow

#: a declared channel's (drift rate, gain) by the kind it was named (None: learnt), in the
#: states' units: a bias, a drift, a noise or spikes leave the sensor's gain alone (g = 0); a
#: gain learns its own, and a zero or a stuck reading learns -1 (it reads nothing of the
#: state). A bias, a noise and spikes do not drift; a drift named one of them is one the slow
#: test declared (a step shows in the probabilities), whose drift rate stays learnt
#: (:meth:`DeclaredSetDetector.error_holds`; docs/design)
_NAMED_ERRORS: dict[str, tuple[float | None, float | None]] = {
    "bias": (0.0, 0.0),
    "drift": (None, 0.0),
    "noise": (0.0, 0.0),
    "spikes": (0.0, 0.0),
}
#: the slow-evidence test's window: three fixes at the 1 Hz of the campaigns' GPS (a fault
#: mode's own history is about 1 s, ``history_floor / onset`` steps, so each fix is nearly
#: fresh evidence); not swept
_REST_WINDOW_S = 3.0
#: times closer than this are one instant at the window's edge (s): sample times are sums of
#: steps, off by ~1e-12 s, so a fix exactly one window old stayed in it or left it by chance
#: (four fixes at 1 Hz instead of three); far below any IMU step
_EDGE_S = 1e-3
#: the slow-evidence test's threshold: a log-likelihood ratio has mean exp of 1 when the base
#: is right, so one window passes ``h`` nats with probability at most ``exp(-h)`` (Markov's
#: inequality); over six slots tested at most at 100 Hz for 3 h, a 5 % chance of one false
#: declaration in all
_REST_NATS = math.log(6 * 100 * 3 * 3600 / 0.05)

#: spikes (outliers of a channel's learnt offset the base prices at the signature quantile's
#: odds) that declare it while its slot holds the threshold: the first may be one tail sample,
#: a second confirms (the sustained test's largest sample)
_SPIKES_TO_DECLARE = 2
#: one spike that declares on its own: a one-sample likelihood ratio passes ``h`` nats with
#: probability at most ``exp(-h)`` when the base is right (Markov's inequality, as the slow
#: test's), so six slots at 100 Hz for 3 h pass it by chance with 5 % in all
_DECISIVE_NATS = _REST_NATS


@dataclass(frozen=True)
class NamedFailure:
    """How a declared channel was named to fail, for its life test (size in its unit)."""

    kind: str | None
    size: float | None
    t_s: float


def shows_life(failure: NamedFailure, reading: float, noise_sigma: float, sigmas: float) -> bool:
    """Whether ``reading`` is more than ``sigmas`` noise sigmas from what ``failure`` reads.

    True for a failure defined against the truth (its recovery shows elsewhere), False while
    the failure is not named.
    """
    if failure.kind is None or not math.isfinite(reading):
        return False
    if failure.kind == "zero":
        return bool(abs(reading) > sigmas * noise_sigma)
    if failure.kind == "stuck":
        held = failure.size if failure.size is not None else math.nan
        return bool(abs(reading - held) > sigmas * noise_sigma)  # NaN held: no
    return True


@functools.lru_cache(maxsize=64)
def _chi2_quantile(q: float, dof: int) -> float:
    """The chi-square quantile, kept: the slow test asks it at every sample for a few dofs."""
    return float(chi2.ppf(q, dof))


def _beyond_the_others(ratios: np.ndarray) -> np.ndarray:
    """Each slot's ratio to slot 0 less what the other fault slots typically gained at once.

    A failed channel corrupts every slot that reads it, as it does slot 0, so the slot that
    leaves it out is ahead alone; a fix that most slots predict better than slot 0 says that
    slot 0's model erred (a turn in moderate air). The reference is the median of the other
    slots' ratios, when positive. Slot 0 keeps 0.
    """
    ratios = np.asarray(ratios, dtype=float)
    out = np.zeros_like(ratios)
    for j in range(1, len(ratios)):
        others = np.delete(ratios[1:], j - 1)
        out[j] = ratios[j] - max(float(np.median(others)), 0.0)
    return out


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
        config.settling()  # resolved against the filter model
        self.config = config
        self.start_s = start_s
        self._bits = 0 if declared is None else declared.bits
        self.modes = bank_modes(self.declared)
        self._since: dict[int, float] = {}  # slot -> when it crossed its level
        self._outliers: dict[int, int] = {}  # slot -> spikes on its channel since then
        self._base_low_since: float | None = None
        self._failed_since: float | None = None  # new-failure slots together at the threshold
        #: when the last declared failure took the bank's lead (None: the slow test declared it)
        self.failing_since_s: float | None = None
        self._unisolated_said = False
        self._window = SignatureWindow(config)
        self._life: dict[int, float] = {}  # declared channel -> decayed count of life
        self._failure: dict[int, NamedFailure] = {}
        self._read_scales: np.ndarray | None = None
        self._holds: dict[int, tuple[float | None, float | None]] = {}
        self._slowly: set[int] = set()  # declared channels the slow test declared
        self._zero_offset_since: dict[int, float] = {}  # declared channel -> reads healthy since
        self._consistent = float(chi2.ppf(config.signature_quantile, 1))
        q = config.signature_quantile
        self._sustained_nats = math.log(q / (1.0 - q))
        self._evidence: deque[np.ndarray] = deque(maxlen=config.signature_window)
        # (t_s, rest ratios, rest NIS, their degrees of freedom) over the slow test's window
        self._rest: deque[tuple[float, np.ndarray, np.ndarray, int]] = deque()
        for channel in range(N_IMU):
            if self._bits >> channel & 1:
                self._start_latch(channel)
        self._last_t_s: float | None = None

    @property
    def sustained_nats(self) -> float:
        """``ln(q / (1 - q))`` (``q = signature_quantile``): evidence that makes a mode likely."""
        return self._sustained_nats

    @property
    def declared(self) -> FaultMode | None:
        """The declared set (None: nothing)."""
        return FaultMode(self._bits) if self._bits else None

    @property
    def declared_slowly(self) -> FaultMode | None:
        """The declared channels the slow test declared (None: none), released on the fixes.

        Their recovery slots are scored on the GPS fix alone (:meth:`AircraftEstimator.rebased`).
        """
        bits = sum(1 << c for c in self._slowly)
        return FaultMode(bits) if bits else None

    def named(self, channel: int, kind: str, size: float | None, t_s: float) -> None:
        """How declared ``channel`` was named to fail (its life is judged against it)."""
        if self._bits >> channel & 1:
            self._failure[channel] = NamedFailure(kind, size, t_s)
            self._reread()

    def read_var_scales(self) -> np.ndarray | None:
        """``(6,)``: the variance over ``R`` a declared channel named noisy is read with.

        A channel named to fail by noise of factor ``k`` still measures its quantity, at ``k^2``
        times its noise variance: read at that variance it keeps informing the state where read
        at ``R`` it shook it (and its slot lost to any that widened the channel). 1 elsewhere;
        None when no declared channel is named noisy.
        """
        return self._read_scales

    def error_holds(self) -> dict[int, tuple[float | None, float | None]]:
        """Each named declared channel's drift rate and gain where its name knows them.

        ``{channel: (drift rate, gain)}`` (``None``: learnt) for
        :meth:`~immukf_sitl.estimation.fault_modes.ChannelOffset.holding`: a channel named a
        bias, a drift, a noise or spikes reads its rate at the sensor's own gain. Learnt, a
        declared gyro's gain took up the model's error of the rate it predicts in turbulence.
        A channel named a bias, a noise or spikes does not drift either, unless the slow test
        declared it: a failure that grew too slowly for the probabilities is a drift, whatever
        its first seconds looked like. Learnt, a biased gyro's drift rate let its offset wander
        by hundredths of a rad/s, and the base lost the attitude the gyro was read for; a noisy
        yaw gyro's, read at its noise, left the heading to the model as if the gyro were dead.
        """
        return dict(self._holds)

    def _reread(self) -> None:
        """Work out :meth:`read_var_scales` and :meth:`error_holds`: per naming or change."""
        scales = np.ones(N_IMU)
        self._holds = {}
        for channel, failure in self._failure.items():
            if failure.kind == "noise" and failure.size is not None and failure.size > 1.0:
                scales[channel] = failure.size**2
            if failure.kind in _NAMED_ERRORS:
                drift, gain = _NAMED_ERRORS[failure.kind]
                self._holds[channel] = (None if channel in self._slowly else drift, gain)
        self._read_scales = scales if (scales > 1.0).any() else None

    def _change(self, channel: int) -> None:
        """Declare or release ``channel``; the bank re-bases on the new set."""
        self._bits ^= 1 << channel
        self.modes = bank_modes(self.declared)
        self._since.clear()
        self._outliers.clear()
        self._base_low_since = None
        self._failed_since = None
        self._unisolated_said = False
        self._window.forget_residuals()
        self._evidence.clear()
        self._rest.clear()
        self._life.pop(channel, None)
        self._failure.pop(channel, None)
        self._zero_offset_since.pop(channel, None)
        self._slowly.discard(channel)
        if self._bits >> channel & 1:
            self._start_latch(channel)
        self._reread()

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
        """Decay each declared channel's life, count this reading's; note a known zero offset."""
        cfg = self.config
        dt = 0.0 if self._last_t_s is None else max(t_s - self._last_t_s, 0.0)
        decay = math.exp(-dt / cfg.clear_dwell_s) if cfg.clear_dwell_s else 0.0
        nu, var = innovations
        for channel in list(self._life):
            sigma = float(imu_sigmas[channel])
            known = var[0, channel] <= (cfg.alive_sigmas * sigma) ** 2
            # a noise is a spread, not an offset: its offset of zero says nothing of its health
            spread = self._failure[channel].kind == "noise"
            if known and not spread and nu[0, channel] ** 2 <= self._consistent * var[0, channel]:
                self._zero_offset_since.setdefault(channel, t_s)
            else:
                self._zero_offset_since.pop(channel, None)
            alive = shows_life(self._failure[channel], float(imu[channel]), sigma, cfg.alive_sigmas)
            self._life[channel] = self._life[channel] * decay + float(alive)

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
        """Feed the bank's probabilities at ``t_s`` (slot order of :attr:`modes`).

        ``imu`` and ``imu_sigmas`` feed the zero test; ``innovations`` (each slot's residuals
        of its own prediction of each channel and their variances, ``(7, 6)`` each) feed the
        inconsistency test and the life test; ``failure_weights`` ``(7, 6, w)`` (how each slot
        believes each channel failed, :data:`~.fault_modes.FAILURE_WAYS`) the seen test;
        ``log_likelihoods`` ``(7,)`` (this step's, eq. 25; None on a step without an update)
        the sustained test;
        ``outliers`` ``(7, 6)`` (the samples each slot kept out of its update as outliers of a
        channel's learnt offset) the spike test; ``rest`` (each slot's log-likelihood ratio to
        slot 0 over the GPS fix, ``(7,)``, its normalised innovation squared
        over them, ``(7,)``, and how many they are) the slow test.
        Returns the events of this sample: at most one declaration or release, after which
        :attr:`modes` is the re-based bank's.
        """
        cfg = self.config
        readings = None
        if imu is not None and imu_sigmas is not None:
            readings = np.asarray(imu, dtype=float)[:N_IMU] / np.asarray(imu_sigmas)[:N_IMU]
        residuals = None if innovations is None else innovations[0] ** 2 / innovations[1]
        self._window.push(readings, residuals)
        spike = np.zeros(N_IMU + 1, dtype=bool)  # slots whose outlier this sample is a spike
        jump = np.zeros(N_IMU + 1, dtype=bool)  # slots this one sample puts far ahead of slot 0
        decisive = np.zeros(N_IMU + 1, dtype=bool)  # ... and beyond chance on their channel
        if log_likelihoods is not None:
            ratio = np.asarray(log_likelihoods, dtype=float)
            self._evidence.append(ratio - ratio[0])
            jump = self._evidence[-1] >= self._sustained_nats
            if outliers is not None:
                spike[1:] = np.diagonal(outliers[1:]) & jump[1:]
            beyond = self._evidence[-1] >= _DECISIVE_NATS  # rare: only then the residuals
            if residuals is not None and beyond.any():
                decisive = beyond & self._worst_read(residuals[0])
        if rest is not None and rest[2] > 0:
            ratios, nis, dof = rest
            self._rest.append((t_s, _beyond_the_others(ratios), np.asarray(nis), dof))
        while self._rest and self._rest[0][0] <= t_s - _REST_WINDOW_S + _EDGE_S:
            self._rest.popleft()
        if imu is not None and imu_sigmas is not None and innovations is not None:
            self._update_life(t_s, np.asarray(imu, dtype=float), imu_sigmas, innovations)
        if outliers is not None:  # an offset of zero between spikes is not a recovery
            for channel in np.flatnonzero(outliers[0]).tolist():
                self._zero_offset_since.pop(channel, None)
        self._last_t_s = t_s
        for j in range(1, N_IMU + 1):
            channel = j - 1
            release = bool(self._bits >> channel & 1)
            level = 1.0 - cfg.clear_threshold if release else cfg.threshold
            if probabilities[j] >= level:
                # the sample that lifts a slot to the threshold on its own is its first spike
                # (no offset learnt yet to call it an outlier of)
                lifted = j not in self._since and jump[j] and not release
                self._since.setdefault(j, t_s)
                if spike[j] or lifted:
                    count = _SPIKES_TO_DECLARE if decisive[j] else 1
                    self._outliers[j] = self._outliers.get(j, 0) + count
            else:
                self._since.pop(j, None)
                self._outliers.pop(j, None)
        new = self._new_failure_slots()
        if new and float(np.sum(probabilities[new])) >= cfg.threshold:
            if self._failed_since is None:
                self._failed_since = t_s
        else:
            self._failed_since = None
        for channel in range(N_IMU):
            if not self._bits >> channel & 1:
                continue
            j = 1 + channel
            since = min(
                self._since.get(j, math.inf), self._zero_offset_since.get(channel, math.inf)
            )
            alive = imu_sigmas is None or self._life.get(channel, 0.0) >= cfg.alive_samples
            if t_s - since >= cfg.clear_dwell_s and alive:
                mode = FaultMode(1 << channel)
                self._change(channel)
                p = float(probabilities[j])
                return [DetectionEvent("cleared", mode, t_s, p, declared_after=self._after())]
        if t_s - self.start_s < cfg.settling():
            return []
        leaders = [
            j
            for j, since in sorted(self._since.items(), key=lambda kv: -probabilities[kv[0]])
            if not self._bits >> (j - 1) & 1 and t_s - since >= cfg.dwell_s
        ]
        handed = self._handed_over(t_s)
        if handed is not None and handed not in leaders:
            leaders.append(handed)
        for j in leaders:
            channel = j - 1
            if self._fixes_contradict(j):
                continue
            if self._shows_failure(j, channel, failure_weights):
                failed = self._failed_since if self._failed_since is not None else math.inf
                self.failing_since_s = min(self._since.get(j, math.inf), failed)
                mode = FaultMode(1 << channel)
                self._change(channel)
                p = float(probabilities[j])
                return [DetectionEvent("detected", mode, t_s, p, declared_after=self._after())]
        slow = self._slow_slot(probabilities)
        if slow is not None:
            j, nats = slow
            mode = FaultMode(1 << (j - 1))
            self._change(j - 1)
            self._slowly.add(j - 1)
            self.failing_since_s = None
            p = -math.expm1(-nats)  # the window passes by chance with at most exp(-nats)
            return [DetectionEvent("detected", mode, t_s, p, declared_after=self._after())]
        return self._unisolated(t_s, probabilities)

    def _worst_read(self, base_residuals: np.ndarray) -> np.ndarray:
        """The slot of the trusted channel slot 0 reads worst, as a mask (none if all declared)."""
        out = np.zeros(N_IMU + 1, dtype=bool)
        trusted = (self._bits >> np.arange(N_IMU)) & 1 == 0
        if trusted.any():
            out[1 + int(np.argmax(np.where(trusted, base_residuals, -np.inf)))] = True
        return out

    def _new_failure_slots(self) -> list[int]:
        """The slots that add a failure to the declared set (one per channel not declared)."""
        return [1 + c for c in range(N_IMU) if not self._bits >> c & 1]

    def _shows_failure(self, j: int, channel: int, failure_weights: np.ndarray | None) -> bool:
        """Whether ``channel``, its slot ``j`` in the lead, shows a failure (module docstring)."""
        failed = np.arange(N_IMU) == channel
        return (
            self._window.reads_zero(failed)
            or (
                (
                    self._window.offset_beyond(j, failed)
                    or self._seen_failing(failure_weights, j, channel)
                    or self._window.base_inconsistent(failed)
                )
                and self._sustained(j)
            )
            or self._outliers.get(j, 0) >= _SPIKES_TO_DECLARE
        )

    def _handed_over(self, t_s: float) -> int | None:
        """The slot the window's evidence picks when the lead passed between failure slots.

        While the new-failure slots together held the threshold for ``dwell_s`` (the bank is
        sure that something failed) but no one slot held it throughout: the slot whose
        log-likelihoods summed over the window beat slot 0's and every other new-failure
        slot's by ``ln(q / (1 - q))``, as a bank without transitions would weigh them. Two
        channels failing at once leave no slot of the bank right: each slot that explains one
        failure is refuted sample by sample by the other, and a slot that explains a dead
        normal accelerometer by a pitch rate of its own (the gyro it leaves out) wins samples
        from the accelerometer's. The lead then flips between them every few samples and no
        one dwell completes, though over the window the accelerometer's slot is ahead by
        hundreds of nats. None: no such slot.
        """
        if self._failed_since is None or t_s - self._failed_since < self.config.dwell_s:
            return None
        if not self._evidence:
            return None
        sums = np.sum(np.array(self._evidence), axis=0)  # each slot's over slot 0's
        rivals = [0, *self._new_failure_slots()]
        best = max(rivals[1:], key=lambda j: sums[j])
        runner_up = max(sums[j] for j in rivals if j != best)
        return best if sums[best] - runner_up >= self._sustained_nats else None

    def _slow_slot(self, probabilities: np.ndarray) -> tuple[int, float] | None:
        """The slot its evidence at the GPS fixes declares, and that evidence in nats.

        Only while nothing is declared (a re-based bank's slots have no history of their own),
        and only while that slot does not hold the threshold itself: where the probabilities
        see its failure, their tests decide once the slot has learnt its channel's offset over
        the dwell (declared at the fix that first put it in the lead, a p drift's slot was
        re-based with its offset unlearnt, the slot that trusted p again won within 0.1 s, and
        five channels followed; with only that slot left out, the runner-up was declared slowly
        in its place). Another slot's lead does not stop it: the window puts that slot behind
        this one, so its own declaration waits (:meth:`_fixes_contradict`). The module
        docstring says the rule.
        """
        if self._bits or not self._rest:
            return None
        sums = self._fix_sums()
        order = np.argsort(sums)[::-1]
        best, second = int(order[0]), int(order[1])
        if probabilities[best] >= self.config.threshold:
            return None
        if sums[best] >= _REST_NATS and sums[best] - sums[second] >= self._sustained_nats:
            return best, float(sums[best])
        return None

    def _fix_sums(self) -> np.ndarray:
        """``(7,)``: each slot's evidence over slot 0 at the window's fixes, beyond the others'.

        -inf for slot 0 and for a slot that does not fit the fixes itself (its normalised
        innovations squared beyond the chi-square quantile ``signature_quantile``).
        """
        sums = np.sum([ratios for _, ratios, _, _ in self._rest], axis=0)
        nis = np.sum([n for _, _, n, _ in self._rest], axis=0)
        dof = sum(d for _, _, _, d in self._rest)
        sums[0] = -math.inf
        # the slot must fit the fixes itself, not only less badly than slot 0
        sums[nis > _chi2_quantile(self.config.signature_quantile, dof)] = -math.inf
        return sums

    def _fixes_contradict(self, j: int) -> bool:
        """Whether the fixes' window puts another slot at the slow test's level ahead of ``j``.

        Only while nothing is declared, as the slow test. A drifting roll gyro and the lateral
        accelerometer, which reads the roll error the drift makes, run close at the fixes
        (a calm p drift of the tuning draw: 109.1 and 104.3 nats over the window, slot p
        ahead) and the IMU samples after a fix can tip the probabilities to either: slot p,
        at its probability floor until the fix, still learns its channel's offset, while
        slot y has learnt the one the roll error puts on its accelerometer (y declared, the
        estimate lost). The slot the fixes put ahead holds the wrong one's declaration; the
        next fix's window decides, or the probabilities turn.
        """
        if self._bits or not self._rest:
            return False
        sums = self._fix_sums()
        ahead = float(np.max(np.delete(sums, j)))
        return ahead >= _REST_NATS and ahead > sums[j]

    def _sustained(self, j: int) -> bool:
        """Whether slot ``j`` out-scored slot 0 over the window without its best sample.

        No log-likelihoods fed (a caller that has none): the other tests decide alone.
        """
        if not self._evidence:
            return True
        ratios = np.array(self._evidence)[:, j]
        return bool(np.sum(ratios) - np.max(ratios) >= self._sustained_nats)

    def _seen_failing(self, weights: np.ndarray | None, j: int, channel: int) -> bool:
        """Whether slot ``j`` has seen its channel fail in a way no healthy offset explains.

        Its weights of every way but the offset together at least ``signature_quantile``
        (dead and stuck move only on readings the reference predicts away from zero or from the
        held value).
        """
        if weights is None:
            return False
        return bool(1.0 - weights[j, channel, 2] >= self.config.signature_quantile)

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
