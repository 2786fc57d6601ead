"""Aircraft parameter file: loading, validation errors, PWM maps."""

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from immukf_sitl.models.params import (
    AircraftParams,
    AircraftParamsError,
    MassProperties,
    ServoChannel,
    default_params_path,
    load_aircraft_params,
)


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load(default_params_path().read_text(encoding="utf-8"))


def write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_packaged_file_loads_with_design_values() -> None:
    p = load_aircraft_params()
    assert isinstance(p, AircraftParams)
    assert p.source.endswith("params.yaml")
    # values that public copies disagree on
    assert p.mass.mass_kg == 11.0
    assert p.aero.C_D_0 == 0.043
    assert p.aero.C_D_alpha == 0.030
    assert p.aero.C_n_p == -0.069
    assert p.propulsion.C_T == (0.09357, -0.06044, -0.1079)
    assert p.propulsion.C_Q == (0.005230, 0.004970, -0.01664)
    assert p.propulsion.K_V_Vs_per_rad == pytest.approx(60.0 / (2 * math.pi * 145.0))
    assert p.geometry.imu_position_m == (0.0, 0.0, 0.0)
    assert p.actuators.aileron.servo_channel == 1
    assert p.actuators.elevator.servo_channel == 2
    assert p.actuators.throttle.servo_channel == 3
    assert p.actuators.rudder.servo_channel == 4
    np.testing.assert_allclose(p.actuators.upper_limits, [0.4363, 0.4363, 0.4363, 1.0])
    inertia = p.mass.inertia_kgm2
    assert inertia[0, 2] == inertia[2, 0] == -0.1204


def test_params_are_frozen() -> None:
    p = load_aircraft_params()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.mass.mass_kg = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["mass"].pop("Jy_kgm2"), r"params\.yaml: mass\.Jy_kgm2: missing field"),
        (lambda d: d["aero"].update(C_X_0=0.1), r"aero\.C_X_0: unknown field"),
        (lambda d: d.update(wind={}), r"wind: unknown section"),
        (lambda d: d.pop("actuators"), r"actuators: missing section"),
        (lambda d: d["aero"].update(C_L_0="0.23"), r"aero\.C_L_0: expected a finite number"),
        (lambda d: d["aero"].update(C_m_q=float("nan")), r"aero\.C_m_q: expected a finite"),
        (lambda d: d["mass"].update(mass_kg=True), r"mass\.mass_kg: expected a finite number"),
        (lambda d: d["mass"].update(mass_kg=0.0), r"mass\.mass_kg: expected a value > 0"),
        (lambda d: d["mass"].update(Jz_kgm2=-1.0), r"mass\.Jz_kgm2: expected a value > 0"),
        (lambda d: d["mass"].update(Jxz_kgm2=1.3), r"mass\.Jxz_kgm2: expected Jx\*Jz > Jxz\^2"),
        (lambda d: d["mass"].update(Jz_kgm2=5.0), r"mass\.Jz_kgm2: expected principal moments"),
        (lambda d: d["geometry"].update(S_m2=0.0), r"geometry\.S_m2: expected a value > 0"),
        (lambda d: d["geometry"].update(b_m=-2.0), r"geometry\.b_m: expected a value > 0"),
        (lambda d: d["geometry"].update(c_m=0), r"geometry\.c_m: expected a value > 0"),
        (
            lambda d: d["geometry"].update(imu_position_m=[0.1, 0.0]),
            r"geometry\.imu_position_m: expected a list of 3 finite numbers",
        ),
        (
            lambda d: d["propulsion"].update(C_T=[0.1, 0.2]),
            r"propulsion\.C_T: expected a list of 3",
        ),
        (
            lambda d: d["propulsion"].update(C_Q=[0.0, 0.0, 0.0]),
            r"propulsion\.C_Q: expected a static torque coefficient",
        ),
        (
            lambda d: d["propulsion"].update(R_motor_ohm=0.0),
            r"propulsion\.R_motor_ohm: expected a value > 0",
        ),
        (
            lambda d: d["actuators"]["elevator"].update(limit_rad=0.0),
            r"actuators\.elevator\.limit_rad: expected a deflection limit",
        ),
        (
            lambda d: d["actuators"]["aileron"].update(pwm_trim=2000),
            r"actuators\.aileron\.pwm_trim: expected pwm_min < pwm_trim < pwm_max",
        ),
        (
            lambda d: d["actuators"]["rudder"].update(servo_channel=17),
            r"actuators\.rudder\.servo_channel: expected a SERVO_OUTPUT_RAW channel",
        ),
        (
            lambda d: d["actuators"]["rudder"].update(servo_channel=2.0),
            r"actuators\.rudder\.servo_channel: expected an integer",
        ),
        (
            lambda d: d["actuators"]["rudder"].update(reversed="no"),
            r"actuators\.rudder\.reversed: expected true or false",
        ),
        (
            lambda d: d["actuators"]["throttle"].update(pwm_max=900),
            r"actuators\.throttle\.pwm_max: expected pwm_max > pwm_min",
        ),
        (
            lambda d: d["actuators"]["throttle"].update(servo_channel=2),
            r"actuators\.servo_channel: expected distinct channels",
        ),
        (lambda d: d["aero"].update(alpha0_rad=-0.4), r"aero\.alpha0_rad: expected a value > 0"),
    ],
)
def test_validation_error_names_file_and_field(tmp_path: Path, raw: dict, edit, match) -> None:
    data = copy.deepcopy(raw)
    edit(data)
    with pytest.raises(AircraftParamsError, match=match) as info:
        load_aircraft_params(write(tmp_path, data))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(tmp_path / "params.yaml"))


def test_unreadable_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(AircraftParamsError, match=r"nope\.yaml: cannot read"):
        load_aircraft_params(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("mass: [1, 2\n", encoding="utf-8")
    with pytest.raises(AircraftParamsError, match=r"bad\.yaml: cannot read"):
        load_aircraft_params(bad)
    bad.write_text("- 1\n- 2\n", encoding="utf-8")
    with pytest.raises(AircraftParamsError, match=r"bad\.yaml: top level: expected a mapping"):
        load_aircraft_params(bad)


def test_direct_construction_is_validated_too() -> None:
    with pytest.raises(AircraftParamsError, match=r"^mass_kg: expected a value > 0"):
        MassProperties(mass_kg=-1.0, Jx_kgm2=1.0, Jy_kgm2=1.0, Jz_kgm2=1.0, Jxz_kgm2=0.0)


def test_pwm_round_trip_all_integer_pwms() -> None:
    act = load_aircraft_params().actuators
    for pwm in range(1000, 2001, 7):
        pwms = {1: pwm, 2: 3000 - pwm, 3: pwm, 4: pwm}
        controls = act.pwm_to_controls(pwms)
        assert act.controls_to_pwm(controls) == pwms


def test_pwm_map_values_and_clipping() -> None:
    act = load_aircraft_params().actuators
    lim = act.elevator.limit_rad
    np.testing.assert_allclose(act.pwm_to_controls({1: 1500, 2: 1500, 3: 1000, 4: 1500}), 0.0)
    np.testing.assert_allclose(
        act.pwm_to_controls({1: 2000, 2: 1000, 3: 2000, 4: 1750}), [-lim, lim, lim / 2, 1.0]
    )
    # beyond the PWM range: clipped to the limits
    np.testing.assert_allclose(act.pwm_to_controls([2500, 500, 2600, 900]), [-lim, lim, -lim, 1.0])
    assert act.controls_to_pwm([1.0, -1.0, 0.0, 2.0]) == {2: 2000, 1: 1000, 4: 1500, 3: 2000}
    # a sequence is indexed from channel 1
    np.testing.assert_allclose(act.pwm_to_controls([1500, 1750, 1500, 1500]), [lim / 2, 0, 0, 0.5])


def test_pwm_piecewise_linear_about_an_off_centre_trim_and_reversed() -> None:
    servo = ServoChannel(
        servo_channel=1, limit_rad=0.5, pwm_min=1100, pwm_trim=1400, pwm_max=1900, reversed=True
    )
    assert servo.pwm_to_rad(1400) == 0.0
    assert servo.pwm_to_rad(1900) == pytest.approx(-0.5)
    assert servo.pwm_to_rad(1100) == pytest.approx(0.5)
    assert servo.pwm_to_rad(1650) == pytest.approx(-0.25)
    assert servo.pwm_to_rad(1250) == pytest.approx(0.25)
    for pwm in range(1100, 1901):
        assert servo.rad_to_pwm(servo.pwm_to_rad(pwm)) == pwm


def test_pwm_missing_or_nan_channel() -> None:
    act = load_aircraft_params().actuators
    with pytest.raises(ValueError, match="servo channel 4 missing"):
        act.pwm_to_controls({1: 1500, 2: 1500, 3: 1500})
    with pytest.raises(ValueError, match="servo channel 3: PWM is not finite"):
        act.pwm_to_controls({1: 1500, 2: 1500, 3: float("nan"), 4: 1500})
