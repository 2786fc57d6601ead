"""ArduPilot's servo outputs to the model's controls: SERVOn_* parameters, elevons and V-tails.

The expected values are worked by hand from ArduPlane's mixer (``left = g (pitch - roll)``,
``right = g (pitch + roll)`` for elevons, ``left = g (pitch + yaw)``, ``right = g (pitch - yaw)``
for a V-tail) and ``SRV_Channel::pwm_from_angle`` (trim + fraction of the span on its side).
"""

from __future__ import annotations

import numpy as np
import pytest

from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.servo_map import (
    ControlMap,
    ServoMap,
    ServoMapError,
    ServoOutput,
    has_servo_functions,
    load_servo_map,
)

PARAMS = load_aircraft_params()
LIMIT = PARAMS.actuators.elevator.limit_rad


def _pwm(by_channel: dict[int, int]) -> list[int]:
    out = [0] * 16
    for channel, value in by_channel.items():
        out[channel - 1] = value
    return out


def test_elevons_worked_by_hand() -> None:
    elevons = ServoMap.layout("elevon")
    # pitch 0.4, roll 0.2, g 0.5: left 0.1 -> 1550 us, right 0.3 -> 1650 us
    assert elevons.pwm([0.4, 0.2, 0.0, 0.5]) == {1: 1550, 2: 1650, 3: 1500, 4: 1500}
    commands = elevons.commands(_pwm({1: 1550, 2: 1650, 3: 1500, 4: 1500}))
    np.testing.assert_allclose(commands, [0.4, 0.2, 0.0, 0.5], atol=1e-12)


def test_vtail_worked_by_hand() -> None:
    vtail = ServoMap.layout("vtail")
    # pitch 0.2, yaw -0.4: left 0.5 (0.2 - 0.4) = -0.1 -> 1450 us, right 0.3 -> 1650 us
    assert vtail.pwm([0.2, 0.0, -0.4, 1.0]) == {1: 1500, 2: 1450, 3: 2000, 4: 1650}
    commands = vtail.commands(_pwm({1: 1500, 2: 1450, 3: 2000, 4: 1650}))
    np.testing.assert_allclose(commands, [0.2, 0.0, -0.4, 1.0], atol=1e-12)


def test_reversed_asymmetric_output() -> None:
    out = ServoOutput(
        channel=2, function=19, pwm_min=1100, pwm_trim=1400, pwm_max=1900, reversed=True
    )
    # reversed: a pitch-up command of 0.5 moves below trim by half of (trim - min) = 150 us
    assert out.pwm(0.5) == 1250
    assert out.fraction(1250) == pytest.approx(0.5)
    assert out.fraction(1900) == pytest.approx(-1.0)
    assert out.fraction(2100) == pytest.approx(-1.0)  # beyond MAX: clipped


def test_commands_become_the_deflections_the_airframe_needs() -> None:
    """A pitch-up command is the elevator that gives a nose-up moment (C_m_delta_e < 0)."""
    control = ControlMap(ServoMap.layout("conventional"), PARAMS)
    de, da, dr, dt = control.pwm_to_controls(_pwm({1: 1750, 2: 1750, 3: 1750, 4: 1750}))
    aero = PARAMS.aero
    assert aero.C_m_delta_e * de > 0.0  # nose up
    assert aero.C_ell_delta_a * da > 0.0  # roll right
    assert aero.C_n_delta_r * dr > 0.0  # yaw right
    assert abs(de) == pytest.approx(LIMIT / 2)
    assert dt == pytest.approx(0.75)


@pytest.mark.parametrize("layout", ["conventional", "elevon", "vtail"])
def test_round_trip_within_one_microsecond(layout: str) -> None:
    control = ControlMap(ServoMap.layout(layout), PARAMS)
    rng = np.random.default_rng(7)
    for _ in range(200):
        controls = np.concatenate([rng.uniform(-LIMIT, LIMIT, 3), rng.uniform(0, 1, 1)])
        pwm = _pwm(control.controls_to_pwm(controls))
        back = control.pwm_to_controls(pwm)
        # a mixed surface is rounded to 1 us of 500 on each of two outputs, then unmixed
        np.testing.assert_allclose(back[:3], controls[:3], atol=LIMIT / 250)
        assert back[3] == pytest.approx(controls[3], abs=1 / 1000)


def test_same_function_on_two_outputs_is_averaged() -> None:
    params = {
        **ServoMap.layout("conventional").to_params(),
        "SERVO5_FUNCTION": 4,
        "SERVO5_MIN": 1000,
        "SERVO5_TRIM": 1500,
        "SERVO5_MAX": 2000,
        "SERVO5_REVERSED": 1,
    }
    servo_map = ServoMap.from_params(params)
    pwm = _pwm({1: 1600, 2: 1500, 3: 1000, 4: 1500, 5: 1400})  # both say roll right 0.2
    assert servo_map.commands(pwm)[1] == pytest.approx(0.2)


@pytest.mark.parametrize(
    ("drop", "named"),
    [(4, "rudder is unassigned"), (1, "aileron is unassigned"), (3, "throttle is unassigned")],
)
def test_unassigned_control_is_one_line(drop: int, named: str) -> None:
    params = ServoMap.layout("conventional").to_params()
    params[f"SERVO{drop}_FUNCTION"] = 0
    with pytest.raises(ServoMapError, match=named) as info:
        ServoMap.from_params(params, "test.parm")
    assert "\n" not in str(info.value)
    assert "SERVOn_FUNCTION" in str(info.value)


def test_elevon_without_its_pair() -> None:
    params = ServoMap.layout("elevon").to_params()
    params["SERVO2_FUNCTION"] = 19
    with pytest.raises(ServoMapError, match="77 .elevon_left. needs its pair 78"):
        ServoMap.from_params(params)


def test_unknown_functions_are_ignored() -> None:
    params = {**ServoMap.layout("conventional").to_params(), "SERVO6_FUNCTION": 2}  # flap
    params["SERVO7_FUNCTION"] = 33  # a quadplane motor
    assert len(ServoMap.from_params(params).outputs) == 4


@pytest.mark.parametrize(
    "text",
    [
        "SERVO1_FUNCTION 77\nSERVO2_FUNCTION 78\nSERVO3_FUNCTION 70\nSERVO4_FUNCTION 21\n"
        "# comment\nMIXING_GAIN 0.5\n",
        "SERVO1_FUNCTION,77\nSERVO2_FUNCTION,78\nSERVO3_FUNCTION,70\nSERVO4_FUNCTION,21\n",
        "SERVO1_FUNCTION: 77\nSERVO2_FUNCTION: 78\nSERVO3_FUNCTION: 70\nSERVO4_FUNCTION: 21\n",
    ],
    ids=["mavproxy", "mission-planner", "yaml"],
)
def test_parameter_files(tmp_path, text: str) -> None:
    path = tmp_path / "plane.parm"
    path.write_text(text)
    servo_map = load_servo_map(path)
    assert [o.function for o in servo_map.outputs] == [77, 78, 70, 21]
    assert has_servo_functions({"SERVO1_FUNCTION": 77})
    assert not has_servo_functions({"SERVO_AUTO_TRIM": 0})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("SERVO1_FUNCTION abc\n", "SERVO1_FUNCTION is not a number"),
        ("SERVO1_FUNCTION\n", "expected NAME VALUE"),
        ("ARSPD_TYPE 0\n", "no SERVOn_FUNCTION"),
        ("SERVO1_FUNCTION 4\nSERVO2_FUNCTION 19\nSERVO3_FUNCTION 70\n", "rudder is unassigned"),
    ],
)
def test_bad_parameter_files(tmp_path, text: str, message: str) -> None:
    path = tmp_path / "bad.parm"
    path.write_text(text)
    with pytest.raises(ServoMapError, match=message):
        load_servo_map(path)
    with pytest.raises(ServoMapError, match="cannot read"):
        load_servo_map(tmp_path / "missing.parm")
