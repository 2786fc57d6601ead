"""Strapdown INS mechanisation: the process model of the paper's UKF-3.

The IMU reading drives the state as a known input (the "traditional INS equations" of the
paper, section 3) and GPS observes it. Same earth as :class:`~immukf_sitl.models.aero.AeroModel`:
a flat, non-rotating NED tangent plane at the origin with WGS-84 normal gravity at the origin,
corrected for height by the free-air gradient (see that module for why the flat earth is
enough here). The navigated point is the IMU.

State ``x = [pN, pE, pD (m), vN, vE, vD (m/s), phi, theta, psi (rad)]`` (nx = 9), input
``u = [f_x, f_y, f_z (m/s^2), p, q, r (rad/s)]`` (the HIGHRES_IMU channels, body FRD), process
noise ``v`` (nv = 6) added to the input, i.e. the IMU's own white noise. Array layout: state
axis first, any batch axes after (``docs/conventions.md``).
"""

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from immukf_sitl.models.earth import (
    EULER_LABELS,
    POSITION_NED_LABELS,
    NedOrigin,
    normal_gravity_mps2,
)
from immukf_sitl.models.sensors import IMU_PERIOD_S, ImuSpec

__all__ = ["InsModel"]

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class InsModel:
    """Strapdown INS in local NED: ``x = [pN, pE, pD, vN, vE, vD, phi, theta, psi]``.

    Parameters
    ----------
    origin : NedOrigin
        Origin of the flat NED frame; its latitude and height set the normal gravity.
    dt_s : float
        Integration step of :meth:`step` (s), the IMU period (100 Hz).
    gravity_mps2 : float, optional
        Gravity at the origin; default WGS-84 normal gravity at the origin.
    gravity_gradient_ps2 : float, optional
        ``d g / d pD`` (1/s^2); default the free-air gradient at the origin.
    accel_noise_mps2, gyro_noise_radps : float
        IMU white-noise sigmas of the default Q (Beard & McLain ch. 7).

    Notes
    -----
    ``x`` has shape ``(9, *batch)``; ``u`` ``(6,)`` or ``(6, *batch)``; ``v`` ``(6, *batch)``,
    ``(6,)`` or None. Euler angles are singular at ``|theta| = 90 deg`` (not handled).
    """

    origin: NedOrigin = NedOrigin(0.0, 0.0, 0.0)
    dt_s: float = IMU_PERIOD_S
    gravity_mps2: float | None = None
    gravity_gradient_ps2: float | None = None
    accel_noise_mps2: float = ImuSpec.accel_sigma_mps2
    gyro_noise_radps: float = ImuSpec.gyro_sigma_radps

    nx: ClassVar[int] = 9
    nu: ClassVar[int] = 6
    nv: ClassVar[int] = 6
    state_labels: ClassVar[tuple[str, ...]] = (
        *POSITION_NED_LABELS,
        "vN_mps",
        "vE_mps",
        "vD_mps",
        *EULER_LABELS,
    )
    input_labels: ClassVar[tuple[str, ...]] = ("x", "y", "z", "p", "q", "r")
    gps_labels: ClassVar[tuple[str, ...]] = ("pN_m", "pE_m", "pD_m", "Vg_mps", "chi_rad")
    #: State indices that are wrapped angles (phi, psi; theta never nears +-pi).
    angle_indices: ClassVar[tuple[int, ...]] = (6, 8)

    _g0: float = field(init=False, repr=False, compare=False)
    _dg: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.dt_s > 0.0:
            raise ValueError(f"InsModel.dt_s: expected > 0, got {self.dt_s}")
        if not (self.accel_noise_mps2 > 0.0 and self.gyro_noise_radps > 0.0):
            raise ValueError("InsModel: IMU noise sigmas must be > 0")
        lat, h0 = self.origin.lat_deg, self.origin.alt_m
        g0 = float(normal_gravity_mps2(lat, h0)) if self.gravity_mps2 is None else self.gravity_mps2
        if self.gravity_gradient_ps2 is None:
            dg = float(normal_gravity_mps2(lat, h0 - 0.5) - normal_gravity_mps2(lat, h0 + 0.5))
        else:
            dg = self.gravity_gradient_ps2
        object.__setattr__(self, "_g0", g0)
        object.__setattr__(self, "_dg", dg)

    def process_noise_cov(self) -> np.ndarray:
        """Default Q (6x6) of ``v``: the IMU noise variances on the input channels."""
        sig = np.array([self.accel_noise_mps2] * 3 + [self.gyro_noise_radps] * 3)
        return np.diag(sig**2)

    def derivatives(
        self, t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None = None
    ) -> np.ndarray:
        """State derivative ``(9, *batch)``: ``p_dot = v``, ``v_dot = R_nb f + g``, Euler rates.

        The arguments follow :meth:`AeroModel.derivatives` with a ``(9, *batch)`` state and
        the IMU reading ``[f_x, f_y, f_z, p, q, r]`` as the input ``u`` (``(6,)`` or
        ``(6, *batch)``); ``v`` is noise added to ``u`` (None: zero).
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if v is not None:
            v = np.asarray(v, dtype=float)
            if v.ndim == 1 and u.ndim > 1:
                v = v.reshape((6,) + (1,) * (u.ndim - 1))
            elif u.ndim == 1 and v.ndim > 1:
                u = u.reshape((6,) + (1,) * (v.ndim - 1))
            u = u + v
        out = np.empty(x.shape, dtype=float)
        fx, fy, fz, p, q, r = u[0], u[1], u[2], u[3], u[4], u[5]
        phi, theta, psi = x[6], x[7], x[8]
        sph, cph = np.sin(phi), np.cos(phi)
        sth, cth = np.sin(theta), np.cos(theta)
        sps, cps = np.sin(psi), np.cos(psi)
        sph_sth = sph * sth
        cph_sth = cph * sth
        out[0:3] = x[3:6]
        # v_dot = R_nb f + [0, 0, g(pD)]  (Beard & McLain eq. 3.14 rotation; flat earth)
        out[3] = (
            cth * cps * fx + (sph_sth * cps - cph * sps) * fy + (cph_sth * cps + sph * sps) * fz
        )
        out[4] = (
            cth * sps * fx + (sph_sth * sps + cph * cps) * fy + (cph_sth * sps - sph * cps) * fz
        )
        out[5] = -sth * fx + sph * cth * fy + cph * cth * fz + self._g0 + self._dg * x[2]
        # Beard & McLain eq. (3.16): Euler angle rates
        q_sph_r_cph = q * sph + r * cph
        out[6] = p + q_sph_r_cph * (sth / cth)
        out[7] = q * cph - r * sph
        out[8] = q_sph_r_cph / cth
        return out

    def step(
        self, t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None = None
    ) -> np.ndarray:
        """State after one step ``dt_s``: classical RK4 with u and v held (paper eq. 1).

        Returns
        -------
        numpy.ndarray
            ``(9, *batch)`` state at ``t_s + dt_s`` with phi and psi wrapped to [-pi, pi).
        """
        x = np.asarray(x, dtype=float)
        h = self.dt_s
        k1 = self.derivatives(t_s, x, u, v)
        k2 = self.derivatives(t_s, x + (0.5 * h) * k1, u, v)
        k3 = self.derivatives(t_s, x + (0.5 * h) * k2, u, v)
        k4 = self.derivatives(t_s, x + h * k3, u, v)
        out = x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
        out[6] = (out[6] + math.pi) % _TWO_PI - math.pi
        out[8] = (out[8] + math.pi) % _TWO_PI - math.pi
        return out

    def gps(
        self, t_s: float, x: np.ndarray, u: np.ndarray, velocity_down: bool = False
    ) -> np.ndarray:
        """Predicted GPS ``[pN, pE, pD (m), ground speed (m/s), course (rad)]``.

        Returns
        -------
        numpy.ndarray
            ``(5, *batch)``; ground speed is horizontal, course ``atan2(vE, vN)``;
            ``velocity_down``: ``(6, *batch)``, the state's ``vD`` last.
        """
        x = np.asarray(x, dtype=float)
        out = np.empty((6 if velocity_down else 5, *x.shape[1:]), dtype=float)
        out[0:3] = x[0:3]
        out[3] = np.hypot(x[3], x[4])
        out[4] = np.arctan2(x[4], x[3])
        if velocity_down:
            out[5] = x[5]
        return out
