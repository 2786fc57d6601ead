"""Sensor models of the simulation: IMU and GPS.

Beard & McLain, *Small Unmanned Aircraft*, 2012, ch. 7; the specs and their defaults are
:mod:`immukf_sitl.models.sensors`.

- IMU, every step (100 Hz): specific force (m/s^2) and inertial body rates (rad/s) in body FRD,
  plus zero-mean white Gaussian noise and an optional constant bias — the HIGHRES_IMU fields
  ``xacc..zacc``, ``xgyro..zgyro``.
- GPS, at ``rate_hz`` (1 Hz): position with a first-order Gauss-Markov error per axis
  (B&M eq. 7.17, ``nu[n+1] = exp(-k_GPS T) nu[n] + eta[n]``, ``eta ~ N(0, sigma^2)`` at
  ``T = 1 s`` and the same process sampled at other rates; north/east sigma 0.21 m, height
  0.40 m, ``k_GPS = 1/1100`` 1/s), ground speed with white noise
  (0.05 m/s) and course with white noise of ``0.05 / Vg`` rad (B&M eq. 7.19-7.20). Outputs are
  latitude/longitude (deg), height (m), ground speed (m/s) and course (rad, wrapped); the MAVLink
  layer converts them to GPS_RAW_INT units.

The samples are the project's one sample type, :class:`immukf_sitl.samples.ImuSample` and
:class:`immukf_sitl.samples.GpsSample` (SI units), which the MAVLink codec encodes.

All randomness comes from an injected :class:`numpy.random.Generator` (STYLE.md rule 11).
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from immukf_sitl.models.sensors import IMU_PERIOD_S, GpsSpec, ImuSpec
from immukf_sitl.samples import GpsSample, ImuSample
from sim.truth import TruthState

__all__ = ["GpsModel", "ImuModel"]


class ImuModel:
    """Accelerometers and rate gyros with white noise and a bias.

    The bias of each channel is the spec's constant bias, plus a turn-on bias drawn once per run
    from the spec sheet's bias sigma, plus (``bias_instability``) a first-order Gauss-Markov
    wander started from its stationary distribution.

    Parameters
    ----------
    spec : ImuSpec
        Noise and bias.
    rng : numpy.random.Generator
        Source of the white noise.
    bias_rng : numpy.random.Generator, optional
        Source of the turn-on bias and the wander (a stream of its own, so that switching a
        bias on leaves the white noise of the same seed unchanged); required when the spec has
        a bias sigma or a wander.
    dt_s : float
        Sample period (s), for the wander's discretisation.
    """

    def __init__(
        self,
        spec: ImuSpec,
        rng: np.random.Generator,
        bias_rng: np.random.Generator | None = None,
        dt_s: float = IMU_PERIOD_S,
    ) -> None:
        self.spec = spec
        self._rng = rng
        self._bias_rng = bias_rng
        random_bias = bool(np.any(spec.bias_sigmas > 0.0)) or spec.bias_instability
        if random_bias and bias_rng is None:
            raise ValueError("ImuModel: a bias sigma or bias_instability needs bias_rng")
        self._bias = np.concatenate([spec.accel_bias_mps2, spec.gyro_bias_radps]).astype(float)
        if bias_rng is not None and np.any(spec.bias_sigmas > 0.0):
            self._bias = self._bias + spec.bias_sigmas * bias_rng.standard_normal(6)
        self._wander = np.zeros(6)
        self._decay = 1.0
        self._drive = np.zeros(6)
        if spec.bias_instability:
            assert bias_rng is not None
            stationary = np.array(
                [spec.accel_bias_instability_mps2] * 3 + [spec.gyro_bias_instability_radps] * 3
            )
            self._decay = math.exp(-dt_s / spec.bias_time_constant_s)
            self._drive = stationary * math.sqrt(1.0 - self._decay**2)
            self._wander = stationary * bias_rng.standard_normal(6)

    @property
    def bias(self) -> np.ndarray:
        """The current true bias of ``[f_x, f_y, f_z, p, q, r]`` (m/s^2, rad/s), a copy."""
        return self._bias + self._wander

    def read(self, truth: TruthState) -> ImuSample:
        """Sample the IMU at a truth state.

        Parameters
        ----------
        truth : TruthState
            True specific force and inertial rates.

        Returns
        -------
        ImuSample
            Truth plus bias plus noise.
        """
        noise = self._rng.standard_normal(6)
        if self.spec.bias_instability:
            assert self._bias_rng is not None
            self._wander = self._decay * self._wander + self._drive * (
                self._bias_rng.standard_normal(6)
            )
        bias = self._bias + self._wander
        accel = truth.specific_force_body_mps2 + bias[:3] + self.spec.accel_sigma_mps2 * noise[:3]
        gyro = truth.rates_body_radps + bias[3:] + self.spec.gyro_sigma_radps * noise[3:]
        return ImuSample(time_s=truth.time_s, accel_mps2=accel, gyro_radps=gyro)


class GpsModel:
    """GPS receiver with Gauss-Markov position errors, sampled at ``spec.rate_hz``.

    Parameters
    ----------
    spec : GpsSpec
        Rate and noise.
    rng : numpy.random.Generator
        Source of all the noise.
    start_time_s : float, optional
        Time of the first fix (s).
    velocity_down_rng : numpy.random.Generator, optional
        Source of the vertical velocity's noise, where ``spec.reports_velocity_down``: a
        stream of its own, so that a receiver that reports it draws every other error as one
        that does not.

    Notes
    -----
    The Gauss-Markov errors start at zero (as in B&M's simulation) and then wander with a
    stationary standard deviation of ``sigma / sqrt(1 - exp(-2 k_GPS 1 s))`` (about 4.9 m north
    and east for the defaults) at any rate; they are propagated once per fix, with the share of
    the driving noise a fix of that period takes (``GpsSpec.driving_sigmas_ned_m``).
    """

    def __init__(
        self,
        spec: GpsSpec,
        rng: np.random.Generator,
        start_time_s: float = 0.0,
        velocity_down_rng: np.random.Generator | None = None,
    ) -> None:
        if spec.reports_velocity_down and velocity_down_rng is None:
            raise ValueError("a receiver that reports its vertical velocity needs its own rng")
        self.spec = spec
        self._rng = rng
        self._velocity_down_rng = velocity_down_rng
        self._next_time_s = float(start_time_s)
        self._count = 0
        self._start_time_s = float(start_time_s)
        self._error_ned_m = np.zeros(3)
        self._decay = math.exp(-spec.k_gps_per_s * spec.period_s)
        self._sigma_ned_m = spec.driving_sigmas_ned_m()

    @property
    def position_error_ned_m(self) -> np.ndarray:
        """Current Gauss-Markov position error, NED (m) (a copy)."""
        return self._error_ned_m.copy()

    def due(self, time_s: float) -> bool:
        """Whether a fix is due at ``time_s`` (half a simulation step of tolerance)."""
        return time_s >= self._next_time_s - 1e-6

    def read(self, truth: TruthState) -> GpsSample | None:
        """Return a fix if one is due at the truth's time, else ``None``.

        Parameters
        ----------
        truth : TruthState
            True position and velocity.

        Returns
        -------
        GpsSample or None
            The fix (the Gauss-Markov errors advance one period on each fix).
        """
        if not self.due(truth.time_s):
            return None
        spec = self.spec
        if self._count > 0:
            eta = self._sigma_ned_m * self._rng.standard_normal(3)
            self._error_ned_m = self._decay * self._error_ned_m + eta
        self._count += 1
        self._next_time_s = self._start_time_s + self._count * spec.period_s
        north, east, down = self._error_ned_m
        lat, lon, alt = pymap3d.ned2geodetic(
            north, east, down, truth.lat_deg, truth.lon_deg, truth.alt_m
        )
        ground_speed_true = truth.ground_speed_mps
        ground_speed = ground_speed_true + spec.ground_speed_sigma_mps * self._rng.standard_normal()
        course_sigma = spec.course_sigma_mps / max(ground_speed_true, 1.0)
        course = truth.course_rad + course_sigma * self._rng.standard_normal()
        velocity_down = None
        if spec.reports_velocity_down:
            assert self._velocity_down_rng is not None
            noise = spec.velocity_down_sigma_mps * self._velocity_down_rng.standard_normal()
            velocity_down = float(truth.velocity_ned_mps[2] + noise)
        return GpsSample(
            time_s=truth.time_s,
            lat_deg=float(lat),
            lon_deg=float(lon),
            alt_m=float(alt),
            ground_speed_mps=float(abs(ground_speed)),
            course_rad=float(math.remainder(course, 2.0 * math.pi)),
            velocity_down_mps=velocity_down,
        )
