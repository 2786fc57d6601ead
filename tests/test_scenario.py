"""Scenario files: every shipped file loads; a wrong file gets one line naming file and field."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from immukf_sitl.scenario import ScenarioError, load_scenario

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "scenarios"
SHIPPED = sorted(SCENARIO_DIR.glob("*.yaml"))

MINIMAL = """\
name: t
duration_s: 10
seed: 1
flight_plan:
  waypoints:
    - {north_m: 300, east_m: 0, alt_m: 150}
"""


def write(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_the_shipped_scenarios_load_and_are_twins_in_still_and_real_air():
    names = {p.stem for p in SHIPPED}
    still = {"fault_free", "x_accel_zeroed", "y_accel_zeroed", "z_accel_zeroed",
             "p_gyro_zeroed", "q_gyro_zeroed", "r_gyro_zeroed"}  # fmt: skip
    assert names == still | {f"{n}_windy" for n in still} | {"fault_free_windy_10min"}
    seeds = set()
    for path in SHIPPED:
        scenario = load_scenario(path)
        seeds.add(scenario.seed)
        windy = path.stem.endswith(("_windy", "_10min"))
        assert scenario.duration_s == (600.0 if path.stem.endswith("_10min") else 90.0)
        assert scenario.wind.is_calm != windy and scenario.airframe.is_exact != windy
        assert scenario.expect is not None and scenario.expect.within_s == 1.0
        if path.stem.startswith("fault_free"):
            assert scenario.faults == () and scenario.expect.detect == "none"
            continue
        (fault,) = scenario.faults
        assert fault.t_s == 30.0 and fault.kind == "zero" and fault.end_t_s is None
        assert fault.channels == (path.stem[0],)
        assert scenario.expect.detect == path.stem[0]
    assert len(seeds) == len(SHIPPED)  # independent noise in every scenario


def test_minimal_file_gets_the_defaults(tmp_path):
    scenario = load_scenario(write(tmp_path, MINIMAL, "ok.yaml"))
    assert scenario.faults == () and scenario.manoeuvres == () and scenario.expect is None
    assert scenario.sensors.imu.accel_sigma_mps2 == 0.0245
    assert scenario.flight_plan.loop is True


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (MINIMAL + "colour: red\n", r"bad\.yaml: colour: unknown field"),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [w]}\n",
            r"bad\.yaml: faults\[0\]\.channels: expected a list of distinct channels from "
            r"x, y, z, p, q, r, got \['w'\]",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: frozen}\n",
            r"bad\.yaml: faults\[0\]\.kind: expected one of zero, stuck, bias, drift, "
            r"scale, noise, spikes, got 'frozen'",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: bias}\n",
            r"bad\.yaml: faults\[0\]\.value: kind bias needs one \(the offset",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: zero, value: 1}\n",
            r"bad\.yaml: faults\[0\]\.value: kind zero takes none, got 1",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: noise, value: 0.5}\n",
            r"bad\.yaml: faults\[0\]\.value: expected the factor on the noise sigma, > 1 for "
            r"kind noise, got 0\.5",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: scale, value: 1}\n",
            r"bad\.yaml: faults\[0\]\.value: expected the gain, finite and not 1",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: spikes, value: 0.3}\n",
            r"bad\.yaml: faults\[0\]\.rate_hz: expected spikes per second in \(0, 100\]",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 5, channels: [q], kind: bias, value: 0.1, rate_hz: 2}\n",
            r"bad\.yaml: faults\[0\]\.rate_hz: only kind spikes takes one",
        ),
        (
            MINIMAL + "faults:\n  - {t_s: 50, channels: [q]}\n",
            r"bad\.yaml: faults\[0\]\.t_s: expected a number >= 0\.0 and <= 10\.0, got 50",
        ),
        (
            "name: t\nduration_s: 10\nseed: 1\nflight_plan: {loop: true}\n",
            r"bad\.yaml: flight_plan\.waypoints: required field is missing",
        ),
        (
            "name: t\nduration_s: 10\nseed: 1\nflight_plan: {waypoints: []}\n",
            r"bad\.yaml: flight_plan\.waypoints: expected a non-empty list of waypoints",
        ),
        (
            MINIMAL.replace("north_m: 300, ", ""),
            r"bad\.yaml: flight_plan\.waypoints\[0\]\.north_m: required field is missing",
        ),
        (MINIMAL.replace("seed: 1", "seed: -3"), r"bad\.yaml: seed: expected a non-negative"),
        (
            MINIMAL + "manoeuvres:\n  - {t_s: 31, kind: barrel_roll, amplitude_rad: 0.1, "
            "duration_s: 1}\n",
            r"bad\.yaml: manoeuvres\[0\]\.kind: expected one of",
        ),
        (MINIMAL + "expect: {detect: w}\n", r"bad\.yaml: expect\.detect: expected none or"),
        ("name: [unclosed\n", r"bad\.yaml: not valid YAML at line \d+"),
        ("- just\n- a list\n", r"bad\.yaml: top level: expected a mapping"),
    ],
    ids=[
        "unknown-field",
        "bad-channel",
        "bad-kind",
        "bias-without-value",
        "zero-with-value",
        "noise-factor-below-one",
        "unit-gain",
        "spikes-without-rate",
        "rate-on-bias",
        "fault-after-end",
        "missing-waypoints",
        "empty-waypoints",
        "waypoint-field",
        "negative-seed",
        "bad-manoeuvre",
        "bad-expect",
        "not-yaml",
        "not-a-mapping",
    ],
)
def test_a_wrong_file_names_the_file_and_the_field(tmp_path, text, pattern):
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError, match=pattern) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))


def test_a_missing_file_is_one_line(tmp_path):
    path = tmp_path / "nowhere.yaml"
    with pytest.raises(ScenarioError, match=re.escape(f"{path}: no such scenario file")):
        load_scenario(path)


@pytest.mark.parametrize(
    "extra, pattern",
    [
        ("start:\n", r"bad\.yaml: start: expected a mapping, got None"),
        ("sensors:\n", r"bad\.yaml: sensors: expected a mapping, got None"),
        ("sensors: {imu: null}\n", r"bad\.yaml: sensors\.imu: expected a mapping, got None"),
        (
            "sensors: {gps: {reports_velocity_down: yes please}}\n",
            r"bad\.yaml: sensors\.gps\.reports_velocity_down: expected true or false",
        ),
        (
            "sensors: {gps: {velocity_down_sigma_mps: 0}}\n",
            r"bad\.yaml: sensors\.gps\.velocity_down_sigma_mps: expected a number > 0",
        ),
    ],
)
def test_an_empty_block_is_one_line(tmp_path, extra, pattern):
    with pytest.raises(ScenarioError, match=pattern):
        load_scenario(write(tmp_path, MINIMAL + extra))


def test_a_binary_file_is_one_line(tmp_path):
    path = tmp_path / "bin.yaml"
    path.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(ScenarioError, match=r"bin\.yaml: not a text \(UTF-8\) file"):
        load_scenario(path)
