"""The filter's aircraft models as types: the paper's model and the real-air model.

A filter model is everything the aerodynamic-model bank (UKF-1, UKF-2, UKF-4) is built over and
that differs from one model to another: its states, its process noise, its tuning preset, its
Markov chain (eq. 3) and start-up odds, its sigma points, and what runs beside the filters.
:class:`FilterModel` is the configuration a user picks (``--filter-model NAME``, a frozen record
of the model's own settings); :meth:`FilterModel.build` makes it a :class:`ModelDynamics` for one
airframe and sensor spec sheet, which the bank (:mod:`immukf_sitl.service.filters`) calls at
start-up, every step and for the navigation solution. Nothing outside this module tests which
model it holds.

- :class:`PaperModel`: the paper's 12 rigid-body states in still air with exact sensors and
  airframe (section 3), white process noise on the body and angular accelerations, Julier's
  sigma points, and an asymmetric chain (onset 1e-4, recovery 0.25 per step) that starts at its
  stationary distribution.
- :class:`RealAirModel`: 18 more states (wind, force and moment corrections, rotational gusts,
  gyro biases, GPS error; :mod:`immukf_sitl.models.augmented`), noise from documented quantities
  (:mod:`immukf_sitl.service.noise_model`), scaled sigma points, the GPS error as Schmidt
  consider states, the observability gate, the turbulence learnt in flight
  (:mod:`immukf_sitl.service.turbulence`), and a sticky symmetric chain (1e-7 both ways) whose
  fault modes start at their onset probability.

A third model is one more :class:`FilterModel` subclass and its entry in :data:`FILTER_MODELS`.
"""

from __future__ import annotations

import copy
import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from immukf_sitl.estimation import (
    FAULT_SIGNATURES,
    ChannelOffset,
    DeadOrAnyEvidence,
    FaultMode,
    ImmEstimate,
    ImmEstimator,
    JulierSigmaPoints,
    Measurement,
    ObservabilityGate,
    ProcessModel,
    ScaledSigmaPoints,
    fault_mode_noise_var,
)
from immukf_sitl.estimation.fault_modes import FAILURE_PRIOR, IMU_CHANNELS, N_IMU
from immukf_sitl.estimation.symmetry import StateSymmetry
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.airframe import AirframeUncertainty
from immukf_sitl.models.augmented import (
    FORCE,
    GPS_ERROR,
    GUST,
    GYRO_BIAS,
    HEADING,
    MOMENT,
    N_RIGID,
    WIND,
    AugmentedAeroModel,
    heading_tangent,
)
from immukf_sitl.models.earth import body_to_ned
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS
from immukf_sitl.service.alignment import NavSolution
from immukf_sitl.service.noise_model import SlowStateNoise, slow_state_noise
from immukf_sitl.service.turbulence import TurbulenceAdapter, TurbulenceEstimate

__all__ = [
    "FILTER_MODELS",
    "SLOW_STATE_GROUPS",
    "FilterModel",
    "ModelDynamics",
    "PaperModel",
    "RealAirModel",
    "consider_indices",
    "filter_model",
]

#: the slow-state groups :attr:`RealAirModel.consider_states` may name
SLOW_STATE_GROUPS = {
    "wind": WIND,
    "gyro_bias": GYRO_BIAS,
    "force": FORCE,
    "moment": MOMENT,
    "gust": GUST,
    "gps_error": GPS_ERROR,
}
#: the body and angular accelerations, the rows of the rigid-body state ``v`` moves
_ACCELERATION_ROWS = (3, 4, 5, 9, 10, 11)


def consider_indices(groups: Sequence[str]) -> tuple[int, ...]:
    """State indices of the slow-state ``groups`` (names of :data:`SLOW_STATE_GROUPS`)."""
    out: list[int] = []
    for name in groups:
        if name not in SLOW_STATE_GROUPS:
            raise ValueError(
                f"consider_states: expected names of {', '.join(SLOW_STATE_GROUPS)}, got {name!r}"
            )
        part = SLOW_STATE_GROUPS[name]
        out.extend(range(N_RIGID + part.start, N_RIGID + part.stop))
    return tuple(out)


class ModelDynamics(ABC):
    """A filter model built for one airframe and sensor spec sheet: what the bank calls.

    Attributes
    ----------
    flown : AeroModel or AugmentedAeroModel
        The model the filters fly and whose IMU and GPS outputs they predict (eq. 1, 2).
    process : ProcessModel
        ``x(k+1) = f[x(k), u(k), v(k)]`` (eq. 1) with the model's noise; the control argument
        is the pair ``[u(k), u(k+1)]``: ``f`` flies the step on ``u(k)``, the output model
        predicts the IMU at ``k+1`` with ``u(k+1)``.
    """

    flown: AeroModel | AugmentedAeroModel
    process: ProcessModel
    modes: tuple[FaultMode, ...]
    sensors: SensorSpec

    #: the untrusted modes' offsets on their newly failed channels (None: zero modes)
    offset: ChannelOffset | None = None

    def with_modes(self, modes: Sequence[FaultMode]) -> ModelDynamics:
        """The same model over another bank of modes (a bank re-based on a declaration).

        Only the evidence, the offsets (each declared channel's drift rate and gain: the state
        grows by two per declared channel) and the turbulence adapter's choice of channels
        read the modes; the flown model and what was learnt are shared.
        """
        other = copy.copy(self)
        other.modes = tuple(modes)
        if self.offset is not None:
            tracked = tuple(IMU_CHANNELS.index(c) for c in other.modes[0].channels)
            offset = dataclasses.replace(self.offset, modes=other.modes, tracked=tracked, held=())
            other._use_offset(offset)
        return other

    def holding(self, errors: Mapping[int, tuple[float | None, float | None]]) -> ModelDynamics:
        """The same model with declared channels' drift rates and gains held where known.

        ``errors``: :meth:`ChannelOffset.holding`'s, from the channels' names. Returns this
        model where nothing changes.
        """
        if self.offset is None:
            return self
        offset = self.offset.holding(errors)
        if offset.held == self.offset.held:
            return self
        other = copy.copy(self)
        other._use_offset(offset)
        return other

    def _use_offset(self, offset: ChannelOffset) -> None:
        """Fly ``offset``'s states after the model's own (a copy's: the process is rebuilt)."""
        self.offset = offset
        self.process = self._padded_process(self._core_process, offset)

    def _offset_state(self, sensors: SensorSpec, model: FilterModel) -> None:
        """Append the six offsets to :attr:`process` for untrusted modes (see ChannelOffset)."""
        if model.fault_signature != "untrusted":
            return
        walk = (model.offset_walk_sigmas * sensors.imu.gyro_sigma_radps) ** 2
        walk_var = walk / sensors.imu.gyro_range_radps**2  # in full scales
        declared = tuple(IMU_CHANNELS.index(c) for c in self.modes[0].channels)
        self.offset = ChannelOffset(
            self.modes, sensors.imu.ranges, self.process.nx, walk_var, declared
        )
        self._core_process = self.process
        self.process = self._padded_process(self.process, self.offset)

    def _padded_process(self, core: ProcessModel, offset: ChannelOffset) -> ProcessModel:
        """``core`` with the offsets' states after its own (:meth:`ChannelOffset.fly`)."""
        n, k = core.nx, offset.n_states
        inner = core.f
        dt_s = self.flown.dt_s
        walk = offset.walk(dt_s)

        def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
            out = np.empty(x.shape)
            out[:n] = inner(t_s, x[:n], u, v)
            offset.fly(x, out, dt_s)  # their noise is the state noise below
            return out

        def padded(cov: np.ndarray | None) -> np.ndarray:
            out = np.zeros((n + k, n + k))
            if cov is not None:
                out[:n, :n] = cov
            out[range(n, n + k), range(n, n + k)] = walk
            return out

        return ProcessModel(
            f, n + k, core.noise_cov, padded(core.additive_noise_cov), core.angle_idx,
            padded(core.state_noise_cov), core.consider_idx, core.symmetry,
        )  # fmt: skip

    def _with_offset(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``mean``, ``cov`` of the model's states, the offsets' states appended at their prior."""
        if self.offset is None:
            return mean, cov
        n = mean.shape[0]
        prior_mean, prior_var = self.offset.prior()
        k = len(prior_var)
        full_mean = np.zeros(n + k)
        full_mean[:n] = mean
        full_mean[n:] = prior_mean
        full_cov = np.zeros((n + k, n + k))
        full_cov[:n, :n] = cov
        full_cov[range(n, n + k), range(n, n + k)] = prior_var
        return full_mean, full_cov

    def moved_states(
        self, previous: ModelDynamics, means: np.ndarray, covs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``means (r, nx)``, ``covs`` of ``previous``'s state laid out as this model's.

        Only a re-base changes the layout: a tracked channel's drift rate and gain stay with
        it, a channel newly declared gets them at their prior, a released one loses them.
        """
        mine, theirs = self.offset, previous.offset
        if mine is None or theirs is None or mine.tracked == theirs.tracked:
            return means, covs
        prior_mean, prior_var = mine.prior()
        source = list(range(mine.index + N_IMU))
        for c in mine.tracked:
            if c in theirs.tracked:
                source.extend(theirs.tracked_rows(theirs.tracked.index(c)))
            else:
                source.extend([-1, -1])
        src = np.array(source)
        kept = np.flatnonzero(src >= 0)
        r, nx = means.shape[0], len(src)
        out_means = np.zeros((r, nx))
        out_covs = np.zeros((r, nx, nx))
        out_means[:, kept] = means[:, src[kept]]
        out_covs[:, kept[:, None], kept[None, :]] = covs[:, src[kept][:, None], src[kept][None, :]]
        fresh = np.flatnonzero(src < 0)
        out_means[:, fresh] = prior_mean[fresh - mine.index]
        out_covs[:, fresh, fresh] = prior_var[fresh - mine.index]
        return out_means, out_covs

    def _idle_offsets(self, bank: ImmEstimate) -> ImmEstimate:
        """The slots that read no offset hold it at its prior (what mixing seeds others with)."""
        if self.offset is None:
            return bank
        means, covs = self.offset.reset(bank.mode_means, bank.mode_covs)
        weights = bank.failure_weights
        if weights is not None:
            weights = weights.copy()
            weights[~self.offset.failed.T] = FAILURE_PRIOR
        return dataclasses.replace(bank, mode_means=means, mode_covs=covs, failure_weights=weights)

    def history_states(self) -> slice:
        """The states a fault mode keeps its own history of: all but the channels' offsets.

        A mode's offset and its failure weights are mixed as the textbook IMM mixes them, so
        that a mode nobody believes starts its offset again from the prior: an offset learnt
        over a long history explains the airframe's model error as the channel's, which
        declared channels in fault-free flight. The offsets are the last states.
        """
        return slice(0, self.process.nx if self.offset is None else self.offset.index)

    def settled_offsets(self, bank: ImmEstimate) -> ImmEstimate:
        """``bank`` with each slot's trusted channels' offsets and weights at their prior.

        What every step ends with, and what a bank moved onto new slots needs (a re-base: a
        slot may now trust a channel whose offset its source had learnt).
        """
        return self._idle_offsets(bank)

    @abstractmethod
    def sigma_points(self, kappa: float) -> JulierSigmaPoints | ScaledSigmaPoints:
        """The sigma-point scheme (eqs. 11-12)."""

    @abstractmethod
    def gate(self) -> ObservabilityGate | DeadOrAnyEvidence | None:
        """What corrects the fault modes' evidence on their failed channels, if anything."""

    @abstractmethod
    def augmented(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A 12-state rigid-body ``mean``, ``cov`` extended to the model's state."""

    @abstractmethod
    def initial_state(self, nav: NavSolution) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of the model's state at an aligned navigation solution."""

    @abstractmethod
    def start_air(self) -> TurbulenceEstimate | None:
        """What the model knows of the air at start-up (carried from step to step)."""

    @abstractmethod
    def step(
        self,
        imm: ImmEstimator,
        previous: ImmEstimate,
        air: TurbulenceEstimate | None,
        t_next_s: float,
        controls_pair: np.ndarray,
        z: Measurement,
        previous_z: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[ImmEstimate, TurbulenceEstimate | None]:
        """One bank step (eqs. 6-28) and what the model learnt of the air from it.

        ``previous_z``: the last IMU reading before this one (a stuck channel repeats it);
        ``held_beyond_chance``: where it has repeated for longer than chance explains.
        """

    @abstractmethod
    def wind_ned_mps(self, mean: np.ndarray) -> np.ndarray | None:
        """The wind estimate in a state ``mean`` (NED, m/s), if the model has one."""

    def imu_spread_var(self, air: TurbulenceEstimate | None) -> np.ndarray | None:
        """``(6,)``: each IMU channel's variance beyond ``S`` that the modes are scored with."""
        return None


class FilterModel(ABC):
    """A filter model's configuration: its tuning preset and its Markov chain (eq. 3).

    Every model has ``process_noise_factor`` (the white process noise, in IMU noise sigmas),
    ``onset_probability`` (per step, fault-free to each fault), ``recovery_probability`` (per
    step, a fault back to fault-free), ``probability_floor`` (the IMM's floor on a mode) and
    ``fault_signature``, what a fault mode predicts on its failed channel
    (:data:`~immukf_sitl.estimation.fault_modes.FAULT_SIGNATURES`): ``zero`` (the paper's zero
    plus noise; the default) or ``untrusted`` (anything within the sensor's range, so every way
    a sensor fails fits; docs/design/detection-and-tuning.md says what it does and misses).
    An untrusted mode reads its newly failed channel through an offset state
    (:class:`~immukf_sitl.estimation.fault_modes.ChannelOffset`) that walks by
    ``offset_walk_sigmas`` gyro noise sigmas a step (0.01: a bias, held once learnt; in full
    scales, 0.41 as many of an accelerometer's). An untrusted bank's modes that add a failure
    to the declared set keep their own history where the IMM mixes their states, as if their
    probability were at least ``history_floor`` (0: the textbook mixing;
    :class:`~immukf_sitl.estimation.imm.ImmEstimator`); a recovery slot mixes as the textbook.
    """

    name: ClassVar[str]
    process_noise_factor: float
    onset_probability: float
    recovery_probability: float
    probability_floor: float
    fault_signature: str
    offset_walk_sigmas: float
    history_floor: float

    @property
    def settle_s(self) -> float:
        """Seconds after alignment before anything is declared: the alignment's transient."""
        return 3.0

    def transition(self, modes: Sequence[FaultMode]) -> np.ndarray:
        """``T[i, j] = P(M(k+1)=j | M(k)=i)`` (eq. 3) over ``modes``, the base mode first.

        The base (fault-free in the paper's bank, the declared set in a re-based one,
        :func:`~immukf_sitl.estimation.fault_modes.bank_modes`) goes to each other mode with
        the onset probability; each other mode goes back to it with the recovery probability.
        """
        r = len(modes)
        if r == 1:
            return np.ones((1, 1))
        eps, delta = self.onset_probability, self.recovery_probability
        if not (0 < eps * (r - 1) < 1 and 0 < delta + eps * (r - 2) < 1):
            raise ValueError("onset/recovery probabilities leave no mass to stay in a mode")
        matrix = np.full((r, r), eps)
        matrix[1:, 0] = delta
        np.fill_diagonal(matrix, 0.0)
        np.fill_diagonal(matrix, 1.0 - matrix.sum(axis=1))
        return matrix

    @abstractmethod
    def prior_probabilities(self, modes: Sequence[FaultMode], transition: np.ndarray) -> np.ndarray:
        """Mode probabilities the bank starts from."""

    @abstractmethod
    def build(
        self, aero: AeroModel, sensors: SensorSpec, modes: Sequence[FaultMode]
    ) -> ModelDynamics:
        """The model for the airframe ``aero`` flies, the sensors' spec sheet and the modes."""

    def _check_signature(self) -> None:
        if self.fault_signature not in FAULT_SIGNATURES:
            raise ValueError(
                f"fault modes: expected one of {', '.join(FAULT_SIGNATURES)}, got "
                f"{self.fault_signature!r}"
            )

    def _check_positive(self, **values: float) -> None:
        for name, value in values.items():
            if not value > 0.0:
                raise ValueError(f"{name}: expected > 0, got {value}")


def stationary_distribution(transition: np.ndarray) -> np.ndarray:
    """The Markov chain's stationary distribution: the left eigenvector of eigenvalue 1."""
    eigval, eigvec = np.linalg.eig(transition.T)
    stationary = np.real(eigvec[:, np.argmin(np.abs(eigval - 1.0))])
    return stationary / stationary.sum()


def _white_noise(
    sensors: SensorSpec, factor: float, rows: Sequence[int], nx: int, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """White process noise ``v`` on ``rows``: its covariance and its additive-form covariance.

    ``v`` has ``factor`` times the IMU noise (accelerometers in m/s^2, gyros read as rad/s^2);
    held over one step it moves the velocity (and rates) by ``v dt``.
    """
    sigma = (factor * sensors.imu.sigmas)[: len(rows)]
    q = np.diag(sigma**2)
    additive = np.zeros((nx, nx))
    additive[np.ix_(rows, rows)] = q * dt_s**2
    return q, additive


def _rigid_state(nav: NavSolution, euler_sigma_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 12-state mean and covariance of ``nav`` with independent sigmas.

    The state holds the velocity in body axes, ``v_b = R_bn v_n``: its uncertainty is that of
    ``v_n`` and of the attitude (a heading error turns the ground velocity into the body's y
    axis), correlated with the attitude; first order, with the derivative by central
    differences.
    """
    sigma = np.concatenate(
        [nav.position_sigma_m, nav.velocity_sigma_mps, euler_sigma_rad, nav.rates_sigma_radps]
    )
    euler = np.asarray(nav.euler_rad, dtype=float)
    v_n = np.asarray(nav.velocity_ned_mps, dtype=float)
    mean = np.concatenate([nav.position_ned_m, body_to_ned(euler).T @ v_n, euler, nav.rates_radps])
    # Jacobian of [p, v_b, euler, rates] with respect to [p, v_n, euler, rates]
    jac = np.eye(12)
    jac[3:6, 3:6] = body_to_ned(euler).T
    step = 1e-6
    for i in range(3):
        d = np.zeros(3)
        d[i] = step
        plus = body_to_ned(euler + d).T @ v_n
        minus = body_to_ned(euler - d).T @ v_n
        jac[3:6, 6 + i] = (plus - minus) / (2.0 * step)
    cov = jac @ np.diag(np.asarray(sigma, dtype=float) ** 2) @ jac.T
    return mean, 0.5 * (cov + cov.T)


# -- the paper's model ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperModel(FilterModel):
    """The paper's model: 12 rigid-body states, still air, exact sensors and airframe.

    ``process_noise_factor``: the white noise on the body and angular accelerations, 10 times the
    IMU noise. The paper uses 100 times (section 3); with that the fault-free filter predicts
    near-zero channels less sharply than a zeroed channel's prediction of exactly zero, and a
    fault mode gains likelihood in fault-free flight. The model reproduces the JSBSim aircraft
    to a relative RMS of 6e-6 in specific force (``immukf-sitl validate-model``), so 10 is safe.

    The chain is asymmetric: ``onset_probability`` 1e-4 per step to each fault,
    ``recovery_probability`` 0.25 per step back to fault-free. A recovery above the small edge an
    unobservable fault mode keeps bounds its posterior odds near ``onset / recovery``, while a
    fault that shows (a true value a few sigma from zero) wins within a few steps; the detector's
    latch (:mod:`immukf_sitl.service.detection`) makes a declaration mean "failed". The bank
    starts at the chain's stationary distribution (about 4e-4 per fault mode).
    """

    name: ClassVar[str] = "paper"
    process_noise_factor: float = 10.0
    onset_probability: float = 1e-4
    recovery_probability: float = 0.25
    probability_floor: float = 1e-6
    fault_signature: str = "zero"
    offset_walk_sigmas: float = 0.01
    history_floor: float = 0.0

    def __post_init__(self) -> None:
        self._check_positive(process_noise_factor=self.process_noise_factor)
        self._check_signature()

    def prior_probabilities(self, modes: Sequence[FaultMode], transition: np.ndarray) -> np.ndarray:
        """The chain's stationary distribution."""
        return stationary_distribution(transition)

    def build(
        self, aero: AeroModel, sensors: SensorSpec, modes: Sequence[FaultMode]
    ) -> ModelDynamics:
        """The rigid body of ``aero`` with white acceleration noise."""
        return _PaperDynamics(aero, sensors, self, tuple(modes))


def _untrusted_evidence(dynamics: ModelDynamics) -> DeadOrAnyEvidence | None:
    """The "dead or anything" scoring of a bank of untrusted modes (None: zero modes, one mode)."""
    modes, sensors = dynamics.modes, dynamics.sensors
    if dynamics.offset is None or len(modes) == 1:
        return None
    width = fault_mode_noise_var(modes, "untrusted", sensors.imu.ranges)
    noise_var = np.diagonal(sensors.imu.noise_cov())
    return DeadOrAnyEvidence(modes, noise_var, width, offset=dynamics.offset)


class _PaperDynamics(ModelDynamics):
    """The paper's model flown: the book's aircraft, nothing estimated beside the rigid body."""

    def __init__(
        self,
        aero: AeroModel,
        sensors: SensorSpec,
        model: PaperModel,
        modes: tuple[FaultMode, ...],
    ) -> None:
        self.model, self.sensors, self.modes = model, sensors, modes
        self.flown = aero
        q, additive = _white_noise(
            sensors, model.process_noise_factor, _ACCELERATION_ROWS, aero.nx, aero.dt_s
        )

        def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
            return aero.step(t_s, x, u[0], v)

        self.process = ProcessModel(
            f=f, nx=aero.nx, noise_cov=q, additive_noise_cov=additive, angle_idx=aero.angle_indices
        )
        self._offset_state(sensors, model)

    def sigma_points(self, kappa: float) -> JulierSigmaPoints:
        """Julier's points (the paper's unscented transform, eqs. 11-12)."""
        return JulierSigmaPoints(kappa)

    def gate(self) -> DeadOrAnyEvidence | None:
        """None for zero modes (as in the paper); "dead or anything" for untrusted ones."""
        return _untrusted_evidence(self)

    def augmented(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rigid-body state is the whole model state (untrusted modes: and the offset)."""
        return self._with_offset(np.array(mean, dtype=float), np.array(cov, dtype=float))

    def initial_state(self, nav: NavSolution) -> tuple[np.ndarray, np.ndarray]:
        """The aligned solution with its own sigmas."""
        mean, cov = _rigid_state(nav, np.array(nav.euler_sigma_rad, dtype=float))
        return self.augmented(mean, cov)

    def start_air(self) -> None:
        """Still air: nothing to learn."""
        return None

    def step(
        self,
        imm: ImmEstimator,
        previous: ImmEstimate,
        air: TurbulenceEstimate | None,
        t_next_s: float,
        controls_pair: np.ndarray,
        z: Measurement,
        previous_z: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[ImmEstimate, None]:
        """The bank's step."""
        bank = imm.step(
            previous, t_next_s, controls_pair, z, previous_z=previous_z,
            held_beyond_chance=held_beyond_chance,
        )  # fmt: skip
        return self._idle_offsets(bank), None

    def wind_ned_mps(self, mean: np.ndarray) -> None:
        """No wind state."""
        return None


# -- the real-air model --------------------------------------------------------------------------


@dataclass(frozen=True)
class RealAirModel(FilterModel):
    """The model of a real airframe in real air: 30 states, noise from documented quantities.

    The design air (``design_turbulence`` moderate, ``design_height_m`` 150 m,
    ``design_airspeed_mps`` 25 m/s) is by default the roughest MIL-F-8785C air it is meant to hold
    in; with ``adaptive_turbulence`` the wind and gust states' driving noise is scaled in flight to
    the air the innovations show, between ``turbulence_floor`` (0.1) times the design's and
    ``roughest_turbulence``'s (by W20; None, the default: the design's; severe's 1.5 was flown on
    the tuning draw and not taken, docs/design/real-air-model.md), from ``turbulence_averaging_s``
    (10 s) averages. With ``score_unexplained`` and the untrusted modes,
    each IMU channel's and each GPS channel's variance beyond ``S`` over the last minute (the
    base's innovations, a declared channel's forgotten at its declaration) is added to ``S``
    where the modes are scored, not in the gain. ``model_uncertainty`` (10 % aero, 5 % mass,
    10 % inertia, 1-sigma relative) sizes the force and moment corrections, whose part that changes
    with the flight condition is a random walk over ``correction_time_constant_s`` (10 s).
    ``initial_wind_sigma_mps`` (10 m/s): nothing much is known of the wind at start-up.

    ``sigma_point_alpha`` 0.01 draws van der Merwe's scaled points: Julier's sit at
    ``sqrt(n_a)`` sigma, 6 sigma for 33 augmented dimensions, which with the initial wind sigma
    probes 60 m/s of wind, where the aerodynamics are nothing like the aircraft's.
    ``consider_states`` (the GPS error) are Schmidt consider states: the receiver's error and the
    position are told apart only by the dynamics, so an estimated error would absorb every
    vertical model error. ``observability_sigmas`` (3): a fault mode scores its failed channel
    only while the model predicts it that many noise sigmas from zero.

    The chain is sticky and symmetric (1e-7 both ways), so a mode's odds move only with
    evidence; every fault mode starts at ``initial_fault_probability`` (its onset probability):
    the chain's stationary distribution would be 1/7 per mode, a 6-in-7 belief that some sensor
    is dead at power-on.

    An untrusted bank's modes that add a failure keep their own history (``history_floor``
    1e-5), in a bank re-based on a declared set too: each takes 1 % of its start from the base
    a step, so it is a filter that has not read its channel for about a second, and a failure
    that grows too slowly for the base to notice (a drift, which the base's bias and gust states
    follow) shows against it, mostly at the GPS fixes. Their offsets walk by
    ``offset_walk_sigmas`` 0.001 gyro sigmas a step (a mode with a history of its own fits less
    of the airframe's model error as the channel's offset).
    """

    name: ClassVar[str] = "real-air"
    process_noise_factor: float = 10.0
    onset_probability: float = 1e-7
    recovery_probability: float = 1e-7
    probability_floor: float = 1e-9
    initial_fault_probability: float = 1e-7
    design_turbulence: str = "moderate"
    design_height_m: float = 150.0
    design_airspeed_mps: float = 25.0
    model_uncertainty: AirframeUncertainty = field(
        default_factory=lambda: AirframeUncertainty(aero=0.10, mass=0.05, inertia=0.10)
    )
    correction_time_constant_s: float = 10.0
    initial_wind_sigma_mps: float = 10.0
    observability_sigmas: float = 3.0
    sigma_point_alpha: float = 0.01
    consider_states: tuple[str, ...] = ("gps_error",)
    adaptive_turbulence: bool = True
    turbulence_floor: float = 0.1
    roughest_turbulence: str | None = None
    turbulence_averaging_s: float = 10.0
    score_unexplained: bool = True
    fault_signature: str = "zero"
    offset_walk_sigmas: float = 0.001
    history_floor: float = 1e-5

    @property
    def turbulence_ceiling(self) -> float:
        """The largest turbulence scale: the roughest air's W20 over the design air's."""
        design = TURBULENCE_LEVELS[self.design_turbulence].w20_mps
        if self.roughest_turbulence is None or not design:
            return 1.0
        return TURBULENCE_LEVELS[self.roughest_turbulence].w20_mps / design

    @property
    def settle_s(self) -> float:
        """One ``correction_time_constant_s`` after alignment before anything is declared.

        Until the airframe's model error is learnt, a mode that leaves a channel out explains
        that error as the channel's offset.
        """
        return self.correction_time_constant_s

    def __post_init__(self) -> None:
        self._check_signature()
        levels = ", ".join(TURBULENCE_LEVELS)
        if self.design_turbulence not in TURBULENCE_LEVELS:
            raise ValueError(
                f"design_turbulence: expected one of {levels}, got {self.design_turbulence!r}"
            )
        roughest = self.roughest_turbulence  # None: the design air
        if roughest is not None:
            if roughest not in TURBULENCE_LEVELS:
                raise ValueError(f"roughest_turbulence: expected one of {levels}, got {roughest!r}")
            if roughest != "none" and not TURBULENCE_LEVELS[self.design_turbulence].w20_mps:
                raise ValueError(
                    "roughest_turbulence: a design for still air has no turbulence to scale, "
                    f"got {roughest!r}"
                )
            if self.turbulence_ceiling < 1.0:
                raise ValueError(
                    f"roughest_turbulence: expected at least the design's "
                    f"({self.design_turbulence}), got {roughest!r}"
                )
        self._check_positive(
            process_noise_factor=self.process_noise_factor,
            design_airspeed_mps=self.design_airspeed_mps,
            correction_time_constant_s=self.correction_time_constant_s,
            initial_wind_sigma_mps=self.initial_wind_sigma_mps,
            turbulence_averaging_s=self.turbulence_averaging_s,
            sigma_point_alpha=self.sigma_point_alpha,
        )
        p0 = self.initial_fault_probability
        if not 0.0 < p0 < 0.1:
            raise ValueError(f"initial_fault_probability: expected in (0, 0.1), got {p0}")
        if not 0.0 < self.turbulence_floor <= 1.0:
            raise ValueError(f"turbulence_floor: expected in (0, 1], got {self.turbulence_floor}")
        consider_indices(self.consider_states)

    def prior_probabilities(self, modes: Sequence[FaultMode], transition: np.ndarray) -> np.ndarray:
        """Every mode but the base (fault-free, or the declared set) at its onset probability."""
        if len(modes) == 1:
            return stationary_distribution(transition)
        probs = np.full(len(modes), self.initial_fault_probability)
        probs[0] = 1.0
        return probs / probs.sum()

    def build(
        self, aero: AeroModel, sensors: SensorSpec, modes: Sequence[FaultMode]
    ) -> ModelDynamics:
        """``aero`` with the 18 slow states, their noise from the design air and spec sheet."""
        return _RealAirDynamics(aero, sensors, self, tuple(modes))


class _RealAirDynamics(ModelDynamics):
    """The real-air model flown: the 30-state model, its gate and its turbulence adapter."""

    def _use_offset(self, offset: ChannelOffset) -> None:
        """:meth:`ModelDynamics._use_offset`, the turbulence adapter scaling the new process."""
        super()._use_offset(offset)
        if self.adapter is not None:
            self.adapter = dataclasses.replace(self.adapter, process=self.process)

    def __init__(
        self,
        aero: AeroModel,
        sensors: SensorSpec,
        model: RealAirModel,
        modes: tuple[FaultMode, ...],
    ) -> None:
        self.model, self.sensors, self.modes = model, sensors, modes
        self.noise: SlowStateNoise = slow_state_noise(aero.params, sensors, model)
        flown = AugmentedAeroModel(aero, self.noise.decay_per_s)
        self.flown = flown
        dt, nx = flown.dt_s, flown.nx
        # v on the body accelerations only: the angular accelerations' fast part is the
        # rotational gusts', carried as states (a white residue would cost 6 sigma points a mode)
        q, additive = _white_noise(sensors, model.process_noise_factor, (3, 4, 5), nx, dt)
        q_slow = self.noise.step_variance(dt)
        additive[N_RIGID:, N_RIGID:] = np.diag(q_slow)  # referred to the step's end
        at_start = np.zeros((nx, nx))  # the same noise before the step's decay
        at_start[N_RIGID:, N_RIGID:] = np.diag(q_slow * np.exp(2.0 * self.noise.decay_per_s * dt))

        def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
            if v is not None:  # the body accelerations only: zero on the angular ones
                full = np.zeros((6,) + v.shape[1:])
                full[:3] = v
                v = full
            return flown.step(t_s, x, u[0], v)

        self.process = ProcessModel(
            f=f,
            nx=nx,
            noise_cov=q,
            additive_noise_cov=additive,
            angle_idx=flown.angle_indices,
            state_noise_cov=at_start,
            consider_idx=consider_indices(model.consider_states),
            # heading and wind are seen together until a turn (estimation.symmetry)
            symmetry=StateSymmetry(HEADING, heading_tangent),
        )
        self._offset_state(sensors, model)
        self.adapter: TurbulenceAdapter | None = None
        if model.adaptive_turbulence:
            turbulent = np.flatnonzero(self.noise.turbulence_share > 0.0)
            self.adapter = TurbulenceAdapter(
                self.process, N_RIGID + turbulent, np.diagonal(sensors.imu.noise_cov()), dt,
                model.turbulence_averaging_s, floor=model.turbulence_floor,
                ceiling=model.turbulence_ceiling,
                turbulence_share=self.noise.turbulence_share[turbulent],
            )  # fmt: skip

    def sigma_points(self, kappa: float) -> ScaledSigmaPoints:
        """Van der Merwe's scaled points at ``alpha`` (beta 2, the Gaussian optimum)."""
        return ScaledSigmaPoints(self.model.sigma_point_alpha, 2.0, kappa)

    def gate(self) -> ObservabilityGate | DeadOrAnyEvidence | None:
        """What a bank's fault modes score their failed channels with.

        Zero modes: a failed channel scores only while predicted clear of zero. Untrusted
        modes: "dead or anything" (:class:`DeadOrAnyEvidence`).
        """
        modes = self.modes
        if self.model.fault_signature == "untrusted":
            return _untrusted_evidence(self)
        if len(modes) == 1:
            return None
        flown = self.flown

        def own_imu(t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
            return flown.imu(t_s, x, u[1])  # u is the pair [u(k), u(k+1)]

        noise_var = np.diagonal(self.sensors.imu.noise_cov())
        return ObservabilityGate(modes, own_imu, noise_var, self.model.observability_sigmas)

    def augmented(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The slow states appended at zero mean with their initial sigmas."""
        nx = self.flown.nx
        full_mean = np.zeros(nx)
        full_mean[:N_RIGID] = mean
        full_cov = np.zeros((nx, nx))
        full_cov[:N_RIGID, :N_RIGID] = cov
        full_cov[N_RIGID:, N_RIGID:] = np.diag(self.noise.initial_sigma**2)
        return self._with_offset(full_mean, full_cov)

    def initial_state(self, nav: NavSolution) -> tuple[np.ndarray, np.ndarray]:
        """The aligned solution, its heading off by an unknown wind's crab, and the slow states.

        The GPS error is what separates the fix ``nav`` took its position from and the true
        position, so the two start fully anti-correlated.
        """
        euler_sigma = np.array(nav.euler_sigma_rad, dtype=float)
        speed = max(float(np.linalg.norm(nav.velocity_ned_mps[:2])), 1.0)
        crab = np.arctan2(self.noise.initial_sigma[WIND.start], speed)  # heading = course
        euler_sigma[2] = np.hypot(euler_sigma[2], crab)
        mean, cov = self.augmented(*_rigid_state(nav, euler_sigma))
        errors = np.arange(N_RIGID + GPS_ERROR.start, N_RIGID + GPS_ERROR.stop)
        gps_var = np.diagonal(cov)[errors]
        cov[[0, 1, 2], [0, 1, 2]] += gps_var  # the fix is the true position plus its error
        cov[[0, 1, 2], errors] = -gps_var
        cov[errors, [0, 1, 2]] = -gps_var
        return mean, cov

    def start_air(self) -> TurbulenceEstimate | None:
        """The design air, until the innovations say otherwise (None: not adapted)."""
        return None if self.adapter is None else TurbulenceEstimate()

    def step(
        self,
        imm: ImmEstimator,
        previous: ImmEstimate,
        air: TurbulenceEstimate | None,
        t_next_s: float,
        controls_pair: np.ndarray,
        z: Measurement,
        previous_z: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> tuple[ImmEstimate, TurbulenceEstimate | None]:
        """The bank's step at the air's scale, then the scale learnt from its innovations."""
        adapter = self.adapter
        if adapter is None or air is None:
            bank = imm.step(
                previous, t_next_s, controls_pair, z, previous_z=previous_z,
                held_beyond_chance=held_beyond_chance,
            )  # fmt: skip
            return self._idle_offsets(bank), air
        process = adapter.process_at(air.scale)
        score_var = self.imu_spread_var(air)
        if score_var is not None:
            n_gps = 0 if z is None else z.model.nz - N_IMU
            if n_gps > 0:  # a fix: its channels against the spread the base's fixes show
                score_var = np.concatenate([score_var, air.gps_unexplained_var(n_gps)])
        bank = imm.step(
            previous, t_next_s, controls_pair, z, process, previous_z, score_var,
            held_beyond_chance,
        )  # fmt: skip
        bank = self._idle_offsets(bank)
        if bank.updated and bank.innovations is not None and bank.innovation_var is not None:
            if bank.innovations.shape[1] > N_IMU:
                air = adapter.update_gps(
                    air, t_next_s, bank.innovations[0, N_IMU:], bank.innovation_var[0, N_IMU:]
                )
            lead = bank.most_likely_mode
            base = (bank.innovations[0, :6], bank.innovation_var[0, :6], self.modes[0].healthy_mask)
            air = adapter.update(
                air, bank.innovations[lead, :6], bank.innovation_var[lead, :6],
                self.modes[lead].healthy_mask, base,
            )  # fmt: skip
        return bank, air

    def imu_spread_var(self, air: TurbulenceEstimate | None) -> np.ndarray | None:
        """The spread the base's innovations show beyond ``S`` (untrusted modes, adapted air)."""
        if (
            air is None
            or self.adapter is None
            or not self.model.score_unexplained
            or self.model.fault_signature != "untrusted"  # the zero test needs none
        ):
            return None
        return air.unexplained_var()

    def wind_ned_mps(self, mean: np.ndarray) -> np.ndarray:
        """The wind states."""
        return mean[N_RIGID + WIND.start : N_RIGID + WIND.stop].copy()


#: the filter models by their ``--filter-model`` name
FILTER_MODELS: dict[str, type[FilterModel]] = {
    PaperModel.name: PaperModel,
    RealAirModel.name: RealAirModel,
}


def filter_model(name: str, **settings: float | str) -> FilterModel:
    """The model called ``name`` (``--filter-model``) with its preset, changed by ``settings``."""
    if name not in FILTER_MODELS:
        raise ValueError(f"filter model: expected one of {', '.join(FILTER_MODELS)}, got {name!r}")
    return FILTER_MODELS[name](**settings)  # type: ignore[arg-type]
