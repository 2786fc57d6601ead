"""The real-air matrix computed from a campaign's ``runs.csv`` rows.

Identification within 1 s of observability, false declarations per fault-free hour, and the IMM's
attitude error against UKF-2's on the same flights, per filter model and air, with the acceptance
criteria; for a campaign of pairs, how the IMM found each channel of a pair, per gap.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from immukf_sitl.experiments.metrics import (
    false_declaration_rate,
    fault_free_flights,
    poisson_rate_upper_95,
    pre_fault_events,
)
from immukf_sitl.experiments.tables import (
    Row,
)

#: the matrix's acceptance criteria: identified within this long of becoming observable (s) ...
MATRIX_WITHIN_S = 1.0


#: ... in at least this share of the observable single faults
MATRIX_IDENTIFIED_SHARE = 0.95


#: zero false declarations in at least this much fault-free flight (h)
MATRIX_FAULT_FREE_HOURS = 1.0


#: the IMM's attitude MSE at most this multiple of UKF-2's on the same fault-free flight
MATRIX_ATTITUDE_RATIO = 1.2


#: survival: after the declaration, the attitude MSE at most this multiple of the same air's and
#: airframe's fault-free flight ...
SURVIVAL_ATTITUDE_RATIO = 1.5


#: ... and the largest position error under this (m)
SURVIVAL_POSITION_M = 20.0


#: every fault kind: the median delay of its observable single faults at most this (s) ...
KIND_MEDIAN_DELAY_S = 0.3


#: ... the kind named right in at least this share of them ...
KIND_NAMED_SHARE = 0.90


#: ... and the median relative error of the named size at most this (bias, drift, scale);
#: with no false declaration in at least this much fault-free flight (h): below 1 per hour
#: at 95 %
KIND_SIZE_ERROR = 0.20
KIND_FAULT_FREE_HOURS = 3.0


#: pairs: at least this share of the observable second faults identified within
#: :data:`MATRIX_WITHIN_S`, at every gap
PAIRS_SECOND_SHARE = 0.90


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan
    return text


def _ordered(values: Sequence[str]) -> list[str]:
    """Distinct values in first-seen order."""
    return list(dict.fromkeys(values))


def pre_fault_declarations(row: Row) -> list[str]:
    """Modes the run declared in its fault-free time (all of a fault-free run's declarations).

    ``declarations`` holds ``mode@t`` items; the detector declares nothing while it settles.
    """
    return [item.partition("@")[0] for item in pre_fault_events(row)]


def _identification(imm: Sequence[Row]) -> dict[str, object]:
    faulted = [r for r in imm if r["fault"] != "none"]
    # a run stopped by a critical failure before its fault never had the fault
    before = [r for r in faulted if _float(r["flown_s"]) < _float(r["fault_t_s"])]
    observable = [r for r in faulted if r["observable_t_s"] != ""]
    within = [r for r in observable if r["identified_within_1s"] == "true"]
    late = [r for r in observable if r["identified_ok"] == "true" and r not in within]
    wrong = [r for r in observable if r["identified"] not in ("none", r["fault"])]
    missed = [r for r in observable if r["identified"] == "none"]
    delays = [_float(r["detection_delay_s"]) for r in observable if r["detection_delay_s"]]
    fault_free = _fault_free_attitude(imm)
    channels = {}
    for channel in ("x", "y", "z", "p", "q", "r"):
        mine = [r for r in observable if r["fault"] == channel]
        twinned = [r for r in mine if _flight_key(r) in fault_free]
        ratios = [
            _float(r.get("est_att_mse_after_decl_deg2", "")) / fault_free[_flight_key(r)]
            for r in twinned
        ]
        channels[channel] = {
            "observable": len(mine),
            "identified_within_1s": sum(r in within for r in mine),
            "with_fault_free_twin": len(twinned),
            "survived": sum(survived(r, fault_free[_flight_key(r)]) for r in twinned),
            # over the runs declared (a run never declared has no error after a declaration)
            "attitude_ratio_median": _number(_median([x for x in ratios if math.isfinite(x)])),
            "attitude_nees_median": _number(_median(_attitude_nees(mine))),
        }
    share = len(within) / len(observable) if observable else math.nan
    return {
        "by_kind": _by_kind(observable, within, fault_free),
        "faulted_runs": len(faulted),
        "observable": len(observable),
        "ended_before_fault": len(before),
        "not_observable": len(faulted) - len(observable) - len(before),
        "identified_within_1s": len(within),
        "identified_within_1s_share": _number(share),
        "identified_later": len(late),
        "wrong_mode_first": len(wrong),
        "missed": len(missed),
        "detection_delay_s_median": _number(_median(delays)),
        "detection_delay_s_max": _number(max(delays) if delays else math.nan),
        "by_channel": channels,
        "fault_free_attitude_nees_median": _number(
            _median(_attitude_nees([r for r in imm if r["fault"] == "none"]))
        ),
    }


def _attitude_nees(rows: Sequence[Row]) -> list[float]:
    """The rows' attitude NEES per axis after the declaration, NaN where they have none.

    A fault-free flight's is from its drawn onset on.
    """
    return [_float(r.get("est_att_nees_after_decl") or "") for r in rows]


#: kinds whose named size is compared with the injected one (relative error)
SIZED_KINDS = ("bias", "drift", "scale")


def _flight_key(row: Row) -> tuple[str, str, str]:
    """Which flight a row's airframe, air and loop make (its fault-free twin shares it)."""
    return (row["air"], row.get("loop") or "closed", row["replicate"])


def _fault_free_attitude(imm: Sequence[Row]) -> dict[tuple[str, str, str], float]:
    """The fault-free IMM flights' attitude MSE (deg^2), by :func:`_flight_key`.

    From the flight's own drawn onset on (its ``est_att_mse_after_decl_deg2``), as a faulted
    run's is from its declaration: the whole flight's holds the alignment's first seconds, 4
    times the rest's in calm air (0.88 against 0.20 deg^2 on the tuning draw). An older
    ``runs.csv`` without it gives the whole flight's.
    """
    return {
        _flight_key(r): _float(r.get("est_att_mse_after_decl_deg2") or r["est_att_mse_deg2"])
        for r in imm
        if r["fault"] == "none" and r["status"] == "stable"
    }


def survived(row: Row, fault_free_att_mse_deg2: float) -> bool:
    """Whether a faulted run flew on after its declaration as its fault-free twin does.

    Declared, not critical, the attitude MSE after the declaration at most
    :data:`SURVIVAL_ATTITUDE_RATIO` times the twin's (:func:`_fault_free_attitude`), and the
    position error after it under :data:`SURVIVAL_POSITION_M`. A run never declared has
    nothing to survive with: it does not count as survived.
    """
    att = _float(row.get("est_att_mse_after_decl_deg2", ""))
    pos = _float(row.get("est_pos_max_after_decl_m", ""))
    return (
        row["status"] == "stable"
        and math.isfinite(att)
        and att <= SURVIVAL_ATTITUDE_RATIO * fault_free_att_mse_deg2
        and pos < SURVIVAL_POSITION_M
    )


def _by_kind(
    observable: Sequence[Row],
    within: Sequence[Row],
    fault_free: dict[tuple[str, str, str], float],
) -> dict[str, dict[str, object]]:
    """Per fault kind: identified within the bound, its delay, named right, the size's error.

    And survival: runs lost, and :func:`survived` over the runs whose twin flew fault-free.
    """
    out: dict[str, dict[str, object]] = {}
    for kind in _ordered([r.get("fault_kind") or "zero" for r in observable]):
        mine = [r for r in observable if (r.get("fault_kind") or "zero") == kind]
        named = [r for r in mine if r.get("named_kind") == kind]
        errors = [
            abs(_float(r["named_size"]) - _float(r["fault_value"])) / abs(_float(r["fault_value"]))
            for r in named
            if kind in SIZED_KINDS and r.get("named_size") and _float(r["fault_value"]) != 0.0
        ]
        twinned = [r for r in mine if _flight_key(r) in fault_free]
        delays = [_float(r["detection_delay_s"]) for r in mine if r["detection_delay_s"]]
        out[kind] = {
            "observable": len(mine),
            "identified_within_1s": sum(r in within for r in mine),
            "detection_delay_s_median": _number(_median(delays)),
            "named_right": len(named),
            "size_error_median": _number(_median(errors)),
            "lost": sum(r["status"] == "critical" for r in mine),
            "with_fault_free_twin": len(twinned),
            "survived": sum(survived(r, fault_free[_flight_key(r)]) for r in twinned),
        }
    return out


def _false_declarations(imm: Sequence[Row]) -> dict[str, object]:
    """Declarations in fault-free flight, each distinct flight once (common random numbers)."""
    rate = false_declaration_rate(imm)
    modes: dict[str, int] = {}
    for flight in fault_free_flights(imm):
        for event in flight.declarations:
            mode = event.partition("@")[0]
            modes[mode] = modes.get(mode, 0) + 1
    return {
        "declarations": int(rate["declarations"]),
        "hours": _number(rate["hours"]),
        "per_hour": _number(rate["per_hour"]),
        "per_hour_upper_95": _number(
            poisson_rate_upper_95(int(rate["declarations"]), rate["hours"])
        ),
        "flights_with_declarations": int(rate["flights_with_declarations"]),
        "flights": int(rate["flights"]),
        "by_mode": dict(sorted(modes.items())),
    }


def _attitude_flights(rows: Sequence[Row]) -> list[dict[str, object]]:
    """Per fault-free flight (air, loop, replicate): the IMM's, UKF-2's and UKF-3's attitude error.

    Open loop (the autopilot on truth), the variants estimate the very same flight; closed, each
    flies its own from the first turn on.
    """
    cells: dict[tuple[str, str, str], dict[str, Row]] = {}
    for row in rows:
        if row["fault"] == "none" and row["variant"] in ("imm", "ukf2", "ukf3"):
            key = (row["air"], row.get("loop") or "closed", row["replicate"])
            cells.setdefault(key, {})[row["variant"]] = row
    out = []
    for (air, loop, replicate), by in cells.items():
        flight: dict[str, object] = {"air": air, "loop": loop, "replicate": int(replicate)}
        for variant in ("imm", "ukf2", "ukf3"):
            row = by.get(variant)
            flight[f"{variant}_att_max_deg"] = _number(
                _float(row["est_att_max_deg"]) if row else math.nan
            )
            flight[f"{variant}_att_mse_deg2"] = _number(
                _float(row["est_att_mse_deg2"]) if row else math.nan
            )
            flight[f"{variant}_status"] = row["status"] if row else None
        imm, ukf2 = flight["imm_att_mse_deg2"], flight["ukf2_att_mse_deg2"]
        ratio = imm / ukf2 if isinstance(imm, float) and isinstance(ukf2, float) and ukf2 else None
        flight["imm_over_ukf2_mse"] = _number(ratio if ratio is not None else math.nan)
        out.append(flight)
    return out


def _attitude(flights: Sequence[dict[str, object]]) -> dict[str, object]:
    def column(key: str) -> list[float]:
        return [f[key] for f in flights if isinstance(f[key], float)]

    out: dict[str, object] = {"flights": len(flights)}
    for variant in ("imm", "ukf2", "ukf3"):
        mse, top = column(f"{variant}_att_mse_deg2"), column(f"{variant}_att_max_deg")
        out[f"{variant}_att_mse_deg2_mean"] = _number(sum(mse) / len(mse) if mse else math.nan)
        out[f"{variant}_att_max_deg_max"] = _number(max(top) if top else math.nan)
    # a flight whose UKF-2 failed has no reference: counted apart, never as within the ratio
    ratios = [
        f["imm_over_ukf2_mse"]
        for f in flights
        if isinstance(f["imm_over_ukf2_mse"], float) and f["ukf2_status"] == "stable"
    ]
    out["flights_ukf2_critical"] = sum(f["ukf2_status"] == "critical" for f in flights)
    # the ratio of the means over the flights both flew (a flight only one has finished would
    # tilt it)
    paired = [f for f in flights if isinstance(f["imm_over_ukf2_mse"], float)]
    imm = sum(f["imm_att_mse_deg2"] for f in paired)
    ukf2 = sum(f["ukf2_att_mse_deg2"] for f in paired)
    out["imm_over_ukf2_mse_of_means"] = _number(imm / ukf2 if paired and ukf2 else math.nan)
    out["imm_over_ukf2_mse_worst"] = _number(max(ratios) if ratios else math.nan)
    out["flights_within_ratio"] = sum(r <= MATRIX_ATTITUDE_RATIO for r in ratios)
    out["flights_compared"] = len(ratios)
    return out


def is_pair_row(row: Row) -> bool:
    """Whether a row is a pair run's (two channels, the second failing at its own time)."""
    return bool(row.get("second_fault"))


def pair_gap_label(gap_s: float) -> str:
    """``at once`` for a gap of 0, ``after 10 s`` otherwise."""
    return "at once" if gap_s == 0.0 else f"after {gap_s:g} s"


def _pair_gap_s(row: Row) -> float:
    """The gap of a pair run (s) from its two fault times."""
    return round(_float(row["second_t_s"]) - _float(row["fault_t_s"]), 3)


def _within(delay_text: str) -> bool:
    """Whether a detection delay cell is at most :data:`MATRIX_WITHIN_S`."""
    delay = _float(delay_text)
    return math.isfinite(delay) and delay <= MATRIX_WITHIN_S


def declarations_outside_pair(row: Row) -> int:
    """Declarations of channels outside a pair run's two, at or after its first fault."""
    pair = set(row["fault"].split("+"))
    fault_t = _float(row["fault_t_s"])
    count = 0
    for item in row.get("declarations", "").split():
        mode, _, t_text = item.partition("@")
        count += _float(t_text) >= fault_t and not set(mode.split("+")) <= pair
    return count


def _pair_group(rows: Sequence[Row]) -> dict[str, object]:
    """The figures of the pair runs of one gap (see :func:`matrix_summary`)."""
    first = [r for r in rows if r["observable_t_s"] != ""]
    second = [r for r in rows if r["second_observable_t_s"] != ""]
    within = [r for r in second if r["second_identified_within_1s"] == "true"]
    delays = [
        _float(r["second_detection_delay_s"]) for r in second if r["second_detection_delay_s"]
    ]
    share = len(within) / len(second) if second else math.nan
    return {
        "runs": len(rows),
        "first_observable": len(first),
        "first_identified_within_1s": sum(_within(r["detection_delay_s"]) for r in first),
        "second_observable": len(second),
        "second_identified_within_1s": len(within),
        "second_identified_within_1s_share": _number(share),
        "second_detection_delay_s_median": _number(_median(delays)),
        "both_declared_at_end": sum(
            set(r["fault"].split("+")) <= set(r.get("declared_at_end", "").split("+")) for r in rows
        ),
        "declarations_outside_pair": sum(declarations_outside_pair(r) for r in rows),
        "lost": sum(r["status"] == "critical" for r in rows),
    }


def _pairs(rows: Sequence[Row]) -> dict[str, object]:
    """The pair runs of a filter model, per gap (in increasing order), with their criterion."""
    gaps = sorted({_pair_gap_s(r) for r in rows})
    by_gap = {
        pair_gap_label(gap): dict(
            gap_s=gap, **_pair_group([r for r in rows if _pair_gap_s(r) == gap])
        )
        for gap in gaps
    }
    shares = [g["second_identified_within_1s_share"] for g in by_gap.values()]
    return {
        "by_gap": by_gap,
        "acceptance": {
            "second_identified_within_1s": all(
                s is not None and s >= PAIRS_SECOND_SHARE for s in shares
            )
        },
    }


def _matrix_group(rows: Sequence[Row]) -> dict[str, object]:
    imm = [r for r in rows if r["variant"] == "imm"]
    return {
        "identification": _identification([r for r in imm if not is_pair_row(r)]),
        "false_declarations": _false_declarations(imm),
        "attitude": _attitude(_attitude_flights(rows)),
    }


def matrix_summary(rows: Sequence[Row]) -> dict[str, object]:
    """The real-air matrix from ``runs.csv`` rows, per filter model: per air and overall.

    Per group: identification of the observable single faults (within
    :data:`MATRIX_WITHIN_S` of observability, by channel), false declarations per hour of
    fault-free exposure (:func:`~immukf_sitl.experiments.metrics.false_declaration_rate`), and
    the attitude error of the IMM beside UKF-2 and UKF-3 on the fault-free flights. Rows of
    runs that failed to run are left out; critical runs count with what they flew.

    When the rows hold pair runs, ``pairs`` gives per gap (all airs): the runs, each fault
    identified within the bound (the declaration that added its channel, at most
    :data:`MATRIX_WITHIN_S` after it became observable) over the observable ones, the second
    delay's median, the runs that ended with both channels declared, the declarations of
    other channels from the first fault on, and the runs lost (critical).
    """
    rows = [r for r in rows if r["status"] != "error"]
    out: dict[str, object] = {}
    for model in _ordered([r["filter_model"] for r in rows]):
        mine = [r for r in rows if r["filter_model"] == model]
        airs = _ordered([r["air"] for r in mine])
        overall = _matrix_group(mine)
        out[model] = {
            "airs": {air: _matrix_group([r for r in mine if r["air"] == air]) for air in airs},
            "overall": overall,
            "flights": _attitude_flights(mine),
            "critical": [
                {
                    "run_id": r["run_id"],
                    "failure": r["failure"],
                    "failure_t_s": _float(r["failure_t_s"]),
                }
                for r in mine
                if r["status"] == "critical"
            ],
            "acceptance": _acceptance(overall),
        }
        pairs = [r for r in mine if r["variant"] == "imm" and is_pair_row(r)]
        if pairs:
            out[model]["pairs"] = _pairs(pairs)
    return out


def _kind_acceptance(by_kind: dict[str, dict[str, object]]) -> dict[str, dict[str, bool]]:
    """Per fault kind: identified in time, named right and sized, and every run survived.

    In time is the share within 1 s and the median delay; survived is :func:`survived` for
    every run that has a fault-free twin, and no run lost.
    """
    out = {}
    for kind, k in by_kind.items():
        n, delay, size = k["observable"], k["detection_delay_s_median"], k["size_error_median"]
        sized = kind not in SIZED_KINDS or (size is not None and size <= KIND_SIZE_ERROR)
        out[kind] = {
            "identified_within_1s": n > 0
            and k["identified_within_1s"] >= MATRIX_IDENTIFIED_SHARE * n
            and delay is not None
            and delay <= KIND_MEDIAN_DELAY_S,
            "named_right": n > 0 and k["named_right"] >= KIND_NAMED_SHARE * n and sized,
            "survived": k["lost"] == 0
            and k["with_fault_free_twin"] > 0
            and k["survived"] == k["with_fault_free_twin"],
        }
    return out


def _acceptance(group: dict) -> dict[str, object]:
    ident, false, att = group["identification"], group["false_declarations"], group["attitude"]
    share = ident["identified_within_1s_share"]
    kinds = ident["by_kind"]
    extra = {}
    if not set(kinds) <= {"zero"}:
        extra["kinds"] = _kind_acceptance(kinds)
        extra["no_false_declarations_in_3h"] = (
            false["declarations"] == 0 and (false["hours"] or 0.0) >= KIND_FAULT_FREE_HOURS
        )
    return {
        **extra,
        "identified_within_1s": share is not None and share >= MATRIX_IDENTIFIED_SHARE,
        "no_false_declarations_in_1h": false["declarations"] == 0
        and (false["hours"] or 0.0) >= MATRIX_FAULT_FREE_HOURS,
        "attitude_within_1_2x_of_ukf2": att["flights_compared"] > 0
        and att["flights_within_ratio"] == att["flights_compared"]
        and att["flights_ukf2_critical"] == 0,
    }


def _number(value: float) -> float | None:
    return None if not math.isfinite(value) else round(float(value), 6)


def _median(values: Sequence[float]) -> float:
    values = sorted(v for v in values if math.isfinite(v))
    if not values:
        return math.nan
    mid = len(values) // 2
    return values[mid] if len(values) % 2 else 0.5 * (values[mid - 1] + values[mid])
