"""The paper's filter variants assembled from the aircraft models and the estimation core.

- UKF-1: aerodynamic model, one filter matched to the true fault mode (an oracle);
- UKF-2: aerodynamic model, one filter matched to the fault-free mode;
- UKF-3: strapdown INS equations (IMU as input, GPS as observation), fault-free;
- UKF-4 (``imm``): aerodynamic model, IMM over the 7 single fault modes.

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
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np

from immukf_sitl.estimation import (
    FaultMode,
    FilterDiagnostics,
    ImmEstimate,
    ImmEstimator,
    JulierSigmaPoints,
    Measurement,
    MeasurementModel,
    ObservabilityGate,
    ProcessModel,
    ScaledSigmaPoints,
    UnscentedKalmanFilter,
    fault_masked_output,
    single_fault_modes,
)
from immukf_sitl.estimation.ukf import Backend, NoiseForm
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.augmented import (
    FORCE,
    GPS_ERROR,
    GUST,
    GYRO_BIAS,
    MOMENT,
    N_RIGID,
    WIND,
    AugmentedAeroModel,
)
from immukf_sitl.models.earth import NedOrigin, body_to_ned
from immukf_sitl.models.ins import InsModel
from immukf_sitl.models.params import AircraftParams
from immukf_sitl.models.sensors import IMU_PERIOD_S, SensorSpec
from immukf_sitl.service.alignment import NavSolution
from immukf_sitl.service.noise_model import SlowStateNoise, slow_state_noise
from immukf_sitl.service.tuning import FilterTuning
from immukf_sitl.service.turbulence import TurbulenceAdapter, TurbulenceEstimate

Variant = Literal["ukf1", "ukf2", "ukf3", "imm"]
VARIANTS: tuple[str, ...] = ("ukf1", "ukf2", "ukf3", "imm")
GPS_COURSE_CHANNEL = 4


def aero_process_model(
    model: AeroModel | AugmentedAeroModel,
    noise: SlowStateNoise | None,
    sensors: SensorSpec,
    tuning: FilterTuning,
) -> ProcessModel:
    """``x(k+1) = f[x(k), u(k), v(k)]`` (eq. 1): RK4 of the 6-DOF model with its slow states.

    ``v`` is additive on the body and angular accelerations, with standard deviations
    ``tuning.process_noise_factor`` times the accelerometer (m/s^2) and gyro (rad/s, read as
    rad/s^2) noise: the fast residue the slow states do not carry. With slow states (the
    real-air model), ``v`` is the three body accelerations only: the angular accelerations'
    fast part is the rotational gusts', carried as states, and a white residue under them
    would cost six sigma points per mode for nothing. The slow states' driving noise
    (``noise``) is linear and rides on the sigma points (``state_noise_cov``). The filter's
    control argument is the pair ``[u(k), u(k+1)]`` (shape (2, 4)): ``f`` flies the step on
    ``u(k)``, the output model predicts the IMU at ``k+1`` with ``u(k+1)`` (the specific force
    depends on the surfaces and throttle acting at the sample).
    """
    sigma = tuning.process_noise_factor * sensors.imu.sigmas
    noisy = [3, 4, 5, 9, 10, 11] if noise is None else [3, 4, 5]  # the rows v moves
    sigma = sigma[: len(noisy)]
    q = np.diag(sigma**2)
    dt = model.dt_s
    nx = model.nx
    slow = np.zeros((nx, nx))  # referred to the step's end
    slow_at_start = np.zeros((nx, nx))  # the same noise before the step's decay
    if noise is not None:
        q_slow = noise.step_variance(dt)
        slow[N_RIGID:, N_RIGID:] = np.diag(q_slow)
        slow_at_start[N_RIGID:, N_RIGID:] = np.diag(q_slow * np.exp(2.0 * noise.decay_per_s * dt))
    # additive form: v held over one step moves velocity (and rates) by v dt
    additive = slow.copy()
    additive[np.ix_(noisy, noisy)] = q * dt**2

    if len(noisy) == 6:

        def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
            return model.step(t_s, x, u[0], v)

    else:

        def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
            if v is not None:  # the body accelerations only: zero on the angular ones
                full = np.zeros((6,) + v.shape[1:])
                full[:3] = v
                v = full
            return model.step(t_s, x, u[0], v)

    return ProcessModel(
        f=f,
        nx=nx,
        noise_cov=q,
        additive_noise_cov=additive,
        angle_idx=model.angle_indices,
        state_noise_cov=slow_at_start if noise is not None else None,
        consider_idx=consider_indices(tuning.consider_states) if noise is not None else (),
    )


#: the slow-state groups :attr:`FilterTuning.consider_states` may name
SLOW_STATE_GROUPS = {
    "wind": WIND,
    "gyro_bias": GYRO_BIAS,
    "force": FORCE,
    "moment": MOMENT,
    "gust": GUST,
    "gps_error": GPS_ERROR,
}


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


def aero_measurement_models(
    model: AeroModel | AugmentedAeroModel, modes: Sequence[FaultMode], sensors: SensorSpec
) -> tuple[MeasurementModel, MeasurementModel]:
    """Mode-batched output models (eq. 2): IMU alone, and IMU followed by GPS.

    The GPS position is the receiver's, wandering error included (a state); its white ``R`` is
    the receiver's driving noise (the per-fix increment of that error, B&M eq. 7.17).
    """

    def imu(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return model.imu(t_s, x, u[1])

    def imu_gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return np.concatenate([model.imu(t_s, x, u[1]), model.gps(t_s, x, u[1])])

    imu_only = MeasurementModel(
        fault_masked_output(imu, modes), sensors.imu.noise_cov(), name="imu"
    )
    gps_cov = np.zeros((11, 11))
    gps_cov[:6, :6] = sensors.imu.noise_cov()
    gps_cov[6:, 6:] = sensors.gps.noise_cov()
    with_gps = MeasurementModel(
        fault_masked_output(imu_gps, modes, n_extra=5),
        gps_cov,
        angle_idx=(6 + GPS_COURSE_CHANNEL,),
        name="imu+gps",
    )
    return imu_only, with_gps


def _sigma(cov: np.ndarray, idx: slice) -> np.ndarray:
    return np.sqrt(np.clip(np.diagonal(cov)[idx], 0.0, None))


@dataclass(frozen=True)
class Observation:
    """What arrived at one IMU sample time.

    Attributes
    ----------
    imu : ndarray, shape (6,)
        ``[f_x, f_y, f_z, p, q, r]``; non-finite across a gap (predict only).
    gps : ndarray, shape (5,), or None
        ``[pN, pE, pD, ground speed, course]`` when a fix is due.
    """

    imu: np.ndarray
    gps: np.ndarray | None = None


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
    """

    t_s: float
    filter: ImmEstimate
    controls: np.ndarray
    imu: np.ndarray
    turbulence: TurbulenceEstimate | None = None

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
        """Mode probabilities to start from.

        ``initial_fault_probability`` per fault mode when the variant sets one, else the
        Markov chain's stationary distribution (the paper's chain: about ``onset / recovery``,
        4e-4, per fault mode).
        """
        p_fault = getattr(self, "initial_fault_probability", None)
        if p_fault is not None and len(self.modes) > 1:
            probs = np.array([1.0 if m.bits == 0 else p_fault for m in self.modes])
            return probs / probs.sum()
        eigval, eigvec = np.linalg.eig(self.imm.transition.T)
        stationary = np.real(eigvec[:, np.argmin(np.abs(eigval - 1.0))])
        return stationary / stationary.sum()

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
        not given); ``mode_probabilities`` default to the chain's stationary distribution.
        """
        probs = self.prior_probabilities() if mode_probabilities is None else mode_probabilities
        bank = self.imm.initial_estimate(t_s, mean, cov, probs)
        imu = np.zeros(6) if imu is None else np.array(imu, dtype=float)
        adapts = getattr(self, "turbulence", None) is not None
        return VariantEstimate(
            t_s, bank, np.array(controls, dtype=float), imu,
            TurbulenceEstimate() if adapts else None,
        )  # fmt: skip

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
    """A bank of mode-matched UKFs over the aerodynamic model (one mode for UKF-1/UKF-2).

    Build it with :func:`build_aero_estimator`.
    """

    variant: str
    modes: tuple[FaultMode, ...]
    imm: ImmEstimator
    imu_model: MeasurementModel
    imu_gps_model: MeasurementModel
    noise: SlowStateNoise | None
    turbulence: TurbulenceAdapter | None = None
    initial_fault_probability: float | None = None

    @cached_property
    def _healthy_masks(self) -> np.ndarray:
        """``(r, 6)``: 1 on the channels each mode takes as healthy."""
        return np.array([m.healthy_mask for m in self.modes], dtype=float)

    def initial_estimate(
        self,
        nav: NavSolution,
        controls: np.ndarray,
        imu: np.ndarray,
        mode_probabilities: np.ndarray | None = None,
    ) -> VariantEstimate:
        """Every mode starts from ``nav`` (e.g. :func:`align`); ``controls`` act from its time.

        The slow states start at zero with their initial sigmas; the GPS error is what
        separates the fix ``nav`` took its position from and the true position, so the two
        start fully anti-correlated.
        """
        euler_sigma = np.array(nav.euler_sigma_rad, dtype=float)
        if self.noise is not None:  # heading = course: off by the crab of an unknown wind
            speed = max(float(np.linalg.norm(nav.velocity_ned_mps[:2])), 1.0)
            crab = np.arctan2(self.noise.initial_sigma[WIND.start], speed)
            euler_sigma[2] = np.hypot(euler_sigma[2], crab)
        mean, cov = _body_velocity_state(
            nav.position_ned_m, nav.velocity_ned_mps, nav.euler_rad, nav.rates_radps,
            np.concatenate([nav.position_sigma_m, nav.velocity_sigma_mps, euler_sigma,
                            nav.rates_sigma_radps]),
        )  # fmt: skip
        mean, cov = self.augmented(mean, cov)
        if self.noise is None:
            return self.start(nav.t_s, mean, cov, controls, imu, mode_probabilities)
        errors = np.arange(N_RIGID + GPS_ERROR.start, N_RIGID + GPS_ERROR.stop)
        gps_var = np.diagonal(cov)[errors]
        cov[[0, 1, 2], [0, 1, 2]] += gps_var  # the fix is the true position plus its error
        cov[[0, 1, 2], errors] = -gps_var
        cov[errors, [0, 1, 2]] = -gps_var
        return self.start(nav.t_s, mean, cov, controls, imu, mode_probabilities)

    def augmented(self, mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A 12-state rigid-body ``mean``, ``cov`` with the slow states appended (zero mean).

        The paper's model (no slow states) takes them as they are.
        """
        if self.noise is None:
            return np.array(mean, dtype=float), np.array(cov, dtype=float)
        nx = self.imm.ukf.process.nx
        full_mean = np.zeros(nx)
        full_mean[:N_RIGID] = mean
        full_cov = np.zeros((nx, nx))
        full_cov[:N_RIGID, :N_RIGID] = cov
        full_cov[N_RIGID:, N_RIGID:] = np.diag(self.noise.initial_sigma**2)
        return full_mean, full_cov

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
            z = Measurement(imu, self.imu_model)
        else:
            z = Measurement(np.concatenate([imu, gps]), self.imu_gps_model)
        controls = np.asarray(controls, dtype=float)
        pair = np.array([previous.controls, controls])  # u(k), u(k+1)
        adapter, rough = self.turbulence, previous.turbulence
        if adapter is None or rough is None:
            bank = self.imm.step(previous.filter, t_next_s, pair, z)
            return VariantEstimate(t_next_s, bank, controls, imu)  # the IMU drives nothing here
        bank = self.imm.step(previous.filter, t_next_s, pair, z, adapter.process_at(rough.scale))
        if bank.updated and bank.innovations is not None and bank.innovation_var is not None:
            lead = bank.most_likely_mode
            rough = adapter.update(
                rough, bank.innovations[lead, :6], bank.innovation_var[lead, :6],
                self._healthy_masks[lead],
            )  # fmt: skip
        return VariantEstimate(t_next_s, bank, controls, imu, rough)

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
            None if self.noise is None else x[N_RIGID + WIND.start : N_RIGID + WIND.stop].copy(),
        )


def _body_velocity_state(
    position_ned_m: np.ndarray,
    velocity_ned_mps: np.ndarray,
    euler_rad: np.ndarray,
    rates_radps: np.ndarray,
    sigma: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The 12-state mean and covariance of a navigation solution with independent ``sigma``.

    The state holds the velocity in body axes, ``v_b = R_bn v_n``: its uncertainty is that of
    ``v_n`` and of the attitude (a heading error turns the ground velocity into the body's y
    axis), correlated with the attitude; first order, with the derivative by central
    differences.
    """
    euler = np.asarray(euler_rad, dtype=float)
    v_n = np.asarray(velocity_ned_mps, dtype=float)
    mean = np.concatenate([position_ned_m, body_to_ned(euler).T @ v_n, euler, rates_radps])
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


def build_aero_estimator(
    variant: Variant,
    model: AeroModel,
    true_mode: FaultMode | None = None,
    sensors: SensorSpec | None = None,
    tuning: FilterTuning | None = None,
    noise_form: NoiseForm = "augmented",
    kappa: float = 0.0,
    backend: Backend = "auto",
) -> AircraftEstimator:
    """UKF-1 (``"ukf1"``, needs ``true_mode``), UKF-2 (``"ukf2"``) or UKF-4 (``"imm"``).

    ``backend`` selects how the filter's kernels run (``"auto"``/``"numba"`` compiled,
    ``"python"`` the same functions uncompiled, see :class:`UnscentedKalmanFilter`); the
    model's is chosen when ``model`` is built.
    """
    sensors = sensors if sensors is not None else SensorSpec()
    tuning = tuning if tuning is not None else FilterTuning()
    if variant == "imm":
        modes = single_fault_modes()
    elif variant == "ukf1":
        if true_mode is None:
            raise ValueError("UKF-1 is matched to the true mode: pass true_mode")
        modes = (true_mode,)
    elif variant == "ukf2":
        modes = (FaultMode(0),)
    else:
        raise ValueError(f"not an aerodynamic-model variant: {variant!r}")
    if tuning.slow_states:
        noise: SlowStateNoise | None = slow_state_noise(model.params, sensors, tuning)
        flown: AeroModel | AugmentedAeroModel = AugmentedAeroModel(model, noise.decay_per_s)
    else:
        noise, flown = None, model
    process = aero_process_model(flown, noise, sensors, tuning)
    points = (
        JulierSigmaPoints(kappa)
        if tuning.sigma_point_alpha is None
        else ScaledSigmaPoints(tuning.sigma_point_alpha, 2.0, kappa)
    )
    ukf = UnscentedKalmanFilter(process, points, noise_form, backend)
    transition = tuning.transition(modes)
    floor = tuning.probability_floor if len(modes) > 1 else 0.0

    def own_imu(t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return flown.imu(t_s, x, u[1])  # u is the pair [u(k), u(k+1)]

    gate = None
    if tuning.slow_states and len(modes) > 1:
        noise_var = np.diagonal(sensors.imu.noise_cov())
        gate = ObservabilityGate(modes, own_imu, noise_var, tuning.observability_sigmas)
    imm = ImmEstimator(ukf, transition, floor, gate)
    imu_model, imu_gps_model = aero_measurement_models(flown, modes, sensors)
    adapter = None
    if noise is not None and tuning.adaptive_turbulence:
        turbulence_idx = [N_RIGID + i for g in (WIND, GUST) for i in range(g.start, g.stop)]
        adapter = TurbulenceAdapter(
            process, turbulence_idx, np.diagonal(sensors.imu.noise_cov()), flown.dt_s,
            tuning.turbulence_averaging_s, floor=tuning.turbulence_floor,
        )  # fmt: skip
    return AircraftEstimator(
        variant, tuple(modes), imm, imu_model, imu_gps_model, noise, adapter,
        tuning.initial_fault_probability,
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
        z = None if gps is None else Measurement(gps, self.gps_model)
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

    def gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        z = ins.gps(t_s, x, u)
        return z if w is None else z + w

    gps_model = MeasurementModel(
        gps, sensors.gps.noise_cov(), angle_idx=(GPS_COURSE_CHANNEL,), name="gps"
    )
    imm = ImmEstimator(
        UnscentedKalmanFilter(process, JulierSigmaPoints(kappa), noise_form), np.ones((1, 1))
    )
    return InsEstimator(ins, imm, gps_model)


Estimator = AircraftEstimator | InsEstimator


def build_estimator(
    variant: str,
    params: AircraftParams,
    origin: NedOrigin,
    true_mode: FaultMode | None = None,
    sensors: SensorSpec | None = None,
    tuning: FilterTuning | None = None,
) -> Estimator:
    """Any of the paper's four variants (``ukf1``, ``ukf2``, ``ukf3``, ``imm``) about ``origin``."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}: expected one of {', '.join(VARIANTS)}")
    if variant == "ukf3":
        return build_ins_estimator(origin, sensors)
    return build_aero_estimator(
        variant, AeroModel(params, origin), true_mode=true_mode, sensors=sensors, tuning=tuning
    )
