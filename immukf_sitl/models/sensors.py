"""What the sensors are: rates, noise and bias of the IMU and the GPS receiver, in one record.

One source of truth for the scenario parser (the user's ``sensors:`` block), the simulation's
sensor models (``sim/sensors.py``) and the filter's measurement noise ``R``. Defaults are those of
Beard & McLain, *Small Unmanned Aircraft*, 2012, ch. 7:

- accelerometers: white noise 0.0025 g = 0.0245 m/s^2; rate gyros 0.13 deg/s = 0.00227 rad/s;
  both at the IMU rate (100 Hz);
- GPS at 1 Hz: north/east and height errors as first-order Gauss-Markov processes
  (B&M eq. 7.17) with driving sigmas 0.21 m and 0.40 m and ``k_GPS = 1/1100`` 1/s; ground speed
  with white noise 0.05 m/s; course with white noise ``0.05 / Vg`` rad.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "DETECTABLE_SIGMAS",
    "IMU_PERIOD_S",
    "IMU_RATE_HZ",
    "MIN_NOISE_FACTOR",
    "NOMINAL_GROUND_SPEED_MPS",
    "GpsSpec",
    "ImuSpec",
    "SensorSpec",
]

#: A fault is detectable once it moves its channel beyond this many of
#: :attr:`ImuSpec.band_sigmas` (one sample in 1.7 million of a healthy sensor's noise).
DETECTABLE_SIGMAS = 5.0
#: A noise fault whose sigma factor is at most this is within what one IMU sample can show: a
#: factor k puts 1 sample in ``2 (1 - Phi(n / k))`` beyond ``n`` noise sigmas of the healthy
#: reading, one a second at 100 Hz with ``n = DETECTABLE_SIGMAS`` for k = 5 / 2.58 = 1.94 (the
#: healthy sensor: one in 1.7 million samples).
MIN_NOISE_FACTOR = 2.0
#: Rate of the IMU, of the simulation step and of the filter step (Hz).
IMU_RATE_HZ = 100.0
#: One IMU period (s): the simulation's and the filter's time step.
IMU_PERIOD_S = 1.0 / IMU_RATE_HZ
#: Ground speed at which the filter evaluates the course sigma ``course_sigma_mps / Vg`` (m/s).
NOMINAL_GROUND_SPEED_MPS = 20.0


def _check_vector3(name: str, values: tuple[float, float, float]) -> None:
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name}: expected 3 finite values, got {values!r}")


@dataclass(frozen=True)
class ImuSpec:
    """Noise and bias of the inertial sensors, body FRD.

    Attributes
    ----------
    accel_sigma_mps2 : float
        White-noise standard deviation of each accelerometer (m/s^2).
    gyro_sigma_radps : float
        White-noise standard deviation of each rate gyro (rad/s).
    accel_bias_mps2, gyro_bias_radps : tuple of float
        Constant biases the simulation adds (m/s^2, rad/s). The filter is never told them.
    accel_bias_sigma_mps2, gyro_bias_sigma_radps : float
        Turn-on bias sigma of the spec sheet (m/s^2, rad/s): the simulation draws a turn-on bias
        per run and per channel from it (added to the constant biases); the filter may use the
        sigma, never the drawn value.
    bias_instability : bool
        Whether the bias also wanders, as a first-order Gauss-Markov process of time constant
        ``bias_time_constant_s`` and stationary sigma ``accel_bias_instability_mps2`` /
        ``gyro_bias_instability_radps``.
    accel_bias_instability_mps2, gyro_bias_instability_radps : float
        Stationary sigma of the wander (defaults: a tactical MEMS IMU's bias instability, about
        0.2 mg and 10 deg/h).
    bias_time_constant_s : float
        Correlation time of the wander (s).
    accel_range_mps2, gyro_range_radps : float
        Full-scale range of the spec sheet: a channel reads within +-range (defaults: the
        +-16 g and +-2000 deg/s of the MEMS IMUs on common autopilot boards). A failed channel
        may read anything in it: the untrusted fault modes' width
        (:mod:`immukf_sitl.estimation.fault_modes`).
    """

    accel_sigma_mps2: float = 0.0245
    gyro_sigma_radps: float = 0.00227
    accel_bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_sigma_mps2: float = 0.0
    gyro_bias_sigma_radps: float = 0.0
    bias_instability: bool = False
    accel_bias_instability_mps2: float = 0.002
    gyro_bias_instability_radps: float = 5e-5
    bias_time_constant_s: float = 300.0
    accel_range_mps2: float = 16.0 * 9.80665
    gyro_range_radps: float = math.radians(2000.0)

    def __post_init__(self) -> None:
        sigmas = {
            "accel_sigma_mps2": self.accel_sigma_mps2,
            "gyro_sigma_radps": self.gyro_sigma_radps,
            "accel_bias_sigma_mps2": self.accel_bias_sigma_mps2,
            "gyro_bias_sigma_radps": self.gyro_bias_sigma_radps,
            "accel_bias_instability_mps2": self.accel_bias_instability_mps2,
            "gyro_bias_instability_radps": self.gyro_bias_instability_radps,
        }
        for name, value in sigmas.items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: expected a value >= 0, got {value}")
        for name in ("accel_range_mps2", "gyro_range_radps"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)}")
        if not self.bias_time_constant_s > 0.0:
            raise ValueError(f"bias_time_constant_s: expected > 0, got {self.bias_time_constant_s}")
        _check_vector3("accel_bias_mps2", self.accel_bias_mps2)
        _check_vector3("gyro_bias_radps", self.gyro_bias_radps)

    @property
    def sigmas(self) -> np.ndarray:
        """White-noise sigmas of ``[f_x, f_y, f_z, p, q, r]`` (m/s^2, rad/s)."""
        return np.array([self.accel_sigma_mps2] * 3 + [self.gyro_sigma_radps] * 3)

    @property
    def ranges(self) -> np.ndarray:
        """Full-scale ranges of ``[f_x, f_y, f_z, p, q, r]`` (m/s^2, rad/s)."""
        return np.array([self.accel_range_mps2] * 3 + [self.gyro_range_radps] * 3)

    def noise_cov(self) -> np.ndarray:
        """``R`` of the six IMU channels (6x6, diagonal)."""
        return np.diag(self.sigmas**2)

    @property
    def bias_sigmas(self) -> np.ndarray:
        """Turn-on bias sigmas of ``[f_x, f_y, f_z, p, q, r]`` (m/s^2, rad/s)."""
        return np.array([self.accel_bias_sigma_mps2] * 3 + [self.gyro_bias_sigma_radps] * 3)

    @property
    def band_sigmas(self) -> np.ndarray:
        """What a healthy channel can read off the truth, 1 sigma: white noise and turn-on bias.

        A fault that moves a channel by less than :data:`DETECTABLE_SIGMAS` of these is one the
        spec sheet allows a healthy sensor (``[f_x, f_y, f_z, p, q, r]``, m/s^2 and rad/s).
        """
        return np.hypot(self.sigmas, self.bias_sigmas)

    def spec_sheet(self) -> ImuSpec:
        """What a filter may be told: the sigmas, without the simulation's true bias values."""
        return dataclasses.replace(
            self, accel_bias_mps2=(0.0, 0.0, 0.0), gyro_bias_radps=(0.0, 0.0, 0.0)
        )


@dataclass(frozen=True)
class GpsSpec:
    """Rate and noise of the GPS receiver.

    Attributes
    ----------
    rate_hz : float
        Fix rate (Hz).
    north_east_sigma_m, height_sigma_m : float
        Driving-noise standard deviations of the Gauss-Markov position errors at a 1 Hz fix
        (m): the error is one process in time, whatever the rate it is sampled at
        (:meth:`driving_sigmas_ned_m`).
    k_gps_per_s : float
        Inverse time constant of the Gauss-Markov errors (1/s).
    ground_speed_sigma_mps : float
        White-noise standard deviation of the ground speed (m/s).
    course_sigma_mps : float
        Course noise numerator: the course sigma is this divided by the ground speed (rad).
    velocity_down_sigma_mps : float
        White-noise standard deviation of the vertical (NED down) velocity (m/s): a Doppler
        velocity, about twice the horizontal one's, as receivers' sheets give it (0.05 m/s
        horizontal, 0.1 m/s vertical).
    reports_velocity_down : bool
        Whether the receiver reports that velocity: the simulated one sends it, and the
        estimator told so fuses it. A receiver measures it, but GPS_RAW_INT has no field for
        it: ArduPilot's and PX4's telemetry drop it (their logs keep it). Told false (the
        default), the estimator leaves a log's ``vD`` out and counts it.
    """

    rate_hz: float = 1.0
    north_east_sigma_m: float = 0.21
    height_sigma_m: float = 0.40
    k_gps_per_s: float = 1.0 / 1100.0
    ground_speed_sigma_mps: float = 0.05
    course_sigma_mps: float = 0.05
    velocity_down_sigma_mps: float = 0.1
    reports_velocity_down: bool = False

    def __post_init__(self) -> None:
        if not self.rate_hz > 0.0:
            raise ValueError(f"rate_hz: expected a value > 0, got {self.rate_hz}")
        if not self.k_gps_per_s >= 0.0:
            raise ValueError(f"k_gps_per_s: expected a value >= 0, got {self.k_gps_per_s}")
        sigmas = (
            self.north_east_sigma_m,
            self.height_sigma_m,
            self.ground_speed_sigma_mps,
            self.course_sigma_mps,
            self.velocity_down_sigma_mps,
        )
        if not all(s >= 0.0 for s in sigmas):
            raise ValueError(f"GPS standard deviations: expected values >= 0, got {sigmas}")

    @property
    def period_s(self) -> float:
        """Time between fixes (s)."""
        return 1.0 / self.rate_hz

    def driving_sigmas_ned_m(self) -> np.ndarray:
        """Driving-noise sigmas (m) the position errors take at each fix, north, east, down.

        The spec's sigmas are a 1 Hz fix's; a receiver ``f`` times faster samples the same
        Gauss-Markov process ``f`` times as often, so each fix takes the share
        ``(1 - exp(-2 k T)) / (1 - exp(-2 k))`` of the variance (``T / 1 s`` for a random walk)
        and the stationary sigma is the 1 Hz one. Taken per fix at 5 Hz, the same numbers made
        a GPS whose height wandered 2.2 times as far (stationary 21 m against 9.4 m).
        """
        base = np.array([self.north_east_sigma_m, self.north_east_sigma_m, self.height_sigma_m])
        k = self.k_gps_per_s
        share = (
            math.expm1(-2.0 * k * self.period_s) / math.expm1(-2.0 * k)
            if k > 0.0
            else (self.period_s / 1.0)
        )
        return base * math.sqrt(share)

    @property
    def course_sigma_rad(self) -> float:
        """Course sigma at :data:`NOMINAL_GROUND_SPEED_MPS` (rad)."""
        return self.course_sigma_mps / NOMINAL_GROUND_SPEED_MPS

    def noise_cov(self, velocity_down: bool = False) -> np.ndarray:
        """``R`` of ``[pN, pE, pD, ground speed, course]`` (diagonal, white noise).

        ``velocity_down``: followed by the vertical velocity's (6x6 instead of 5x5).
        """
        sigmas = [
            self.north_east_sigma_m,
            self.north_east_sigma_m,
            self.height_sigma_m,
            self.ground_speed_sigma_mps,
            self.course_sigma_rad,
        ]
        if velocity_down:
            sigmas.append(self.velocity_down_sigma_mps)
        return np.diag(np.square(sigmas))


@dataclass(frozen=True)
class SensorSpec:
    """The IMU and the GPS receiver: a scenario's ``sensors:`` block."""

    imu: ImuSpec = field(default_factory=ImuSpec)
    gps: GpsSpec = field(default_factory=GpsSpec)

    def spec_sheet(self) -> SensorSpec:
        """What a filter may be told (true bias values removed; sigmas kept)."""
        return SensorSpec(self.imu.spec_sheet(), self.gps)
