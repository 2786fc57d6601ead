"""JSBSim driver of the Aerosonde truth aircraft: initial conditions, trim, lock-step stepping.

One :class:`JsbsimDriver` owns one ``jsbsim.FGFDMExec`` running the project's own aircraft
(``sim/aircraft/aerosonde/aerosonde.xml``, rendered from the shared parameter file by
:mod:`sim.aircraft_xml`). It steps at a fixed ``dt_s`` (0.01 s, 100 Hz) as fast as the machine
allows and returns one immutable :class:`TruthState` per step.

Timing of one step (JSBSim runs Propagate first, then the FCS, aerodynamics and accelerations;
found when the aircraft was built): :meth:`JsbsimDriver.step` sets the controls, calls
``run()`` once, and the
returned record holds the state ``x(t)`` at the new time together with the forces evaluated at
``x(t)`` with those controls. Those forces drive the integration from ``x(t)`` to ``x(t + dt)``
in the next step, so a record's ``controls`` and ``specific_force`` belong to the interval that
starts at its time — the ``x(k+1) = f(x(k), u(k))`` convention of the filter.

The specific force is built from ``forces/fb{x,y,z}-total-lbs`` of the current step divided by
the mass (these forces exclude gravity: aerodynamics and propeller only), never from
``accelerations/a-pilot-*``, which lags one step. With the IMU at the CG
(the parameter file's ``imu_position_m`` is zero) that is exactly what an ideal accelerometer
reads; a non-zero lever arm adds ``omega_dot x r + omega x (omega x r)``.

Frames and units follow ``docs/conventions.md``: NED about a fixed WGS-84 origin (the initial
position), body FRD, ZYX Euler angles, SI units in the names.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import jsbsim
import numpy as np
import pymap3d
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.models.sensors import IMU_PERIOD_S
from immukf_sitl.models.wind import WindSpec
from sim.aircraft_xml import AIRCRAFT_NAME
from sim.truth import InitialConditions, TrimResult, TruthState

__all__ = [
    "JsbsimDriver",
    "JsbsimError",
    "sim_root_dir",
]

_FT = 0.3048  # m per ft
_LBF = 4.4482216152605  # N per lbf
_SLUG = 14.5939029372  # kg per slug
#: ``atmosphere/turb-type`` of JSBSim's MIL-F-8785C Dryden turbulence.
_TURB_MILSPEC_DRYDEN = 3

# Silence JSBSim's banner and load messages (a class-level debug level shared by all instances).
jsbsim.FGJSBBase().debug_lvl = 0


class JsbsimError(RuntimeError):
    """JSBSim could not load the aircraft, or a trim failed to converge."""


def sim_root_dir() -> Path:
    """The JSBSim root directory: the ``sim`` package (``aircraft/``, ``engine/``, ``systems/``)."""
    return Path(__file__).resolve().parent


def _readonly(values: np.ndarray | list[float] | tuple[float, ...]) -> np.ndarray:
    array = np.array(values, dtype=float)
    array.setflags(write=False)
    return array


class JsbsimDriver:
    """Lock-step JSBSim simulation of the Aerosonde.

    Parameters
    ----------
    initial : InitialConditions
        Start position (also the NED origin), airspeed and heading.
    params : AircraftParams, optional
        Aircraft parameters (default: the packaged file). Only the mass and actuator limits are
        read here; the aerodynamics come from the committed XML, which a test keeps equal to a
        rendering of the packaged parameters.
    dt_s : float, optional
        Integration step (s), default 0.01.
    root_dir : pathlib.Path, optional
        JSBSim root directory with ``aircraft/aerosonde/aerosonde.xml`` (default: the ``sim``
        package).

    Raises
    ------
    JsbsimError
        If JSBSim cannot load the aircraft.

    Notes
    -----
    Call :meth:`trim` (or :meth:`reset` with explicit controls) before :meth:`step`. JSBSim's
    earth rotates (WGS-84) while the filter's does not: a deliberate, realistic model mismatch.
    """

    def __init__(
        self,
        initial: InitialConditions | None = None,
        params: AircraftParams | None = None,
        dt_s: float = IMU_PERIOD_S,
        root_dir: Path | None = None,
        wind: WindSpec | None = None,
        turbulence_seed: int = 0,
    ) -> None:
        self.initial = initial if initial is not None else InitialConditions()
        self.params = params if params is not None else load_aircraft_params()
        self.dt_s = float(dt_s)
        root = root_dir if root_dir is not None else sim_root_dir()
        self._fdm = jsbsim.FGFDMExec(os.fspath(root))
        self._fdm.set_debug_level(0)
        if not self._fdm.load_model(AIRCRAFT_NAME):
            raise JsbsimError(f"JSBSim could not load {AIRCRAFT_NAME!r} from {root}")
        self._fdm.set_dt(self.dt_s)
        act = self.params.actuators
        self._limits_rad = np.array(
            [act.elevator.limit_rad, act.aileron.limit_rad, act.rudder.limit_rad]
        )
        self._mass_kg = self._fdm["inertia/mass-slugs"] * _SLUG
        self._imu_m = np.array(self.params.geometry.imu_position_m, dtype=float)
        self._controls = np.array([0.0, 0.0, 0.0, 0.0])
        self._trim: TrimResult | None = None
        self._origin = (self.initial.lat_deg, self.initial.lon_deg, self.initial.alt_m)
        self.wind = wind if wind is not None else WindSpec()
        self._turbulence_seed = int(turbulence_seed) % (2**31 - 1)

    # ------------------------------------------------------------------------------- set-up

    @property
    def origin(self) -> tuple[float, float, float]:
        """NED origin ``(lat_deg, lon_deg, alt_m)``: the position at time 0.

        JSBSim's initial height is set as height above sea level, which differs from the
        WGS-84 ellipsoidal height by millimetres; the origin is the ellipsoidal position JSBSim
        actually starts at, so that the NED position is exactly zero at time 0.
        """
        return self._origin

    def _fix_origin(self) -> None:
        fdm = self._fdm
        self._origin = (
            float(fdm["position/lat-geod-deg"]),
            float(fdm["position/long-gc-deg"]),
            float(fdm["position/geod-alt-ft"] * _FT),
        )

    @property
    def mass_kg(self) -> float:
        """Mass of the JSBSim aircraft (kg)."""
        return float(self._mass_kg)

    @property
    def trim_result(self) -> TrimResult | None:
        """The last trim, if :meth:`trim` was called."""
        return self._trim

    def _set_controls(self, controls: np.ndarray) -> None:
        fdm = self._fdm
        fdm["fcs/elevator-cmd-norm"] = float(controls[0] / self._limits_rad[0])
        fdm["fcs/aileron-cmd-norm"] = float(controls[1] / self._limits_rad[1])
        fdm["fcs/rudder-cmd-norm"] = float(controls[2] / self._limits_rad[2])
        fdm["fcs/throttle-cmd-norm"] = float(controls[3])

    def _set_air(self, calm: bool) -> np.ndarray:
        """Set JSBSim's steady wind and turbulence (still air if ``calm``); the wind, NED m/s."""
        fdm, wind = self._fdm, self.wind
        steady = np.zeros(3) if calm else wind.steady_ned_mps()
        fdm["atmosphere/wind-north-fps"] = steady[0] / _FT
        fdm["atmosphere/wind-east-fps"] = steady[1] / _FT
        fdm["atmosphere/wind-down-fps"] = steady[2] / _FT
        level = wind.level
        if calm or level.name == "none":
            fdm["atmosphere/turb-type"] = 0
        else:
            fdm["atmosphere/randomseed"] = self._turbulence_seed
            fdm["atmosphere/turb-type"] = _TURB_MILSPEC_DRYDEN
            fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = level.w20_mps / _FT
            fdm["atmosphere/turbulence/milspec/severity"] = level.severity_index
        return steady

    def _set_ic(
        self,
        alpha_rad: float,
        beta_rad: float,
        phi_rad: float,
        controls: np.ndarray,
        calm: bool = True,
    ) -> None:
        """Initial conditions at the airspeed, ``alpha``, ``beta`` relative to the air.

        JSBSim's ``ic/{u,v,w}-fps`` are velocities over the ground in body axes: in wind they
        are the air-relative velocity plus the wind rotated into the body, so that the aircraft
        starts trimmed with respect to the air it flies in.
        """
        ic, fdm = self.initial, self._fdm
        wind_ned = np.zeros(3) if calm else self.wind.steady_ned_mps()
        wind_body = (
            Rotation.from_euler("ZYX", [ic.heading_rad, alpha_rad, phi_rad]).as_matrix().T
            @ wind_ned
        ) / _FT
        va_fps = ic.airspeed_mps / _FT
        fdm["ic/lat-geod-deg"] = ic.lat_deg
        fdm["ic/long-gc-deg"] = ic.lon_deg
        fdm["ic/h-sl-ft"] = ic.alt_m / _FT
        fdm["ic/phi-rad"] = phi_rad
        fdm["ic/theta-rad"] = alpha_rad
        fdm["ic/psi-true-rad"] = ic.heading_rad
        fdm["ic/u-fps"] = va_fps * math.cos(alpha_rad) * math.cos(beta_rad) + wind_body[0]
        fdm["ic/v-fps"] = va_fps * math.sin(beta_rad) + wind_body[1]
        fdm["ic/w-fps"] = va_fps * math.sin(alpha_rad) * math.cos(beta_rad) + wind_body[2]
        fdm["ic/p-rad_sec"] = 0.0
        fdm["ic/q-rad_sec"] = 0.0
        fdm["ic/r-rad_sec"] = 0.0
        self._set_controls(controls)
        self._controls = np.array(controls, dtype=float)
        if not fdm.run_ic():
            raise JsbsimError("JSBSim run_ic() failed")
        steady = self._set_air(calm)  # after run_ic, which resets the atmosphere's wind
        if np.any(steady != 0.0) or (not calm and self.wind.level.name != "none"):
            # recompute the state at time 0 in that air (alpha, beta, forces: the first IMU
            # sample and the first step's forces) without advancing time; run_ic computed it
            # in still air, where the wind in the body velocities reads as a sideslip
            fdm.suspend_integration()
            fdm.run()
            fdm.resume_integration()

    def _accelerations(self) -> np.ndarray:
        fdm = self._fdm
        return np.array(
            [
                fdm["accelerations/udot-ft_sec2"] * _FT,
                fdm["accelerations/vdot-ft_sec2"] * _FT,
                fdm["accelerations/wdot-ft_sec2"] * _FT,
                fdm["accelerations/pdot-rad_sec2"],
                fdm["accelerations/qdot-rad_sec2"],
                fdm["accelerations/rdot-rad_sec2"],
            ]
        )

    def trim(self) -> TrimResult:
        """Trim straight, wings-level, constant-altitude flight and reset to it.

        Solves for ``(alpha, beta, delta_e, delta_a, delta_r, delta_t)`` such that the six body
        accelerations vanish at the initial airspeed, altitude and heading with ``phi = 0`` and
        ``theta = alpha`` (zero flight-path angle), on the JSBSim model itself (JSBSim's own trim
        needs a JSBSim engine to adjust the throttle; this aircraft's propeller is an external
        reaction). The propeller torque makes the lateral trim non-zero.

        Returns
        -------
        TrimResult
            The trim; the simulation is left at time 0 in that state.

        Raises
        ------
        JsbsimError
            If the solver does not converge to residual accelerations below 1e-6.
        """
        scale = np.array([1.0, 1.0, 1.0, 10.0, 10.0, 10.0])

        def unpack(z: np.ndarray) -> tuple[float, float, np.ndarray]:
            alpha, beta, de, da, dr, dt = (float(v) for v in z)
            return alpha, beta, np.array([de, da, dr, dt])

        def residual(z: np.ndarray) -> np.ndarray:
            alpha, beta, controls = unpack(z)
            self._set_ic(alpha, beta, 0.0, controls)
            return self._accelerations() * scale

        lower = np.concatenate([[-0.3, -0.3], -self._limits_rad, [0.0]])
        upper = np.concatenate([[0.3, 0.3], self._limits_rad, [1.0]])
        z0 = np.array([0.05, 0.0, -0.1, 0.0, 0.0, 0.8])
        solution = least_squares(residual, z0, bounds=(lower, upper), xtol=1e-14, ftol=1e-14)
        alpha, beta, controls = unpack(solution.x)
        self._set_ic(alpha, beta, 0.0, controls)
        self._fix_origin()
        acc = self._accelerations()
        result = TrimResult(
            controls=_readonly(controls),
            alpha_rad=alpha,
            beta_rad=beta,
            theta_rad=alpha,
            residual_accel_mps2=float(np.max(np.abs(acc[:3]))),
            residual_angular_accel_radps2=float(np.max(np.abs(acc[3:]))),
        )
        if result.residual_accel_mps2 > 1e-6 or result.residual_angular_accel_radps2 > 1e-6:
            raise JsbsimError(
                f"trim did not converge at {self.initial.airspeed_mps} m/s (level flight "
                "needs about 17-33 m/s within the control limits): residual "
                f"{result.residual_accel_mps2:.3g} m/s^2, "
                f"{result.residual_angular_accel_radps2:.3g} rad/s^2"
            )
        self._trim = result
        return result

    def reset(
        self,
        controls: np.ndarray | None = None,
        alpha_rad: float | None = None,
        beta_rad: float = 0.0,
    ) -> TruthState:
        """Restart at the initial conditions (time 0).

        Parameters
        ----------
        controls : numpy.ndarray, optional
            ``(4,)`` controls to hold; default the last trim's.
        alpha_rad : float, optional
            Angle of attack (= pitch, level flight); default the last trim's.
        beta_rad : float, optional
            Sideslip (rad), used only with an explicit ``alpha_rad``.

        Returns
        -------
        TruthState
            The state at time 0.
        """
        if controls is None or alpha_rad is None:
            if self._trim is None:
                self.trim()
            assert self._trim is not None
            if controls is None:
                controls = self._trim.controls
            if alpha_rad is None:
                alpha_rad, beta_rad = self._trim.alpha_rad, self._trim.beta_rad
        self._set_ic(alpha_rad, beta_rad, 0.0, np.asarray(controls, dtype=float), calm=False)
        self._fix_origin()
        return self.truth()

    # ------------------------------------------------------------------------------ stepping

    def step(self, controls: np.ndarray) -> TruthState:
        """Apply the controls and advance one step.

        Parameters
        ----------
        controls : numpy.ndarray
            ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]``; surfaces beyond
            their limits and throttle outside [0, 1] are clipped by the aircraft's FCS.

        Returns
        -------
        TruthState
            The state at the new time with the forces of these controls.
        """
        controls = np.asarray(controls, dtype=float)
        if controls.shape != (4,) or not np.all(np.isfinite(controls)):
            raise ValueError(f"controls: expected 4 finite values, got {controls!r}")
        self._set_controls(controls)
        if not self._fdm.run():
            raise JsbsimError("JSBSim run() returned false")
        return self.truth()

    def _vector(self, names: tuple[str, str, str], scale: float = 1.0) -> np.ndarray:
        """Three JSBSim properties as an array, times ``scale``."""
        fdm = self._fdm
        return np.array([fdm[names[0]], fdm[names[1]], fdm[names[2]]]) * scale

    def _specific_force(self, rates: np.ndarray) -> np.ndarray:
        """True specific force at the IMU (m/s^2) from this step's forces over the mass.

        A lever arm adds ``omega_dot x r + omega x (omega x r)`` when the IMU is not at the CG.
        """
        force_n = self._vector(
            ("forces/fbx-total-lbs", "forces/fby-total-lbs", "forces/fbz-total-lbs"), _LBF
        )
        specific_force = force_n / self._mass_kg
        if np.any(self._imu_m != 0.0):
            omega_dot = self._vector(
                (
                    "accelerations/pidot-rad_sec2",
                    "accelerations/qidot-rad_sec2",
                    "accelerations/ridot-rad_sec2",
                )
            )
            specific_force = (
                specific_force
                + np.cross(omega_dot, self._imu_m)
                + np.cross(rates, np.cross(rates, self._imu_m))
            )
        return specific_force

    def truth(self) -> TruthState:
        """The current true state (see :class:`TruthState`)."""
        fdm = self._fdm
        lat = fdm["position/lat-geod-deg"]
        lon = fdm["position/long-gc-deg"]
        alt = fdm["position/geod-alt-ft"] * _FT
        lat0, lon0, alt0 = self.origin
        north, east, down = pymap3d.geodetic2ned(lat, lon, alt, lat0, lon0, alt0)
        rates = self._vector(
            ("velocities/pi-rad_sec", "velocities/qi-rad_sec", "velocities/ri-rad_sec")
        )
        controls = np.array(
            [fdm["fcs/delta-e-rad"], fdm["fcs/delta-a-rad"], fdm["fcs/delta-r-rad"],
             fdm["fcs/delta-t"]]
        )  # fmt: skip
        euler = self._vector(("attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad"))
        euler[2] = math.remainder(euler[2], 2.0 * math.pi)
        return TruthState(
            time_s=float(fdm["simulation/sim-time-sec"]),
            lat_deg=float(lat),
            lon_deg=float(lon),
            alt_m=float(alt),
            position_ned_m=_readonly([north, east, down]),
            velocity_ned_mps=_readonly(
                self._vector(
                    ("velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps"),
                    _FT,
                )
            ),
            velocity_body_mps=_readonly(
                self._vector(("velocities/u-fps", "velocities/v-fps", "velocities/w-fps"), _FT)
            ),
            euler_rad=_readonly(euler),
            rates_body_radps=_readonly(rates),
            airspeed_mps=float(fdm["velocities/vt-fps"] * _FT),
            alpha_rad=float(fdm["aero/alpha-rad"]),
            beta_rad=float(fdm["aero/beta-rad"]),
            specific_force_body_mps2=_readonly(self._specific_force(rates)),
            controls=_readonly(controls),
            wind_ned_mps=_readonly(
                self._vector(
                    (
                        "atmosphere/total-wind-north-fps",
                        "atmosphere/total-wind-east-fps",
                        "atmosphere/total-wind-down-fps",
                    ),
                    _FT,
                )
            ),
        )

    def get_property(self, name: str) -> float:
        """Read any JSBSim property (for diagnostics and tests)."""
        return float(self._fdm[name])
