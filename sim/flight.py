"""The in-process simulation loop: JSBSim driver + autopilot + sensor models, one record a step.

:class:`Flight` is the loop's state machine (start, then one :meth:`Flight.step` per 0.01 s);
:func:`fly` runs it on truth navigation and yields the records. The SITL MAVLink emitter wraps a
:class:`Flight`: per record it sends HIGHRES_IMU (``record.imu``), SERVO_OUTPUT_RAW
(``record.controls``) and, when present, GPS_RAW_INT (``record.gps``); it flies on truth. The
closed loop, in which the autopilot flies on the estimator's
:class:`~sim.autopilot.NavigationState` (``Flight.step(navigation=...)``), is what the in-process
experiments fly (:mod:`immukf_sitl.experiments.inprocess`, ``immukf-sitl experiment``).

Timing (see :mod:`sim.driver`): record ``k`` holds the true state at ``t_k``, the controls that
act from ``t_k`` (so the forces, the IMU's specific force and the controls of one record belong
together), and the IMU sample of ``t_k``. The autopilot computes the controls of record ``k+1``
from the navigation state of record ``k`` (one step of computation delay).

Manoeuvres (a scenario's control doublets, :class:`~immukf_sitl.scenario.ManoeuvreSpec`) are added
to the autopilot's command of their surface for the record whose time falls inside the doublet,
then clipped to the surface limits; the autopilot does not see them (its integrators and slew
limits act on its own command), so it reacts to the doublet only through the aircraft's motion.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.models.sensors import IMU_PERIOD_S, GpsSpec, ImuSpec
from immukf_sitl.models.wind import WindSpec
from immukf_sitl.samples import GpsSample, ImuSample
from immukf_sitl.scenario import FlightPlan, ManoeuvreSpec
from sim.autopilot import Autopilot, AutopilotGains, AutopilotStatus, NavigationState
from sim.driver import JsbsimDriver
from sim.sensors import GpsModel, ImuModel
from sim.truth import InitialConditions, TrimResult, TruthState

__all__ = ["Flight", "FlightRecord", "fly"]


#: Children of ``numpy.random.SeedSequence(seed)`` of the sim's random sources beyond the IMU
#: noise (0) and the GPS (1): the fault proxy uses 2, the airframe draw 3
#: (:data:`immukf_sitl.models.airframe.AIRFRAME_STREAM_INDEX`).
TURBULENCE_STREAM_INDEX = 4
IMU_BIAS_STREAM_INDEX = 5
#: seed spawn key of the GPS receiver's vertical-velocity noise
GPS_VELOCITY_DOWN_STREAM_INDEX = 7


@dataclass(frozen=True)
class FlightRecord:
    """Everything that happened at one simulation step.

    Attributes
    ----------
    step : int
        Step index (0 at the initial conditions).
    truth : TruthState
        True state at this step.
    controls : numpy.ndarray
        ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` acting from this step
        (docs/conventions.md); equal to ``truth.controls``.
    imu : ImuSample
        IMU sample of this step.
    gps : GpsSample or None
        GPS fix, when one is due at this step.
    autopilot : AutopilotStatus or None
        The autopilot's commands that produced ``controls`` (``None`` at step 0, which holds
        the trim).
    """

    step: int
    truth: TruthState
    controls: np.ndarray
    imu: ImuSample
    gps: GpsSample | None
    autopilot: AutopilotStatus | None

    @property
    def time_s(self) -> float:
        """Simulation time of the record (s)."""
        return self.truth.time_s


class Flight:
    """Driver, autopilot and sensors stepped together.

    Parameters
    ----------
    plan : FlightPlan
        Waypoints for the autopilot.
    seed : int
        Seed of every noise source (the IMU and the GPS get independent streams spawned from
        it); the same seed gives the same flight.
    initial : InitialConditions, optional
        Start position and airspeed (default :class:`~sim.driver.InitialConditions`).
    params : AircraftParams, optional
        Aircraft parameters (default: the packaged file).
    imu_spec : ImuSpec, optional
        IMU noise (default: B&M values).
    gps_spec : GpsSpec, optional
        GPS noise and rate (default: B&M values, 1 Hz).
    gains : AutopilotGains, optional
        Autopilot gains.
    dt_s : float, optional
        Step (s), default 0.01.
    manoeuvres : sequence of ManoeuvreSpec, optional
        Control doublets added on top of the autopilot's commands (default none).
    wind : WindSpec, optional
        Steady wind and turbulence of JSBSim's atmosphere (default still air).
    root_dir : Path, optional
        JSBSim root directory holding the aircraft (default the packaged one; a perturbed
        airframe is rendered into a directory of its own).
    """

    def __init__(
        self,
        plan: FlightPlan,
        seed: int,
        initial: InitialConditions | None = None,
        params: AircraftParams | None = None,
        imu_spec: ImuSpec | None = None,
        gps_spec: GpsSpec | None = None,
        gains: AutopilotGains | None = None,
        dt_s: float = IMU_PERIOD_S,
        manoeuvres: Sequence[ManoeuvreSpec] = (),
        wind: WindSpec | None = None,
        root_dir: Path | None = None,
    ) -> None:
        self.params = params if params is not None else load_aircraft_params()
        self.plan = plan
        self.seed = int(seed)
        turbulence_sequence = np.random.SeedSequence(
            self.seed, spawn_key=(TURBULENCE_STREAM_INDEX,)
        )
        turbulence_seed = int(turbulence_sequence.generate_state(1)[0])
        self.driver = JsbsimDriver(
            initial=initial,
            params=self.params,
            dt_s=dt_s,
            root_dir=root_dir,
            wind=wind,
            turbulence_seed=turbulence_seed,
        )
        imu_seed, gps_seed = np.random.SeedSequence(self.seed).spawn(2)
        bias_seed = np.random.SeedSequence(self.seed, spawn_key=(IMU_BIAS_STREAM_INDEX,))
        self.imu = ImuModel(
            imu_spec if imu_spec is not None else ImuSpec(),
            np.random.default_rng(imu_seed),
            bias_rng=np.random.default_rng(bias_seed),
            dt_s=dt_s,
        )
        velocity_down_seed = np.random.SeedSequence(
            self.seed, spawn_key=(GPS_VELOCITY_DOWN_STREAM_INDEX,)
        )
        self.gps = GpsModel(
            gps_spec if gps_spec is not None else GpsSpec(),
            np.random.default_rng(gps_seed),
            velocity_down_rng=np.random.default_rng(velocity_down_seed),
        )
        self._gains = gains
        self.manoeuvres = tuple(manoeuvres)
        #: factors of the parameters that differ from the book's (see ``airframe.py``)
        self.airframe_factors: dict[str, float] = {}
        self._autopilot: Autopilot | None = None
        self._last: FlightRecord | None = None

    @property
    def trim(self) -> TrimResult:
        """The trim the flight started from (after :meth:`start`)."""
        result = self.driver.trim_result
        if result is None:
            raise RuntimeError("Flight.start() has not been called")
        return result

    @property
    def autopilot(self) -> Autopilot:
        """The autopilot (after :meth:`start`)."""
        if self._autopilot is None:
            raise RuntimeError("Flight.start() has not been called")
        return self._autopilot

    @property
    def origin(self) -> tuple[float, float, float]:
        """NED origin ``(lat_deg, lon_deg, alt_m)`` of the truth positions."""
        return self.driver.origin

    def _record(self, step: int, truth: TruthState, status: AutopilotStatus | None) -> FlightRecord:
        record = FlightRecord(
            step=step,
            truth=truth,
            controls=truth.controls,
            imu=self.imu.read(truth),
            gps=self.gps.read(truth),
            autopilot=status,
        )
        self._last = record
        return record

    def start(self) -> FlightRecord:
        """Trim, reset to time 0 and return the first record (controls = trim)."""
        trim = self.driver.trim()
        truth = self.driver.reset()
        act = self.params.actuators
        self._autopilot = Autopilot(
            self.plan,
            trim,
            self.driver.dt_s,
            act.lower_limits,
            act.upper_limits,
            gains=self._gains,
        )
        return self._record(0, truth, None)

    def apply_manoeuvres(self, controls: np.ndarray, time_s: float) -> np.ndarray:
        """Add the doublets active at ``time_s`` to the controls, clipped to the limits.

        Parameters
        ----------
        controls : numpy.ndarray
            ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` from the autopilot.
        time_s : float
            Time of the record the controls act in (s).

        Returns
        -------
        numpy.ndarray
            ``(4,)`` controls with the doublets, within ``params.actuators`` limits.
        """
        out = np.array(controls, dtype=float)
        for manoeuvre in self.manoeuvres:
            out[manoeuvre.control_index] += manoeuvre.offset_rad(time_s)
        act = self.params.actuators
        return np.clip(out, act.lower_limits, act.upper_limits)

    def step(self, navigation: NavigationState | None = None) -> FlightRecord:
        """Advance one step.

        Parameters
        ----------
        navigation : NavigationState, optional
            What the autopilot flies on: default the truth of the last record (open loop); pass
            the estimator's state to fly closed loop.

        Returns
        -------
        FlightRecord
            The record of the new step.
        """
        if self._last is None or self._autopilot is None:
            raise RuntimeError("Flight.start() has not been called")
        nav = navigation if navigation is not None else NavigationState.from_truth(self._last.truth)
        controls = self._autopilot.update(nav)
        if self.manoeuvres:
            controls = self.apply_manoeuvres(controls, self._last.time_s + self.driver.dt_s)
        truth = self.driver.step(controls)
        return self._record(self._last.step + 1, truth, self._autopilot.status)


def fly(
    plan: FlightPlan,
    seed: int,
    duration_s: float,
    initial: InitialConditions | None = None,
    params: AircraftParams | None = None,
    imu_spec: ImuSpec | None = None,
    gps_spec: GpsSpec | None = None,
    gains: AutopilotGains | None = None,
    manoeuvres: Sequence[ManoeuvreSpec] = (),
    wind: WindSpec | None = None,
) -> Iterator[FlightRecord]:
    """Fly a plan on truth navigation and yield one record per 0.01 s step.

    Parameters
    ----------
    plan : FlightPlan
        Waypoints.
    seed : int
        Seed of all sensor noise.
    duration_s : float
        Simulated time (s); records from 0 to ``duration_s`` inclusive.
    initial, params, imu_spec, gps_spec, gains, manoeuvres, wind
        As for :class:`Flight`.

    Yields
    ------
    FlightRecord
        Step 0 (trim) first, then every step.
    """
    flight = Flight(
        plan,
        seed,
        initial=initial,
        params=params,
        imu_spec=imu_spec,
        gps_spec=gps_spec,
        gains=gains,
        manoeuvres=manoeuvres,
        wind=wind,
    )
    record = flight.start()
    yield record
    steps = int(round(duration_s / flight.driver.dt_s))
    for _ in range(steps):
        yield flight.step()
