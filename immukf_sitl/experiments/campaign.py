"""Campaign files: a Monte Carlo study as a product of axes (YAML), expanded into runs.

A wrong file gets one line naming the file, the field and what was expected
(:class:`CampaignError`), as scenario files do. The schema, with every default::

    name: paper                    # required, a label (the default --out-dir is results/<name>)
    description: ...               # optional
    seed: 2013                     # required: replicate r flies with the seed
                                   # SeedSequence(seed, spawn_key=(r,)), so every variant and
                                   # fault set of replicate r sees the same sensor noise
    replicates: 5                  # required, >= 1 (the seeds axis: 0 .. replicates-1)
    scenario: {...}                # required: a scenario mapping without name, seed and faults
                                   # (flight plan, duration, start, sensors, manoeuvres), or
                                   # the path of a scenario file, relative to this file
    variants:                      # required: each variant and the fault sets it flies
      ukf1: all_64                 # all_64 (the paper's Table 2) | single (none, x .. r) |
      ukf2: all_64                 # pairs (the 15 two-channel sets, x+y .. q+r) |
      ukf3: all_64                 # a list of modes: [none, q, x+q]
      imm: single                  # the IMM: single modes, and pairs with fault_modes: untrusted
    fault_times_s: [5.0]           # optional axis (default [5.0]): when the channels go dead;
                                   # or {uniform: [20, 80]}: one time per (replicate, air entry,
                                   # fault set), drawn from the seed (see "Random fault times")
    pair_gaps_s: [0]               # optional axis (default [0]) of the IMM's pairs only: the
                                   # second channel fails this long (s) after the first, 0 at
                                   # the same instant (see "Pairs")
    filter_model: paper            # optional axis: paper (12 states) | real-air (30 states),
                                   # or a list of both (as --filter-model)
    fault_modes: zero              # optional: zero (the paper's) | untrusted, as --fault-modes
    fault_kinds:                   # optional axis (default [{kind: zero}]): how the fault set's
      - {kind: zero}               # channels fail (immukf_sitl/fault_kinds.py); a kind that takes
      - {kind: bias, accel: [0.2, 2.0], gyro: [0.01, 0.1]}  # a value draws its size per run,
      - {kind: spikes, accel: [1, 5], gyro: [0.1, 0.5], rate_hz: 2}  # uniformly in the range of
                                   # the channel's sensor (bias, drift, spikes: either sign)
    report: paper                  # optional: paper (Tables 1-3 beside the paper's) | matrix
                                   # (the real-air matrix: identification within 1 s, false
                                   # declarations per hour, attitude IMM/UKF-2, per air)
    loop: [closed]                 # optional axis: closed (autopilot on the estimate) | open
                                   # (on truth)
    air:                           # optional axis (default one entry: the scenario's own air)
      - {name: still}              # name, then optional airframe: and wind: blocks as in a
      - {name: windy, wind: {speed_mps: 6, from_deg: 270, turbulence: light}}  # scenario file
    failure:                       # optional: the critical-failure criterion
      lateral_m: 100               # true aircraft farther than this from the desired path
      vertical_m: 30               # true height this far from the commanded altitude
      ground_alt_m: 0              # true height above the ellipsoid below this: ground hit
      estimate_position_m: 100     # estimate this far from truth: diverged
      estimate_attitude_deg: 45    # roll/pitch/yaw error norm beyond this: diverged
      stop: true                   # end a run at its first critical failure
    figure: {variant: imm, fault: q}   # optional: the run re-flown for fig2.png

The runs are the product, in this order: filter model, air, loop, fault time, variant (ukf1,
ukf2, ukf3, imm), fault set (Table 2 order), fault kind, pair gap, replicate. A run's index is
its place in that order; nothing random depends on it, so results do not depend on how many jobs
run them.

**Airframe draws.** A scenario's ``airframe: uncertainty`` is drawn from the scenario seed
(:func:`immukf_sitl.models.airframe.airframe_factors`), and the scenario seed of replicate ``r``
is :meth:`Campaign.replicate_seed` ``(r)``, which depends on nothing but the campaign seed and
``r``. So replicate ``r`` is airframe draw ``r``: the same aircraft in every air entry, loop,
fault time, variant, fault set and filter model (unless an air entry brings its own
``airframe:`` block). The sensor noise, IMU biases and turbulence of replicate ``r`` are the
same across them too (common random numbers).

**Fault kinds.** Each faulted fault set is flown once per ``fault_kinds`` entry (a fault-free
run once). A kind's size is drawn per run, uniformly in the entry's ``accel`` or ``gyro`` range,
from ``SeedSequence(seed, spawn_key=(FAULT_VALUE_STREAM, r, crc32(air name), fault set bits,
crc32(kind)))``; bias, drift and spikes take a random sign. A fault set with both kinds of
sensor gets one fault per sensor kind, at the same time (a kind without a size, one fault).

**Random fault times.** With ``fault_times_s: {uniform: [lo, hi]}`` the fault time of a run is
drawn uniformly in ``[lo, hi]`` (rounded to 10 ms, the IMU's period) from
``SeedSequence(seed, spawn_key=(FAULT_TIME_STREAM, r, crc32(air name), fault set bits))``: the
same for every variant, loop and filter model of a cell, so that UKF-2, UKF-3 and the IMM of
one cell lose the channel at the same moment, different across replicates, airs and fault sets,
and independent of ``--jobs``. A fault-free run has a drawn time too; nothing uses it but its
``run_id``.

**Pairs.** A two-channel fault set of the IMM (``fault_modes: untrusted``: the zero modes' bank
holds single faults) is a *pair run*, flown once per ``pair_gaps_s`` entry: the first channel (in
x y z p q r order) fails at the run's fault time, the second ``gap`` seconds later, each with its
own fault and its own size, drawn in the range of its sensor from the fault kinds' key above
plus the channel's bit (``1 << channel index``). Time and sizes do not depend on the gap, so the
gaps of a cell differ in nothing else. Its ``run_id`` carries the gap after the time
(``t31.58+g10``); single-fault and fault-free runs are flown once, as before. The UKF variants
fly a multi-channel set as one fault at one time, as before: their filters hold one mode.
"""

from __future__ import annotations

import dataclasses
import json
import math
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from immukf_sitl.errors import UserError
from immukf_sitl.estimation.fault_modes import (
    FAULT_SIGNATURES,
    FaultMode,
    all_fault_modes,
    single_fault_modes,
)
from immukf_sitl.fault_kinds import KIND_VALUES, check_fault_parameters
from immukf_sitl.scenario import FaultSpec, Scenario, ScenarioError, parse_scenario
from immukf_sitl.service.filter_models import FILTER_MODELS as MODEL_TYPES
from immukf_sitl.service.filters import VARIANTS
from immukf_sitl.yaml_fields import YamlFields

LOOPS = ("closed", "open")
FAULT_SET_NAMES = ("all_64", "single", "pairs")
#: ``filter_model`` values (as ``--filter-model``): the paper's 12-state model, the 30-state one
FILTER_MODELS = tuple(MODEL_TYPES)
#: ``report`` values: the paper's tables, or the real-air matrix
REPORT_KINDS = ("paper", "matrix")
#: first element of the spawn key of the fault-time draws (apart from the replicates' ``(r,)``)
FAULT_TIME_STREAM = 0xFA17
#: first element of the spawn key of the fault-size draws
FAULT_VALUE_STREAM = 0xFA18
#: kinds whose size takes a random sign
SIGNED_KINDS = ("bias", "drift", "spikes")
#: drawn fault times are rounded to this (s): the IMU's period
FAULT_TIME_RESOLUTION_S = 0.01
#: the sensor of each channel (a fault kind's size range is per sensor)
SENSOR_CHANNELS = (("accel", ("x", "y", "z")), ("gyro", ("p", "q", "r")))
#: scenario fields a campaign sets itself
_CAMPAIGN_SCENARIO_FIELDS = ("name", "seed", "faults", "expect")


#: validated scenario blocks by (campaign digest, air name): a campaign of a thousand runs parses
#: its scenario once per air entry
_BASE_CACHE: dict[tuple[str, str], Scenario] = {}


class CampaignError(UserError):
    """A campaign file that cannot be used; the message is one line."""


@dataclass(frozen=True)
class FailureCriterion:
    """When a run is a critical failure (the paper's Table 2 "x"; docs/results/paper/report.md)."""

    lateral_m: float = 100.0
    vertical_m: float = 30.0
    ground_alt_m: float = 0.0
    estimate_position_m: float = 100.0
    estimate_attitude_deg: float = 45.0
    stop: bool = True


@dataclass(frozen=True)
class AirSpec:
    """One entry of the ``air`` axis: a name and the scenario blocks it replaces."""

    name: str
    blocks: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class UniformFaultTimes:
    """``fault_times_s: {uniform: [lo, hi]}``: one drawn time per (replicate, air, fault set)."""

    lo_s: float
    hi_s: float

    def draw(self, seed: int, replicate: int, air: str, mode: FaultMode) -> float:
        """The fault time of a cell (s), rounded to :data:`FAULT_TIME_RESOLUTION_S`."""
        key = (FAULT_TIME_STREAM, replicate, zlib.crc32(air.encode("utf-8")), mode.bits)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))
        t_s = float(rng.uniform(self.lo_s, self.hi_s))
        return round(round(t_s / FAULT_TIME_RESOLUTION_S) * FAULT_TIME_RESOLUTION_S, 6)


@dataclass(frozen=True)
class FaultKindSpec:
    """A ``fault_kinds`` entry: a kind, the size ranges of its value per sensor, a spike rate."""

    kind: str = "zero"
    accel: tuple[float, float] | None = None
    gyro: tuple[float, float] | None = None
    rate_hz: float | None = None

    def faults(
        self, channels: tuple[str, ...], t_s: float, key: tuple[int, ...]
    ) -> tuple[FaultSpec, ...]:
        """The faults of a run on ``channels`` at ``t_s``; sizes drawn from ``key``'s stream."""
        if self.accel is None and self.gyro is None:  # a kind without a size: one fault
            return (FaultSpec(t_s, channels, self.kind, 0.0, None, self.rate_hz or 0.0),)
        rng = np.random.default_rng(np.random.SeedSequence(key))
        out = []
        for sensor, names in SENSOR_CHANNELS:
            mine = tuple(c for c in channels if c in names)
            if not mine:
                continue
            value = self._size(sensor, rng)
            out.append(FaultSpec(t_s, mine, self.kind, round(value, 6), None, self.rate_hz or 0.0))
        return tuple(out)

    def channel_fault(self, channel: str, t_s: float, key: tuple[int, ...]) -> FaultSpec:
        """The fault of one channel of a pair at ``t_s``; its size drawn from ``key``'s stream."""
        rng = np.random.default_rng(np.random.SeedSequence(key))
        sensor = next(s for s, names in SENSOR_CHANNELS if channel in names)
        value = self._size(sensor, rng)
        return FaultSpec(t_s, (channel,), self.kind, round(value, 6), None, self.rate_hz or 0.0)

    def _size(self, sensor: str, rng: np.random.Generator) -> float:
        """A size in ``sensor``'s range (0 without one), of either sign for a signed kind."""
        span = getattr(self, sensor)
        if span is None:
            return 0.0
        value = float(rng.uniform(*span))
        if self.kind in SIGNED_KINDS and rng.random() < 0.5:
            value = -value
        return value


def pair_fault_modes() -> tuple[FaultMode, ...]:
    """The 15 two-channel fault sets, x+y .. q+r, in the paper's Table 2 order."""
    return tuple(m for m in all_fault_modes() if len(m.channels) == 2)


def is_pair(variant: str, mode: FaultMode) -> bool:
    """Whether ``variant`` flies ``mode`` as a pair run: the IMM on two channels."""
    return variant == "imm" and len(mode.channels) == 2


@dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: everything a worker needs, picklable.

    Attributes
    ----------
    index : int
        Place in the campaign's order.
    variant : str
    mode : FaultMode
        The zeroed channels (``none`` for a fault-free run).
    replicate : int
    seed : int
        The scenario seed of this replicate.
    fault_t_s : float
    loop : str
        ``closed`` or ``open``.
    air : str
        Name of the air entry.
    scenario : Scenario
        The flight, with its seed and fault.
    failure : FailureCriterion
    filter_model : str
        ``paper`` or ``real-air``: the estimator's filter model (as ``--filter-model``).
    fault_modes : str
        ``untrusted`` or ``zero``: what its fault modes predict (as ``--fault-modes``).
    fault_kind : str
        How the fault set's channels fail (:data:`immukf_sitl.fault_kinds.FAULT_KINDS`).
    pair_gap_s : float or None
        A pair run: how long after the first channel the second fails (s); None otherwise.
    """

    index: int
    variant: str
    mode: FaultMode
    replicate: int
    seed: int
    fault_t_s: float
    loop: str
    air: str
    scenario: Scenario
    failure: FailureCriterion
    filter_model: str = "paper"
    fault_modes: str = "zero"
    fault_kind: str = "zero"
    pair_gap_s: float | None = None

    @property
    def run_id(self) -> str:
        """A stable key of the run (``--resume`` matches rows by it; a zero fault adds nothing).

        A pair run adds its gap to the time: ``t31.58+g10``.
        """
        kind = "" if self.fault_kind == "zero" else f"/{self.fault_kind}"
        gap = "" if self.pair_gap_s is None else f"+g{self.pair_gap_s:g}"
        return (
            f"{self.variant}/{self.mode.name}/r{self.replicate}/t{self.fault_t_s:g}{gap}/"
            f"{self.loop}/{self.air}/{self.filter_model}{kind}"
        )

    @property
    def second_fault(self) -> str | None:
        """The channel of a pair run that fails second (None for any other run)."""
        return None if self.pair_gap_s is None else self.mode.channels[1]

    @property
    def second_t_s(self) -> float | None:
        """When the second channel of a pair run fails (s; None for any other run)."""
        return None if self.pair_gap_s is None else self.scenario.faults[-1].t_s

    @property
    def fault_value(self) -> float:
        """The size of the run's first fault (0 for a fault-free run or a kind without one)."""
        return self.scenario.faults[0].value if self.scenario.faults else 0.0


@dataclass(frozen=True)
class FigureSpec:
    """Which run ``fig2.png`` re-flies (the paper's Fig. 2: IMM under a q-gyro failure)."""

    variant: str = "imm"
    fault: str = "q"


@dataclass(frozen=True)
class Campaign:
    """A validated campaign file."""

    name: str
    seed: int
    replicates: int
    scenario: Mapping[str, Any]
    variants: tuple[tuple[str, tuple[FaultMode, ...]], ...]
    fault_times_s: tuple[float, ...] | UniformFaultTimes = (5.0,)
    loops: tuple[str, ...] = ("closed",)
    air: tuple[AirSpec, ...] = (AirSpec("default"),)
    failure: FailureCriterion = field(default_factory=FailureCriterion)
    figure: FigureSpec = field(default_factory=FigureSpec)
    description: str = ""
    path: str = ""
    filter_models: tuple[str, ...] = ("paper",)
    report: str = "paper"
    fault_modes: str = "zero"
    fault_kinds: tuple[FaultKindSpec, ...] = (FaultKindSpec(),)
    pair_gaps_s: tuple[float, ...] = (0.0,)

    @property
    def digest(self) -> str:
        """Everything that decides the runs' results, as canonical JSON (``--resume`` checks it).

        The variants, fault sets, replicates, loops and pair gaps are not in it: they choose
        which runs there are, and a run's row is found by its ``run_id``. The filter models are
        in it (as well as in the ``run_id``), so that ``--resume`` refuses a changed model.
        """
        data = {
            "seed": self.seed,
            "scenario": self.scenario,
            "fault_times_s": self.fault_times_s,
            "air": [(a.name, a.blocks) for a in self.air],
            "failure": self.failure.__dict__,
            "filter_models": self.filter_models,
            "fault_modes": self.fault_modes,
            "fault_kinds": [dataclasses.astuple(k) for k in self.fault_kinds],
        }
        return json.dumps(data, sort_keys=True, default=str)

    def replicate_seed(self, replicate: int) -> int:
        """The scenario seed of replicate ``replicate`` (child ``replicate`` of the seed)."""
        sequence = np.random.SeedSequence(self.seed, spawn_key=(replicate,))
        return int(sequence.generate_state(1)[0])

    def fault_times_for(self, replicate: int, air: AirSpec, mode: FaultMode) -> tuple[float, ...]:
        """The fault times of a cell: the listed ones, or the one drawn for it."""
        if isinstance(self.fault_times_s, UniformFaultTimes):
            return (self.fault_times_s.draw(self.seed, replicate, air.name, mode),)
        return self.fault_times_s

    def pair_gaps_for(self, variant: str, mode: FaultMode) -> tuple[float | None, ...]:
        """The gaps a fault set is flown with: the pair gaps for a pair, else one run (None)."""
        return self.pair_gaps_s if is_pair(variant, mode) else (None,)

    def imm_pairs(self) -> tuple[FaultMode, ...]:
        """The two-channel fault sets the IMM flies (pair runs)."""
        return tuple(m for v, modes in self.variants for m in modes if is_pair(v, m))

    def _time_slots(self) -> int:
        """How many fault times each cell has (1 when drawn)."""
        if isinstance(self.fault_times_s, UniformFaultTimes):
            return 1
        return len(self.fault_times_s)

    def scenario_for(
        self,
        mode: FaultMode,
        replicate: int,
        fault_t_s: float,
        air: AirSpec,
        kind: FaultKindSpec | None = None,
        gap_s: float | None = None,
    ) -> Scenario:
        """The scenario of one run (its seed, air and fault of ``kind``, default zero).

        With ``gap_s`` (a pair run) each of the two channels gets its own fault, the second
        ``gap_s`` after the first.
        """
        base = self._base_scenario(air)
        if fault_t_s >= base.duration_s:
            raise CampaignError(
                f"{self.path}: fault_times_s: expected times before the scenario's end "
                f"({base.duration_s:g} s), got {fault_t_s:g}"
            )
        faults: tuple[FaultSpec, ...] = ()
        kind = kind if kind is not None else FaultKindSpec()
        if mode.bits:
            key = (
                self.seed, FAULT_VALUE_STREAM, replicate, zlib.crc32(air.name.encode("utf-8")),
                mode.bits, zlib.crc32(kind.kind.encode("utf-8")),
            )  # fmt: skip
            if gap_s is None:
                faults = kind.faults(mode.channels, fault_t_s, key)
            else:
                faults = self._pair_faults(mode, fault_t_s, gap_s, kind, key, base)
        suffix = "" if kind.kind == "zero" else f"-{kind.kind}"
        suffix += "" if gap_s is None else f"-g{gap_s:g}"
        return dataclasses.replace(
            base,
            name=f"{self.name}-{mode.name}{suffix}-r{replicate}",
            seed=self.replicate_seed(replicate),
            faults=faults,
        )

    def _pair_faults(
        self,
        mode: FaultMode,
        fault_t_s: float,
        gap_s: float,
        kind: FaultKindSpec,
        key: tuple[int, ...],
        base: Scenario,
    ) -> tuple[FaultSpec, FaultSpec]:
        """The two faults of a pair run: one per channel, the second ``gap_s`` later."""
        first, second = mode.channels
        second_t_s = round(fault_t_s + gap_s, 6)
        if second_t_s >= base.duration_s:
            raise CampaignError(
                f"{self.path}: pair_gaps_s: expected the second fault before the scenario's end "
                f"({base.duration_s:g} s), got {second_t_s:g} s ({fault_t_s:g} + {gap_s:g})"
            )
        return (
            kind.channel_fault(first, fault_t_s, key + (FaultMode.from_name(first).bits,)),
            kind.channel_fault(second, second_t_s, key + (FaultMode.from_name(second).bits,)),
        )

    def _base_scenario(self, air: AirSpec) -> Scenario:
        """The scenario block with an air entry's blocks, validated (seed 0, no faults)."""
        key = air.name
        cached = _BASE_CACHE.get((self.digest, key))
        if cached is not None:
            return cached
        data = dict(self.scenario)
        data.update(air.blocks)
        data.update(name=self.name, seed=0)
        try:
            scenario = parse_scenario(data, f"{self.path}: scenario (air {air.name})")
        except ScenarioError as exc:
            raise CampaignError(str(exc)) from None
        _BASE_CACHE[(self.digest, key)] = scenario
        return scenario

    def runs(self) -> tuple[RunSpec, ...]:
        """Every run, in the campaign's order."""
        out: list[RunSpec] = []
        cells = [
            (model, air, loop, slot, variant, mode, kind, gap_s, replicate)
            for model in self.filter_models
            for air in self.air
            for loop in self.loops
            for slot in range(self._time_slots())
            for variant, modes in self.variants
            for mode in modes
            for kind in (self.fault_kinds if mode.bits else self.fault_kinds[:1])
            for gap_s in self.pair_gaps_for(variant, mode)
            for replicate in range(self.replicates)
        ]
        for model, air, loop, slot, variant, mode, kind, gap_s, replicate in cells:
            fault_t_s = self.fault_times_for(replicate, air, mode)[slot]
            out.append(
                RunSpec(
                    index=len(out),
                    variant=variant,
                    mode=mode,
                    replicate=replicate,
                    seed=self.replicate_seed(replicate),
                    fault_t_s=fault_t_s,
                    loop=loop,
                    air=air.name,
                    scenario=self.scenario_for(mode, replicate, fault_t_s, air, kind, gap_s),
                    failure=self.failure,
                    filter_model=model,
                    fault_modes=self.fault_modes,
                    fault_kind=kind.kind if mode.bits else "zero",
                    pair_gap_s=gap_s,
                )
            )
        return tuple(out)

    def figure_run(self) -> RunSpec | None:
        """The run ``fig2.png`` re-flies (first replicate, first of each axis), if any."""
        try:
            mode = FaultMode.from_name(self.figure.fault)
        except ValueError:
            return None
        for variant, modes in self.variants:
            if variant == self.figure.variant and mode in modes:
                air = self.air[0]
                t_s = self.fault_times_for(0, air, mode)[0]
                gap_s = self.pair_gaps_for(variant, mode)[0]
                return RunSpec(
                    index=-1,
                    variant=variant,
                    mode=mode,
                    replicate=0,
                    seed=self.replicate_seed(0),
                    fault_t_s=t_s,
                    loop=self.loops[0],
                    air=air.name,
                    scenario=self.scenario_for(mode, 0, t_s, air, gap_s=gap_s),
                    failure=self.failure,
                    filter_model=self.filter_models[0],
                    fault_modes=self.fault_modes,
                    pair_gap_s=gap_s,
                )
        return None


# -- parsing -------------------------------------------------------------------------------------


def _fields(path: str, where: str, data: Any) -> YamlFields:
    """A reader of one mapping of a campaign file: its errors are :class:`CampaignError`."""
    return YamlFields(path, where, data, CampaignError)


def _fault_set(r: YamlFields, variant: str, value: Any) -> tuple[FaultMode, ...]:
    where = f"variants.{variant}"
    if value == "all_64":
        return all_fault_modes()
    if value == "single":
        return single_fault_modes()
    if value == "pairs":
        return pair_fault_modes()
    expected = "all_64, single or a list of fault modes (none, q, x+q, ...), or pairs"
    if not isinstance(value, list) or not value:
        raise CampaignError(f"{r.path}: {where}: expected {expected}, got {value!r}")
    modes = []
    for item in value:
        try:
            mode = FaultMode.from_name(str(item))
        except ValueError:
            raise CampaignError(
                f"{r.path}: {where}: expected fault modes such as none, q or x+q, got {item!r}"
            ) from None
        if mode in modes:
            raise CampaignError(f"{r.path}: {where}: fault mode {mode.name} listed twice")
        modes.append(mode)
    order = {m: i for i, m in enumerate(all_fault_modes())}
    return tuple(sorted(modes, key=order.__getitem__))


def _variants(r: YamlFields) -> tuple[tuple[str, tuple[FaultMode, ...]], ...]:
    raw = r.raw("variants")
    if not isinstance(raw, Mapping) or not raw:
        r.fail("variants", f"a mapping of variants ({', '.join(VARIANTS)}) to fault sets", raw)
    out = []
    for variant in raw:
        if variant not in VARIANTS:
            raise CampaignError(
                f"{r.path}: variants.{variant}: unknown variant "
                f"(expected one of {', '.join(VARIANTS)})"
            )
        modes = _fault_set(r, variant, raw[variant])
        if variant == "imm":
            extra = [m.name for m in modes if len(m.channels) > 2]
            if extra:
                raise CampaignError(
                    f"{r.path}: variants.imm: the IMM flies single faults and pairs; "
                    f"got {extra[0]} (use ukf1 for three or more channels)"
                )
        out.append((variant, modes))
    out.sort(key=lambda item: VARIANTS.index(item[0]))
    return tuple(out)


def _number_list(r: YamlFields, key: str, default: list[float], lo: float) -> tuple[float, ...]:
    value = r.raw(key, default)
    if not isinstance(value, list):
        value = [value]
    ok = value and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= lo
        for v in value
    )
    if not ok or len(set(value)) != len(value):
        r.fail(key, f"a list of distinct numbers >= {lo:g}", value)
    return tuple(float(v) for v in value)


def _check_pairs(r: YamlFields, campaign: Campaign) -> None:
    """Pairs only with the untrusted modes; ``pair_gaps_s`` only with pairs to fly."""
    pairs = campaign.imm_pairs()
    if pairs and campaign.fault_modes != "untrusted":
        raise CampaignError(
            f"{r.path}: variants.imm: the IMM's bank holds the 7 single modes with fault_modes: "
            f"{campaign.fault_modes}; got {pairs[0].name} (pairs need fault_modes: untrusted)"
        )
    if r.has("pair_gaps_s") and not pairs:
        raise CampaignError(
            f"{r.path}: pair_gaps_s: only for pair runs, and variants.imm has no two-channel "
            "fault set (variants: imm: pairs)"
        )


def _fault_times(r: YamlFields) -> tuple[float, ...] | UniformFaultTimes:
    value = r.raw("fault_times_s", [5.0])
    if not isinstance(value, Mapping):
        return _number_list(r, "fault_times_s", [5.0], lo=0.0)
    expected = "a list of times or {uniform: [lo, hi]} with 0 <= lo < hi"
    bounds = value.get("uniform") if set(value) == {"uniform"} else None
    ok = (
        isinstance(bounds, list)
        and len(bounds) == 2
        and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in bounds
        )
        and 0.0 <= bounds[0] < bounds[1]
    )
    if not ok:
        r.fail("fault_times_s", expected, value)
    return UniformFaultTimes(float(bounds[0]), float(bounds[1]))


def _entries(r: YamlFields, key: str, default: list, expected: str) -> list[YamlFields]:
    """The mappings of the list at ``key`` (``default`` if absent), each read as a field set."""
    raw = r.raw(key, default)
    if not isinstance(raw, list) or not raw:
        r.fail(key, f"a non-empty list of {expected} entries", raw)
    return [_fields(r.path, f"{key}[{i}]", item) for i, item in enumerate(raw)]


def _fault_kinds(r: YamlFields) -> tuple[FaultKindSpec, ...]:
    out = []
    for i, f in enumerate(_entries(r, "fault_kinds", [{"kind": "zero"}], "{kind: ...}")):
        kind = f.string("kind")
        if kind not in KIND_VALUES:
            f.fail("kind", f"one of {', '.join(KIND_VALUES)}", kind)
        spans = {s: _span(f, s) for s in ("accel", "gyro")}
        rate = f.number("rate_hz") if f.has("rate_hz") else None
        f.done()
        for sensor, span in spans.items():  # both ends must be a valid value of the kind
            for end in span if span is not None else (None,):
                problem = check_fault_parameters(kind, end, rate)
                if problem is not None and not (span is None and "needs one" in problem):
                    raise r.error(f"{r.path}: fault_kinds[{i}].{sensor}: {problem}")
        if KIND_VALUES.get(kind) is not None and None in spans.values():
            r.fail(f"fault_kinds[{i}]", f"accel: and gyro: ranges for kind {kind}", f.data)
        out.append(FaultKindSpec(kind, spans["accel"], spans["gyro"], rate))
    if len({k.kind for k in out}) != len(out):
        r.fail("fault_kinds", "distinct kinds", [k.kind for k in out])
    return tuple(out)


def _span(f: YamlFields, key: str) -> tuple[float, float] | None:
    if not f.has(key):
        return None
    value = f.raw(key)
    if (
        not isinstance(value, list)
        or len(value) != 2
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in value)
        or not value[0] < value[1]
    ):
        f.fail(key, "a range [lo, hi] with lo < hi", value)
    return float(value[0]), float(value[1])


def _filter_models(r: YamlFields) -> tuple[str, ...]:
    value = r.raw("filter_model", ["paper"])
    if isinstance(value, str):
        value = [value]
    if (
        not isinstance(value, list)
        or not value
        or any(v not in FILTER_MODELS for v in value)
        or len(set(value)) != len(value)
    ):
        r.fail("filter_model", f"{' or '.join(FILTER_MODELS)}, or a list of both", value)
    return tuple(value)


def _loops(r: YamlFields) -> tuple[str, ...]:
    value = r.raw("loop", ["closed"])
    if isinstance(value, str):
        value = [value]
    if (
        not isinstance(value, list)
        or not value
        or any(v not in LOOPS for v in value)
        or len(set(value)) != len(value)
    ):
        r.fail("loop", "closed, open or a list of both", value)
    return tuple(value)


def _air(r: YamlFields) -> tuple[AirSpec, ...]:
    if r.raw("air", None) is None:  # absent or null: the scenario's own air
        return (AirSpec("default"),)
    out: list[AirSpec] = []
    for entry in _entries(r, "air", [], "{name, airframe, wind}"):
        name = entry.string("name")
        blocks = {k: entry.raw(k) for k in ("airframe", "wind") if k in entry.data}
        entry.done()
        if any(a.name == name for a in out):
            entry.fail("name", "a name no other entry has", name)
        out.append(AirSpec(name, blocks))
    return tuple(out)


def _failure(r: YamlFields) -> FailureCriterion:
    f = _fields(r.path, "failure", r.raw("failure", {}) or {})
    d = FailureCriterion()
    stop = f.raw("stop", d.stop)
    if not isinstance(stop, bool):
        f.fail("stop", "true or false", stop)
    out = FailureCriterion(
        lateral_m=f.number("lateral_m", d.lateral_m, lo=1.0),
        vertical_m=f.number("vertical_m", d.vertical_m, lo=1.0),
        ground_alt_m=f.number("ground_alt_m", d.ground_alt_m),
        estimate_position_m=f.number("estimate_position_m", d.estimate_position_m, lo=1.0),
        estimate_attitude_deg=f.number("estimate_attitude_deg", d.estimate_attitude_deg, lo=1.0),
        stop=stop,
    )
    f.done()
    return out


def _scenario_block(r: YamlFields) -> Mapping[str, Any]:
    value = r.raw("scenario")
    if isinstance(value, str):
        path = Path(r.path).parent / value
        try:
            value = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError:
            raise CampaignError(f"{r.path}: scenario: no such scenario file {value!r}") from None
        except yaml.YAMLError:
            raise CampaignError(f"{r.path}: scenario: {value!r} is not valid YAML") from None
    if not isinstance(value, Mapping):
        r.fail("scenario", "a scenario mapping or the path of a scenario file", value)
    return {k: v for k, v in value.items() if k not in _CAMPAIGN_SCENARIO_FIELDS}


def parse_campaign(data: Any, path: str = "<campaign>") -> Campaign:
    """Validate parsed YAML into a :class:`Campaign`; raises :class:`CampaignError`."""
    r = _fields(path, "", data)
    figure_f = _fields(path, "figure", r.raw("figure", {}) or {})
    figure = FigureSpec(
        variant=figure_f.string("variant", "imm"), fault=figure_f.string("fault", "q")
    )
    figure_f.done()
    campaign = Campaign(
        name=r.string("name"),
        description=r.string("description", "") if "description" in r.data else "",
        seed=r.integer("seed"),
        replicates=r.integer("replicates", lo=1),
        scenario=_scenario_block(r),
        variants=_variants(r),
        fault_times_s=_fault_times(r),
        loops=_loops(r),
        air=_air(r),
        failure=_failure(r),
        figure=figure,
        path=path,
        filter_models=_filter_models(r),
        report=r.string("report", "paper"),
        fault_modes=r.string("fault_modes", "zero"),
        fault_kinds=_fault_kinds(r),
        pair_gaps_s=_number_list(r, "pair_gaps_s", [0.0], lo=0.0),
    )
    if campaign.fault_modes not in FAULT_SIGNATURES:
        r.fail("fault_modes", " or ".join(FAULT_SIGNATURES), campaign.fault_modes)
    if campaign.report not in REPORT_KINDS:
        r.fail("report", " or ".join(REPORT_KINDS), campaign.report)
    r.done()
    _check_pairs(r, campaign)
    times = campaign.fault_times_s
    if isinstance(times, UniformFaultTimes):
        times = (times.hi_s,)  # the latest time a draw can give
    pairs = campaign.imm_pairs()
    for air in campaign.air:  # every air entry and fault time must make a valid scenario
        for t_s in times:
            campaign.scenario_for(FaultMode.from_name("q"), 0, t_s, air)
            if pairs:  # and the latest second fault of a pair
                campaign.scenario_for(pairs[0], 0, t_s, air, gap_s=max(campaign.pair_gaps_s))
    return campaign


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign file; raises :class:`CampaignError` with one line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CampaignError(f"{path}: no such campaign file") from None
    except (OSError, UnicodeDecodeError):
        raise CampaignError(f"{path}: cannot read it as a text file") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise CampaignError(f"{path}: not valid YAML{where}") from None
    return parse_campaign(data, str(path))
