"""The summary of a run or a replay: faults, detections, false alarms, errors, timing; a plot.

Inputs are plain arrays and records, so that ``run`` (which reads the tlogs the processes wrote)
and ``replay`` (which runs the pipeline itself) give the same summary for the same flight.

Definitions (README, "Quick start"):

- ``observable_t_s``: the first time at or after a fault's start at which the faulted channel
  differs from a healthy one by more than 5 sigma of its sensor noise (a zeroed q gyro in
  straight and level flight reads what a healthy one would);
- detection delay: from the later of the fault's start and ``observable_t_s`` to the first
  declaration of the fault's mode;
- false alarm: a declaration of any mode other than the one the active faults form (any
  declaration when no fault is active);
- estimation errors over the flight from the end of the settling period after alignment:
  position as the NED distance to truth, attitude as the norm of the wrapped roll, pitch and
  yaw errors.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.estimation.angles import wrap_angle
from immukf_sitl.estimation.fault_modes import FaultMode, failure_marginals
from immukf_sitl.experiments.observability import fault_observable_time_s
from immukf_sitl.models.earth import NedOrigin, geodetic_to_ned
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.samples import TruthSample
from immukf_sitl.scenario import ExpectSpec, FaultSpec
from immukf_sitl.service.detection import DetectionEvent
from immukf_sitl.service.pipeline import EstimateOutput
from immukf_sitl.service.timing import TimingStats


@dataclass(frozen=True)
class EstimateTrack:
    """The estimator's published attitude and position over time."""

    attitude_t_s: np.ndarray
    euler_rad: np.ndarray
    position_t_s: np.ndarray
    lat_lon_alt: np.ndarray


@dataclass(frozen=True)
class EstimateHistory:
    """The pipeline's outputs of one flight (a replay or an in-process run), step by step."""

    outputs: tuple[EstimateOutput, ...]

    def events(self) -> list[DetectionEvent]:
        """Detections and clearings in time order."""
        return [e for out in self.outputs for e in out.events]

    def track(self) -> EstimateTrack:
        """The estimate over time (every step)."""
        t = np.array([o.t_s for o in self.outputs])
        return EstimateTrack(
            t,
            np.array([o.nav.euler_rad for o in self.outputs]).reshape(-1, 3),
            t,
            np.array([(o.lat_deg, o.lon_deg, o.alt_m) for o in self.outputs]).reshape(-1, 3),
        )

    def step_us(self) -> TimingStats:
        """Wall time of the filter steps."""
        return TimingStats.of(o.step_us for o in self.outputs)

    def probability_series(self, names: Sequence[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """P(no failure) and P(each channel failed) over time, keyed by ``names``.

        ``names`` name the seven figures of :func:`failure_marginals` in their order (the
        paper's bank's modes: the marginals are its mode probabilities; a re-based bank's
        change slots at each declaration, the marginals do not).
        """
        if not self.outputs:
            return np.zeros(0), {}
        t = np.array([o.t_s for o in self.outputs])
        probs = np.array([failure_marginals(o.modes, o.mode_probabilities) for o in self.outputs])
        return t, {name: probs[:, j] for j, name in enumerate(names)}


@dataclass(frozen=True)
class FaultOutcome:
    """What became of one injected fault (a row of the summary's ``faults``)."""

    channels: tuple[str, ...]
    kind: str
    t_s: float
    mode: str
    observable_t_s: float | None
    detected_t_s: float | None
    detection_delay_s: float | None
    named_kind: str | None = None
    named_size: float | None = None

    def to_json(self) -> dict[str, object]:
        """The JSON row (keys as documented in README)."""
        return {
            "channels": list(self.channels),
            "kind": self.kind,
            "t_s": self.t_s,
            "mode": self.mode,
            "observable_t_s": self.observable_t_s,
            "detected_t_s": self.detected_t_s,
            "detection_delay_s": self.detection_delay_s,
            "named_kind": self.named_kind,
            "named_size": self.named_size,
        }


@dataclass(frozen=True)
class Summary:
    """The summary of one flight, built by :func:`summarize` only; ``to_json`` is the contract.

    The fields after ``expectation`` are what the command that flew or replayed the flight adds
    (``dataclasses.replace`` on the summarised record); ``None`` ones are left out of the JSON.
    """

    scenario: str
    faults: tuple[FaultOutcome, ...]
    detections: tuple[DetectionEvent, ...]
    clearings: tuple[DetectionEvent, ...]
    false_alarms: tuple[DetectionEvent, ...]
    est_error: dict[str, float | None]
    step_us: TimingStats
    expectation: dict | None = None
    variant: str | None = None
    lag_us: TimingStats | None = None
    wall_s: float | None = None
    sim_time_s: float | None = None
    received_truth_messages: int | None = None
    stream: dict | None = None
    files: dict[str, str] | None = None
    tlog: str | None = None
    note: str | None = None
    airframe: dict[str, float] | None = None
    wind: dict | None = None
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        """The JSON object ``run --json`` and ``replay --json`` print (README lists the keys)."""
        out: dict[str, object] = {
            "scenario": self.scenario,
            "faults": [f.to_json() for f in self.faults],
            "detections": [
                {
                    "mode": e.mode.name,
                    "t_s": _ms(e.t_s),
                    "probability": e.probability,
                    "kind": e.failure,
                    "size": e.size,
                }
                for e in self.detections
            ],
            "clearings": [
                {"mode": e.mode.name, "t_s": e.t_s, "probability": e.probability}
                for e in self.clearings
            ],
            "false_alarms": len(self.false_alarms),
            "false_alarm_detections": [
                {"mode": e.mode.name, "t_s": e.t_s} for e in self.false_alarms
            ],
            "est_error": dict(self.est_error),
            "step_us": {"median": self.step_us.median, "p99": self.step_us.p99},
        }
        if self.expectation is not None:
            out["expectation"] = self.expectation
        optional = {
            "variant": self.variant,
            "lag_us": None if self.lag_us is None else self.lag_us.to_json(),
            "wall_s": None if self.wall_s is None else round(self.wall_s, 2),
            "sim_time_s": self.sim_time_s,
            "received_truth_messages": self.received_truth_messages,
            "stream": self.stream,
            "files": self.files,
            "tlog": self.tlog,
            "note": self.note,
            "airframe": self.airframe,
            "wind": self.wind,
        }
        out.update({k: v for k, v in optional.items() if v is not None})
        out.update(self.extra)
        return out


def _ms(t_s: float | None) -> float | None:
    """Times in the summary, to the millisecond (they come from a 100 Hz clock)."""
    return None if t_s is None else round(float(t_s), 3)


def _active_mode(faults: Sequence[FaultSpec], t_s: float) -> FaultMode:
    channels = {c for f in faults if f.active(t_s) for c in f.channels}
    return FaultMode.from_channels(channels)


def _match_times(t_ref: np.ndarray, t_other: np.ndarray, tol_s: float = 0.006) -> np.ndarray:
    """Index into ``t_other`` of the sample nearest each ``t_ref`` (-1 if none within tol)."""
    if t_other.size == 0:
        return np.full(t_ref.shape, -1)
    idx = np.clip(np.searchsorted(t_other, t_ref), 0, t_other.size - 1)
    left = np.maximum(idx - 1, 0)
    nearer = np.where(np.abs(t_other[left] - t_ref) <= np.abs(t_other[idx] - t_ref), left, idx)
    return np.where(np.abs(t_other[nearer] - t_ref) <= tol_s, nearer, -1)


def estimation_errors(
    truth: Sequence[TruthSample], track: EstimateTrack, from_s: float = 0.0
) -> dict:
    """Max and mean-square position (m) and attitude (deg) errors against truth from ``from_s``."""
    truth = [s for s in truth if s.t_s >= from_s]
    t_truth = np.array([s.t_s for s in truth])
    out = {"pos_max_m": None, "pos_mse_m2": None, "att_max_deg": None, "att_mse_deg2": None}
    if t_truth.size == 0:
        return out
    origin = NedOrigin(truth[0].lat_deg, truth[0].lon_deg, truth[0].alt_m)
    idx = _match_times(track.attitude_t_s, t_truth)
    ok = idx >= 0
    if np.any(ok):
        true_euler = np.array([truth[i].euler_rad for i in idx[ok]])
        err = np.degrees(wrap_angle(track.euler_rad[ok] - true_euler))
        norm2 = np.sum(err**2, axis=1)
        out["att_max_deg"] = float(np.sqrt(norm2.max()))
        out["att_mse_deg2"] = float(norm2.mean())
    idx = _match_times(track.position_t_s, t_truth)
    ok = idx >= 0
    if np.any(ok):
        true_lla = np.array([(truth[i].lat_deg, truth[i].lon_deg, truth[i].alt_m) for i in idx[ok]])
        est = geodetic_to_ned(*track.lat_lon_alt[ok].T, origin)
        tru = geodetic_to_ned(*true_lla.T, origin)
        norm2 = np.sum((est - tru) ** 2, axis=0)
        out["pos_max_m"] = float(np.sqrt(norm2.max()))
        out["pos_mse_m2"] = float(norm2.mean())
    return out


def _named_detections(events: Sequence[DetectionEvent]) -> tuple[DetectionEvent, ...]:
    """The detections, each with the failure kind and size of the naming that followed it."""
    out: list[DetectionEvent] = []
    for event in events:
        if event.kind == "detected":
            out.append(event)
        elif event.kind == "named":
            k = next((k for k in reversed(range(len(out))) if out[k].mode == event.mode), None)
            if k is not None:
                out[k] = dataclasses.replace(out[k], failure=event.failure, size=event.size)
    return tuple(out)


def _declared_sets(events: Sequence[DetectionEvent]) -> list[tuple[DetectionEvent, int]]:
    """Each detection and clearing, with the bits of everything declared once it took effect."""
    out = []
    for event in events:
        if event.kind not in ("detected", "cleared"):
            continue
        if event.declared_after is not None:
            bits = event.declared_after.bits
        else:  # a detector that holds one mode at a time
            bits = event.mode.bits if event.kind == "detected" else 0
        out.append((event, bits))
    return out


def declared_at_end(events: Sequence[DetectionEvent]) -> FaultMode:
    """What the detector held declared after its last declaration or release (none: fault-free)."""
    sets = _declared_sets(events)
    return FaultMode(sets[-1][1]) if sets else FaultMode(0)


def _first_declaration(
    fault: FaultSpec, sets: Sequence[tuple[DetectionEvent, int]]
) -> DetectionEvent | None:
    """The first detection after ``fault`` began that declared one of its channels, all declared.

    The detection must name one of the fault's channels: a channel declared before its fault
    began (falsely) is not declared again, and a later declaration of another channel, which
    leaves it declared too, is not this fault's.
    """
    bits = fault.mode.bits
    return next(
        (
            event
            for event, declared in sets
            if event.kind == "detected"
            and event.t_s >= fault.t_s - 1e-9
            and event.mode.bits & bits
            and declared & bits == bits
        ),
        None,
    )


def summarize(
    scenario_name: str,
    faults: Sequence[FaultSpec],
    truth: Sequence[TruthSample],
    events: Sequence[DetectionEvent],
    track: EstimateTrack,
    step_us: TimingStats,
    imu_noise: ImuSpec | None = None,
    expect: ExpectSpec | None = None,
    settle_s: float = 0.0,
) -> Summary:
    """The summary of one flight (see the module docstring).

    Estimation errors count from ``settle_s`` after the first estimate (the alignment
    transient is not what the errors are meant to show).
    """
    imu_noise = imu_noise if imu_noise is not None else ImuSpec()
    t_truth = np.array([s.t_s for s in truth])
    true_imu = np.array(
        [np.concatenate([s.specific_force_mps2, s.rates_radps]) for s in truth]
    ).reshape(-1, 6)
    detections = _named_detections(events)
    sets = _declared_sets(events)
    first_estimate_s = float(track.attitude_t_s[0]) if track.attitude_t_s.size else 0.0
    outcomes = []
    for fault in faults:
        observable = fault_observable_time_s(fault, t_truth, true_imu, imu_noise)
        mode = fault.mode
        start = max(fault.t_s, observable) if observable is not None else None
        declaration = _first_declaration(fault, sets)
        first = next(
            (e for e in detections if declaration is not None and e.t_s == declaration.t_s
             and e.mode == declaration.mode),
            None,
        )  # fmt: skip
        delay = None if first is None or start is None else first.t_s - start
        outcomes.append(
            FaultOutcome(
                channels=tuple(fault.channels),
                kind=fault.kind,
                t_s=fault.t_s,
                mode=mode.name,
                observable_t_s=_ms(observable),
                detected_t_s=None if first is None else _ms(first.t_s),
                detection_delay_s=_ms(delay),
                named_kind=None if first is None else first.failure,
                named_size=None if first is None else first.size,
            )
        )
    summary = Summary(
        scenario=scenario_name,
        faults=tuple(outcomes),
        detections=detections,
        clearings=tuple(e for e in events if e.kind == "cleared"),
        false_alarms=tuple(
            e for e in detections if e.mode.bits & ~_active_mode(faults, e.t_s).bits
        ),
        est_error=estimation_errors(truth, track, first_estimate_s + settle_s),
        step_us=step_us,
    )
    if expect is None:
        return summary
    return dataclasses.replace(summary, expectation=check_expectation(summary, expect))


def check_expectation(summary: Summary, expect: ExpectSpec) -> dict:
    """Whether a summary meets the scenario's ``expect`` block."""
    if expect.detect == "none":
        met = not summary.false_alarms and not summary.detections
        return {"detect": "none", "met": met}
    name = FaultMode.from_name(expect.detect).name
    rows = [r for r in summary.faults if r.mode == name]
    ok = bool(rows) and all(
        r.detection_delay_s is not None and r.detection_delay_s <= expect.within_s for r in rows
    )
    return {
        "detect": expect.detect,
        "within_s": expect.within_s,
        "met": ok and not summary.false_alarms,
    }


def _named(event: DetectionEvent) -> str:
    """`` (bias +0.049)``: the failure a detection was named, if it was."""
    if event.failure is None:
        return ""
    return f" ({event.failure}{'' if event.size is None else f' {event.size:+.3g}'})"


def human_summary(summary: Summary) -> str:
    """A few lines for people."""
    lines = [f"scenario {summary.scenario}"]
    for row in summary.faults:
        obs, det, delay = row.observable_t_s, row.detected_t_s, row.detection_delay_s
        lines.append(
            f"  fault {row.kind} {'+'.join(row.channels)} at {row.t_s:.2f} s, "
            f"observable {'never' if obs is None else f'{obs:.2f} s'}, "
            f"detected {'never' if det is None else f'{det:.2f} s'}"
            + ("" if delay is None else f" (delay {delay:.2f} s)")
        )
    if not summary.faults:
        lines.append("  no fault injected")
    found = ", ".join(f"{d.mode.name}@{d.t_s:.2f}s{_named(d)}" for d in summary.detections)
    lines.append(f"  detections: {found or 'none'}; false alarms: {len(summary.false_alarms)}")
    err = summary.est_error
    if err["pos_max_m"] is not None:
        lines.append(
            f"  estimate error: position max {err['pos_max_m']:.2f} m "
            f"(MSE {err['pos_mse_m2']:.2f} m^2), attitude max {err['att_max_deg']:.2f} deg "
            f"(MSE {err['att_mse_deg2']:.3f} deg^2)"
        )
    st = summary.step_us
    if st.median is not None:
        lines.append(f"  filter step: median {st.median:.0f} us, p99 {st.p99:.0f} us")
    if summary.expectation is not None:
        lines.append(f"  expectation {'MET' if summary.expectation['met'] else 'NOT MET'}")
    return "\n".join(lines)


def plot_summary(
    path: str,
    summary: Summary,
    probability_t_s: np.ndarray,
    probabilities: dict[str, np.ndarray],
    truth: Sequence[TruthSample],
    track: EstimateTrack,
) -> None:
    """PNG: mode probabilities (top) and attitude error (bottom), faults and detections marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_p, ax_e) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for name, values in sorted(probabilities.items()):
        ax_p.plot(probability_t_s, values, label=name, lw=1.2)
    ax_p.set_ylabel("mode probability")
    ax_p.set_ylim(-0.02, 1.02)
    ax_p.legend(loc="center left", fontsize=8, ncol=1, bbox_to_anchor=(1.0, 0.5))
    ax_p.set_title(f"{summary.scenario}: IMM-UKF mode probabilities and attitude error")
    t_truth = np.array([s.t_s for s in truth])
    idx = _match_times(track.attitude_t_s, t_truth)
    ok = idx >= 0
    if np.any(ok):
        true_euler = np.array([truth[i].euler_rad for i in idx[ok]])
        err = np.degrees(wrap_angle(track.euler_rad[ok] - true_euler))
        for k, label in enumerate(("roll", "pitch", "yaw")):
            ax_e.plot(track.attitude_t_s[ok], err[:, k], label=label, lw=1.0)
    ax_e.set_ylabel("attitude error (deg)")
    ax_e.set_xlabel("time (s)")
    ax_e.legend(loc="center left", fontsize=8, bbox_to_anchor=(1.0, 0.5))
    for row in summary.faults:
        for ax in (ax_p, ax_e):
            ax.axvline(row.t_s, color="red", ls="--", lw=1)
            if row.observable_t_s is not None:
                ax.axvline(row.observable_t_s, color="orange", ls=":", lw=1)
    for det in summary.detections:
        ax_p.annotate(
            f"{det.mode.name} detected",
            (det.t_s, 1.0),
            xytext=(5, -12),
            textcoords="offset points",
            fontsize=8,
            color="black",
        )
        ax_p.axvline(det.t_s, color="black", lw=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
