"""Noise of the filter model's slow states, derived from documented quantities, not tuned.

Each of the 18 slow states of :class:`~immukf_sitl.models.augmented.AugmentedAeroModel` is a
first-order Gauss-Markov process (or a random walk) whose parameters come from a published
number:

- **wind**: a random walk (a steady wind of any size is learnt) driven as hard as the
  turbulence of MIL-F-8785C drives the gust velocity, with the intensities and scale lengths
  of the low-altitude model at ``design.design_turbulence`` (``moderate``: W20 = 30 kt) and
  height, and airspeed ``design.design_airspeed_mps``. A state of this model is a first-order
  process, so the horizontal gusts are MIL-HDBK-1797's first-order forms of the Dryden spectra
  (Yeager, NASA CR-1998-206937, eqs. 30-31): the longitudinal gust with time constant
  ``L_u / V``, the lateral one with ``L_v / 2V``, which keeps the high-frequency power of its
  second-order spectrum. Driving PSDs: ``2 sigma_u^2 V / L_u`` along the mean wind and
  ``4 sigma_v^2 V / L_v`` across it; the wind's direction is learnt, not known, so each
  horizontal axis takes their mean. The vertical wind is the gust itself: no mean over level
  ground, sigma ``sigma_w``, rate ``V / L_w``. Its first-order form would be ``2 V / L_w``
  (eq. 32), but that doubled the attitude error of the first 25 s of a windy flight, while the
  turbulence adapter still flies the design air. The initial sigma is
  ``design.initial_wind_sigma_mps`` horizontally, ``sigma_w`` vertically.
- **gyro bias**: the IMU spec sheet: turn-on sigma (initial), and a random walk with the bias
  instability's driving PSD, ``2 sigma^2 / tau`` of the sheet's sigma and correlation time. The
  state holds the turn-on bias, which is constant, with the wander on it: as a Gauss-Markov
  state of that time constant it pulled the turn-on bias toward zero, and the attitude sat a
  fraction of a degree off with a sigma a third of that.
- **force correction**: the model error of an airframe with ``design.model_uncertainty``
  (:func:`~immukf_sitl.models.augmented.model_error_sigmas`), combined with the
  accelerometer's turn-on bias and instability, is the initial sigma. Most of it is a constant
  offset; a random walk covers the part that changes with the flight condition within
  ``design.correction_time_constant_s``. A correction that followed every change of the
  specific force (a Gauss-Markov process at the error's full size) would also follow a sensor
  dying slowly into view: the healthy filter would absorb the fault. The air changes the
  condition too: a vertical gust of the design air's ``sigma_w`` turns the angle of attack by
  ``sigma_w / V`` (3.5 deg in moderate air at 25 m/s), and a lift slope 10 % wrong then errs
  by 0.7 m/s^2 on the Aerosonde's z axis, fifty times the error's change between the calm
  conditions. That part walks over the same time constant, and its driving noise is the
  turbulence's (:attr:`SlowStateNoise.turbulence_share`): it scales with the air learnt in
  flight, so calm air keeps corrections that a slow fault cannot hide in.
- **moment correction**: the same, for the angular acceleration.
- **rotational gusts**: the turbulence's gust gradients turn the air about the aircraft
  (MIL-F-8785C / MIL-HDBK-1797 ``p_g``, ``q_g``, ``r_g``; :func:`rotational_gust_sigmas`), which
  the model's rate derivatives (``C_lp``, ``C_mq``, ``C_nr``, ...) make into angular
  accelerations of 0.4-3 rad/s^2 in moderate turbulence. First-order Gauss-Markov processes of
  those sigmas and the time constants of JSBSim's generator (0.32, 0.15, 0.11 s at 25 m/s): as
  states, the one-step prediction of the rates stays tight (the gust is nearly the same from
  one 10 ms step to the next) while their spread over a second is the turbulence's.
- **GPS error**: the receiver's own Gauss-Markov model (B&M eq. 7.17): rate ``k_GPS``, driving
  sigmas per fix; stationary sigma ``sigma / sqrt(1 - exp(-2 k_GPS T_s))`` (4.9 m with the
  defaults). The first fix is where the filter starts, so the state starts at that sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.integrate

from immukf_sitl.models.augmented import (
    FORCE,
    GPS_ERROR,
    GUST,
    GYRO_BIAS,
    MOMENT,
    N_SLOW,
    WIND,
    model_error_sigmas,
)
from immukf_sitl.models.params import AircraftParams
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS, milspec_low_altitude_sigmas

if TYPE_CHECKING:  # the model builds its noise from here
    from immukf_sitl.service.filter_models import RealAirModel

__all__ = [
    "SlowStateNoise",
    "milspec_scale_lengths_m",
    "rotational_gust_sigmas",
    "slow_state_noise",
]

_FT_M = 0.3048


def milspec_scale_lengths_m(height_m: float) -> np.ndarray:
    """MIL-F-8785C low-altitude scale lengths ``(L_u, L_v, L_w)`` (m) at ``height_m``."""
    h_ft = min(max(height_m / _FT_M, 10.0), 1000.0)
    l_uv = h_ft / (0.177 + 0.000823 * h_ft) ** 1.2
    return np.array([l_uv, l_uv, h_ft]) * _FT_M


@dataclass(frozen=True)
class SlowStateNoise:
    """Initial sigmas, decay rates and driving noise of the 18 slow states.

    Attributes
    ----------
    initial_sigma : ndarray, shape (15,)
        Standard deviation at the start (units of each state).
    decay_per_s : ndarray, shape (15,)
        Inverse time constants (1/s); 0 for a random walk.
    stationary_sigma : ndarray, shape (15,)
        Gauss-Markov stationary sigma; for a random walk, the sigma its driving noise adds per
        second (``sqrt(PSD)``).
    turbulence_share : ndarray, shape (18,)
        The part of each state's driving variance that the turbulence makes (1 for the wind
        and the rotational gusts, the gust part of the force and moment corrections, 0 for the
        rest): what the turbulence adapter scales with the air.
    """

    initial_sigma: np.ndarray
    decay_per_s: np.ndarray
    stationary_sigma: np.ndarray
    turbulence_share: np.ndarray = field(default_factory=lambda: np.zeros(N_SLOW))

    def step_variance(self, dt_s: float) -> np.ndarray:
        """Variance the driving noise adds over ``dt_s``: exact for the discretised process."""
        lam = self.decay_per_s
        gm = self.stationary_sigma**2 * -np.expm1(-2.0 * lam * dt_s)
        walk = self.stationary_sigma**2 * dt_s
        return np.where(lam > 0.0, gm, walk)


def slow_state_noise(
    params: AircraftParams, sensors: SensorSpec, design: RealAirModel
) -> SlowStateNoise:
    """The slow states' noise for ``params``, the sensors' spec sheet and the design air."""
    initial = np.zeros(N_SLOW)
    decay = np.zeros(N_SLOW)
    stationary = np.zeros(N_SLOW)
    share = np.zeros(N_SLOW)
    imu, gps = sensors.imu, sensors.gps
    speed = design.design_airspeed_mps

    # wind: random walk driven by the design turbulence (MIL-HDBK-1797's first-order forms:
    # psd 2 sigma_u^2 V / L_u along the wind, 4 sigma_v^2 V / L_v across; each axis the mean)
    level = TURBULENCE_LEVELS[design.design_turbulence]
    gust = milspec_low_altitude_sigmas(level.w20_mps, design.design_height_m)
    scale = milspec_scale_lengths_m(design.design_height_m)
    along, across = 2.0 * gust[0] ** 2 * speed / scale[0], 4.0 * gust[1] ** 2 * speed / scale[1]
    stationary[WIND] = math.sqrt(0.5 * (along + across))
    initial[WIND] = [design.initial_wind_sigma_mps, design.initial_wind_sigma_mps, gust[2]]
    # vertical wind: no mean over level ground, the gust itself (sigma_w, time constant L_w / V;
    # the first-order form's L_w / 2V loosened the early attitude, module docstring)
    down = WIND.start + 2
    decay[down] = speed / scale[2]
    stationary[down] = gust[2]
    share[WIND] = 1.0

    # gyro bias: the spec sheet. The state holds the turn-on bias, a constant, and the wander
    # on it, so it walks with the wander's driving PSD (2 sigma^2 / tau) and never decays: a
    # Gauss-Markov state would pull the turn-on bias toward zero (as the force correction
    # carries the accelerometer's)
    instability = imu.bias_instability
    gyro_wander = imu.gyro_bias_instability_radps if instability else 0.0
    initial[GYRO_BIAS] = math.hypot(imu.gyro_bias_sigma_radps, gyro_wander)
    stationary[GYRO_BIAS] = math.sqrt(2.0 * gyro_wander**2 / imu.bias_time_constant_s)

    # model error (with the accelerometer's bias folded into the force correction): a random
    # walk from its size, driven so that it covers its variation with the flight condition in
    # one correction_time_constant_s; its gust part is that of the design air's vertical gust
    # (sigma_w / V of angle of attack), scaled with the air in flight
    error = model_error_sigmas(
        params, design.model_uncertainty, speed, gust_attack_rad=float(gust[2]) / speed
    )
    accel_wander = imu.accel_bias_instability_mps2 if instability else 0.0
    tau = design.correction_time_constant_s
    initial[FORCE] = np.sqrt(error.force_mps2**2 + imu.accel_bias_sigma_mps2**2 + accel_wander**2)
    force_gust_psd = error.force_gust_mps2**2 / tau
    force_psd = (
        error.force_variation_mps2**2 / tau
        + 2.0 * accel_wander**2 / imu.bias_time_constant_s  # the wander's driving PSD
        + force_gust_psd
    )
    stationary[FORCE] = np.sqrt(force_psd)
    share[FORCE] = np.divide(force_gust_psd, force_psd, out=np.zeros(3), where=force_psd > 0.0)
    initial[MOMENT] = error.moment_radps2
    moment_gust_psd = error.moment_gust_radps2**2 / tau
    moment_psd = error.moment_variation_radps2**2 / tau + moment_gust_psd
    stationary[MOMENT] = np.sqrt(moment_psd)
    share[MOMENT] = np.divide(moment_gust_psd, moment_psd, out=np.zeros(3), where=moment_psd > 0.0)

    # rotational gusts: first-order Gauss-Markov processes of the MIL-F-8785C sigmas and the
    # time constants of JSBSim's generator (Yeager eqs. 9, 13, 17: L_p / V, 4 b / (pi V), 3 b /
    # (pi V))
    span = params.geometry.b_m
    if level.w20_mps > 0.0:
        l_w = scale[2]
        tau_g = np.array([math.sqrt(l_w * span) / 2.6 / speed, 4.0 * span / (math.pi * speed),
                          3.0 * span / (math.pi * speed)])  # fmt: skip
        sigma_g = rotational_gust_sigmas(design, span)
        initial[GUST] = sigma_g
        stationary[GUST] = sigma_g
        decay[GUST] = 1.0 / tau_g
        share[GUST] = 1.0

    # GPS receiver: its own Gauss-Markov model
    errors = GPS_ERROR
    driving = gps.driving_sigmas_ned_m()
    if gps.k_gps_per_s > 0.0:
        per_fix = -math.expm1(-2.0 * gps.k_gps_per_s * gps.period_s)
        stationary[errors] = driving / math.sqrt(per_fix)
        decay[errors] = gps.k_gps_per_s
    else:  # a random walk of the driving sigma per fix
        stationary[errors] = driving / math.sqrt(gps.period_s)
    initial[errors] = stationary[errors] if gps.k_gps_per_s > 0.0 else driving
    return SlowStateNoise(initial, decay, stationary, share)


def rotational_gust_sigmas(design: RealAirModel, span_m: float) -> np.ndarray:
    """Standard deviations of the rotational gusts ``(p_g, q_g, r_g)`` (rad/s) at the design air.

    MIL-F-8785C / MIL-HDBK-1797 (Dryden) as JSBSim's turbulence implements them (Yeager,
    NASA CR-1998-206937): ``sigma_p = 1.9 sigma_w / sqrt(L_w b)`` (Yeager eq. 8); ``q_g`` is the
    vertical gust's gradient along the span, ``(s / V) / (1 + 4 b s / (pi V))`` applied to
    ``w_g``, and ``r_g`` the lateral one, ``(s / V) / (1 + 3 b s / (pi V))`` applied to ``v_g``
    (eqs. 13, 16); their variances are those filters' outputs integrated over the Dryden
    spectra of ``w_g`` and ``v_g``.
    """
    level = TURBULENCE_LEVELS[design.design_turbulence]
    _, sigma_v, sigma_w = milspec_low_altitude_sigmas(level.w20_mps, design.design_height_m)
    _, l_v, l_w = milspec_scale_lengths_m(design.design_height_m)
    speed = design.design_airspeed_mps

    def dryden_lateral(omega: float, sigma: float, scale: float) -> float:
        # one-sided Dryden PSD of v_g or w_g, (m/s)^2 / (rad/s): integrates to sigma^2
        x = scale * omega / speed
        return sigma**2 * scale / (math.pi * speed) * (1.0 + 3.0 * x * x) / (1.0 + x * x) ** 2

    def gradient_variance(sigma: float, scale: float, lag_span: float) -> float:
        tau = lag_span * span_m / (math.pi * speed)

        def psd(omega: float) -> float:
            return (
                (omega / speed) ** 2
                / (1.0 + (tau * omega) ** 2)
                * dryden_lateral(omega, sigma, scale)
            )

        return scipy.integrate.quad(psd, 0.0, np.inf, limit=200)[0]

    sigma_p = 1.9 * sigma_w / math.sqrt(l_w * span_m)
    sigma_q = math.sqrt(gradient_variance(sigma_w, l_w, 4.0))
    sigma_r = math.sqrt(gradient_variance(sigma_v, l_v, 3.0))
    return np.array([sigma_p, sigma_q, sigma_r])
