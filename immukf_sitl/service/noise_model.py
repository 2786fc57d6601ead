"""Noise of the filter model's slow states, derived from documented quantities, not tuned.

Each of the 15 slow states of :class:`~immukf_sitl.models.augmented.AugmentedAeroModel` is a
first-order Gauss-Markov process (or a random walk) whose parameters come from a published
number:

- **wind**: a random walk (a steady wind of any size is learnt) driven as hard as the Dryden
  turbulence of MIL-F-8785C drives the gust velocity: ``2 sigma^2 V / L`` per axis, with the
  intensities and scale lengths of the low-altitude model at ``tuning.design_turbulence``
  (``moderate``: W20 = 30 kt) and height, and airspeed ``tuning.design_airspeed_mps``. The
  initial sigma is ``tuning.initial_wind_sigma_mps`` horizontally, the turbulence's ``sigma_w``
  vertically.
- **gyro bias**: the IMU spec sheet: turn-on sigma (initial) and the bias instability as a
  Gauss-Markov process of the sheet's correlation time.
- **force correction**: the model error of an airframe with ``tuning.model_uncertainty``
  (:func:`~immukf_sitl.models.augmented.model_error_sigmas`), combined with the
  accelerometer's turn-on bias and instability, is the initial sigma. Most of it is a constant
  offset; a random walk covers the part that changes with the flight condition within
  ``tuning.correction_time_constant_s``. A correction that followed every change of the
  specific force (a Gauss-Markov process at the error's full size) would also follow a sensor
  dying slowly into view: the healthy filter would absorb the fault.
- **moment correction**: the same, for the angular acceleration.
- **GPS error**: the receiver's own Gauss-Markov model (B&M eq. 7.17): rate ``k_GPS``, driving
  sigmas per fix; stationary sigma ``sigma / sqrt(1 - exp(-2 k_GPS T_s))`` (4.9 m with the
  defaults). The first fix is where the filter starts, so the state starts at that sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from immukf_sitl.models.augmented import (
    FORCE,
    GPS_ERROR,
    GYRO_BIAS,
    MOMENT,
    N_SLOW,
    WIND,
    model_error_sigmas,
)
from immukf_sitl.models.params import AircraftParams
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS, milspec_low_altitude_sigmas
from immukf_sitl.service.tuning import FilterTuning

__all__ = ["SlowStateNoise", "milspec_scale_lengths_m", "slow_state_noise"]

_FT_M = 0.3048


def milspec_scale_lengths_m(height_m: float) -> np.ndarray:
    """MIL-F-8785C low-altitude scale lengths ``(L_u, L_v, L_w)`` (m) at ``height_m``."""
    h_ft = min(max(height_m / _FT_M, 10.0), 1000.0)
    l_uv = h_ft / (0.177 + 0.000823 * h_ft) ** 1.2
    return np.array([l_uv, l_uv, h_ft]) * _FT_M


@dataclass(frozen=True)
class SlowStateNoise:
    """Initial sigmas, decay rates and driving noise of the 15 slow states.

    Attributes
    ----------
    initial_sigma : ndarray, shape (15,)
        Standard deviation at the start (units of each state).
    decay_per_s : ndarray, shape (15,)
        Inverse time constants (1/s); 0 for a random walk.
    stationary_sigma : ndarray, shape (15,)
        Gauss-Markov stationary sigma; for a random walk, the sigma its driving noise adds per
        second (``sqrt(PSD)``).
    """

    initial_sigma: np.ndarray
    decay_per_s: np.ndarray
    stationary_sigma: np.ndarray

    def step_variance(self, dt_s: float) -> np.ndarray:
        """Variance the driving noise adds over ``dt_s``: exact for the discretised process."""
        lam = self.decay_per_s
        gm = self.stationary_sigma**2 * -np.expm1(-2.0 * lam * dt_s)
        walk = self.stationary_sigma**2 * dt_s
        return np.where(lam > 0.0, gm, walk)


def slow_state_noise(
    params: AircraftParams, sensors: SensorSpec, tuning: FilterTuning
) -> SlowStateNoise:
    """The slow states' noise for ``params``, the sensors' spec sheet and the design air."""
    initial = np.zeros(N_SLOW)
    decay = np.zeros(N_SLOW)
    stationary = np.zeros(N_SLOW)
    imu, gps = sensors.imu, sensors.gps

    # wind: random walk driven by the design turbulence (Dryden: psd 2 sigma^2 V / L)
    level = TURBULENCE_LEVELS[tuning.design_turbulence]
    gust = milspec_low_altitude_sigmas(level.w20_mps, tuning.design_height_m)
    scale = milspec_scale_lengths_m(tuning.design_height_m)
    stationary[WIND] = np.sqrt(2.0 * gust**2 * tuning.design_airspeed_mps / scale)
    initial[WIND] = [tuning.initial_wind_sigma_mps, tuning.initial_wind_sigma_mps, gust[2]]
    # vertical wind: no mean over level ground, the Dryden gust itself (sigma_w, L_w / V)
    down = WIND.start + 2
    decay[down] = tuning.design_airspeed_mps / scale[2]
    stationary[down] = gust[2]

    # gyro bias: the spec sheet
    instability = imu.bias_instability
    gyro_wander = imu.gyro_bias_instability_radps if instability else 0.0
    initial[GYRO_BIAS] = math.hypot(imu.gyro_bias_sigma_radps, gyro_wander)
    if gyro_wander > 0.0:
        decay[GYRO_BIAS] = 1.0 / imu.bias_time_constant_s
        stationary[GYRO_BIAS] = gyro_wander

    # model error (with the accelerometer's bias folded into the force correction): a random
    # walk from its size, driven so that it covers its variation with the flight condition in
    # one correction_time_constant_s
    error = model_error_sigmas(params, tuning.model_uncertainty, tuning.design_airspeed_mps)
    accel_wander = imu.accel_bias_instability_mps2 if instability else 0.0
    initial[FORCE] = np.sqrt(error.force_mps2**2 + imu.accel_bias_sigma_mps2**2 + accel_wander**2)
    stationary[FORCE] = np.sqrt(
        error.force_variation_mps2**2 / tuning.correction_time_constant_s
        + 2.0 * accel_wander**2 / imu.bias_time_constant_s  # the wander's driving PSD
    )
    initial[MOMENT] = error.moment_radps2
    stationary[MOMENT] = error.moment_variation_radps2 / math.sqrt(
        tuning.correction_time_constant_s
    )

    # GPS receiver: its own Gauss-Markov model
    errors = GPS_ERROR
    driving = np.array([gps.north_east_sigma_m, gps.north_east_sigma_m, gps.height_sigma_m])
    if gps.k_gps_per_s > 0.0:
        per_fix = -math.expm1(-2.0 * gps.k_gps_per_s * gps.period_s)
        stationary[errors] = driving / math.sqrt(per_fix)
        decay[errors] = gps.k_gps_per_s
    else:  # a random walk of the driving sigma per fix
        stationary[errors] = driving / math.sqrt(gps.period_s)
    initial[errors] = stationary[errors] if gps.k_gps_per_s > 0.0 else driving
    return SlowStateNoise(initial, decay, stationary)
