"""Command-line options shared by sub-commands, as frozen records.

Each record has one ``add_arguments`` / ``from_args`` pair.

Library code takes these records, never an ``argparse.Namespace``. One meaning per flag name
across every sub-command:

- ``--in URL`` / ``--out URL``: MAVLink connections (``udpin:HOST:PORT``, ``udpout:HOST:PORT``);
  ``serve`` may repeat ``--out`` (one per ground station);
- ``--out-dir DIR``: a directory the command writes its results into;
- ``--tlog FILE``: a tlog the command records into;
- ``--json``: one JSON object on stdout, everything for people on stderr;
- ``--signing-key FILE``: MAVLink 2 signing with the 32-byte key in FILE (64 hex characters).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from immukf_sitl.errors import UserError
from immukf_sitl.estimation.fault_modes import FAULT_SIGNATURES, FaultMode
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.servo_map import ControlMap, load_servo_map
from immukf_sitl.scenario import load_sensors
from immukf_sitl.service.detection import DetectorConfig
from immukf_sitl.service.filter_models import FILTER_MODELS, FilterModel, PaperModel, filter_model
from immukf_sitl.service.filters import VARIANTS
from immukf_sitl.service.pipeline import EstimatorPipeline, PipelineConfig

__all__ = [
    "FilterOptions",
    "RunOptions",
    "add_json_argument",
    "add_link_arguments",
    "add_signing_argument",
    "add_tlog_argument",
]


def add_json_argument(parser: argparse.ArgumentParser, what: str = "the summary") -> None:
    """``--json``: print ``what`` as one JSON object on stdout."""
    parser.add_argument(
        "--json", action="store_true", help=f"print {what} as one JSON object on stdout"
    )


def add_tlog_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """``--tlog FILE``: record ``what`` into a tlog."""
    parser.add_argument("--tlog", metavar="FILE", default=None, help=f"record {what} to FILE")


def add_signing_argument(parser: argparse.ArgumentParser) -> None:
    """``--signing-key FILE`` (dest ``signing_key``): MAVLink 2 signing on the links."""
    parser.add_argument(
        "--signing-key",
        metavar="FILE",
        default=None,
        help="sign everything sent and accept only correctly signed MAVLink 2 input, with the "
        "32-byte key held in FILE as 64 hex characters (docs/security.md; default: no signing)",
    )


def add_link_arguments(
    parser: argparse.ArgumentParser,
    in_default: str | None,
    out_default: str,
    in_help: str = "",
    out_help: str = "",
    repeat_out: bool = False,
) -> None:
    """``--in URL`` (dest ``in_url``, if ``in_default`` is given) and ``--out URL`` (``out_url``).

    With ``repeat_out`` the ``--out`` option may be given several times and ``out_url`` is a
    list (default ``[out_default]``, filled in by the caller when the user gave none).
    """
    if in_default is not None:
        parser.add_argument(
            "--in",
            dest="in_url",
            metavar="URL",
            default=in_default,
            help=f"{in_help} (default: %(default)s)",
        )
    if repeat_out:
        parser.add_argument(
            "--out",
            dest="out_url",
            metavar="URL",
            action="append",
            default=None,
            help=f"{out_help}; repeat for several (default: {out_default})",
        )
    else:
        parser.add_argument(
            "--out",
            dest="out_url",
            metavar="URL",
            default=out_default,
            help=f"{out_help} (default: %(default)s)",
        )


@dataclass(frozen=True)
class FilterOptions:
    """Which filter runs and how it decides: the options of ``serve``, ``replay`` and ``run``.

    Attributes
    ----------
    variant : str
        ``ukf1``, ``ukf2``, ``ukf3`` or ``imm`` (the paper's UKF-1 to UKF-4).
    true_mode : FaultMode or None
        The mode UKF-1 is matched to.
    detector : DetectorConfig
        Declaration and clearing thresholds and dwells, settling time.
    filter_model : FilterModel
        The filter's aircraft model with its tuning and Markov chain (``--filter-model``).
    params_path : str or None
        Aircraft parameter YAML (None: the packaged Aerosonde).
    sensors : SensorSpec
        What the filter is told about the sensors: noise sigmas and bias sigmas of the spec
        sheet (``--sensors FILE``), never a simulation's true biases.
    sensors_path : str or None
        The file ``sensors`` came from.
    servo_map_path : str or None
        ``--servo-map``: ArduPilot's SERVOn_* parameters of the aircraft (None: the vehicle's
        or the log's own, else the params file's channel map).
    """

    variant: str = "imm"
    true_mode: FaultMode | None = None
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    filter_model: FilterModel = field(default_factory=PaperModel)
    params_path: str | None = None
    sensors: SensorSpec = field(default_factory=SensorSpec)
    sensors_path: str | None = None
    servo_map_path: str | None = None

    def __post_init__(self) -> None:
        # a settling time left to the filter model is the filter model's
        object.__setattr__(self, "detector", self.detector.resolved(self.filter_model.settle_s))

    #: (flag, record, attribute, help): the numeric options, each written once
    _NUMERIC = (
        ("--threshold", "detector", "threshold", "mode probability that declares a fault"),
        ("--dwell", "detector", "dwell_s", "seconds above the threshold before declaring"),
        (
            "--clear-threshold",
            "detector",
            "clear_threshold",
            "probability below which a declared fault clears",
        ),
        (
            "--clear-dwell",
            "detector",
            "clear_dwell_s",
            "seconds below the clear threshold before clearing",
        ),
        (
            "--settle",
            "detector",
            "settle_s",
            "seconds after alignment with no declarations (default: the filter model's, 3 for "
            "paper, 10 for real-air: its correction time constant)",
        ),
        (
            "--recovery-probability",
            "filter_model",
            "recovery_probability",
            "per-step Markov probability fault -> fault-free; --filter-model real-air: 1e-7 "
            "(docs/design/detection-and-tuning.md)",
        ),
    )

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Add the filter and detection options (defaults from the records)."""
        defaults = {"detector": DetectorConfig(), "filter_model": PaperModel()}
        group = parser.add_argument_group("filter and detection")
        group.add_argument(
            "--variant",
            choices=VARIANTS,
            default="imm",
            help="the paper's filter variant: ukf1 (aero model matched to --true-mode), ukf2 "
            "(aero model, fault-free), ukf3 (INS equations, fault-free), imm (UKF-4, 7 modes; "
            "default)",
        )
        group.add_argument(
            "--true-mode", default=None, help="fault mode UKF-1 is matched to (e.g. q, x+q)"
        )
        group.add_argument(
            "--filter-model",
            choices=tuple(FILTER_MODELS),
            default="paper",
            help="the aircraft model of ukf1/ukf2/imm: paper (12 states: still air, exact "
            "sensors and airframe; default) or real-air (30 states: wind, gyro biases, force "
            "and moment corrections, rotational gusts, GPS error, with a sticky Markov chain of "
            "1e-7 per step; "
            "docs/design/real-air-model.md)",
        )
        group.add_argument(
            "--fault-modes",
            dest="fault_signature",
            choices=FAULT_SIGNATURES,
            default="zero",
            help="what a fault mode predicts on its failed channel: zero (the paper's zero plus "
            "noise and its fixed bank of single faults; default) or untrusted (dead, stuck, or "
            "healthy plus a learnt offset anywhere in the sensor's range; the bank re-bases on "
            "each declaration, so further faults are found beside it, and each failure is "
            "named; docs/design/detection-and-tuning.md)",
        )
        for flag, record, attribute, text in cls._NUMERIC:
            default = getattr(defaults[record], attribute)
            group.add_argument(
                flag,
                dest=attribute,
                type=float,
                default=default,
                help=text if default is None else f"{text} (default {default})",
            )
        # the chain's recovery default depends on --filter-model (real-air: 1e-7)
        parser.set_defaults(recovery_probability=None)
        group.add_argument(
            "--params",
            dest="params_path",
            default=None,
            metavar="FILE",
            help="aircraft parameter YAML (default: the packaged Aerosonde)",
        )
        group.add_argument(
            "--sensors",
            dest="sensors_path",
            default=None,
            metavar="FILE",
            help="YAML with a scenario's 'sensors:' block (or a whole scenario): the noise and "
            "bias sigmas the filter assumes (default: Beard & McLain's; `run` passes the "
            "scenario's own)",
        )
        group.add_argument(
            "--servo-map",
            dest="servo_map_path",
            default=None,
            metavar="FILE",
            help="ArduPilot parameter file (.parm/.param, NAME VALUE or NAME,VALUE per line, or "
            "YAML) with SERVOn_FUNCTION/MIN/TRIM/MAX/REVERSED and MIXING_GAIN: which output "
            "drives which surface, elevons and V-tails mixed (default: the SERVOn_* the vehicle "
            "answers or the log carries, else the params file's channels)",
        )

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> FilterOptions:
        """The record of parsed options; a user mistake raises :class:`UserError`."""
        true_mode = None
        if args.variant == "ukf1":
            if not args.true_mode:
                raise UserError("--variant ukf1 needs --true-mode (the mode it is matched to)")
            try:
                true_mode = FaultMode.from_name(args.true_mode)
            except ValueError as exc:
                raise UserError(f"--true-mode: {exc}") from None
        values: dict[str, dict[str, float]] = {"detector": {}, "filter_model": {}}
        for flag, record, attribute, _ in cls._NUMERIC:
            value = getattr(args, attribute)
            if value is None:
                continue  # a default that depends on another option
            if not math.isfinite(value):
                raise UserError(f"{flag}: expected a finite number, got {value}")
            values[record][attribute] = value
        try:
            detector = DetectorConfig(**values["detector"])
            model = filter_model(
                getattr(args, "filter_model", "paper"),
                fault_signature=getattr(args, "fault_signature", "zero"),
                **values["filter_model"],
            )
            model.transition((FaultMode(0), FaultMode(1)))  # validates the chain
        except ValueError as exc:
            raise UserError(str(exc)) from None
        if args.params_path is not None and not Path(args.params_path).is_file():
            raise UserError(f"--params {args.params_path}: no such file")
        sensors = SensorSpec()
        if args.sensors_path is not None:
            sensors = load_sensors(args.sensors_path).spec_sheet()
        servo_map_path = getattr(args, "servo_map_path", None)
        if servo_map_path is not None:
            load_servo_map(servo_map_path)  # a bad or incomplete map: one line, before any step
        return cls(
            args.variant,
            true_mode,
            detector,
            model,
            args.params_path,
            sensors,
            args.sensors_path,
            servo_map_path,
        )

    def pipeline(self) -> EstimatorPipeline:
        """The estimator pipeline these options describe (aircraft from ``params_path``)."""
        config = PipelineConfig(
            variant=self.variant,
            true_mode=self.true_mode,
            filter_model=self.filter_model,
            detector=self.detector,
            sensors=self.sensors,
        )
        params = load_aircraft_params(self.params_path)
        pipeline = EstimatorPipeline(params, config)
        if self.servo_map_path is not None:
            pipeline.control_map = ControlMap(load_servo_map(self.servo_map_path), params)
        return pipeline

    def to_argv(self) -> list[str]:
        """The same options as command-line arguments (``run`` passes them to ``serve``)."""
        argv = ["--variant", self.variant]
        argv += ["--filter-model", self.filter_model.name]
        argv += ["--fault-modes", self.filter_model.fault_signature]
        if self.true_mode is not None:
            argv += ["--true-mode", self.true_mode.name]
        for flag, record, attribute, _ in self._NUMERIC:
            argv += [flag, repr(getattr(getattr(self, record), attribute))]
        if self.params_path is not None:
            argv += ["--params", self.params_path]
        if self.sensors_path is not None:
            argv += ["--sensors", self.sensors_path]
        if self.servo_map_path is not None:
            argv += ["--servo-map", self.servo_map_path]
        return argv


@dataclass(frozen=True)
class RunOptions:
    """How ``run`` flies a scenario through the three processes.

    Attributes
    ----------
    scenario_path : str
    out_dir : Path or None
        Where the run's files go (None: ``out/<scenario name>``).
    realtime : bool
        Pace the sim to the wall clock (times ``speed``).
    speed : float or None
    duration_s : float or None
        Fly this long instead of the scenario's ``duration_s``.
    gcs : tuple of str
        Extra ground stations the estimator publishes to.
    truth_hz : float or None
        Thin the truth in ``flight.tlog`` to this rate.
    keep_intermediate : bool
        Keep ``sim.tlog`` and ``proxy.tlog``.
    verbose : bool
        Echo the children's stderr.
    realtime_priority : int or None
        Run ``serve`` under SCHED_FIFO at this priority.
    sign : bool
        Sign every link of the chain with a key made for this run (``OUT_DIR/signing.key``).
    signing_key_path : str or None
        Sign every link with this key file instead.
    filter : FilterOptions
    """

    scenario_path: str
    out_dir: Path | None = None
    realtime: bool = False
    speed: float | None = None
    duration_s: float | None = None
    gcs: tuple[str, ...] = ()
    truth_hz: float | None = None
    keep_intermediate: bool = False
    verbose: bool = False
    realtime_priority: int | None = None
    sign: bool = False
    signing_key_path: str | None = None
    filter: FilterOptions = field(default_factory=FilterOptions)

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        """Add ``run``'s options (the filter's included)."""
        parser.add_argument("scenario_path", metavar="SCENARIO", help="scenario YAML file")
        parser.add_argument(
            "--out-dir",
            default=None,
            metavar="DIR",
            help="directory for the run's files (default out/<scenario name>)",
        )
        add_json_argument(parser)
        parser.add_argument(
            "--realtime", action="store_true", help="pace the sim to the wall clock (for watching)"
        )
        parser.add_argument("--speed", type=float, default=None, help="with --realtime: X times")
        parser.add_argument(
            "--duration", dest="duration_s", type=float, default=None, help="override duration_s"
        )
        parser.add_argument(
            "--gcs",
            action="append",
            default=None,
            metavar="URL",
            help="also publish to this ground station (e.g. udpout:127.0.0.1:14550); repeatable",
        )
        parser.add_argument(
            "--truth-hz",
            type=float,
            default=None,
            help="thin the truth in flight.tlog to this rate (default: every step)",
        )
        parser.add_argument(
            "--keep-intermediate",
            action="store_true",
            help="keep sim.tlog and proxy.tlog beside the merged flight.tlog",
        )
        parser.add_argument("--verbose", action="store_true", help="echo the children's stderr")
        parser.add_argument(
            "--realtime-priority",
            type=int,
            default=None,
            metavar="PRIO",
            help="run serve under SCHED_FIFO at PRIO (1-99; needs CAP_SYS_NICE)",
        )
        parser.add_argument(
            "--sign",
            action="store_true",
            help="MAVLink 2 signing on every link: a key made for this run (OUT_DIR/signing.key) "
            "is passed to sim, proxy and serve",
        )
        parser.add_argument(
            "--signing-key",
            dest="signing_key_path",
            metavar="FILE",
            default=None,
            help="like --sign, with the key in FILE (64 hex characters; docs/security.md)",
        )
        FilterOptions.add_arguments(parser)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> RunOptions:
        """The record of parsed options; range checks that need no scenario raise here."""
        if args.speed is not None and (not args.realtime or not 0.0 < args.speed <= 100.0):
            raise UserError("--speed: expected a factor in (0, 100], with --realtime")
        if args.truth_hz is not None and not 0.0 < args.truth_hz <= 100.0:
            raise UserError(f"--truth-hz: expected a rate in (0, 100], got {args.truth_hz}")
        names = {f.name for f in fields(cls)} - {"filter", "out_dir", "gcs"}
        return cls(
            out_dir=Path(args.out_dir) if args.out_dir else None,
            gcs=tuple(args.gcs or ()),
            filter=FilterOptions.from_args(args),
            **{name: getattr(args, name) for name in names},
        )
