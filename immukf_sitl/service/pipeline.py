"""The estimator service's logic without sockets: samples in, estimates and events out.

:class:`EstimatorPipeline` takes the decoded stream (SERVO_OUTPUT_RAW, GPS_RAW_INT and
HIGHRES_IMU as :mod:`immukf_sitl.samples`), sets the NED origin at the first GPS fix, aligns
the chosen filter variant on the first IMU sample that has a fix beside it, runs one filter step
per IMU sample and turns mode probabilities into detection events. The MAVLink service
(:mod:`immukf_sitl.mavlink.serve`) and the tlog replay are thin shells around it, so both give
the same answers.

Stream rules, each counted in :class:`StreamCounters`: an IMU sample not newer than the last is
dropped (out of order or duplicate), unless the clock went back by more than ``max_gap_s`` (a
new flight: everything restarts); servo outputs and GPS fixes not newer than the last of their
kind are dropped the same way (``actuator_out_of_order``, ``gps_out_of_order``: a late servo
sample would act as the current controls, a repeated fix would be fused twice), and one more
than ``max_gap_s`` older starts their new stream; a servo time that wrapped (SERVO_OUTPUT_RAW's
``time_usec`` is 32-bit: every 71.6 min) is unwrapped against the IMU clock; a gap of several
IMU periods is bridged by predict-only steps (up to ``max_gap_s``, beyond which the filter
re-aligns); the filter waits for the first actuator sample and the first GPS fix; a fix far
off the estimate is rejected (a run of rejections re-aligns instead); stale servo outputs hold
the decisions; an estimate that diverges (non-finite, or faster than any aircraft) is dropped
and the filter re-aligns. After the detector's settling time the mode-matched filters are
re-seeded from the fault-free one (paper, section 2.A).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.estimation.fault_modes import FaultMode, failure_marginals
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import LocalGeodetic, NedOrigin
from immukf_sitl.models.params import Actuators, AircraftParams
from immukf_sitl.models.sensors import DETECTABLE_SIGMAS, IMU_PERIOD_S, SensorSpec
from immukf_sitl.models.servo_map import ControlMap
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.service.alignment import NavSolution, align
from immukf_sitl.service.control_hold import ControlHold
from immukf_sitl.service.declared_set import DeclaredSetDetector
from immukf_sitl.service.detection import DetectionEvent, DetectorConfig, FaultDetector
from immukf_sitl.service.fault_naming import FaultNamer
from immukf_sitl.service.filter_models import FilterModel, PaperModel
from immukf_sitl.service.filters import (
    AircraftEstimator,
    ControlSensitivity,
    Estimator,
    Observation,
    VariantEstimate,
    build_estimator,
)
from immukf_sitl.service.recent_steps import RecentSteps, Step, rerun
from immukf_sitl.service.stream_rate import StreamRate, averaged_var_scale

#: airspeeds tried, in turn, for the warm-up's steady flight (any aircraft in the params'
#: envelope trims at one of them; the filter itself aligns on the data, not on a trim)
WARM_UP_SPEEDS_MPS = (25.0, 30.0, 35.0, 20.0, 40.0, 45.0, 50.0, 15.0)

#: SERVO_OUTPUT_RAW's ``time_usec`` is a uint32: actuator times repeat modulo this (71.6 min).
ACTUATOR_TIME_WRAP_S = 2**32 * 1e-6


@dataclass(frozen=True)
class PipelineConfig:
    """What the service runs: the variant, its tuning and the detection rule."""

    variant: str = "imm"
    true_mode: FaultMode | None = None
    filter_model: FilterModel = field(default_factory=PaperModel)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    min_align_speed_mps: float = 10.0
    max_gap_s: float = 1.0
    #: a fix whose position is this many sigma (squared, 3 d.o.f.) off the estimate is rejected
    gps_gate_chi2: float = 50.0
    #: added in quadrature to the gate's sigmas: a receiver's slowly wandering error (several
    #: metres, Gauss-Markov) must pass; a glitch of tens of metres or more must not
    gps_gate_floor_m: float = 10.0
    #: after this many rejected fixes in a row the filter re-aligns on the next one
    gps_max_rejections: int = 5
    #: servo outputs older than this many of their own stream's intervals are stale (the
    #: filter steps on, decisions are held); never sooner than ``actuator_timeout_s`` (a fast
    #: stream's jitter on a loaded link)
    actuator_stale_intervals: float = 3.0
    actuator_timeout_s: float = 0.1
    #: below this IMU rate decisions are held (the estimate goes on) and a notice says so
    min_imu_rate_hz: float = 20.0
    #: an estimate faster than this (m/s) has diverged: re-align
    max_speed_mps: float = 150.0

    def __post_init__(self) -> None:
        # a settling time left to the filter model is the filter model's
        object.__setattr__(self, "detector", self.detector.resolved(self.filter_model.settle_s))


@dataclass
class StreamCounters:
    """What the pipeline saw and dropped (reported in the service's stats line).

    ``out_of_order``, ``actuator_out_of_order`` and ``gps_out_of_order`` count IMU samples,
    servo outputs and GPS fixes dropped because they were not newer than the last one of their
    kind (duplicates included). ``actuator_unwrapped`` counts servo samples whose 32-bit time
    had wrapped (expected in a flight longer than 71.6 min, not an error). ``gap_steps`` counts
    IMU samples missing from the stream (against its own rate), ``predict_steps`` the filter's
    predict-only steps (across gaps, and between the samples of a stream slower than the
    filter's step), ``slow_imu_steps`` the steps whose decisions were held because the IMU
    streamed below ``min_imu_rate_hz``. ``gps_velocity_down`` counts the fixes fused with
    their vertical velocity, ``gps_velocity_down_unused`` those that carried one the spec sheet
    does not fuse (``sensors.gps.reports_velocity_down`` false: a log's receiver).
    """

    imu_samples: int = 0
    gps_fixes: int = 0
    gps_velocity_down: int = 0
    gps_velocity_down_unused: int = 0
    actuator_samples: int = 0
    steps: int = 0
    out_of_order: int = 0
    actuator_out_of_order: int = 0
    gps_out_of_order: int = 0
    gap_steps: int = 0
    predict_steps: int = 0
    slow_imu_steps: int = 0
    realignments: int = 0
    restarts: int = 0
    bad_samples: int = 0
    rejected_gps: int = 0
    stale_actuator_steps: int = 0
    diverged: int = 0
    actuator_unwrapped: int = 0


@dataclass(frozen=True)
class EstimateOutput:
    """One filter step's result, ready to publish.

    Attributes
    ----------
    t_s : float
        IMU sample time (s, the sender's clock).
    nav : NavSolution
        Fused estimate, NED about ``origin``.
    lat_deg, lon_deg, alt_m : float
        Fused position, WGS-84.
    modes : tuple of FaultMode
    mode_probabilities : ndarray
    events : tuple of DetectionEvent
    step_us : float
        Wall time of the filter step (us).
    """

    t_s: float
    nav: NavSolution
    lat_deg: float
    lon_deg: float
    alt_m: float
    modes: tuple[FaultMode, ...]
    mode_probabilities: np.ndarray
    events: tuple[DetectionEvent, ...]
    step_us: float


def _warm_up_state(model: AeroModel) -> tuple[np.ndarray, np.ndarray]:
    """A steady flight to compile the kernels on: a trim at the first speed that has one.

    A heavy or slow airframe trims at none of the first speeds; with no trim at all (a params
    file far outside any envelope) the warm-up steps level flight at mid controls, which
    compiles the same kernels.
    """
    for speed_mps in WARM_UP_SPEEDS_MPS:
        try:
            return model.trim(speed_mps)
        except RuntimeError:
            continue
    x0 = np.zeros(12)
    x0[3] = WARM_UP_SPEEDS_MPS[0]
    limits = model.params.actuators
    return x0, 0.5 * (np.asarray(limits.lower_limits) + np.asarray(limits.upper_limits))


class EstimatorPipeline:
    """Samples in, :class:`EstimateOutput` per IMU sample out (after alignment).

    Parameters
    ----------
    params : AircraftParams
        Aircraft (model coefficients and the servo channel map).
    config : PipelineConfig
    """

    def __init__(self, params: AircraftParams, config: PipelineConfig | None = None) -> None:
        self.params = params
        self.config = config if config is not None else PipelineConfig()
        self.counters = StreamCounters()
        self.origin: NedOrigin | None = None
        self.estimator: Estimator | None = None
        self.estimate: VariantEstimate | None = None
        self.detector: FaultDetector | DeclaredSetDetector | None = None
        imu = self.config.sensors.imu
        self._namer = FaultNamer(imu.sigmas, bands=DETECTABLE_SIGMAS * imu.band_sigmas)
        #: SERVO_OUTPUT_RAW -> controls: the params file's channels, or an autopilot's servo map
        self.control_map: Actuators | ControlMap = params.actuators
        self._controls: np.ndarray | None = None
        self._gps_queue: deque[GpsSample] = deque(maxlen=16)
        self._last_imu_s: float | None = None
        #: the filter's own clock: a whole number of its steps (IMU_PERIOD_S) from its start
        self._filter_s: float | None = None
        #: the samples of a stream faster than the filter's step, waiting for theirs
        self._pending: list[np.ndarray] = []
        #: the noise variance of this step's IMU reading over the sensor's R (their mean's)
        self._imu_var_scale = 1.0
        #: the servo outputs held between their samples, and how wrong they may be since
        self._hold = ControlHold()
        #: the model's sensitivity to the controls, about the estimate at the last servo sample
        self._sensitivity: ControlSensitivity | None = None
        self.imu_rate = StreamRate()
        self.actuator_rate = StreamRate()
        self.gps_rate = StreamRate()
        #: how reports name the IMU stream, and what raises its rate (set by serve and replay)
        self.imu_label = "IMU"
        self.rate_hint = ""
        #: one-line notices for the operator (serve sends them as STATUSTEXT), oldest first
        self.notices: list[str] = []
        self._slow_noted = False
        self._actuator_s: float | None = None
        self._last_gps_s: float | None = None
        self._gps_rejections = 0
        self._restart_at_s: float | None = None
        #: the last steps, which a declaration re-runs on the re-based bank
        self._recent = RecentSteps()
        self._geodetic: LocalGeodetic | None = None
        #: the navigation solution of ``self.estimate`` (the GPS gate reuses the last step's)
        self._nav: NavSolution | None = None

    def _frame(self) -> LocalGeodetic:
        """Geodetic <-> NED about the current origin (rebuilt when the origin changes)."""
        assert self.origin is not None
        if self._geodetic is None or self._geodetic.origin is not self.origin:
            self._geodetic = LocalGeodetic(self.origin)
        return self._geodetic

    def warm_up(self) -> None:
        """Build and step the configured filter once on a trimmed state, then forget it.

        The first step compiles the model's numba kernels (seconds on a cold cache); a service
        does it before it reports ready, so that its first real sample is not late.
        """
        origin = NedOrigin(0.0, 0.0, 100.0)
        x0, u0 = _warm_up_state(AeroModel(self.params, origin))
        cfg = self.config
        estimator = build_estimator(
            cfg.variant, self.params, origin, cfg.true_mode, cfg.sensors, cfg.filter_model
        )
        imu = np.array([0.5, 0.0, -9.8, 0.0, 0.0, 0.0])
        gps = np.array([0.0, 0.0, 0.0, float(x0[3]), 0.0])
        est = estimator.initial_estimate(align(0.0, imu, gps), u0, imu)
        est = estimator.step(est, IMU_PERIOD_S, u0, Observation(imu, gps))
        estimator.step(est, 2 * IMU_PERIOD_S, u0, Observation(imu))

    @property
    def aligned(self) -> bool:
        """Whether the filter is running."""
        return self.estimator is not None

    def _unwrapped_actuator_s(self, time_s: float) -> float:
        """A servo time with its 32-bit wraps put back, against the IMU clock.

        A time that lies a whole number of wraps behind the last IMU sample (within
        ``max_gap_s``) is moved there; anything else is taken as it is (a sender that restarted
        is a new stream, not a wrap).
        """
        reference = self._last_imu_s if self._last_imu_s is not None else self._actuator_s
        if reference is None or reference - time_s < 0.5 * ACTUATOR_TIME_WRAP_S:
            return time_s
        wraps = round((reference - time_s) / ACTUATOR_TIME_WRAP_S)
        unwrapped = time_s + wraps * ACTUATOR_TIME_WRAP_S
        if abs(unwrapped - reference) > self.config.max_gap_s:
            return time_s
        self.counters.actuator_unwrapped += 1
        return unwrapped

    def _late(self, time_s: float, last_s: float | None) -> bool:
        """Whether a sample at ``time_s`` is a duplicate or late (not a new stream's)."""
        return last_s is not None and last_s - self.config.max_gap_s <= time_s <= last_s + 1e-6

    def on_actuators(self, sample: ActuatorSample) -> None:
        """Latest servo outputs: the controls acting from the next IMU sample on."""
        counters = self.counters
        counters.actuator_samples += 1
        time_s = self._unwrapped_actuator_s(sample.time_s)
        if self._late(time_s, self._actuator_s):
            counters.actuator_out_of_order += 1
            return
        try:
            self._controls = self.control_map.pwm_to_controls(sample.pwm_us)
            self._hold.add(time_s, self._controls)
            self._sensitivity = None  # taken again about the estimate of the coming step
            self._actuator_s = time_s
            self.actuator_rate.add(time_s)
        except ValueError:
            counters.bad_samples += 1

    def on_gps(self, sample: GpsSample) -> None:
        """A fix; the first one sets the NED origin."""
        self.counters.gps_fixes += 1
        if self._late(sample.time_s, self._last_gps_s):
            self.counters.gps_out_of_order += 1
            return
        self._last_gps_s = sample.time_s
        self.gps_rate.add(sample.time_s)
        if self.origin is None:
            self.origin = NedOrigin(sample.lat_deg, sample.lon_deg, sample.alt_m)
        self._gps_queue.append(sample)

    def _gps_observation(self, t_s: float) -> np.ndarray | None:
        """The newest queued fix not later than ``t_s`` (older ones are superseded).

        ``[pN, pE, pD, ground speed, course]``, and the vertical velocity after them where the
        fix carries a finite one and the spec sheet says the receiver reports it
        (``sensors.gps.reports_velocity_down``). A log's ``vD`` is not fused unless told so: on
        the real-air model it biased the vertical prediction and declared healthy channels in
        fault-free flight (docs/results/gps-velocity-down/); such fixes are counted.
        """
        fix = None
        while self._gps_queue and self._gps_queue[0].time_s <= t_s + 0.5 * IMU_PERIOD_S:
            fix = self._gps_queue.popleft()
        if fix is None or self.origin is None:
            return None
        north, east, down = self._frame().to_ned(fix.lat_deg, fix.lon_deg, fix.alt_m)
        observed = [north, east, down, fix.ground_speed_mps, fix.course_rad]
        velocity_down = fix.velocity_down_mps
        if velocity_down is not None and math.isfinite(velocity_down):
            if self.config.sensors.gps.reports_velocity_down:
                observed.append(velocity_down)
                self.counters.gps_velocity_down += 1
            else:
                self.counters.gps_velocity_down_unused += 1
        return np.array(observed)

    def on_imu(self, sample: ImuSample) -> EstimateOutput | None:
        """Run the filter on one IMU sample; None while waiting or for a dropped sample.

        The filter steps at its model's fixed period (:data:`IMU_PERIOD_S`) on its own clock.
        A sample of a slower stream (or after missing samples) is a longer step: predict-only
        steps up to the sample, then the update with it. The samples of a faster stream are
        averaged over each step (what an IMU's integrated output reports) and the step runs at
        the sample that completes it; the others return None.
        """
        counters = self.counters
        counters.imu_samples += 1
        t_s = sample.time_s
        if self._last_imu_s is not None and t_s < self._last_imu_s - self.config.max_gap_s:
            self._restart(t_s)  # the sender's clock went back: a new flight (e.g. sim restarted)
        if self._last_imu_s is not None and t_s <= self._last_imu_s + 1e-6:
            counters.out_of_order += 1
            return None
        previous_s = self._last_imu_s
        self._last_imu_s = t_s
        self.imu_rate.add(t_s)
        self._note_missing(previous_s, t_s)
        self._note_rate()
        if self._controls is None:
            return None
        self._pending.append(sample.as_array())
        steps = self._filter_steps(t_s)
        if steps == 0:
            return None  # a faster stream: this sample waits for the step it belongs to
        imu = self._pending[0] if len(self._pending) == 1 else np.mean(self._pending, axis=0)
        self._imu_var_scale = averaged_var_scale(
            len(self._pending), self.imu_rate.interval_s, IMU_PERIOD_S
        )
        self._pending.clear()
        gps = self._gps_observation(t_s)
        if self.estimator is not None and steps > 1:
            if (steps - 1) * IMU_PERIOD_S > self.config.max_gap_s:
                counters.realignments += 1
                self.estimator = None
            else:
                self._bridge_gap(t_s - steps * IMU_PERIOD_S, steps - 1)
        if self.estimator is not None and gps is not None:
            gps = self._gate_gps(gps)
        if self.estimator is None:
            if gps is None or gps[3] < self.config.min_align_speed_mps:
                return None
            self._align(t_s, imu, gps)
        out = self._step(t_s, imu, gps)
        speed = float(np.linalg.norm(out.nav.velocity_ned_mps))
        if not (np.all(np.isfinite(out.nav.euler_rad)) and speed < self.config.max_speed_mps):
            counters.diverged += 1
            counters.realignments += 1
            self.estimator = None  # re-align on the next fix; publish nothing from this one
            return None
        return out

    def _filter_steps(self, t_s: float) -> int:
        """How many filter steps bring the filter's clock to the sample at ``t_s`` (0: none yet).

        The filter's clock moves in whole steps, so that a stream whose interval is not a
        multiple of the step (60 Hz, a jittery link) is followed without drift: each sample is
        taken at the step nearest its time (within half a step, or half a sample interval for
        a faster stream, whose last sample of a step then closes it).
        """
        if self._filter_s is None:
            self._filter_s = t_s
            return 1
        interval_s = self.imu_rate.interval_s or IMU_PERIOD_S
        ahead_s = t_s - self._filter_s + 0.5 * min(interval_s, IMU_PERIOD_S)
        steps = max(0, math.floor(ahead_s / IMU_PERIOD_S))
        if steps:
            self._filter_s += steps * IMU_PERIOD_S
            if abs(self._filter_s - t_s) > IMU_PERIOD_S:  # a jump of the sender's clock
                self._filter_s = t_s
        return steps

    def _note_missing(self, previous_s: float | None, t_s: float) -> None:
        """Count the samples missing between two, against the stream's own interval."""
        interval_s = self.imu_rate.interval_s
        if previous_s is not None and interval_s is not None:
            self.counters.gap_steps += max(0, round((t_s - previous_s) / interval_s) - 1)

    def imu_too_slow(self) -> bool:
        """Whether the IMU streams below the rate detection needs (decisions are held)."""
        rate = self.imu_rate.rate_hz
        return rate is not None and rate < 0.95 * self.config.min_imu_rate_hz  # 5 %: jitter

    def _note_rate(self) -> None:
        """Say once that the IMU is too slow for detection, with the rate it needs."""
        if self._slow_noted or not self.imu_too_slow():
            return
        self._slow_noted = True
        rate = self.imu_rate.rate_hz
        hint = f"; {self.rate_hint}" if self.rate_hint else ""
        self.notices.append(
            f"{self.imu_label} at {rate:.1f} Hz: detection needs at least "
            f"{self.config.min_imu_rate_hz:.0f} Hz, decisions held{hint}"
        )

    def take_notices(self) -> list[str]:
        """The notices since the last call (and forget them)."""
        notices, self.notices = self.notices, []
        return notices

    def _restart(self, t_s: float) -> None:
        """Forget the old stream at a clock jump back to ``t_s`` (counted in ``restarts``)."""
        self.counters.restarts += 1
        self.estimator = None
        self.detector = None
        self._last_imu_s = None
        self._filter_s = None
        self._pending.clear()
        self._hold.reset()
        self._sensitivity = None
        for rate in (self.imu_rate, self.actuator_rate, self.gps_rate):
            rate.reset()
        self._gps_rejections = 0
        # fixes of the new stream may already be queued behind the old one's
        fresh = [fix for fix in self._gps_queue if fix.time_s <= t_s + IMU_PERIOD_S]
        self._gps_queue.clear()
        self._gps_queue.extend(fresh)
        self.origin = (
            NedOrigin(fresh[0].lat_deg, fresh[0].lon_deg, fresh[0].alt_m) if fresh else None
        )

    def _gate_gps(self, gps: np.ndarray) -> np.ndarray | None:
        """Reject a fix far outside the estimate's and the receiver's uncertainty."""
        assert self.estimator is not None and self.estimate is not None
        nav = self._nav if self._nav is not None else self.estimator.navigation(self.estimate)
        receiver_var = np.diagonal(self.config.sensors.gps.noise_cov())[:3]
        var = nav.position_sigma_m**2 + receiver_var + self.config.gps_gate_floor_m**2
        d2 = float(np.sum((gps[:3] - nav.position_ned_m) ** 2 / var))
        if (
            d2 <= self.config.gps_gate_chi2
            or self._gps_rejections >= self.config.gps_max_rejections
        ):
            if self._gps_rejections >= self.config.gps_max_rejections:
                self.counters.realignments += 1
                self.estimator = None  # the estimate, not the receiver, is what went wrong
            self._gps_rejections = 0
            return gps
        self._gps_rejections += 1
        self.counters.rejected_gps += 1
        return None

    def _align(self, t_s: float, imu: np.ndarray, gps: np.ndarray) -> None:
        assert self.origin is not None and self._controls is not None
        cfg = self.config
        # a re-alignment keeps what the detector declared: the failed channel is not trusted
        # by the alignment, and the bank starts believing it (a re-basing bank: based on it)
        declared = self.detector.declared if self.detector is not None else None
        estimator = build_estimator(
            cfg.variant, self.params, self.origin, cfg.true_mode, cfg.sensors, cfg.filter_model,
            declared if self.rebases else None,
        )  # fmt: skip
        slowly = None
        if isinstance(self.detector, DeclaredSetDetector):
            slowly = self.detector.declared_slowly
        if slowly is not None and isinstance(estimator, AircraftEstimator):
            estimator = estimator.rebased(declared, slowly)  # released on the fixes, as before
        failed = declared.channels if declared is not None else ()
        # the alignment sample itself is the first step's measurement: start one period earlier
        nav = align(t_s - IMU_PERIOD_S, imu, gps, failed)
        probs = estimator.probabilities_believing(declared)
        self.estimate = estimator.initial_estimate(nav, self._controls, imu, probs)
        self._sensitivity = None  # of the new estimator's state
        self._nav = None
        self.estimator = estimator
        if self.detector is None:
            self.detector = (
                DeclaredSetDetector(cfg.detector, t_s)
                if self.rebases
                else FaultDetector(estimator.modes, cfg.detector, t_s)
            )
        else:
            self.detector.start_s = t_s  # settle again; what was declared stays declared
        self._restart_at_s = t_s + cfg.detector.settling()

    def _bridge_gap(self, start_s: float, steps: int) -> None:
        """Predict ``steps`` filter steps after ``start_s`` with the last controls, no update.

        Across missing samples, or up to the next sample of a stream slower than the step.
        """
        assert self.estimator is not None and self.estimate is not None
        assert self._controls is not None
        nothing = Observation(np.full(6, np.nan))  # non-finite: the UKF skips its update
        self._nav = None
        self.counters.predict_steps += steps
        for k in range(1, steps + 1):
            t_s = start_s + k * IMU_PERIOD_S
            self._recent.record(Step(self.estimator, self.estimate, t_s, self._controls, nothing))
            self.estimate = self.estimator.step(self.estimate, t_s, self._controls, nothing)

    @property
    def rebases(self) -> bool:
        """Whether the bank re-bases on each declaration (the untrusted modes' IMM).

        The paper's zero modes keep its fixed bank of seven single faults, so that its study
        reproduces; untrusted modes declare and release channels one at a time over the bank
        about the declared set (:mod:`immukf_sitl.service.declared_set`).
        """
        cfg = self.config
        return cfg.variant == "imm" and cfg.filter_model.fault_signature == "untrusted"

    def _decide(self, t_s: float, est: VariantEstimate, imu: np.ndarray) -> list[DetectionEvent]:
        """The detector's events at this step, the namings that fell due, and the re-base.

        An untrusted declaration is named (:mod:`immukf_sitl.service.fault_naming`) from the
        readings of the window after it, by the base filter that no longer trusts the channel;
        a zero mode's failure is the zero its declaration tested. A declaration or release of
        the re-basing detector moves the bank onto the new declared set.
        """
        assert self.estimator is not None and self.detector is not None
        self._namer.record(t_s, imu)
        innovations = self.estimator.channel_innovations(est)
        sigmas = self.config.sensors.imu.sigmas * math.sqrt(self._imu_var_scale)
        bank = est.filter
        events = self.detector.update(
            t_s, est.mode_probabilities, imu, sigmas, innovations, bank.failure_weights,
            bank.log_likelihoods if bank.updated else None, bank.outliers,
            None if bank.rest_ratios is None else (bank.rest_ratios, bank.rest_nis, bank.rest_dof),
        )  # fmt: skip
        names = []
        naming = self._namer.pending
        if naming:  # the naming residuals only while a declaration waits for them
            residuals = self.estimator.naming_innovations(est)
            names = [] if residuals is None else self._namer.observe(t_s, imu, *residuals)
        for k, event in enumerate(events):
            channel = int(np.flatnonzero(event.mode.healthy_mask == 0.0)[0])
            if event.kind == "cleared":
                self._namer.released(channel)
            elif event.kind == "detected" and not self.rebases:
                events[k] = dataclasses.replace(event, failure="zero")  # what the test showed
            elif event.kind == "detected":
                self._namer.declared(0, channel, t_s)  # the re-based bank's base distrusts it
        marginals = failure_marginals(self.estimator.modes, est.mode_probabilities)
        for channel, name in names:
            if isinstance(self.detector, DeclaredSetDetector):
                self.detector.named(channel, name.kind, name.size, t_s)
            p = float(marginals[1 + channel])  # the belief that the channel failed
            events.append(
                DetectionEvent("named", FaultMode(1 << channel), t_s, p, name.kind, name.size)
            )
        if isinstance(self.detector, DeclaredSetDetector) and any(
            e.kind in ("detected", "cleared") for e in events
        ):
            self._rebase(declared=any(e.kind == "detected" for e in events))
        if naming or any(e.kind in ("detected", "cleared") for e in events):
            self._hold_named_errors()
        return events

    def _hold_named_errors(self) -> None:
        """Hold each declared channel's drift rate and gain where its last name knows them.

        Only a name that is not to be looked at again: a bias, a drift, a gain or a noise named
        in the first second is provisional (a drift or a gain slow to show passes for a bias then),
        and held at it, the second look no longer saw what the name missed.
        """
        if not isinstance(self.detector, DeclaredSetDetector):
            return
        assert isinstance(self.estimator, AircraftEstimator) and self.estimate is not None
        holds = self.detector.error_holds()
        known = {c: v for c, v in holds.items() if not self._namer.looking(c)}
        held = self.estimator.holding(known)
        if held is not self.estimator:
            self.estimate = held.carried_over(self.estimate, self.estimator)
            self.estimator = held

    def _rebase(self, declared: bool) -> None:
        """Move the bank and its estimate onto the detector's declared set.

        A declaration also re-runs the re-based bank from the step at which the declared
        failure took the lead (:mod:`~immukf_sitl.service.recent_steps`), and keeps the re-run
        where a slot that adds a failure out-scored the base over it by ``ln(q / (1 - q))``
        (``q = signature_quantile``): a channel that failed at once with the declared one,
        which the estimate at the declaration has followed. Elsewhere the bank goes on from
        that estimate.
        """
        assert isinstance(self.estimator, AircraftEstimator) and self.estimate is not None
        assert isinstance(self.detector, DeclaredSetDetector)
        rebased = self.estimator.rebased(self.detector.declared, self.detector.declared_slowly)
        since = self.detector.failing_since_s if declared else None
        steps = [] if since is None else self._recent.taken_by(self.estimator, since)
        self._recent.clear()
        moved = self._carried_over(rebased, self.estimate, declared)
        if steps:
            start = self._carried_over(rebased, steps[0].estimate, declared)
            rerun_estimate, evidence = rerun(rebased, start, steps)
            base = rebased.modes[0].bits
            new = [j for j, mode in enumerate(rebased.modes) if mode.bits & ~base]
            if new and float(np.max(evidence[new])) >= self.detector.sustained_nats:
                moved = rerun_estimate
        self.estimate = moved
        self.estimator = rebased
        self._sensitivity = None  # of the re-based bank's state

    def _carried_over(
        self, rebased: AircraftEstimator, estimate: VariantEstimate, declared: bool
    ) -> VariantEstimate:
        """``estimate`` on the re-based bank's slots.

        A declaration is a belief: where the evidence that made it is not the probabilities
        (the slow test), or where the base had not won yet (the start of a re-run), the
        re-based bank's base starts at 0.99.
        """
        assert isinstance(self.estimator, AircraftEstimator) and self.detector is not None
        moved = rebased.carried_over(estimate, self.estimator)
        if declared and moved.filter.mode_probabilities[0] < self.detector.config.threshold:
            probs = rebased.probabilities_believing(self.detector.declared)
            bank = moved.filter
            moved = dataclasses.replace(
                moved,
                filter=dataclasses.replace(
                    bank, mode_probabilities=probs, log_mode_probabilities=np.log(probs)
                ),
            )
        return moved

    def _held_controls(self, t_s: float) -> tuple[np.ndarray | None, ControlSensitivity | None]:
        """The variance of the held controls' error at ``t_s`` and the model's sensitivity.

        The sensitivity is taken once per servo sample, about the estimate at the first step
        that holds it: it moves with the flight condition, not from step to step.
        """
        assert self.estimator is not None and self.estimate is not None
        var = self._hold.variance(t_s)
        if var is None or not var.any():
            return None, None
        if self._sensitivity is None:
            self._sensitivity = self.estimator.control_sensitivity(self.estimate)
        return var, self._sensitivity

    def _failed_var_scale(self) -> np.ndarray | None:
        """How the modes that take a declared channel for failed read it: its named noise."""
        if isinstance(self.detector, DeclaredSetDetector):
            return self.detector.read_var_scales()
        return None

    def _actuators_stale(self, t_s: float) -> bool:
        """Whether the servo outputs are older than a few of their own stream's intervals."""
        if self._actuator_s is None:
            return True
        limit_s = self.config.actuator_timeout_s
        interval_s = self.actuator_rate.interval_s
        if interval_s is not None:
            limit_s = max(limit_s, self.config.actuator_stale_intervals * interval_s)
        return t_s - self._actuator_s > limit_s

    def _step(self, t_s: float, imu: np.ndarray, gps: np.ndarray | None) -> EstimateOutput:
        assert self.estimator is not None and self.detector is not None
        assert self.estimate is not None
        assert self._controls is not None and self.origin is not None
        start = time.perf_counter()
        observation = Observation(
            imu, gps, self._imu_var_scale, *self._held_controls(t_s), self._failed_var_scale()
        )
        self._recent.record(Step(self.estimator, self.estimate, t_s, self._controls, observation))
        est = self.estimator.step(self.estimate, t_s, self._controls, observation)
        if self._restart_at_s is not None and t_s >= self._restart_at_s:
            self._recent.clear()
            # the odds the modes took while the filters converged from the alignment measure
            # that convergence (S >> R), not the sensors: they restart at the prior (what the
            # detector declared stays believed); the seed still distrusts the leading mode's
            # failed channels
            probs = self.estimator.probabilities_believing(self.detector.declared)
            est = self.estimator.restart_from_fault_free(est, probs)
            self._restart_at_s = None
        self.estimate = est
        step_us = (time.perf_counter() - start) * 1e6
        self.counters.steps += 1
        nav = self.estimator.navigation(est)
        self._nav = nav
        north, east, down = (float(c) for c in nav.position_ned_m)
        lat, lon, alt = self._frame().to_geodetic(north, east, down)
        modes = self.estimator.modes  # a decision may re-base the bank for the next step
        if self._actuators_stale(t_s):
            # the model's controls are old: its predictions (and so the modes' odds) are not
            # to be trusted; hold decisions until servo outputs arrive again
            self.counters.stale_actuator_steps += 1
            events = []
        elif self.imu_too_slow():
            self.counters.slow_imu_steps += 1
            events = []
        else:
            events = self._decide(t_s, est, imu)
        return EstimateOutput(
            t_s,
            nav,
            lat,
            lon,
            alt,
            modes,
            est.mode_probabilities,
            tuple(events),
            step_us,
        )
