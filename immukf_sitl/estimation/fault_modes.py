"""Inertial-sensor fault modes: which of the six IMU channels have failed, and what that means.

A fault mode is a subset of the IMU channels ``x, y, z`` (accelerometers) and ``p, q, r`` (rate
gyros), stored as a 6-bit mask (bit ``i`` = channel ``IMU_CHANNELS[i]``, the same order as
HIGHRES_IMU's ``fields_updated`` bits). What the filter matched to mode ``M_j`` predicts for a
failed channel is its *signature* (:data:`FAULT_SIGNATURES`):

- ``zero``, the paper's (section 3): the failed sensor reads zero plus its noise, so the mode
  predicts ``0 + w`` there; the channel gives the state no feedback but scores the mode.
- ``untrusted``: the failed sensor may read anything within its range. The mode predicts the
  healthy value plus an error ``e ~ N(0, V)``, ``V = range^2 / 3`` (the variance of a reading
  spread evenly over +-range): a density as wide as anything the sensor can report, so a zeroed,
  stuck, biased, drifting, scaled or noisy channel all fit it, while the gain ``P_xz / (S + V)``
  leaves the state uncorrected by the channel. Both modes score the same measurement vector, so
  their likelihoods compare. Per step the untrusted mode gains
  ``log N(nu; 0, S + V) - log N(nu; 0, S) ~ nu^2 / (2 S) - ln(V / S) / 2`` nats on a channel with
  innovation ``nu`` of variance ``S``: it wins when the reading is more than ``sqrt(ln(V / S))``
  sigmas from the healthy prediction, 4.3 for a 2000 deg/s gyro of 0.0023 rad/s noise and 4.0
  for a 16 g accelerometer of 0.025 m/s^2.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from immukf_sitl.estimation.models import MeasurementFn

IMU_CHANNELS: tuple[str, ...] = ("x", "y", "z", "p", "q", "r")
CHANNEL_DESCRIPTIONS: dict[str, str] = {
    "x": "x accel",
    "y": "y accel",
    "z": "z accel",
    "p": "p gyro",
    "q": "q gyro",
    "r": "r gyro",
}
N_IMU = len(IMU_CHANNELS)


@dataclass(frozen=True, order=True)
class FaultMode:
    """A set of zeroed IMU channels.

    Parameters
    ----------
    bits : int
        Bit ``i`` set when channel ``IMU_CHANNELS[i]`` has failed (0 = fault-free, 63 = all).
    """

    bits: int

    def __post_init__(self) -> None:
        if not isinstance(self.bits, int | np.integer) or not 0 <= int(self.bits) < 2**N_IMU:
            raise ValueError(f"fault mode bits must be an integer in [0, 63], got {self.bits!r}")

    @classmethod
    def from_channels(cls, channels: Iterable[str]) -> FaultMode:
        """The mode with the given channels failed (``[]`` is fault-free)."""
        bits = 0
        for channel in channels:
            if channel not in IMU_CHANNELS:
                raise ValueError(
                    f"unknown IMU channel {channel!r}: expected one of {', '.join(IMU_CHANNELS)}"
                )
            bits |= 1 << IMU_CHANNELS.index(channel)
        return cls(bits)

    @classmethod
    def from_name(cls, name: str) -> FaultMode:
        """Parse ``"none"`` or channel names joined by ``+`` (``"q"``, ``"x+q"``)."""
        name = name.strip().lower()
        if name in ("none", ""):
            return cls(0)
        return cls.from_channels(part.strip() for part in name.split("+"))

    @cached_property
    def channels(self) -> tuple[str, ...]:
        """Failed channels in IMU order."""
        return tuple(c for i, c in enumerate(IMU_CHANNELS) if self.bits >> i & 1)

    @property
    def name(self) -> str:
        """``"none"``, ``"q"``, ``"x+q"``..."""
        return "+".join(self.channels) if self.bits else "none"

    @property
    def description(self) -> str:
        """Human label: ``"fault-free"``, ``"q gyro"``, ``"x accel + q gyro"``."""
        if not self.bits:
            return "fault-free"
        return " + ".join(CHANNEL_DESCRIPTIONS[c] for c in self.channels)

    @cached_property
    def healthy_mask(self) -> np.ndarray:
        """Shape (6,): 1.0 on working channels, 0.0 on failed ones."""
        mask = np.array([0.0 if self.bits >> i & 1 else 1.0 for i in range(N_IMU)])
        mask.setflags(write=False)
        return mask

    @property
    def paper_index(self) -> int:
        """The paper's fault index I of Table 2 (1 = none, 2-7 single, ..., 64 = all six)."""
        return all_fault_modes().index(self) + 1

    def __str__(self) -> str:
        return self.name


def all_fault_modes() -> tuple[FaultMode, ...]:
    """The 64 subsets in the paper's Table 2 order: by number of faults, then lexicographic."""
    return _ALL_MODES


def single_fault_modes() -> tuple[FaultMode, ...]:
    """The 7 modes of the paper's IMM (UKF-4): fault-free, then x, y, z, p, q, r alone."""
    return _ALL_MODES[: N_IMU + 1]


def _generate_all() -> tuple[FaultMode, ...]:
    modes = []
    for count in range(N_IMU + 1):
        for combo in itertools.combinations(IMU_CHANNELS, count):
            modes.append(FaultMode.from_channels(combo))
    return tuple(modes)


_ALL_MODES = _generate_all()


#: what a fault mode predicts on its failed channels (see the module docstring)
FAULT_SIGNATURES: tuple[str, ...] = ("untrusted", "zero")


def fault_mode_output(
    healthy_output: MeasurementFn,
    modes: Sequence[FaultMode],
    signature: str = "untrusted",
    n_extra: int = 0,
) -> MeasurementFn:
    """Mode-batched output function ``g_j(x, u, w)`` (eq. 2 per mode).

    ``zero``: ``m_j * h(x, u) + w`` with ``m_j`` the mode's healthy mask; ``untrusted``:
    ``h(x, u) + w``, the failed channels' width being :func:`fault_mode_noise_var`'s.

    Parameters
    ----------
    healthy_output : callable
        ``h(t_s, x, u, None)`` returning ``(6 + n_extra, *batch)``: the six IMU channels first,
        then ``n_extra`` channels (e.g. GPS) that no fault mode touches.
    modes : sequence of FaultMode
        One per filter of the bank, in the bank's batch order.
    signature : str
        One of :data:`FAULT_SIGNATURES`.
    n_extra : int
        Number of non-IMU output channels after the six IMU ones.

    Returns
    -------
    callable
        ``g(t_s, x, u, w)`` for ``x`` of shape ``(nx, len(modes), sigma)``.
    """
    _check_signature(signature)
    if signature == "untrusted":

        def untrusted(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
            z = healthy_output(t_s, x, u, None)
            return z if w is None else z + w

        return untrusted
    mask = np.ones((N_IMU + n_extra, len(modes), 1))
    for j, mode in enumerate(modes):
        mask[:N_IMU, j, 0] = mode.healthy_mask

    def output(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        z = healthy_output(t_s, x, u, None) * mask
        return z if w is None else z + w

    return output


def fault_mode_noise_var(
    modes: Sequence[FaultMode], signature: str, ranges: np.ndarray, n_extra: int = 0
) -> np.ndarray | None:
    """``(len(modes), 6 + n_extra)``: the variance each mode adds to each output channel.

    ``untrusted``: ``range^2 / 3`` on every failed channel (``ranges`` are the six channels'
    full scales), 0 elsewhere; ``zero``: None (nothing added).
    """
    _check_signature(signature)
    if signature == "zero":
        return None
    ranges = np.asarray(ranges, dtype=float)
    out = np.zeros((len(modes), N_IMU + n_extra))
    for j, mode in enumerate(modes):
        failed = mode.healthy_mask == 0.0
        out[j, :N_IMU][failed] = ranges[failed] ** 2 / 3.0
    return out


def _check_signature(signature: str) -> None:
    if signature not in FAULT_SIGNATURES:
        raise ValueError(
            f"fault signature: expected one of {', '.join(FAULT_SIGNATURES)}, got {signature!r}"
        )


def failed_channels(modes: Sequence[FaultMode]) -> tuple[np.ndarray, np.ndarray]:
    """Mode and channel indices of every failed channel of every mode, in mode order."""
    pairs = [(j, i) for j, m in enumerate(modes) for i in range(N_IMU) if m.bits >> i & 1]
    return (
        np.array([j for j, _ in pairs], dtype=np.intp),
        np.array([i for _, i in pairs], dtype=np.intp),
    )


def fault_free_index(modes: Sequence[FaultMode]) -> int | None:
    """Where the fault-free mode is among ``modes`` (None: not there)."""
    return next((j for j, m in enumerate(modes) if m.bits == 0), None)


#: ``h(t_s, x, u) -> (6, r)``: the healthy IMU output of ``x`` ``(nx, r)`` (one column per mode).
ChannelPrediction = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ObservabilityGate:
    """A failed channel's evidence counts only while the channel is observable.

    A mode with channel ``f`` zeroed predicts ``z_f ~ N(0, R_f)``, a sharper forecast than any
    healthy model's ``N(h_f, S_f)`` with ``S_f > R_f``. While the true channel is within the
    noise of zero (a q gyro in straight flight) the data cannot tell the two apart, yet every
    step would hand the fault mode about ``log(S_f / R_f) / 2`` nats: evidence of nothing but the
    healthy model's own uncertainty. So while mode ``j``'s *own* prediction of its failed
    channel (which that channel never corrected) is within ``n_sigma`` standard deviations of
    zero, mode ``j`` is scored on that channel with the fault-free mode's marginal likelihood:
    the channel says nothing for or against the fault. Once the model says the channel should
    read a value away from zero, the reading decides: zero-plus-noise (failed) or that value
    (healthy), which is what the mode probabilities then mean. The test uses the fault mode's
    own prediction, not the fault-free mode's: once a channel is dead, the fault-free filter
    fuses its zeros and predicts near zero itself, which would keep the gate shut.

    Parameters
    ----------
    modes : sequence of FaultMode
        The bank's modes, in batch order; needs the fault-free mode among them (otherwise the
        gate does nothing).
    channel_prediction : callable
        ``h(t_s, x, u)``: the six healthy IMU channels of states ``x`` ``(nx, r)``.
    noise_var : ndarray, shape (6,)
        ``R`` of the six IMU channels.
    n_sigma : float
        Observability threshold, in standard deviations of the fault-free mode's innovation.
    """

    modes: tuple[FaultMode, ...]
    channel_prediction: ChannelPrediction
    noise_var: np.ndarray
    n_sigma: float = 3.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "modes", tuple(self.modes))
        object.__setattr__(self, "noise_var", np.asarray(self.noise_var, dtype=float))

    @cached_property
    def _failed(self) -> list[tuple[int, int]]:
        """``(mode index, channel index)`` of every failed channel of every faulty mode."""
        return list(zip(*(a.tolist() for a in failed_channels(self.modes)), strict=True))

    @cached_property
    def _failed_arrays(self) -> tuple[np.ndarray, np.ndarray, list[float]]:
        """:attr:`_failed` as index arrays, and ``log(2 pi R_i)`` of each failed channel."""
        modes, channels = failed_channels(self.modes)
        log_2pi_r = [np.log(2.0 * np.pi * self.noise_var[i]) for _, i in self._failed]
        return modes, channels, log_2pi_r

    @cached_property
    def _healthy(self) -> int | None:
        return fault_free_index(self.modes)

    def __call__(
        self,
        t_s: float,
        predicted_mean: np.ndarray,
        innovation: np.ndarray,
        innovation_cov: np.ndarray,
        z: np.ndarray,
        u: np.ndarray,
        log_likelihood: np.ndarray,
    ) -> np.ndarray:
        """The modes' log-likelihoods with unobservable failed channels neutralised.

        Parameters
        ----------
        predicted_mean : ndarray, shape (r, nx)
            Every mode's ``x(k+1|k)``.
        innovation, innovation_cov : ndarray, shapes (r, nz), (r, nz, nz)
            The update's innovations and their covariances (IMU channels first).
        z : ndarray, shape (nz,)
            The measurement.
        u : ndarray
            The control the output model takes.
        log_likelihood : ndarray, shape (r,)
            ``log Lambda_j`` (eq. 25) as the filters computed them.
        """
        healthy = self._healthy
        if healthy is None or not self._failed:
            return log_likelihood
        own = self.channel_prediction(t_s, np.ascontiguousarray(predicted_mean.T), u)
        out = np.array(log_likelihood, dtype=float)
        modes, channels, log_2pi_r = self._failed_arrays
        s_all = innovation_cov[healthy, channels, channels]
        # observable: the reading decides (written so that a NaN prediction is not)
        observable = np.abs(own[channels, modes]) > self.n_sigma * np.sqrt(s_all)
        for f in np.flatnonzero(~observable).tolist():
            j, i = self._failed[f]
            s_healthy = float(s_all[f])
            r = self.noise_var[i]
            zero_fit = -0.5 * (z[i] * z[i] / r + log_2pi_r[f])
            nu = innovation[healthy, i]
            healthy_fit = -0.5 * (nu * nu / s_healthy + np.log(2.0 * np.pi * s_healthy))
            out[j] += healthy_fit - zero_fit
        return out


@dataclass(frozen=True)
class DeadOrAnyEvidence:
    """An untrusted mode scores its failed channel as "dead (reads zero) or reads anything".

    The commonest failure of a sensor is to read zero plus its noise, and that is the sharpest
    evidence a failure gives: a zero mode wins on it within a few samples where a mode that
    only says "anything within the range" needs the reading ``sqrt(ln(V / S))`` sigmas from a
    prediction that, in turbulence, is itself loose. So an untrusted mode's density of its
    failed channel ``i`` is the mixture

        ``p_j(z_i) = w N(z_i; 0, R_i) + (1 - w) N(nu_ji; 0, S_ji)``

    with ``S_ji`` the UKF's variance of the channel's innovation, ``V`` included (the
    "anything" part), and ``w`` = :attr:`dead_weight`. Where mode ``j``'s own prediction of the
    channel is within ``n_sigma`` standard deviations of the fault-free mode's innovation of
    zero (the test of :class:`ObservabilityGate`), a dead sensor cannot be told from a healthy
    one; there the zero part is scored as the fault-free mode scores the channel (its marginal
    likelihood, weight 1: the zero hypothesis says nothing for or against the mode), as
    :class:`ObservabilityGate` does for the zero modes. The UKF's likelihood (eq. 25) holds the
    channel's term ``N(nu_ji; 0, S_ji)`` as a factor to within ``S / V`` (the wide channel is
    nearly uncorrelated with the others), so that factor is swapped for the mixture.

    Parameters
    ----------
    modes : sequence of FaultMode
        The bank's modes, in batch order (the fault-free mode among them).
    noise_var : ndarray, shape (6,)
        ``R`` of the six IMU channels.
    width_var : ndarray, shape (len(modes), 6)
        The variance each mode adds to each channel (:func:`fault_mode_noise_var`).
    dead_weight : float
        Prior weight of "reads zero" among the ways the channel fails.
    n_sigma : float
        Observability threshold of the zero part, in sigmas of the fault-free mode's innovation.
    """

    modes: tuple[FaultMode, ...]
    noise_var: np.ndarray
    width_var: np.ndarray
    dead_weight: float = 0.5
    n_sigma: float = 3.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "modes", tuple(self.modes))
        object.__setattr__(self, "noise_var", np.asarray(self.noise_var, dtype=float))
        object.__setattr__(self, "width_var", np.asarray(self.width_var, dtype=float))
        if not 0.0 < self.dead_weight < 1.0:
            raise ValueError(f"dead_weight: expected a value in (0, 1), got {self.dead_weight}")

    @cached_property
    def _failed(self) -> tuple[np.ndarray, np.ndarray]:
        return failed_channels(self.modes)

    @cached_property
    def _healthy(self) -> int | None:
        return fault_free_index(self.modes)

    def __call__(
        self,
        t_s: float,
        predicted_mean: np.ndarray,
        innovation: np.ndarray,
        innovation_cov: np.ndarray,
        z: np.ndarray,
        u: np.ndarray,
        log_likelihood: np.ndarray,
    ) -> np.ndarray:
        """The modes' log-likelihoods with each failed channel scored by the mixture.

        Same arguments as :class:`ObservabilityGate`; ``predicted_mean`` and ``u`` are unused
        (the mode's prediction of the channel is ``z - nu``).
        """
        modes, channels = self._failed
        healthy = self._healthy
        if healthy is None or modes.size == 0:
            return log_likelihood
        nu = innovation[modes, channels]
        s_wide = innovation_cov[modes, channels, channels]
        reading = z[channels]
        own = reading - nu  # the mode's prediction of its failed channel
        r = self.noise_var[channels]
        log_any = -0.5 * (nu * nu / s_wide + np.log(2.0 * np.pi * s_wide))
        log_zero = -0.5 * (reading * reading / r + np.log(2.0 * np.pi * r))
        nu0 = innovation[healthy, channels]
        s0 = innovation_cov[healthy, channels, channels]
        log_healthy = -0.5 * (nu0 * nu0 / s0 + np.log(2.0 * np.pi * s0))
        # observable: a dead sensor differs from this prediction (a NaN prediction is not)
        observable = np.abs(own) > self.n_sigma * np.sqrt(s0)
        w = self.dead_weight
        dead = np.where(observable, np.log(w) + log_zero, log_healthy)
        mixture = np.logaddexp(dead, np.log1p(-w) + log_any)
        out = np.array(log_likelihood, dtype=float)
        np.add.at(out, modes, mixture - log_any)
        return out
