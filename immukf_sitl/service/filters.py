"""The paper's filter variants assembled from the aircraft models and the estimation core.

- UKF-1: aerodynamic model, one filter matched to the true fault mode (an oracle);
- UKF-2: aerodynamic model, one filter matched to the fault-free mode;
- UKF-3: strapdown INS equations (IMU as input, GPS as observation), fault-free;
- UKF-4 (``imm``): aerodynamic model, IMM over the 7 single fault modes (with untrusted modes,
  over the 7 modes about what the detector declared: :meth:`AircraftEstimator.rebased`).

Every variant follows one protocol (:class:`Estimator`): ``initial_estimate(nav, controls, imu)``
and then ``step(previous, t_next_s, controls, observation) -> VariantEstimate`` once per IMU
sample, where ``controls`` are the actuator deflections acting from ``t_next_s`` and
``observation`` holds the six IMU channels and, when a fix arrived, the five GPS observables at
``t_next_s`` (``docs/conventions.md``). Which of them a variant treats as a measurement and which
as an input is its own business: the aerodynamic variants measure the IMU and fly on the
controls; the INS variant integrates the IMU and measures GPS only. Estimates are immutable
records; the estimators hold no state but their filters' safeguard counters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np

from immukf_sitl.estimation import (
    ChannelOffset,
    FaultMode,
    FilterDiagnostics,
    ImmEstimate,
    ImmEstimator,
    JulierSigmaPoints,
    Measurement,
    MeasurementModel,
    ProcessModel,
    UnscentedKalmanFilter,
    bank_modes,
    fault_mode_noise_var,
    fault_mode_output,
)
from immukf_sitl.estimation.fault_modes import N_IMU, reference_slots
from immukf_sitl.estimation.held_readings import RepeatRuns
from immukf_sitl.estimation.ukf import NoiseForm
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.augmented import (
    AugmentedAeroModel,
)
from immukf_sitl.models.earth import NedOrigin, body_to_ned
from immukf_sitl.models.ins import InsModel
from immukf_sitl.models.params import AircraftParams
from immukf_sitl.models.sensors import IMU_PERIOD_S, SensorSpec
from immukf_sitl.service.alignment import NavSolution
from immukf_sitl.service.filter_models import (
    FilterModel,
    ModelDynamics,
    PaperModel,
    stationary_distribution,
)
from immukf_sitl.service.turbulence import TurbulenceEstimate

Variant = Literal["ukf1", "ukf2", "ukf3", "imm"]
VARIANTS: tuple[str, ...] = ("ukf1", "ukf2", "ukf3", "imm")
GPS_COURSE_CHANNEL = 4
#: the controls' forward-difference step (rad, or throttle fraction): small beside their travel,
#: large beside rounding
CONTROL_STEP = 1e-3


def aero_measurement_models(
    model: AeroModel | AugmentedAeroModel,
    modes: Sequence[FaultMode],
    sensors: SensorSpec,
    signature: str = "untrusted",
    offset: ChannelOffset | None = None,
) -> tuple[MeasurementModel, MeasurementModel, MeasurementModel]:
    """Mode-batched output models (eq. 2): IMU alone, IMU and GPS, IMU and GPS with ``vD``.

    ``signature`` is what a fault mode predicts on its failed channels
    (:func:`fault_mode_output`): an untrusted mode reads its failed channels through ``offset``
    (their widths are the evidence's, step by step). The GPS
    position is the receiver's, wandering error included (a state); its white ``R`` is the
    receiver's driving noise (the per-fix increment of that error, B&M eq. 7.17).
    """
    ranges = sensors.imu.ranges
    n = model.nx  # the model's states; an offset state, if any, comes after them
    offsets = offset is not None

    def imu(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return model.imu(t_s, x[:n], u[1])

    def imu_gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        x = x[:n]
        return np.concatenate([model.imu(t_s, x, u[1]), model.gps(t_s, x, u[1])])

    def imu_gps_vd(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        x = x[:n]
        return np.concatenate([model.imu(t_s, x, u[1]), model.gps(t_s, x, u[1], True)])

    imu_only = MeasurementModel(
        fault_mode_output(imu, modes, signature, offset=offset),
        sensors.imu.noise_cov(),
        name="imu",
        mode_noise_var=None if offsets else fault_mode_noise_var(modes, signature, ranges),
    )

    def with_fix(output: Callable, velocity_down: bool) -> MeasurementModel:
        n_gps = 6 if velocity_down else 5
        cov = np.zeros((N_IMU + n_gps, N_IMU + n_gps))
        cov[:N_IMU, :N_IMU] = sensors.imu.noise_cov()
        cov[N_IMU:, N_IMU:] = sensors.gps.noise_cov(velocity_down)
        return MeasurementModel(
            fault_mode_output(output, modes, signature, n_extra=n_gps, offset=offset),
            cov,
            angle_idx=(N_IMU + GPS_COURSE_CHANNEL,),
            name="imu+gps+vd" if velocity_down else "imu+gps",
            mode_noise_var=(
                None if offsets else fault_mode_noise_var(modes, signature, ranges, n_gps)
            ),
        )

    return imu_only, with_fix(imu_gps, False), with_fix(imu_gps_vd, True)


def _sigma(cov: np.ndarray, idx: slice) -> np.ndarray:
    return np.sqrt(np.clip(np.diagonal(cov)[idx], 0.0, None))


@dataclass(frozen=True)
class Observation:
    """What arrived at one IMU sample time.

    Attributes
    ----------
    imu : ndarray, shape (6,)
        ``[f_x, f_y, f_z, p, q, r]``; non-finite across a gap (predict only).
    gps : ndarray, shape (5,) or (6,), or None
        ``[pN, pE, pD, ground speed, course]`` when a fix is due, followed by the vertical
        velocity ``vD`` where the fix carries it.
    imu_var_scale : float
        The IMU reading's noise variance over the sensor's own ``R`` (1: one sample per filter
        step; the mean of a faster stream's samples has its own,
        :func:`~immukf_sitl.service.stream_rate.averaged_var_scale`).
    control_var : ndarray, shape (4,), or None
        Variance of each held control's error at this step
        (:class:`~immukf_sitl.service.control_hold.ControlHold`); None: the controls are exact.
    control_sensitivity : ControlSensitivity or None
        The model's sensitivity to the controls that turns ``control_var`` into noise.
    failed_var_scale : ndarray, shape (6,), or None
        The noise variance over ``R`` of each channel as the modes that take it for failed
        read it (a noise the detector named: its factor squared); the mode that trusts the
        channel reads it at ``imu_var_scale``. None: every mode at ``imu_var_scale``.
    """

    imu: np.ndarray
    gps: np.ndarray | None = None
    imu_var_scale: float = 1.0
    control_var: np.ndarray | None = None
    control_sensitivity: ControlSensitivity | None = None
    failed_var_scale: np.ndarray | None = None


@dataclass(frozen=True)
class ControlSensitivity:
    """How one step of the model moves with each control, about an estimate.

    A control wrong by ``e`` (variance ``S``, diagonal) moves the next state by ``B e`` and the
    predicted IMU by ``D e``: process noise ``B S B'`` (eq. 1) and output noise ``D S D'``
    (eq. 2), the linearisation the first-order terms of the unscented transform would give.
    """

    #: ``(nx, 4)``: d x(k+1) / d u(k), the model's whole state
    state: np.ndarray
    #: ``(6, 4)``: d z_imu(k+1) / d u(k+1), the accelerometers' direct feedthrough (and none on
    #: the gyros)
    imu: np.ndarray

    def state_cov(self, var: np.ndarray) -> np.ndarray:
        """``B S B'``: what the controls' error adds to the predicted state's covariance."""
        return (self.state * var) @ self.state.T

    def imu_var(self, var: np.ndarray) -> np.ndarray:
        """``diag(D S D')``: what it adds to each IMU channel's predicted variance."""
        return (self.imu * self.imu) @ var


@dataclass(frozen=True)
class VariantEstimate:
    """An estimate of any variant at ``t_s``: the bank's state and the inputs acting from then.

    Attributes
    ----------
    t_s : float
        Time of the estimate (the IMU sample it used last).
    filter : ImmEstimate
        The bank's (or the single filter's) estimate at ``t_s``.
    controls : ndarray, shape (4,)
        Deflections acting from ``t_s`` (the aerodynamic model flies the next step on them).
    imu : ndarray, shape (6,)
        The IMU sample at ``t_s``; the INS keeps the last finite one, which it integrates over
        the next step.
    turbulence : TurbulenceEstimate or None
        The air's roughness learnt so far (the real-air model), the scale the next step's
        turbulence noise is drawn at; None for a model without turbulence states.
    repeats : RepeatRuns or None
        The IMU channels' runs of exactly repeated readings (the aerodynamic variants); None:
        nothing read yet.
    """

    t_s: float
    filter: ImmEstimate
    controls: np.ndarray
    imu: np.ndarray
    turbulence: TurbulenceEstimate | None = None
    repeats: RepeatRuns | None = None

    @property
    def mode_probabilities(self) -> np.ndarray:
        """``mu_j`` (eq. 26) of the variant's modes."""
        return self.filter.mode_probabilities


class _Bank:
    """What every variant shares: its modes, its IMM (one mode for UKF-1/2/3), its counters."""

    variant: str
    modes: tuple[FaultMode, ...]
    imm: ImmEstimator

    @property
    def diagnostics(self) -> FilterDiagnostics:
        """Safeguard counters of the variant's filters."""
        return self.imm.diagnostics

    def prior_probabilities(self) -> np.ndarray:
        """Mode probabilities to start from: the Markov chain's stationary distribution."""
        return stationary_distribution(self.imm.transition)

    def start_air(self) -> TurbulenceEstimate | None:
        """What the variant knows of the air at start-up (None: nothing to learn)."""
        return None

    @property
    def fault_signature(self) -> str:
        """What the bank's fault modes predict on their failed channels (none: zero)."""
        return "zero"

    def channel_innovations(
        self, estimate: VariantEstimate
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Per-mode IMU innovations (:meth:`AircraftEstimator.channel_innovations`); None: none."""
        return None

    def naming_innovations(self, estimate: VariantEstimate) -> tuple[np.ndarray, np.ndarray] | None:
        """What a failure is named from (:meth:`AircraftEstimator.naming_innovations`)."""
        return None

    def control_sensitivity(self, estimate: VariantEstimate) -> ControlSensitivity | None:
        """The model's sensitivity to the controls (None: the variant does not fly on them)."""
        return None

    def start(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        controls: np.ndarray,
        imu: np.ndarray | None = None,
        mode_probabilities: np.ndarray | None = None,
    ) -> VariantEstimate:
        """Every mode starts from ``mean``, ``cov`` at ``t_s``; ``controls`` act from then.

        ``imu`` is the sample at ``t_s`` (the INS integrates it over the first step; zeros if
        not given); ``mode_probabilities`` default to :meth:`prior_probabilities`.
        """
        probs = self.prior_probabilities() if mode_probabilities is None else mode_probabilities
        bank = self.imm.initial_estimate(t_s, mean, cov, probs)
        imu = np.zeros(6) if imu is None else np.array(imu, dtype=float)
        return VariantEstimate(t_s, bank, np.array(controls, dtype=float), imu, self.start_air())

    def restart_from_fault_free(
        self, estimate: VariantEstimate, mode_probabilities: np.ndarray | None = None
    ) -> VariantEstimate:
        """Re-seed every mode from the most probable one.

        The paper initialises the mode-matched filters from the fault-free UKF's steady state
        (section 2.A); the service runs the bank through a settling period and then calls this.
        The seed is the filter of the most probable mode, fault-free unless the bank already
        believes a channel failed: a channel the IMM calls failed is not trusted for it. The
        modes restart at ``mode_probabilities`` (default: they keep theirs). A bank of one mode
        (UKF-1, UKF-2, UKF-3) has nothing to re-seed.
        """
        if len(self.modes) == 1:
            return estimate
        bank = estimate.filter
        seed = bank.most_likely_mode
        probs = bank.mode_probabilities if mode_probabilities is None else mode_probabilities
        restarted = self.imm.initial_estimate(
            bank.t_s, bank.mode_means[seed], bank.mode_covs[seed], probs
        )
        return dataclasses.replace(estimate, filter=restarted)

    def probabilities_believing(self, mode: FaultMode | None) -> np.ndarray:
        """Mode probabilities to (re)start from when ``mode`` is believed (None: the prior).

        A re-alignment must not forget a declared fault: the declared mode starts at 0.99.
        """
        prior = self.prior_probabilities()
        if mode is None or mode not in self.modes:
            return prior
        probs = 0.01 * prior
        probs[self.modes.index(mode)] += 0.99
        return probs / probs.sum()


@dataclass(frozen=True, eq=False)
class AircraftEstimator(_Bank):
    """A bank of mode-matched UKFs over a filter model (one mode for UKF-1/UKF-2).

    What differs between the paper's and the real-air model (states, noise, start-up, the air)
    is the ``dynamics``'; the bank only wires it to the IMM. Build it with
    :func:`build_aero_estimator`.
    """

    variant: str
    modes: tuple[FaultMode, ...]
    imm: ImmEstimator
    imu_model: MeasurementModel
    imu_gps_model: MeasurementModel
    imu_gps_vd_model: MeasurementModel
    filter_model: FilterModel
    dynamics: ModelDynamics
    sensors: SensorSpec
    #: declared channels whose recovery slots are scored on the GPS fix alone (the slow test's)
    fix_scored: FaultMode | None = None

    def rebased(
        self, declared: FaultMode | None, fix_scored: FaultMode | None = None
    ) -> AircraftEstimator:
        """The same bank over the modes about ``declared`` (:func:`bank_modes`).

        The filters (their kernels and counters) and the model are shared; what changes is what
        each slot believes, its evidence and the Markov chain over the slots. Carry an estimate
        across with :meth:`carried_over`. The slots that trust a channel of ``fix_scored``
        again are scored on the GPS fix alone (``ImmEstimator``'s ``scored_beyond``): declared
        on the fixes' evidence (a drift the state followed), its recovery is theirs to show.
        """
        if self.variant != "imm":
            raise ValueError(f"only the IMM re-bases, not {self.variant!r}")
        modes = bank_modes(declared)
        return self._over(modes, self.dynamics.with_modes(modes), fix_scored)

    def holding(self, errors: Mapping[int, tuple[float | None, float | None]]) -> AircraftEstimator:
        """The same bank with declared channels' drift rates and gains held where known.

        ``errors``: :meth:`ChannelOffset.holding`'s. The state's layout is unchanged, so an
        estimate carries over as it is once :meth:`ModelDynamics.settled_offsets` has put the
        held states at their values. Returns this bank where nothing changes.
        """
        dynamics = self.dynamics.holding(errors)
        if dynamics is self.dynamics:
            return self
        return self._over(self.modes, dynamics, self.fix_scored)

    def _over(
        self, modes: Sequence[FaultMode], dynamics: ModelDynamics, fix_scored: FaultMode | None
    ) -> AircraftEstimator:
        """The bank of ``modes`` over ``dynamics``, its filters' counters carried on."""
        ukf = self.imm.ukf
        if dynamics.process is not ukf.process:  # the declared channels' error states
            ukf = UnscentedKalmanFilter(dynamics.process, ukf.scheme, ukf.noise_form, ukf.compiled)
            ukf.diagnostics = self.imm.ukf.diagnostics
        return _assemble(
            self.variant, modes, ukf, dynamics, self.filter_model, self.sensors, fix_scored
        )

    def carried_over(
        self, estimate: VariantEstimate, previous: AircraftEstimator
    ) -> VariantEstimate:
        """``estimate`` of ``previous``'s bank moved onto this bank's slots.

        A mode both banks hold keeps its filter and its probability; a mode new to this bank
        starts from the filter of this bank's base mode (which the previous bank held: a
        re-base changes the declared set by one channel) at its prior probability. The states
        move onto this bank's layout (:meth:`ModelDynamics.moved_states`).
        """
        bank = estimate.filter
        held = {mode: j for j, mode in enumerate(previous.modes)}
        base = held.get(self.modes[0], bank.most_likely_mode)
        prior = self.prior_probabilities()
        source = [held.get(mode, base) for mode in self.modes]
        probs = np.array(
            [
                bank.mode_probabilities[held[mode]] if mode in held else prior[k]
                for k, mode in enumerate(self.modes)
            ]
        )
        probs = probs / probs.sum()
        r = len(self.modes)
        means, covs = self.dynamics.moved_states(
            previous.dynamics, bank.mode_means[source], bank.mode_covs[source]
        )
        mean, cov = self.dynamics.moved_states(previous.dynamics, bank.mean[None], bank.cov[None])
        moved = dataclasses.replace(
            bank,
            mean=mean[0],
            cov=cov[0],
            predicted_means=None,
            mode_probabilities=probs,
            log_mode_probabilities=np.log(probs),
            mode_means=means.copy(),
            mode_covs=covs.copy(),
            log_likelihoods=np.zeros(r),
            innovations=None,
            nis=np.zeros(r),
            updated=False,
            innovation_var=None,
            rest_ratios=None,
            rest_nis=None,
            rest_dof=0,
        )
        air = estimate.turbulence
        if air is not None:  # a channel that changed state: its spread was its failure's
            changed = self.modes[0].healthy_mask != previous.modes[0].healthy_mask
            air = air.forget_unexplained(changed)
        filtered = self.dynamics.settled_offsets(moved)
        return dataclasses.replace(estimate, filter=filtered, turbulence=air)

    def prior_probabilities(self) -> np.ndarray:
        """The filter model's start-up odds over the bank's modes."""
        return self.filter_model.prior_probabilities(self.modes, self.imm.transition)

    def start_air(self) -> TurbulenceEstimate | None:
        """The filter model's knowledge of the air at start-up."""
        return self.dynamics.start_air()

    @property
    def fault_signature(self) -> str:
        """What the bank's fault modes predict on their failed channels."""
        return self.filter_model.fault_signature

    def channel_innovations(
        self, estimate: VariantEstimate
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Each mode's IMU innovations ``(r, 6)`` and their variances without the mode's width.

        The residual of a mode's own prediction of each channel and the variance of its
        prediction plus the sensor noise: for an untrusted mode's failed channel, how far the
        reading is from what the other sensors say it should be; for a zero mode's, how far
        from zero. None on a predict-only step. A channel a mode trusts has the spread its
        innovations show beyond ``S`` added to its variance, as the modes are scored with it
        (:meth:`ModelDynamics.imu_spread_var`).
        """
        bank = estimate.filter
        if bank.innovations is None or bank.innovation_var is None:
            return None
        nu, var = bank.innovations[:, :6], bank.innovation_var[:, :6]
        width = self.imu_model.mode_noise_var
        if width is not None:
            var = var - width[:, :6]
        spread = self.dynamics.imu_spread_var(estimate.turbulence)
        if spread is not None:
            var = var + spread * self._healthy_masks
        offset = self.dynamics.offset
        if offset is not None:  # a newly failed channel: its offset, the rest's disagreement
            nu, var = offset.residuals(bank.mode_means, bank.mode_covs, nu, var, estimate.imu)
        return nu, np.maximum(var, np.finfo(float).tiny)

    def naming_innovations(self, estimate: VariantEstimate) -> tuple[np.ndarray, np.ndarray] | None:
        """What a declared channel's failure is named from (None on a predict-only step).

        :meth:`channel_innovations`, but each failed channel against the state's prediction of
        it without its offset, with the variance of a mode that trusts it: the learnt offset
        would hide a noisy channel's scatter and a gain's shape.
        """
        bank, offset = estimate.filter, self.dynamics.offset
        reference = self._references
        if offset is None or bank.predicted_means is None or reference is None:
            return self.channel_innovations(estimate)
        if bank.innovations is None or bank.innovation_var is None:
            return None
        raw = bank.innovations[:, :6]
        var = bank.innovation_var[:, :6]
        return offset.naming_residuals(bank.predicted_means, raw, var, reference, estimate.imu)

    @cached_property
    def _references(self) -> np.ndarray | None:
        """:func:`reference_slots` of the bank's modes (fixed for a bank)."""
        return reference_slots(self.modes)

    def initial_estimate(
        self,
        nav: NavSolution,
        controls: np.ndarray,
        imu: np.ndarray,
        mode_probabilities: np.ndarray | None = None,
    ) -> VariantEstimate:
        """Every mode starts from ``nav`` (e.g. :func:`align`); ``controls`` act from its time."""
        mean, cov = self.dynamics.initial_state(nav)
        return self.start(nav.t_s, mean, cov, controls, imu, mode_probabilities)

    def augmented(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A 12-state rigid-body ``mean``, ``cov`` extended to the filter model's state."""
        return self.dynamics.augmented(mean, cov)

    def step(
        self,
        previous: VariantEstimate,
        t_next_s: float,
        controls: np.ndarray,
        observation: Observation,
    ) -> VariantEstimate:
        """Fly from ``previous`` to ``t_next_s`` on its controls; update with the observation.

        The output model predicts the IMU at ``t_next_s`` with ``controls`` (the specific force
        depends on the surfaces and throttle acting at the sample): the filter's control
        argument is the pair ``[u(k), u(k+1)]``.
        """
        imu, gps = observation.imu, observation.gps
        if gps is None:
            model = self.imu_model
        else:
            model = self.imu_gps_vd_model if gps.shape[0] > 5 else self.imu_gps_model
        extra = np.zeros((len(self.modes), model.nz))
        if observation.imu_var_scale != 1.0:  # the reading's own R, not one sample's
            extra[:, :6] = (observation.imu_var_scale - 1.0) * self.sensors.imu.sigmas**2
        if observation.failed_var_scale is not None:  # a noisy channel read at its own noise
            beyond = np.maximum(observation.failed_var_scale - observation.imu_var_scale, 0.0)
            extra[:, :6] += (beyond * self.sensors.imu.sigmas**2) * (1.0 - self._healthy_masks)
        held, var = observation.control_sensitivity, observation.control_var
        if held is not None and var is not None:
            # the held controls' error: process noise on every mode's state (eq. 1), output
            # noise on the channels a mode reads through the model (eq. 2), not on a channel it
            # takes for failed (its reading does not depend on the controls)
            bank = previous.filter
            bank = dataclasses.replace(bank, mode_covs=bank.mode_covs + held.state_cov(var))
            previous = dataclasses.replace(previous, filter=bank)
            extra[:, :6] += held.imu_var(var) * self._healthy_masks
        z = Measurement(
            imu if gps is None else np.concatenate([imu, gps]),
            model,
            extra if extra.any() else None,
        )
        controls = np.asarray(controls, dtype=float)
        pair = np.array([previous.controls, controls])  # u(k), u(k+1)
        before = previous.repeats if previous.repeats is not None else RepeatRuns.start()
        repeats = before.after(imu, self.sensors.imu.ranges)
        bank, air = self.dynamics.step(
            self.imm, previous.filter, previous.turbulence, t_next_s, pair, z,
            before.last, repeats.beyond_chance(),
        )  # fmt: skip
        # the IMU drives nothing here
        return VariantEstimate(t_next_s, bank, controls, imu, air, repeats)

    @cached_property
    def _healthy_masks(self) -> np.ndarray:
        """``(modes, 6)``: 1 where a mode reads the channel through the model."""
        return np.array([mode.healthy_mask for mode in self.modes])

    def control_sensitivity(self, estimate: VariantEstimate) -> ControlSensitivity:
        """The model's sensitivity to each control about ``estimate``'s combined mean.

        Forward differences of one model step and one IMU prediction, batched into one call
        of each (the controls' step is a tenth of a percent of their travel).
        """
        mean = estimate.filter.mean
        n_u = estimate.controls.shape[0]
        states = np.repeat(mean[:, None], n_u + 1, axis=1)
        pair = np.repeat(np.array([estimate.controls] * 2)[:, :, None], n_u + 1, axis=2)
        pair[:, np.arange(n_u), np.arange(1, n_u + 1)] += CONTROL_STEP
        moved = self.dynamics.process.f(estimate.t_s, states, pair, None)
        flown = self.dynamics.flown
        read = flown.imu(estimate.t_s, states[: flown.nx], pair[1])
        return ControlSensitivity(
            (moved[:, 1:] - moved[:, :1]) / CONTROL_STEP, (read[:, 1:] - read[:, :1]) / CONTROL_STEP
        )

    def navigation(self, estimate: VariantEstimate) -> NavSolution:
        """The combined estimate as a navigation solution."""
        bank = estimate.filter
        x, cov = bank.mean, bank.cov
        rot = body_to_ned(x[6:9])
        vel_cov = rot @ cov[3:6, 3:6] @ rot.T
        return NavSolution(
            estimate.t_s,
            x[0:3].copy(),
            rot @ x[3:6],
            x[6:9].copy(),
            x[9:12].copy(),
            _sigma(cov, slice(0, 3)),
            np.sqrt(np.clip(np.diagonal(vel_cov), 0.0, None)),
            _sigma(cov, slice(6, 9)),
            _sigma(cov, slice(9, 12)),
            self.dynamics.wind_ned_mps(x),
        )


def build_aero_estimator(
    variant: Variant,
    model: AeroModel,
    true_mode: FaultMode | None = None,
    sensors: SensorSpec | None = None,
    filter_model: FilterModel | None = None,
    noise_form: NoiseForm = "augmented",
    kappa: float = 0.0,
    compiled: bool = True,
    declared: FaultMode | None = None,
) -> AircraftEstimator:
    """UKF-1 (``"ukf1"``, needs ``true_mode``), UKF-2 (``"ukf2"``) or UKF-4 (``"imm"``).

    ``filter_model`` defaults to the paper's (:class:`PaperModel`). The IMM's bank is based on
    ``declared`` (:func:`bank_modes`; nothing declared: the paper's seven modes). ``compiled``
    selects how the filter's kernels run (False: the same functions uncompiled, see
    :class:`UnscentedKalmanFilter`); the aircraft model's is chosen when ``model`` is built.
    """
    sensors = sensors if sensors is not None else SensorSpec()
    filter_model = filter_model if filter_model is not None else PaperModel()
    if variant == "imm":
        modes = bank_modes(declared)
    elif variant == "ukf1":
        if true_mode is None:
            raise ValueError("UKF-1 is matched to the true mode: pass true_mode")
        modes = (true_mode,)
    elif variant == "ukf2":
        modes = (FaultMode(0),)
    else:
        raise ValueError(f"not an aerodynamic-model variant: {variant!r}")
    dynamics = filter_model.build(model, sensors, modes)
    ukf = UnscentedKalmanFilter(
        dynamics.process, dynamics.sigma_points(kappa), noise_form, compiled
    )
    return _assemble(variant, modes, ukf, dynamics, filter_model, sensors)


def _assemble(
    variant: str,
    modes: Sequence[FaultMode],
    ukf: UnscentedKalmanFilter,
    dynamics: ModelDynamics,
    filter_model: FilterModel,
    sensors: SensorSpec,
    fix_scored: FaultMode | None = None,
) -> AircraftEstimator:
    """The bank of ``ukf`` over ``modes``: its chain (eq. 3), evidence and output models.

    A slot that trusts again a declared channel of ``fix_scored`` is scored on the GPS fix
    alone (:meth:`AircraftEstimator.rebased`).
    """
    floor = filter_model.probability_floor if len(modes) > 1 else 0.0
    # the modes that add a failure keep a history of their own, so a second failure is tested
    # as a first one is; a recovery slot mixes as the textbook does (with a history it followed
    # a dead gyro's zeros and took the lead; docs/design/detection-and-tuning.md)
    history = 0.0
    slots = left_out = None
    untrusted = filter_model.fault_signature == "untrusted"
    if len(modes) > 1 and untrusted and filter_model.history_floor > 0.0:
        history = filter_model.history_floor
        slots = np.array([bool(m.bits & ~modes[0].bits) for m in modes])
        if modes[0].bits == 0:
            # each is also scored against the base on the GPS fix alone (the slow-evidence
            # test of service/declared_set.py, while nothing is declared)
            left_out = np.zeros((len(modes), N_IMU), dtype=bool)
            left_out[1:] = True
    beyond = None
    if fix_scored is not None and len(modes) > 1:
        recovers = np.array([bool(modes[0].bits & ~m.bits & fix_scored.bits) for m in modes])
        beyond = np.repeat(recovers[:, None], N_IMU, axis=1)
    imm = ImmEstimator(
        ukf, filter_model.transition(modes), floor, dynamics.gate(), history,
        dynamics.history_states(), slots, rest_left_out=left_out, scored_beyond=beyond,
    )  # fmt: skip
    imu_model, imu_gps_model, imu_gps_vd_model = aero_measurement_models(
        dynamics.flown, modes, sensors, filter_model.fault_signature, dynamics.offset
    )
    return AircraftEstimator(
        variant, tuple(modes), imm, imu_model, imu_gps_model, imu_gps_vd_model, filter_model,
        dynamics, sensors, fix_scored,
    )  # fmt: skip


@dataclass(frozen=True, eq=False)
class InsEstimator(_Bank):
    """UKF-3: strapdown INS equations with the IMU as input and GPS as the only observation.

    Same protocol as :class:`AircraftEstimator`; the controls are carried but not used.
    Between GPS fixes the step is predict-only.
    """

    ins: InsModel
    imm: ImmEstimator
    gps_model: MeasurementModel
    gps_vd_model: MeasurementModel
    variant: str = "ukf3"
    modes: tuple[FaultMode, ...] = (FaultMode(0),)

    def initial_estimate(
        self,
        nav: NavSolution,
        controls: np.ndarray,
        imu: np.ndarray,
        mode_probabilities: np.ndarray | None = None,
    ) -> VariantEstimate:
        """Start from ``nav`` (9 states); ``imu`` is the sample at its time (one mode only)."""
        mean = np.concatenate([nav.position_ned_m, nav.velocity_ned_mps, nav.euler_rad])
        sigma = np.concatenate([nav.position_sigma_m, nav.velocity_sigma_mps, nav.euler_sigma_rad])
        return self.start(nav.t_s, mean, np.diag(sigma**2), controls, imu)

    def step(
        self,
        previous: VariantEstimate,
        t_next_s: float,
        controls: np.ndarray,
        observation: Observation,
    ) -> VariantEstimate:
        """Integrate the previous IMU sample up to ``t_next_s``; update with GPS if given."""
        gps = observation.gps
        z = None
        if gps is not None:
            z = Measurement(gps, self.gps_vd_model if gps.shape[0] > 5 else self.gps_model)
        bank = self.imm.step(previous.filter, t_next_s, previous.imu, z)
        imu = observation.imu
        last_imu = imu if np.all(np.isfinite(imu)) else previous.imu  # a gap: keep driving
        return VariantEstimate(
            t_next_s, bank, np.asarray(controls, dtype=float), np.array(last_imu, dtype=float)
        )

    def navigation(self, estimate: VariantEstimate) -> NavSolution:
        """The estimate as a navigation solution (rates: the last gyro sample)."""
        x, cov = estimate.filter.mean, estimate.filter.cov
        return NavSolution(
            estimate.t_s,
            x[0:3].copy(),
            x[3:6].copy(),
            x[6:9].copy(),
            estimate.imu[3:6].copy(),
            _sigma(cov, slice(0, 3)),
            _sigma(cov, slice(3, 6)),
            _sigma(cov, slice(6, 9)),
            np.zeros(3),
        )


def build_ins_estimator(
    origin: NedOrigin,
    sensors: SensorSpec | None = None,
    noise_form: NoiseForm = "augmented",
    kappa: float = 0.0,
    dt_s: float = IMU_PERIOD_S,
) -> InsEstimator:
    """UKF-3 of the paper: the INS equations, fault-free, GPS-aided."""
    sensors = sensors if sensors is not None else SensorSpec()
    ins = InsModel(
        origin,
        dt_s=dt_s,
        accel_noise_mps2=sensors.imu.accel_sigma_mps2,
        gyro_noise_radps=sensors.imu.gyro_sigma_radps,
    )
    q = ins.process_noise_cov()
    # additive form: input noise held over one step moves velocity by f dt (rotation ignored)
    additive = np.zeros((9, 9))
    additive[3:6, 3:6] = q[:3, :3] * dt_s**2
    additive[6:9, 6:9] = q[3:, 3:] * dt_s**2
    process = ProcessModel(ins.step, 9, q, additive, angle_idx=ins.angle_indices)

    def gps_model(velocity_down: bool) -> MeasurementModel:
        def gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
            z = ins.gps(t_s, x, u, velocity_down)
            return z if w is None else z + w

        cov = sensors.gps.noise_cov(velocity_down)
        name = "gps+vd" if velocity_down else "gps"
        return MeasurementModel(gps, cov, angle_idx=(GPS_COURSE_CHANNEL,), name=name)

    imm = ImmEstimator(
        UnscentedKalmanFilter(process, JulierSigmaPoints(kappa), noise_form), np.ones((1, 1))
    )
    return InsEstimator(ins, imm, gps_model(False), gps_model(True))


Estimator = AircraftEstimator | InsEstimator


def build_estimator(
    variant: str,
    params: AircraftParams,
    origin: NedOrigin,
    true_mode: FaultMode | None = None,
    sensors: SensorSpec | None = None,
    filter_model: FilterModel | None = None,
    declared: FaultMode | None = None,
) -> Estimator:
    """Any of the paper's four variants (``ukf1``, ``ukf2``, ``ukf3``, ``imm``) about ``origin``.

    ``declared``: what the IMM's bank is based on (:func:`bank_modes`).
    """
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}: expected one of {', '.join(VARIANTS)}")
    if variant == "ukf3":
        return build_ins_estimator(origin, sensors)
    return build_aero_estimator(
        variant,
        AeroModel(params, origin),
        true_mode=true_mode,
        sensors=sensors,
        filter_model=filter_model,
        declared=declared,
    )
