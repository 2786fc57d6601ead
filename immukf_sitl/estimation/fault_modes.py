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
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from immukf_sitl.estimation.failure_kernels import (
    failure_terms,
    failure_update,
    outlier_widths,
    read_way,
)
from immukf_sitl.estimation.models import MeasurementFn, SampleGate

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


def bank_modes(declared: FaultMode | None = None) -> tuple[FaultMode, ...]:
    """The 7 modes of a bank based on the declared set ``D``: ``D``, then ``D`` xor each channel.

    Slot 0 believes what was declared; slot ``1 + i`` believes channel ``IMU_CHANNELS[i]``
    changed state: a further failure when it is not in ``D``, a recovery when it is. With
    nothing declared this is :func:`single_fault_modes`, the paper's bank.
    """
    base = 0 if declared is None else declared.bits
    return (FaultMode(base),) + tuple(FaultMode(base ^ (1 << i)) for i in range(N_IMU))


def failure_marginals(modes: Sequence[FaultMode], probabilities: np.ndarray) -> np.ndarray:
    """``(7,)``: P(no channel failed), then P(channel failed) for x, y, z, p, q, r.

    Sums of the mode probabilities over the modes that hold each: a figure whose meaning does
    not change when the bank re-bases on a declaration (for the paper's bank it is the mode
    probabilities themselves).
    """
    probabilities = np.asarray(probabilities, dtype=float)
    bits = np.array([m.bits for m in modes])
    out = np.empty(N_IMU + 1)
    out[0] = probabilities[bits == 0].sum()
    for i in range(N_IMU):
        out[1 + i] = probabilities[(bits >> i & 1) == 1].sum()
    return out


def _generate_all() -> tuple[FaultMode, ...]:
    modes = []
    for count in range(N_IMU + 1):
        for combo in itertools.combinations(IMU_CHANNELS, count):
            modes.append(FaultMode.from_channels(combo))
    return tuple(modes)


_ALL_MODES = _generate_all()


#: what a fault mode predicts on its failed channels (see the module docstring)
FAULT_SIGNATURES: tuple[str, ...] = ("untrusted", "zero")


#: variance of an offset spread evenly over the full scale, in full scales squared (``1 / 3``)
OFFSET_PRIOR_VAR = 1.0 / 3.0
#: the noise factors (standard deviations over the sensor's) a noisy channel is scored at: a
#: factor-of-two grid, so that any factor from 1.4 to 23 sits within sqrt(2) of one, where the
#: nearest costs at most 0.15 nats a sample against the true one (the Kullback-Leibler
#: divergence of two normals whose variances differ by 2)
NOISE_FACTORS: tuple[float, ...] = (2.0, 4.0, 8.0, 16.0)
#: the ways a channel fails, in the order of the failure weights: then one way per noise factor
FAILURE_WAYS: tuple[str, ...] = ("dead", "stuck", "offset", "anything") + tuple(
    f"noise x{k:g}" for k in NOISE_FACTORS
)
#: where the noise ways start among the failure weights
NOISE_WAY = 4
#: the information a reading at each noise factor carries, over the sensor's (``1 / k^2``)
_NOISE_INFORMATION = 1.0 / np.asarray(NOISE_FACTORS) ** 2
#: prior weights of how a failed channel failed: dead, stuck, offset, anything and noisy alike,
#: the noise's share spread evenly over its factors (a prior uniform in the factor's logarithm)
FAILURE_PRIOR = np.array([0.2] * NOISE_WAY + [0.2 / len(NOISE_FACTORS)] * len(NOISE_FACTORS))
#: a weight of how a channel failed never falls below this (so that it can still change)
FAILURE_WEIGHT_FLOOR = 1e-6
#: a stuck reading repeats to within this many noise sigmas (a held register: exactly)
STUCK_SIGMAS = 0.1
#: prior share of a channel's samples, read through its learnt offset, that are outliers of it
#: (a spike): the offset way is ``(1 - s) N(nu; 0, S) + s N(nu; 0, S + V)``
#: (docs/design/detection-and-tuning.md derives it)
OUTLIER_SHARE = 0.01
#: the least weight a declared channel is read with: its noise at most 1e6 R
_READ_FLOOR = 1e-6
#: the first rate gyro in IMU order (the channels before it are accelerometers)
_FIRST_GYRO = IMU_CHANNELS.index("p")
#: prior variance of a declared channel's drift rate, in full scales a second, squared: a 1-sigma
#: drift crosses the sensor's range in ten minutes (a gyro of 2000 deg/s: 0.058 rad/s a second),
#: far beyond the drifts of a failing sensor's spec sheet, so that any drift is learnt from its
#: readings and none is pulled towards zero
DRIFT_PRIOR_VAR = (1.0 / 600.0) ** 2
#: prior variance of a declared channel's gain error: 1 sigma a gain off by half
GAIN_PRIOR_VAR = 0.5**2
#: a drift rate or gain regains its prior variance over this long (s): its walk
ERROR_MODEL_MEMORY_S = 100.0


@dataclass(frozen=True)
class ChannelOffset:
    """Each failed channel of a mode reads its healthy value plus an offset, a state of its own.

    Slot ``j`` of the bank predicts a channel ``i`` it believes failed as
    ``z_i = h_i(x) + range_i e_i`` with ``e_i`` the state at ``index + i``, in full scales:
    before anything is learnt it is spread evenly over the sensor's range (variance
    :data:`OFFSET_PRIOR_VAR`, the "reads anything" of the untrusted modes), and then it is learnt
    like any state and walks by ``walk_var`` a step. So a channel that jumped to a bias costs
    its mode the price of learning the offset once, where a width that stayed that of the
    whole range (paid again every step) lost to a fault-free filter that had absorbed the jump
    into its gust states; and a declared channel is still explained by its mode as it reads, so
    that the mode that trusts it again does not win on the width alone. Slots that trust
    channel ``i`` hold ``e_i`` at its prior, so that mixing (eqs. 6-8) seeds a slot from them
    with an offset still to learn.

    A channel of the declared set (slot 0's failed channels: ``tracked``) reads more than an
    offset: ``z_i = (1 + g_i) h_i(x) + range_i e_i`` with ``e_i`` moving at a drift rate ``d_i``
    a second (full scales), ``g_i`` and ``d_i`` two states of its own after the six offsets
    (:meth:`tracked_rows`). An offset that only walks lags a drift or a gain, and the state
    followed the channel through that lag until the attitude was lost; a bias learns
    ``d = g = 0``. They are a declared channel's alone: a bank with nothing declared has none,
    so the detection is the offsets' alone. Only a gyro reads its gain: its rate passes
    through zero in every turn, where an accelerometer reads about the 1 g it feels, so that
    its gain is its bias (read, the z accelerometer's gain left its bias to the force
    correction, and a slot that trusted the biased channel again won).

    Parameters
    ----------
    modes : sequence of FaultMode
        The bank's modes.
    ranges : ndarray, shape (6,)
        Full scales of the six channels (m/s^2, rad/s).
    index : int
        Where ``e_x`` is in the state (``e_y`` ... ``e_r`` follow).
    walk_var : float
        Variance an offset gains per step (full scales squared).
    tracked : tuple of int
        Channels (IMU order) with a drift rate and a gain: the declared set.
    held : tuple of (int, float)
        State rows of tracked drift rates and gains known, and their values (:meth:`holding`):
        the offsets read the value in the state's place.
    """

    modes: tuple[FaultMode, ...]
    ranges: np.ndarray
    index: int
    walk_var: float
    tracked: tuple[int, ...] = ()
    held: tuple[tuple[int, float], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "modes", tuple(self.modes))
        object.__setattr__(self, "ranges", np.asarray(self.ranges, dtype=float))
        object.__setattr__(self, "tracked", tuple(int(c) for c in self.tracked))

    @property
    def n_states(self) -> int:
        """The offsets' states: six offsets, then a drift rate and a gain per tracked channel."""
        return N_IMU + 2 * len(self.tracked)

    def tracked_rows(self, k: int) -> tuple[int, int]:
        """State rows of the ``k``-th tracked channel's drift rate and gain."""
        row = self.index + N_IMU + 2 * k
        return row, row + 1

    def holding(self, errors: Mapping[int, tuple[float | None, float | None]]) -> ChannelOffset:
        """These offsets with tracked channels' drift rates and gains held where they are known.

        ``errors`` maps a tracked channel (IMU order) to its ``(drift rate, gain)`` in the
        states' units, ``None`` for one still learnt. A channel named to fail one way has no
        other error: a bias has neither a drift nor a gain, a gain no drift. Learnt anyway, a
        gyro's gain took up the model's own error of the rate it predicts (a noisy r gyro in
        moderate air read 0.25 +- 0.06 over 70 s, its estimate 20 % short in every turn).
        """
        held = []
        for k, channel in enumerate(self.tracked):
            for row, value in zip(
                self.tracked_rows(k), errors.get(channel, (None, None)), strict=True
            ):
                if value is not None:
                    held.append((row, float(value)))
        return replace(self, held=tuple(held))

    @cached_property
    def _tracking(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each tracked channel, its drift-rate and gain rows, and ``(k, r)``: who reads them.

        A slot reads a tracked channel's error states where it believes the channel failed.
        """
        channels = np.array(self.tracked, dtype=np.int64)
        rates = self.index + N_IMU + 2 * np.arange(len(channels), dtype=np.int64)
        reads = self.failed[channels] if len(channels) else np.zeros((0, len(self.modes)), bool)
        reads = reads & (channels >= _FIRST_GYRO)[:, None]  # an accelerometer's gain: its bias
        return channels, rates, rates + 1, reads

    @cached_property
    def failed(self) -> np.ndarray:
        """``(6, r)``: whether each slot believes each channel failed."""
        return np.array([[m.bits >> i & 1 == 1 for m in self.modes] for i in range(N_IMU)])

    @cached_property
    def gain(self) -> np.ndarray:
        """``(6, r)``: how much of its offset each channel reads in each slot (its full scale)."""
        return np.where(self.failed, self.ranges[:, None], 0.0)

    @cached_property
    def states(self) -> slice:
        """The six offsets' rows of the state."""
        return slice(self.index, self.index + N_IMU)

    def output(self, x: np.ndarray, healthy: np.ndarray | None = None) -> np.ndarray:
        """``(6, r, ...)``: what the offsets add to the IMU channels of ``x (nx, r, ...)``.

        ``healthy``: the IMU channels the state predicts, ``(6, r, ...)``, which a tracked
        channel's gain scales (needed when there are tracked channels).
        """
        e = x[self.states]
        out = self.gain.reshape(self.gain.shape + (1,) * (e.ndim - 2)) * e
        channels, _, gains, reads = self._tracking
        if len(channels):
            assert healthy is not None
            for k, c in enumerate(channels):
                read = reads[k].reshape((-1,) + (1,) * (e.ndim - 2))
                g = self._known.get(int(gains[k]))
                out[c] += read * (x[gains[k]] if g is None else g) * healthy[c]  # (1 + g) h
        return out

    def fly(self, x: np.ndarray, out: np.ndarray, dt_s: float) -> None:
        """The offsets' step from ``x (nx, ...)`` into ``out``.

        Random walks (their noise is the process noise); a tracked channel's offset moves by
        its drift rate.
        """
        rows = slice(self.index, self.index + self.n_states)
        out[rows] = x[rows]
        channels, rates, _, _ = self._tracking
        for k, c in enumerate(channels):
            d = self._known.get(int(rates[k]))
            out[self.index + c] += dt_s * (x[rates[k]] if d is None else d)

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance of the offsets' states before anything is learnt."""
        var = np.full(self.n_states, OFFSET_PRIOR_VAR)
        var[N_IMU::2] = DRIFT_PRIOR_VAR
        var[N_IMU + 1 :: 2] = GAIN_PRIOR_VAR
        return np.zeros(self.n_states), var

    def walk(self, dt_s: float) -> np.ndarray:
        """Variance each offset state gains per step of ``dt_s``.

        An offset ``walk_var``; a drift rate and a gain their prior over
        :data:`ERROR_MODEL_MEMORY_S`.
        """
        _, var = self.prior()
        var *= dt_s / ERROR_MODEL_MEMORY_S
        var[:N_IMU] = self.walk_var
        return var

    def reset(self, means: np.ndarray, covs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Copies of ``means (r, nx)``, ``covs (r, nx, nx)``: trusted channels' offsets at prior.

        A slot that trusts a tracked channel holds its drift rate and gain at their prior too;
        every slot holds a :attr:`held` one at its known value and prior variance: read as the
        value, never as the state, it learns nothing, and is learnt from there once let go.
        """
        means, covs = means.copy(), covs.copy()
        slots, rows, var = self._trusted
        means[slots, rows] = 0.0
        covs[slots, rows, :] = 0.0
        covs[slots, :, rows] = 0.0
        covs[slots, rows, rows] = var
        if self.held:
            _, prior_var = self.prior()
            for row, value in self.held:
                means[:, row] = value
                covs[:, row, :] = 0.0
                covs[:, :, row] = 0.0
                covs[:, row, row] = prior_var[row - self.index]
        return means, covs

    @cached_property
    def _known(self) -> dict[int, float]:
        """State row -> value of each :attr:`held` drift rate and gain (read in their place)."""
        return dict(self.held)

    @cached_property
    def _trusted(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Slot, state row and prior variance of every offset state a slot holds at its prior."""
        channels, slots = np.nonzero(~self.failed)
        rows = [self.index + channels]
        held = [slots]
        _, prior_var = self.prior()
        for k, c in enumerate(self.tracked):
            trusting = np.flatnonzero(~self.failed[c])
            for row in self.tracked_rows(k):
                held.append(trusting)
                rows.append(np.full(len(trusting), row))
        slot_idx, row_idx = np.concatenate(held), np.concatenate(rows)
        return slot_idx, row_idx, prior_var[row_idx - self.index]

    def gain_reading(self, means: np.ndarray, nu: np.ndarray, z: np.ndarray | None) -> np.ndarray:
        """``(r, 6)``: what each slot's gains add to its failed channels, ``g h``.

        The prediction ``h = (z - nu - range e) / (1 + g)`` is taken from the innovation ``nu``
        of the reading ``z``.
        """
        out = np.zeros(nu.shape)
        channels, _, gains, reads = self._tracking
        if z is None or not len(channels):
            return out
        for k, c in enumerate(channels):
            known = self._known.get(int(gains[k]))
            g = means[:, gains[k]] if known is None else np.full(len(means), known)
            h = (z[c] - nu[:, c] - self.ranges[c] * means[:, self.index + c]) / (1.0 + g)
            out[:, c] = np.where(reads[k], g * h, 0.0)
        return out

    def residuals(
        self,
        means: np.ndarray,
        covs: np.ndarray,
        nu: np.ndarray,
        var: np.ndarray,
        z: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``nu``, ``var (r, 6)`` with each failed channel's entry its learnt offset.

        The residual of a slot's prediction of a channel it believes failed *without* the
        offset, ``z - h = range e`` (plus a tracked channel's ``g h``, given the reading ``z``),
        and its variance: how far the channel reads from what the other sensors say, which the
        detector's tests and the naming read.
        """
        gained = self.gain_reading(means, nu, z)
        nu, var = nu.copy(), var.copy()
        i, j = np.nonzero(self.failed)
        rows = self.index + i
        nu[j, i] = self.ranges[i] * means[j, rows] + gained[j, i]
        var[j, i] = self.ranges[i] ** 2 * covs[j, rows, rows]
        return nu, var

    def naming_residuals(
        self,
        predicted_means: np.ndarray,
        nu: np.ndarray,
        var: np.ndarray,
        reference: np.ndarray,
        z: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``nu``, ``var (r, 6)``: what a failed channel's kind and size are read from.

        Each failed channel's reading against its offset-free prediction, ``z - h(x(k+1|k))``
        (a tracked channel's gain part too, given the reading ``z``), and how well a mode that
        trusts the channel predicts it (``var`` of the ``reference`` slots of
        :func:`reference_slots`, in :func:`failed_channels` order).
        """
        gained = self.gain_reading(predicted_means, nu, z)
        nu, out = nu.copy(), var.copy()
        j, i = failed_channels(self.modes)
        nu[j, i] += self.ranges[i] * predicted_means[j, self.index + i] + gained[j, i]
        out[j, i] = var[reference, i]
        return nu, out


def fault_mode_output(
    healthy_output: MeasurementFn,
    modes: Sequence[FaultMode],
    signature: str = "untrusted",
    n_extra: int = 0,
    offset: ChannelOffset | None = None,
) -> MeasurementFn:
    """Mode-batched output function ``g_j(x, u, w)`` (eq. 2 per mode).

    ``zero``: ``m_j * h(x, u) + w`` with ``m_j`` the mode's healthy mask; ``untrusted``:
    ``h(x, u) + w``, plus each failed channel's ``offset`` when given (else the failed channels
    have :func:`fault_mode_noise_var`'s width).

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
    offset : ChannelOffset, optional
        The untrusted modes' offsets on their failed channels; None: none.

    Returns
    -------
    callable
        ``g(t_s, x, u, w)`` for ``x`` of shape ``(nx, len(modes), sigma)``.
    """
    _check_signature(signature)
    if signature == "untrusted":

        def untrusted(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
            z = healthy_output(t_s, x, u, None)
            if offset is not None:
                z[:N_IMU] += offset.output(x, z[:N_IMU])
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
    full scales), 0 elsewhere; ``zero``: None (nothing added). A bank that reads its failed
    channels through a :class:`ChannelOffset` sets its widths step by step instead
    (:meth:`DeadOrAnyEvidence.widths`).
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


def reference_slots(modes: Sequence[FaultMode]) -> np.ndarray | None:
    """For every failed channel of :func:`failed_channels`, the slot that trusts that channel.

    A mode that distrusts channel ``i`` scores it against the mode that differs from it by
    trusting ``i`` alone (mode ``j`` minus ``i``); when the bank has no such mode (a bank
    re-based on a declared set holds ``D + c`` but not ``D + c - i``), the nearest mode that
    trusts ``i`` (fewest channels changed). In the paper's bank every reference is the fault-free
    mode. None when some failed channel is trusted by no mode.
    """
    bits = np.array([m.bits for m in modes])
    out = []
    for j, i in zip(*failed_channels(modes), strict=True):
        target = int(bits[j]) & ~(1 << int(i))
        trusting = np.flatnonzero((bits >> int(i) & 1) == 0)
        if trusting.size == 0:
            return None
        distance = [bin(int(bits[k]) ^ target).count("1") for k in trusting]
        out.append(int(trusting[int(np.argmin(distance))]))
    return np.array(out, dtype=np.intp)


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
    zero, mode ``j`` is scored on that channel with its reference mode's marginal likelihood
    (the mode that trusts the channel, :func:`reference_slots`; the fault-free one in the
    paper's bank): the channel says nothing for or against the fault. Once the model says the
    channel should read a value away from zero, the reading decides: zero-plus-noise (failed) or
    that value (healthy), which is what the mode probabilities then mean. The test uses the
    fault mode's own prediction, not the fault-free mode's: once a channel is dead, the
    fault-free filter fuses its zeros and predicts near zero itself, which would keep the gate
    shut.

    Parameters
    ----------
    modes : sequence of FaultMode
        The bank's modes, in batch order; every failed channel needs a mode that trusts it
        (otherwise the gate does nothing).
    channel_prediction : callable
        ``h(t_s, x, u)``: the six healthy IMU channels of states ``x`` ``(nx, r)``.
    noise_var : ndarray, shape (6,)
        ``R`` of the six IMU channels.
    n_sigma : float
        Observability threshold, in standard deviations of the reference mode's innovation.
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
    def _reference(self) -> np.ndarray | None:
        return reference_slots(self.modes)

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
        reference = self._reference
        if reference is None or not self._failed:
            return log_likelihood
        own = self.channel_prediction(t_s, np.ascontiguousarray(predicted_mean.T), u)
        out = np.array(log_likelihood, dtype=float)
        modes, channels, log_2pi_r = self._failed_arrays
        s_all = innovation_cov[reference, channels, channels]
        # observable: the reading decides (written so that a NaN prediction is not)
        observable = np.abs(own[channels, modes]) > self.n_sigma * np.sqrt(s_all)
        for f in np.flatnonzero(~observable).tolist():
            j, i = self._failed[f]
            s_healthy = float(s_all[f])
            r = self.noise_var[i]
            zero_fit = -0.5 * (z[i] * z[i] / r + log_2pi_r[f])
            nu = innovation[reference[f], i]
            healthy_fit = -0.5 * (nu * nu / s_healthy + np.log(2.0 * np.pi * s_healthy))
            out[j] += healthy_fit - zero_fit
        return out

    def prior_weights(self, r: int) -> None:
        """A zero mode's channel fails one way: no weights to carry."""
        return None

    def widths(self, weights: np.ndarray | None) -> None:
        """No widths: a zero mode's channel gives its state no feedback by its output."""
        return None

    def outlier_gate(self, weights: np.ndarray | None) -> None:
        """No gate: a zero mode's channel is never read."""
        return None

    def score(
        self,
        t_s: float,
        predicted_mean: np.ndarray,
        innovation: np.ndarray,
        innovation_cov: np.ndarray,
        z: np.ndarray,
        u: np.ndarray,
        log_likelihood: np.ndarray,
        weights: np.ndarray | None = None,
        previous_z: np.ndarray | None = None,
        widths: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[np.ndarray, None]:
        """:meth:`__call__` in the protocol the IMM calls (no weights)."""
        return self(t_s, predicted_mean, innovation, innovation_cov, z, u, log_likelihood), None


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
    channel is within ``n_sigma`` standard deviations of its reference mode's innovation of zero
    (the mode that trusts the channel, :func:`reference_slots`; the test of
    :class:`ObservabilityGate`), a dead sensor cannot be told from a healthy one; there the zero
    part is scored as the reference mode scores the channel (its marginal likelihood, weight 1:
    the zero hypothesis says nothing for or against the mode), as
    :class:`ObservabilityGate` does for the zero modes. The UKF's likelihood (eq. 25) holds the
    channel's term ``N(nu_ji; 0, S_ji)`` as a factor to within ``S / V`` (the wide channel is
    nearly uncorrelated with the others), so that factor is swapped for the mixture.

    Parameters
    ----------
    modes : sequence of FaultMode
        The bank's modes, in batch order (each failed channel trusted by some mode).
    noise_var : ndarray, shape (6,)
        ``R`` of the six IMU channels.
    width_var : ndarray, shape (len(modes), 6)
        The variance each mode adds to each channel (:func:`fault_mode_noise_var`).
    dead_weight : float
        Prior weight of "reads zero" among the ways the channel fails.
    n_sigma : float
        Observability threshold of the zero part, in sigmas of the reference mode's innovation.
    offset : ChannelOffset, optional
        The modes' offsets on their newly failed channels: the zero part tests the mode's
        prediction of the channel without its offset (what the channel should read).
    """

    modes: tuple[FaultMode, ...]
    noise_var: np.ndarray
    width_var: np.ndarray
    dead_weight: float = 0.5
    n_sigma: float = 3.0
    offset: ChannelOffset | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "modes", tuple(self.modes))
        object.__setattr__(self, "noise_var", np.asarray(self.noise_var, dtype=float))
        object.__setattr__(self, "width_var", np.asarray(self.width_var, dtype=float))
        if not 0.0 < self.dead_weight < 1.0:
            raise ValueError(f"dead_weight: expected a value in (0, 1), got {self.dead_weight}")

    @cached_property
    def _pairs(self) -> np.ndarray | None:
        """``(k, 3)``: mode, channel and reference slot of every failed pair (None: none)."""
        modes, channels = failed_channels(self.modes)
        reference = reference_slots(self.modes)
        if reference is None or modes.size == 0:
            return None
        return np.ascontiguousarray(np.column_stack([modes, channels, reference]), dtype=np.int64)

    @cached_property
    def _limits(self) -> np.ndarray:
        """``R`` of the six channels, the observability threshold and the stuck spread."""
        return np.concatenate([self.noise_var[:N_IMU], [self.n_sigma, STUCK_SIGMAS]])

    @cached_property
    def _noisy(self) -> np.ndarray:
        """``(6, m)``: ``(k^2 - 1) R`` of each channel at each of :data:`NOISE_FACTORS`."""
        factors2 = np.asarray(NOISE_FACTORS) ** 2
        return np.ascontiguousarray(np.outer(self.noise_var[:N_IMU], factors2 - 1.0))

    @cached_property
    def _spreads(self) -> np.ndarray:
        """``V = range^2 / 3`` of the six channels and the weights' floor."""
        assert self.offset is not None
        return np.concatenate([self.offset.ranges**2 / 3.0, [FAILURE_WEIGHT_FLOOR, OUTLIER_SHARE]])

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
        """The modes' log-likelihoods with each failed channel scored by the fixed mixture.

        Same arguments as :class:`ObservabilityGate`; ``u`` is unused (the mode's prediction of
        the channel is ``z - nu``, less its offset in ``predicted_mean``).
        """
        terms = self._terms(predicted_mean, innovation, innovation_cov, z)
        if terms is None:
            return log_likelihood
        pairs, t = terms
        w = self.dead_weight
        log_w_dead = np.where(t[:, 3] > 0.5, np.log(w), 0.0)  # unseen: the reference, weight 1
        mixture = np.logaddexp(log_w_dead + t[:, 1], np.log1p(-w) + t[:, 0])
        out = np.array(log_likelihood, dtype=float)
        np.add.at(out, pairs[:, 0], mixture - t[:, 0])
        return out

    def _terms(
        self,
        predicted_mean: np.ndarray | None,
        innovation: np.ndarray,
        innovation_cov: np.ndarray,
        z: np.ndarray,
        previous_z: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The pairs and their densities (:func:`~.failure_kernels.failure_terms`), or None."""
        pairs = self._pairs
        if pairs is None:
            return None
        offset_reading = np.zeros(len(pairs))
        if self.offset is not None and predicted_mean is not None:
            modes, channels = pairs[:, 0], pairs[:, 1]
            learnt = predicted_mean[modes, self.offset.index + channels]
            offset_reading = self.offset.gain[channels, modes] * learnt
        held = np.full(N_IMU, np.nan) if previous_z is None else previous_z[:N_IMU]
        runs = np.zeros(N_IMU) if held_beyond_chance is None else held_beyond_chance
        t = failure_terms(
            pairs,
            np.ascontiguousarray(innovation, dtype=float),
            np.ascontiguousarray(innovation_cov, dtype=float),
            np.ascontiguousarray(z, dtype=float),
            np.ascontiguousarray(held, dtype=float),
            offset_reading,
            self._limits,
            np.ascontiguousarray(runs, dtype=float),
        )
        return pairs, t

    def prior_weights(self, r: int) -> np.ndarray | None:
        """``(r, 6, w)``: every mode's prior weights of each way to fail (:data:`FAILURE_WAYS`).

        None without offsets (the weights are those of a channel read through its offset).
        """
        return None if self.offset is None else np.tile(FAILURE_PRIOR, (r, N_IMU, 1))

    def widths(self, weights: np.ndarray | None) -> np.ndarray | None:
        """``(r, 6)``: the variance each mode gives each failed channel in its update.

        ``(w_dead + w_stuck) V``, ``V = range^2 / 3``: a channel its mode believes dead or
        stuck says nothing of the state, one it believes offset is read through its offset.
        On a newly failed channel "anything" widens only the mode's likelihood: at the first
        step it cannot be told from an offset still to learn (both are ``N(nu; 0, S + V)``),
        and a width on it would keep the offset from being learnt. On a channel of the
        declared set (slot 0's) the offset was learnt before the declaration, so there
        "anything" is a reading the offset cannot follow (a gain, a drift): read through an
        offset that lags it, such a channel pulled the state, and the attitude was lost. There
        the channel is read with the information it has when read through its offset,
        ``(1 - w) / R`` with ``w`` the weight of dead, stuck and anything: a width
        ``R w / (1 - w)``, a weight where ``w V`` would be a switch. The update is linear in the
        channel, so it cannot follow the mixture itself; this is its reading's weight. A channel
        believed noisy at factor ``k`` is read at its noise, ``(k^2 - 1) R`` more at that way's
        weight on a newly failed channel, and with ``1 / k^2`` of the information on a declared
        one.
        """
        if weights is None or self.offset is None:
            return None
        wide = self.offset.ranges**2 / 3.0
        # the floors are not a belief: a settled offset is read at R alone (a floor of 1e-6 on
        # two ways would leave 2e-6 V, 13 gyro noise sigmas, to it)
        sharp = weights[:, :, 0] + weights[:, :, 1] - 2.0 * FAILURE_WEIGHT_FLOOR
        noisy = np.maximum(weights[:, :, NOISE_WAY:] - FAILURE_WEIGHT_FLOOR, 0.0)
        # a newly failed channel believed noisy is read as the offset way reads it (its noise
        # widens the likelihood only, as "anything" does; the gate keeps its outliers out)
        new = np.maximum(sharp, 0.0) * wide[None, :]
        # a declared channel's offset was learnt before: there "anything" is a reading it
        # cannot follow (a gain, a drift), and the channel informs the state in proportion to
        # the weight it is read through its offset with, a noisy one at 1 / k^2 of it: noise
        # R / (w_offset + sum w_k / k^2)
        unread = sharp + weights[:, :, 3] - FAILURE_WEIGHT_FLOOR
        unread = np.clip(unread, 0.0, 1.0 - _READ_FLOOR)
        read = 1.0 - unread - noisy.sum(axis=2) + noisy @ _NOISE_INFORMATION
        read = np.maximum(read, _READ_FLOOR)
        declared = self.noise_var[None, :N_IMU] * (1.0 / read - 1.0)
        doubt = np.where(self._declared[None, :], declared, new)
        return doubt * self.offset.failed.T

    @cached_property
    def _declared(self) -> np.ndarray:
        """``(6,)``: whether each channel is in the declared set, slot 0 of :func:`bank_modes`."""
        assert self.offset is not None
        return self.offset.failed[:, 0]

    def outlier_gate(self, weights: np.ndarray | None) -> SampleGate | None:
        """What each mode will not read of this sample: an outlier of a channel's learnt offset.

        A channel its mode believes offset (that way leads its weights) reads its healthy value
        plus the offset, except for an outlier now and then (:data:`OUTLIER_SHARE`). Once the
        prediction is known, a sample whose outlier part is the likelier of the two,
        ``s N(nu; 0, S + V) > (1 - s) N(nu; 0, S)`` (about 5 sigmas of ``S`` for the default
        IMU), is given the width ``V`` in this step's update: a spike then moves neither the
        offset nor the state, where read through the offset it taught the offset the spike and
        the healthy samples after it looked like a dead channel. A channel that has really
        moved is still followed: each sample beyond the gate moves the weights ``1 / s``
        towards "anything", which ends the gate within three or four samples. A channel believed
        noisy is gated alike: its update already reads it at its noise (:meth:`widths`), so ``S``
        is the noisy reading's.

        Returns the gate on the pairs whose offset or noise way leads, or None when there are
        none.
        """
        pairs = self._pairs
        if weights is None or self.offset is None or pairs is None:
            return None
        way = read_way(pairs, np.ascontiguousarray(weights, dtype=float))
        leading = (way == 2) | (way >= NOISE_WAY)
        if not leading.any():
            return None
        modes, channels = pairs[leading, 0], pairs[leading, 1]
        wide = self._spreads[channels]  # V of each channel
        # a noise way's inlier part is the reading at its noise
        factor = np.maximum(way[leading] - NOISE_WAY, 0)
        noise = np.where(way[leading] >= NOISE_WAY, self._noisy[channels, factor], 0.0)
        # the outlier part wins where nu^2 / S > 2 ln((1 - s) / s) + ln((S + V) / S), nearly
        log_odds = math.log(OUTLIER_SHARE / (1.0 - OUTLIER_SHARE))

        def widths(innovation: np.ndarray, variance: np.ndarray) -> np.ndarray:
            return outlier_widths(innovation, variance + noise, wide, log_odds)

        return SampleGate(modes, channels, widths)

    def score(
        self,
        t_s: float,
        predicted_mean: np.ndarray,
        innovation: np.ndarray,
        innovation_cov: np.ndarray,
        z: np.ndarray,
        u: np.ndarray,
        log_likelihood: np.ndarray,
        weights: np.ndarray | None = None,
        previous_z: np.ndarray | None = None,
        widths: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The modes' log-likelihoods, and each mode's weights of how each channel failed.

        A failed channel read through its offset (:class:`ChannelOffset`) failed one way, for
        good (:data:`FAILURE_WAYS`): dead, stuck, offset (a bias, learnt and then held),
        anything in the range (a drift or a gain: ``N(nu; 0, S + V)``), or noisy (the offset
        way at ``k`` times the sensor's noise, one way per factor of :data:`NOISE_FACTORS`),
        with the mode's ``weights`` ``(r, 6, 8)`` (mixed from the other modes as the states
        are, eqs. 6-8).
        Its factor is the predictive mixture ``sum_s w_s p_s(z)``, after which the weights are
        the posterior ``w_s p_s(z) / sum`` (floored at :data:`FAILURE_WEIGHT_FLOOR`): once the
        readings have shown which way the channel failed, the others cost nothing, where a
        mixture drawn anew each step would charge ``ln(1 / (1 - w))`` a step for the ways it did
        not fail. ``widths`` ``(r, 6)`` are what :meth:`widths` gave this step's update (the
        offset part's density leaves them out). A part that cannot be seen scores as the
        reference (neutral) and moves no weight (:func:`~.failure_kernels.failure_update`).
        """
        if weights is None or self.offset is None:
            return self(t_s, predicted_mean, innovation, innovation_cov, z, u, log_likelihood), None
        terms = self._terms(
            predicted_mean, innovation, innovation_cov, z, previous_z, held_beyond_chance
        )
        if terms is None:
            return log_likelihood, weights
        pairs, t = terms
        r = len(log_likelihood)
        given = np.zeros((r, N_IMU)) if widths is None else widths
        return failure_update(
            pairs,
            t,
            np.ascontiguousarray(innovation, dtype=float),
            np.ascontiguousarray(innovation_cov, dtype=float),
            np.ascontiguousarray(given, dtype=float),
            np.ascontiguousarray(weights, dtype=float),
            np.ascontiguousarray(log_likelihood, dtype=float),
            self._spreads,
            self._noisy,
        )
