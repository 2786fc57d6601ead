"""Per-run metrics of a campaign, as the paper defines them, and the critical-failure criterion.

Definitions (docs/results/paper/report.md repeats them for readers of the tables):

- **Window.** Every error counts from the end of the settling period after the filter's first
  estimate (3 s by default, the pipeline's ``settle_s``) to the end of the flight.
- **Estimate error**: position as the distance between the estimate and the true aircraft (m);
  attitude as the norm of the wrapped roll, pitch and yaw errors (deg). Max and mean square.
- **Control error**: the true aircraft against what the autopilot was asked to fly. Position:
  the distance from the desired path, ``hypot(cross-track from the active leg, height minus the
  autopilot's altitude reference)`` (m). Attitude: the norm of the true roll and pitch minus the
  autopilot's roll and pitch commands (deg); the autopilot commands no yaw (its lateral loop
  commands a course, then a roll), so yaw has no commanded value. Max and mean square.
- **Critical failure** (the paper's Table 2 "x"), the first of, from the end of the settling
  period: *corridor* (the true aircraft more than ``lateral_m`` from the desired path or
  ``vertical_m`` from the altitude reference), *ground* (true height below ``ground_alt_m``),
  *diverged* (the estimate more than ``estimate_position_m`` or ``estimate_attitude_deg`` from
  truth, or no estimate for more than a second: the pipeline dropped a diverged one). A run
  with none of them is *stable* ("maintain flight").
- **IMM figures**: the detection delay counts from the later of the fault and the moment it
  became observable (docs/scenarios.md, "What to expect in steady flight"); a run *identifies*
  its fault when the first declaration at or after the fault names the true mode (a fault-free
  run: no declaration at all); false declarations are those of a mode other than the active one.
- **After the declaration**: the attitude MSE and the largest position error of the estimate
  from the declaration that names the fault's channel to the end of the flight, to compare
  with the same air's and airframe's fault-free flight (survival); a fault-free IMM run gives
  them from its own drawn onset on, the same phase of flight. Beside them the attitude's
  consistency over the same window: the mean of the roll, pitch and yaw errors squared, each
  over the variance the filter gave it (its normalised estimation error squared per axis,
  1 for a filter whose sigmas are right; 9 means the errors run three times the sigmas).
- **Pair runs** (two channels, the second failing a gap after the first): the run's
  identification columns describe the first fault (the first declaration at or after it must
  name the first channel), the ``second_*`` columns the second; each channel's detection is the
  declaration that added it to the declared set, and the second is *identified within 1 s*
  when that came at most 1 s after it became observable.
- **Fault-free exposure** (the denominator of the false declarations per hour): the time a run
  flies with healthy sensors and the detector listening, from the end of the settling period
  after the first estimate to the fault (the end of the flight, for a fault-free run, or where a
  critical failure stopped it). Its false declarations are the declarations inside that window
  (any declaration there is false: no channel is dead yet). :func:`false_declaration_rate` pools
  them over *distinct flights*: a campaign's runs of one replicate, air, loop, variant and filter
  model share their random numbers (common random numbers), so until its fault each is the same
  flight as the fault-free run; counted per run, a held-out draw's 387 runs of 120 s made 4.9 h
  of "fault-free flight" out of 0.27 h flown, and one false declaration 43.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from immukf_sitl.experiments.campaign import FailureCriterion, RunSpec
from immukf_sitl.experiments.inprocess import InProcessRun
from immukf_sitl.experiments.report import Summary, declared_at_end
from sim.autopilot import NavigationState, wrap_angle_rad
from sim.flight import FlightRecord

#: an estimate older than this (s) means the pipeline stopped publishing (diverged, re-aligning)
STALE_ESTIMATE_S = 1.0


def path_errors_m(record: FlightRecord) -> tuple[float, float]:
    """``(cross-track, height error)`` of the true aircraft against the desired path (m).

    Parameters
    ----------
    record : FlightRecord
        A record with autopilot commands (not step 0).

    Returns
    -------
    tuple of float
        Signed distance right of the active leg, and true height minus the altitude reference.
    """
    status = record.autopilot
    assert status is not None
    start = np.array(status.leg_start_ne_m)
    leg = np.array(status.leg_target_ne_m) - start
    chi = math.atan2(leg[1], leg[0])
    offset = record.truth.position_ned_m[:2] - start
    cross = -math.sin(chi) * offset[0] + math.cos(chi) * offset[1]
    return cross, record.truth.alt_m - status.altitude_ref_m


def attitude_control_error_deg(record: FlightRecord) -> np.ndarray:
    """True roll and pitch minus the autopilot's roll and pitch commands (deg, wrapped)."""
    status = record.autopilot
    assert status is not None
    euler = record.truth.euler_rad
    return np.degrees(
        [
            wrap_angle_rad(float(euler[0]) - status.roll_cmd_rad),
            wrap_angle_rad(float(euler[1]) - status.pitch_cmd_rad),
        ]
    )


def estimate_errors(record: FlightRecord, nav: NavigationState) -> tuple[float, float]:
    """``(position error m, attitude error deg)`` of an estimate against the record's truth."""
    position = float(np.linalg.norm(nav.position_ned_m - record.truth.position_ned_m))
    return position, math.degrees(math.sqrt(sum(d * d for d in attitude_errors_rad(record, nav))))


def attitude_errors_rad(record: FlightRecord, nav: NavigationState) -> list[float]:
    """Roll, pitch and yaw of the estimate less the record's truth, each wrapped (rad)."""
    return [
        wrap_angle_rad(float(a - b))
        for a, b in zip(nav.euler_rad, record.truth.euler_rad, strict=True)
    ]


class FailureMonitor:
    """The critical-failure criterion as a per-step check (a :data:`StopCheck`).

    Parameters
    ----------
    criterion : FailureCriterion
    settle_s : float
        Checks start this long after the first estimate.
    """

    def __init__(self, criterion: FailureCriterion, settle_s: float) -> None:
        self.criterion = criterion
        self.settle_s = settle_s
        self.first_estimate_s: float | None = None
        self.reason: str | None = None
        self.t_s: float | None = None

    def __call__(self, record: FlightRecord, nav: NavigationState | None) -> str | None:
        """The failure this step shows (once one is found, it stops the flight if asked to)."""
        if nav is None or self.reason is not None:
            return None
        if self.first_estimate_s is None:
            self.first_estimate_s = nav.time_s
        if record.time_s < self.first_estimate_s + self.settle_s or record.autopilot is None:
            return None
        reason = self._check(record, nav)
        if reason is None:
            return None
        self.reason, self.t_s = reason, record.time_s
        return reason if self.criterion.stop else None

    def _check(self, record: FlightRecord, nav: NavigationState) -> str | None:
        c = self.criterion
        if record.truth.alt_m < c.ground_alt_m:
            return "ground"
        cross, height = path_errors_m(record)
        if abs(cross) > c.lateral_m or abs(height) > c.vertical_m:
            return "corridor"
        position, attitude = estimate_errors(record, nav)
        stale = record.time_s - nav.time_s > STALE_ESTIMATE_S
        if position > c.estimate_position_m or attitude > c.estimate_attitude_deg or stale:
            return "diverged"
        return None


@dataclass(frozen=True)
class ErrorStats:
    """Max and mean square of an error over the window."""

    max: float
    mse: float

    @classmethod
    def of(cls, values: np.ndarray) -> ErrorStats:
        """Of the non-negative magnitudes ``values`` (nan when empty)."""
        if values.size == 0:
            return cls(math.nan, math.nan)
        return cls(float(np.max(values)), float(np.mean(values**2)))


def _window(run: InProcessRun, settle_s: float) -> list[tuple[FlightRecord, NavigationState]]:
    first = next((nav.time_s for nav in run.estimates if nav is not None), None)
    if first is None:
        return []
    return [
        (rec, nav)
        for rec, nav in zip(run.records, run.estimates, strict=True)
        if nav is not None and rec.autopilot is not None and rec.time_s >= first + settle_s
    ]


def error_metrics(run: InProcessRun, settle_s: float) -> dict[str, float]:
    """Estimate and control errors (max and MSE; m, m^2, deg, deg^2) of a flight."""
    window = _window(run, settle_s)
    est = np.array([estimate_errors(rec, nav) for rec, nav in window]).reshape(-1, 2)
    path = np.array([path_errors_m(rec) for rec, _ in window]).reshape(-1, 2)
    att = np.array([attitude_control_error_deg(rec) for rec, _ in window]).reshape(-1, 2)
    out = {}
    for name, values in (
        ("est_pos", est[:, 0]),
        ("est_att", est[:, 1]),
        ("ctrl_pos", np.hypot(path[:, 0], path[:, 1])),
        ("ctrl_att", np.sqrt(np.sum(att**2, axis=1))),
    ):
        stats = ErrorStats.of(values)
        unit = "m" if name.endswith("pos") else "deg"
        out[f"{name}_max_{unit}"] = stats.max
        out[f"{name}_mse_{unit}2"] = stats.mse
    return out


def errors_after_declaration(
    run: InProcessRun, settle_s: float, declared_t_s: float | None
) -> dict[str, float | None]:
    """The estimate's attitude MSE (deg^2) and largest position error (m) from a declaration on.

    Survival is judged here: once the failed channel is declared, the estimate should fly as
    the same air's fault-free flight does. Never declared (``declared_t_s`` None): both None.
    A critical run's window ends where it stopped.
    """
    if declared_t_s is None:
        return dict.fromkeys(
            ("est_att_mse_after_decl_deg2", "est_pos_max_after_decl_m", "est_att_nees_after_decl")
        )
    start_s = declared_t_s - 5e-4  # declaration times are rounded to the millisecond
    window = [(rec, nav) for rec, nav in _window(run, settle_s) if rec.time_s >= start_s]
    est = np.array([estimate_errors(rec, nav) for rec, nav in window]).reshape(-1, 2)
    return {
        "est_att_mse_after_decl_deg2": ErrorStats.of(est[:, 1]).mse,
        "est_pos_max_after_decl_m": ErrorStats.of(est[:, 0]).max,
        "est_att_nees_after_decl": attitude_nees(run, window),
    }


def attitude_nees(
    run: InProcessRun, window: Sequence[tuple[FlightRecord, NavigationState]]
) -> float | None:
    """Mean normalised attitude error squared per axis over ``window`` (None: no sigmas).

    Each step's wrapped roll, pitch and yaw errors against the truth are divided by the
    sigmas the estimator gave them (``EstimateOutput.nav.euler_sigma_rad`` of the same step),
    squared and averaged over the three axes and the steps: a chi-square with 3 degrees of
    freedom per step, over 3, so 1 when the sigmas are right (Bar-Shalom, Li & Kirubarajan,
    *Estimation with Applications to Tracking and Navigation*, 2001, sec. 5.4).
    """
    sigma_rad = {round(out.t_s, 6): out.nav.euler_sigma_rad for out in run.history.outputs}
    values = []
    for rec, nav in window:
        sigma = sigma_rad.get(round(nav.time_s, 6))
        if sigma is None or not np.all(np.asarray(sigma) > 0.0):
            continue
        diff = np.array(attitude_errors_rad(rec, nav))
        values.append(float(np.mean((diff / np.asarray(sigma)) ** 2)))
    return float(np.mean(values)) if values else None


def fault_free_window_s(
    first_estimate_s: float | None, settle_s: float, fault_t_s: float | None, end_s: float
) -> tuple[float, float]:
    """``(start, end)`` of a run's fault-free exposure (s; ``end <= start`` when empty).

    Parameters
    ----------
    first_estimate_s : float or None
        Time of the filter's first estimate (``None``: it never aligned, no exposure).
    settle_s : float
        The detector's settling time after the first estimate.
    fault_t_s : float or None
        When the channels went dead (``None`` for a fault-free run).
    end_s : float
        The last time flown.
    """
    if first_estimate_s is None:
        return (0.0, 0.0)
    start = first_estimate_s + settle_s
    end = end_s if fault_t_s is None else min(end_s, fault_t_s)
    return (start, end)


#: the columns that make runs one flight until their faults: the replicate's seed (airframe,
#: sensor noise, turbulence), the air, the loop, the estimator variant and its filter model
FLIGHT_COLUMNS = ("seed", "air", "loop", "variant", "filter_model")


def flight_key(row: Mapping[str, str]) -> tuple[str, ...] | None:
    """The flight a ``runs.csv`` row shares with its common-random-number twins (None: no seed)."""
    if not row.get("seed"):
        return None
    return tuple(str(row.get(column, "")) for column in FLIGHT_COLUMNS)


def pre_fault_events(row: Mapping[str, str]) -> list[str]:
    """The ``mode@t`` declarations a row made before its fault (all of a fault-free run's)."""
    try:
        fault_t = float(row["fault_t_s"]) if row.get("fault", "none") != "none" else math.inf
    except (KeyError, ValueError):
        fault_t = math.inf
    out = []
    for item in str(row.get("declarations") or "").split():
        _, _, t_text = item.partition("@")
        try:
            if float(t_text) < fault_t:
                out.append(item)
        except ValueError:
            continue
    return out


@dataclass(frozen=True)
class FaultFreeFlight:
    """One distinct flight's fault-free exposure and what was declared in it.

    ``count`` is the number of declarations: the distinct ``mode@t`` in ``declarations``, or
    more where a run counted more than it listed (hand-made rows).
    """

    exposure_s: float
    declarations: tuple[str, ...]
    count: int


def fault_free_flights(rows: Sequence[Mapping[str, str]]) -> list[FaultFreeFlight]:
    """Each distinct flight's fault-free exposure and the declarations made in it.

    Runs that share a :func:`flight_key` are one flight up to their faults, so their windows
    are prefixes of one another: the flight counts for its longest window, with every distinct
    ``mode@t`` declared in any of them. A row without a seed is a flight of its own; rows without
    a ``fault_free_s`` (single filters, failed runs) do not count.
    """
    groups: dict[object, list[Mapping[str, str]]] = {}
    for i, row in enumerate(rows):
        try:
            exposure = float(row["fault_free_s"])
        except (KeyError, ValueError):
            continue
        if math.isfinite(exposure):
            groups.setdefault(flight_key(row) or i, []).append(row)
    flights = []
    for group in groups.values():
        events = tuple(sorted({e for r in group for e in pre_fault_events(r)}))
        counted = max(int(r.get("false_declarations_fault_free") or 0) for r in group)
        exposure = max(float(r["fault_free_s"]) for r in group)
        flights.append(FaultFreeFlight(exposure, events, max(len(events), counted)))
    return flights


def false_declaration_rate(rows: Sequence[Mapping[str, str]]) -> dict[str, float]:
    """False declarations per hour of distinct fault-free flight (:func:`fault_free_flights`).

    Returns
    -------
    dict
        ``declarations`` (count), ``hours`` (exposure), ``per_hour`` (nan without exposure),
        ``flights`` (distinct flights) and ``flights_with_declarations``.
    """
    flights = fault_free_flights(rows)
    hours = sum(f.exposure_s for f in flights) / 3600.0
    count = sum(f.count for f in flights)
    return {
        "declarations": count,
        "hours": hours,
        "per_hour": count / hours if hours > 0 else math.nan,
        "flights": len(flights),
        "flights_with_declarations": sum(1 for f in flights if f.count),
    }


def poisson_rate_upper_95(events: int, hours: float) -> float:
    """The 95 % upper confidence bound of a Poisson rate (per hour) from ``events`` in ``hours``.

    Exact (Garwood): ``chi2.ppf(0.95, 2 (events + 1)) / (2 hours)``; with no event it is
    ``-ln(0.05) / hours``, about ``3 / hours``: zero false declarations in 1.34 h only say "below
    2.2 per hour". NaN without flight time.
    """
    if not hours or hours <= 0.0:
        return math.nan
    return float(chi2.ppf(0.95, 2 * (events + 1)) / (2.0 * hours))


def identification_metrics(
    spec: RunSpec, run: InProcessRun, settle_s: float = 0.0
) -> dict[str, object]:
    """Detection delay, identified mode and false declarations of a run (IMM figures)."""
    summary = run.summary()
    outcome = summary.faults[0] if summary.faults else None
    after = [e for e in summary.detections if e.t_s >= spec.fault_t_s - 1e-9]
    if spec.mode.bits:
        identified = after[0].mode.name if after else "none"
        correct = identified == _first_mode(spec)
    else:
        identified = summary.detections[0].mode.name if summary.detections else "none"
        correct = not summary.detections
    delay = None if outcome is None else outcome.detection_delay_s
    first = run.history.outputs[0].t_s if run.history.outputs else None
    end_s = run.records[-1].time_s if run.records else 0.0
    start, stop = fault_free_window_s(
        first, settle_s, spec.fault_t_s if spec.mode.bits else None, end_s
    )
    early = [e for e in summary.detections if start <= e.t_s < stop]
    out: dict[str, object] = {
        "observable_t_s": None if outcome is None else outcome.observable_t_s,
        "detected_t_s": None if outcome is None else outcome.detected_t_s,
        "detection_delay_s": delay,
        "identified": identified,
        "identified_ok": correct,
        "identified_within_1s": correct
        and (not spec.mode.bits or (delay is not None and delay <= 1.0)),
        "named_kind": None if outcome is None else outcome.named_kind,
        "named_size": None if outcome is None else outcome.named_size,
        "false_declarations": len(summary.false_alarms),
        "fault_free_s": max(0.0, stop - start),
        "false_declarations_fault_free": len(early),
        "declarations": " ".join(f"{e.mode.name}@{e.t_s:.2f}" for e in summary.detections),
        "declared_at_end": declared_at_end(run.history.events()).name,
    }
    out.update(second_fault_metrics(spec, summary))
    return out


def _first_mode(spec: RunSpec) -> str:
    """The mode a run's first declaration must name: its fault set, or a pair's first channel."""
    return spec.scenario.faults[0].mode.name if spec.pair_gap_s is not None else spec.mode.name


def second_fault_metrics(spec: RunSpec, summary: Summary) -> dict[str, object]:
    """The ``second_*`` figures of a pair run from its summary (none for any other run)."""
    if spec.pair_gap_s is None or len(summary.faults) < 2:
        return {}
    outcome = summary.faults[1]
    delay = outcome.detection_delay_s
    return {
        "second_observable_t_s": outcome.observable_t_s,
        "second_detected_t_s": outcome.detected_t_s,
        "second_detection_delay_s": delay,
        "second_identified_within_1s": delay is not None and delay <= 1.0,
        "second_named_kind": outcome.named_kind,
    }
