"""The filter's model of a real aircraft: the 6-DOF model with wind, sensor and model-error states.

A real aircraft flies in moving air, its IMU has biases, its GPS receiver wanders and its
coefficients are not the book's. The paper's model knows none of these, and a filter built on
it blames every such difference on a sensor (docs/design/real-air-model.md). In the spirit of
vehicle-dynamic-model navigation (Mwenegoha et al., J. Navigation 74(6), 2021: wind and
parameter uncertainty as states) and of every autopilot EKF (ArduPilot EKF3, PX4 EKF2: wind
and IMU biases as states), the state grows by 18 slowly varying quantities:

==========  =====  ==============================================================  =========
states      index  what                                                            unit
==========  =====  ==============================================================  =========
wind        12-14  air mass velocity, NED: the forces see ``v_g - R_bn w``          m/s
force       15-17  specific force the book's model misses (body axes); in the      m/s^2
                   dynamics and in what the accelerometers read
moment      18-20  angular acceleration the book's model misses (body axes)        rad/s^2
gust        21-23  the air's rotation about the aircraft (MIL-F-8785C p_g, q_g,    rad/s
                   r_g, body axes): the forces and moments see ``omega - omega_g``
gyro bias   24-26  added to the body rates the gyros read                          rad/s
GPS error   27-29  the receiver's Gauss-Markov position error, NED (B&M eq. 7.17)  m
==========  =====  ==============================================================  =========

One specific-force correction stands for both an accelerometer bias and a force-model error:
the two differ only in whether the velocity feels them, an effect of the accelerometer bias
(a spec sheet's 0.02 m/s^2) far below what GPS at 1 Hz resolves in minutes, while the force
error of a 10 % airframe is tens of times larger (:func:`model_error_sigmas`). The rigid-body
equations keep the ground velocity; the slow states are held over an integration step and then
decay exactly as first-order Gauss-Markov processes with the rates ``decay_per_s`` (0: a random
walk); the gusts are fast ones (0.1-0.3 s). The states the rigid-body dynamics do not read
(gyro biases, GPS errors) come last: their sigma points fly as the centre does. Their noise
is the filter designer's (``immukf_sitl.service.noise_model``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numba
import numpy as np

from immukf_sitl.models import aero_kernels
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.airframe import AirframeUncertainty, scalable_parameters, scaled_params
from immukf_sitl.models.params import AircraftParams

__all__ = [
    "FORCE",
    "GPS_ERROR",
    "GUST",
    "GYRO_BIAS",
    "HEADING",
    "MOMENT",
    "N_AUGMENTED",
    "N_RIGID",
    "N_SLOW",
    "WIND",
    "SLOW_STATE_LABELS",
    "AugmentedAeroModel",
    "ModelError",
    "model_error_sigmas",
    "heading_tangent",
]

N_RIGID = 12
N_SLOW = aero_kernels.N_EXTRA
N_AUGMENTED = N_RIGID + N_SLOW
# the slow states' groups, as slices of the slow part ``x[12:]`` (add 12 for the full state)
WIND = slice(0, 3)
FORCE = slice(3, 6)
MOMENT = slice(6, 9)
GUST = slice(9, 12)
GYRO_BIAS = slice(12, 15)
GPS_ERROR = slice(15, 18)
SLOW_STATE_LABELS: tuple[str, ...] = (
    "wind_n_mps", "wind_e_mps", "wind_d_mps",
    "force_x_mps2", "force_y_mps2", "force_z_mps2",
    "moment_p_radps2", "moment_q_radps2", "moment_r_radps2",
    "gust_p_radps", "gust_q_radps", "gust_r_radps",
    "gyro_bias_p_radps", "gyro_bias_q_radps", "gyro_bias_r_radps",
    "gps_error_n_m", "gps_error_e_m", "gps_error_d_m",
)  # fmt: skip


@dataclass(frozen=True)
class AugmentedAeroModel:
    """``x = [12 rigid-body states of AeroModel, 18 slow states]`` (module docstring).

    Parameters
    ----------
    aero : AeroModel
        The book's aircraft (its ``dt_s`` is the step).
    decay_per_s : ndarray, shape (18,)
        Inverse time constants of the slow states (1/s); 0 makes a state a random walk.
    """

    aero: AeroModel
    decay_per_s: np.ndarray
    nx: ClassVar[int] = N_AUGMENTED
    state_labels: ClassVar[tuple[str, ...]] = AeroModel.state_labels + SLOW_STATE_LABELS
    angle_indices: ClassVar[tuple[int, ...]] = AeroModel.angle_indices
    _decay_step: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        decay = np.asarray(self.decay_per_s, dtype=float)
        if decay.shape != (N_SLOW,) or np.any(decay < 0.0) or not np.all(np.isfinite(decay)):
            raise ValueError(f"decay_per_s: expected {N_SLOW} finite rates >= 0")
        step = np.exp(-decay * self.aero.dt_s)
        object.__setattr__(self, "_decay_step", step)

    @property
    def dt_s(self) -> float:
        """Integration step (s)."""
        return self.aero.dt_s

    def step(
        self, t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None = None
    ) -> np.ndarray:
        """State after one step: RK4 of the rigid body (slow states held), then their decay.

        ``x`` ``(30, *batch)``; ``u``, ``v`` as :meth:`AeroModel.step`.
        """
        x = np.asarray(x, dtype=float)
        out = np.empty(x.shape)
        out[:N_RIGID] = self.aero.step_with(x[:N_RIGID], u, v, x[N_RIGID:])
        decay = self._decay_step.reshape((N_SLOW,) + (1,) * (x.ndim - 1))
        np.multiply(x[N_RIGID:], decay, out=out[N_RIGID:])
        return out

    def imu(self, t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Noise-free IMU ``(6, *batch)``: air-relative forces, corrections, gyro biases."""
        x = np.asarray(x, dtype=float)
        return self.aero.imu_with(x[:N_RIGID], u, x[N_RIGID:])

    def gps(
        self, t_s: float, x: np.ndarray, u: np.ndarray, velocity_down: bool = False
    ) -> np.ndarray:
        """Noise-free GPS ``(5, *batch)``: position plus the receiver's error, ground velocity.

        ``velocity_down``: ``(6, *batch)``, the vertical velocity last (the receiver's own
        error on it is white: no state).
        """
        x = np.asarray(x, dtype=float)
        return self.aero.gps_with(x[:N_RIGID], x[N_RIGID:], velocity_down)


#: the heading's row of the state (``psi_rad``)
HEADING = AeroModel.state_labels.index("psi_rad")


def heading_tangent(x: np.ndarray) -> np.ndarray:
    """``(B, nx)``: how the states of means ``x (B, nx)`` move per radian of heading unobserved.

    Turning the heading by ``s`` while the ground velocity ``v_n`` and the body's air velocity
    stay (all the IMU and the GPS see in straight flight) turns the body-axis ground velocity,
    ``v_b = R_bn(psi + s) v_n``, and the wind about the ground velocity,
    ``w = v_n - R_z(s) (v_n - w)``: per radian, ``-R_bn (e_z x v_n)`` and
    ``-e_z x (v_n - w)``. Every other state (offsets appended after the model's too) stays.
    Compiled: it runs after every update of every mode.
    """
    x = np.ascontiguousarray(x, dtype=float)
    out = np.zeros(x.shape)
    _heading_tangent(x, N_RIGID + WIND.start, out)
    return out


@numba.njit(cache=True)
def _heading_tangent(x: np.ndarray, wind: int, out: np.ndarray) -> None:
    """:func:`heading_tangent` into ``out`` (zeros), ``wind`` the row of the north wind."""
    for b in range(x.shape[0]):
        sf, cf = math.sin(x[b, 6]), math.cos(x[b, 6])
        st, ct = math.sin(x[b, 7]), math.cos(x[b, 7])
        sp, cp = math.sin(x[b, 8]), math.cos(x[b, 8])
        # R_nb = Rz(psi) Ry(theta) Rx(phi), its north and east rows (earth.body_to_ned)
        r00, r01, r02 = ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp
        r10, r11, r12 = ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp
        u, v, w = x[b, 3], x[b, 4], x[b, 5]
        vn = r00 * u + r01 * v + r02 * w
        ve = r10 * u + r11 * v + r12 * w
        # -R_bn (e_z x v_n), e_z x v_n = (-ve, vn, 0)
        out[b, 3] = -(r00 * -ve + r10 * vn)
        out[b, 4] = -(r01 * -ve + r11 * vn)
        out[b, 5] = -(r02 * -ve + r12 * vn)
        out[b, HEADING] = 1.0
        # -(e_z x (v_n - w)) = (air_e, -air_n, 0)
        out[b, wind] = ve - x[b, wind + 1]
        out[b, wind + 1] = -(vn - x[b, wind])


@dataclass(frozen=True)
class ModelError:
    """1-sigma errors of the book model against an uncertain airframe (body axes).

    Attributes
    ----------
    force_mps2, moment_radps2 : ndarray, shape (3,)
        The error's size: specific force (m/s^2) and angular acceleration (rad/s^2).
    force_variation_mps2, moment_variation_radps2 : ndarray, shape (3,)
        How much of it changes between flight conditions (the rest is a constant offset).
    force_gust_mps2, moment_gust_radps2 : ndarray, shape (3,)
        How much of it a vertical gust changes (zeros without one): the error of a wrong lift
        slope grows with the angle of attack the gust makes.
    """

    force_mps2: np.ndarray
    moment_radps2: np.ndarray
    force_variation_mps2: np.ndarray
    moment_variation_radps2: np.ndarray
    force_gust_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moment_gust_radps2: np.ndarray = field(default_factory=lambda: np.zeros(3))


def model_error_sigmas(
    params: AircraftParams,
    uncertainty: AirframeUncertainty,
    airspeed_mps: float,
    rates_radps: float = 0.2,
    sideslip_rad: float = 0.1,
    gust_attack_rad: float = 0.0,
) -> ModelError:
    """1-sigma errors of the book model's specific force and angular acceleration.

    Each uncertain parameter (every ``C_*``, the mass, the inertias, with the relative sigmas of
    ``uncertainty``) is moved by one sigma alone; the change it makes to the specific force
    ``F/m`` and the angular acceleration is taken at three flight conditions: straight-and-level
    trim at ``airspeed_mps``, that trim with body rates of ``rates_radps`` on all three axes
    (where the damping derivatives act), and with a sideslip of ``sideslip_rad`` (a crosswind
    gust). Per body axis, the error's size is the root sum of squares over the parameters of
    the largest change, and its variation that of the spread of the change across the
    conditions. The gust part is the root sum of squares of the change between trim and trim
    with the angle of attack raised by ``gust_attack_rad`` at the same airspeed (a vertical
    gust of ``gust_attack_rad`` times the airspeed).
    """
    origin_model = AeroModel(params, compiled=False)
    x_trim, u_trim = origin_model.trim(airspeed_mps)
    x_turn = x_trim.copy()
    x_turn[9:12] = rates_radps
    x_slip = x_trim.copy()  # a crosswind gust: sideslip of sideslip_rad, same airspeed
    x_slip[3:6] = airspeed_mps * np.array(
        [math.cos(x_trim[7]) * math.cos(sideslip_rad), math.sin(sideslip_rad),
         math.sin(x_trim[7]) * math.cos(sideslip_rad)]
    )  # fmt: skip
    x_gust = x_trim.copy()  # a vertical gust: (u, w) turned by gust_attack_rad, same airspeed
    turn, lift = math.cos(gust_attack_rad), math.sin(gust_attack_rad)
    x_gust[3] = turn * x_trim[3] - lift * x_trim[5]
    x_gust[5] = lift * x_trim[3] + turn * x_trim[5]
    states = np.stack([x_trim, x_turn, x_slip, x_gust], axis=1)

    def outputs(p: AircraftParams) -> np.ndarray:
        model = dataclasses.replace(origin_model, params=p)
        fm = model.forces_moments(0.0, states, u_trim)
        force = fm[:3] / p.mass.mass_kg
        angular = model.derivatives(0.0, states, u_trim)[9:12]  # moments and gyroscopic terms
        return np.concatenate([force, angular])

    nominal = outputs(params)
    size = np.zeros(6)
    variation = np.zeros(6)
    gust = np.zeros(6)
    names = scalable_parameters(params)
    for name in sorted(names):
        group = names[name][0]
        if name.startswith("C_") and group == "aero":
            sigma = uncertainty.aero
        elif name == "mass_kg":
            sigma = uncertainty.mass
        elif name in ("Jx_kgm2", "Jy_kgm2", "Jz_kgm2", "Jxz_kgm2"):
            sigma = uncertainty.inertia
        else:
            continue
        if sigma == 0.0:
            continue
        try:
            change = outputs(scaled_params(params, {name: 1.0 + sigma})) - nominal
        except ValueError:  # a body that cannot exist (e.g. Jz alone): its draw is never made
            continue
        conditions = change[:, :3]  # trim, turn, slip
        size += np.max(np.abs(conditions), axis=1) ** 2
        variation += (np.max(conditions, axis=1) - np.min(conditions, axis=1)) ** 2
        gust += (change[:, 3] - change[:, 0]) ** 2
    size, variation, gust = np.sqrt(size), np.sqrt(variation), np.sqrt(gust)
    return ModelError(size[:3], size[3:], variation[:3], variation[3:], gust[:3], gust[3:])


def gauss_markov_decay(time_constant_s: float) -> float:
    """Inverse time constant (1/s); an infinite time constant is a random walk (0)."""
    return 0.0 if math.isinf(time_constant_s) else 1.0 / time_constant_s
