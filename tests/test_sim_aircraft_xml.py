"""The JSBSim Aerosonde is params.yaml rendered: it loads and flies the reference propeller."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from immukf_sitl.models.aero import propeller_thrust_torque
from immukf_sitl.models.params import load_aircraft_params
from sim.aircraft_xml import aircraft_xml_path, main, render_aircraft_xml
from sim.driver import JsbsimDriver
from sim.truth import InitialConditions

LBF_N = 4.4482216152605
SLUG_FT3_KG_M3 = 515.378818


def test_committed_xml_equals_a_fresh_rendering():
    params = load_aircraft_params()
    committed = aircraft_xml_path().read_text(encoding="utf-8")
    assert committed == render_aircraft_xml(params), (
        "sim/aircraft/aerosonde/aerosonde.xml is out of date: run python -m sim.aircraft_xml"
    )


def test_rendering_follows_the_parameters():
    params = load_aircraft_params()
    changed = dataclasses.replace(
        params, aero=dataclasses.replace(params.aero, C_m_alpha=-2.123456789)
    )
    text = render_aircraft_xml(changed)
    assert text != render_aircraft_xml(params)
    assert "<value>-2.123456789</value>" in text
    assert render_aircraft_xml(params) == render_aircraft_xml(params)


def test_main_check_reports_drift(tmp_path, capsys):
    target = tmp_path / "aerosonde.xml"
    target.write_text("stale", encoding="utf-8")
    assert main(["--output", str(target), "--check"]) == 1
    assert main(["--output", str(target)]) == 0
    assert main(["--output", str(target), "--check"]) == 0
    assert "up to date" in capsys.readouterr().err


def test_torque_reaction_can_be_switched_off():
    params = load_aircraft_params()
    no_torque = dataclasses.replace(
        params, propulsion=dataclasses.replace(params.propulsion, prop_torque_on_roll=False)
    )
    assert 'name="propeller-torque"' in render_aircraft_xml(params)
    assert 'name="propeller-torque"' not in render_aircraft_xml(no_torque)


@pytest.mark.slow
@pytest.mark.parametrize("airspeed_mps", [15.0, 25.0, 35.0])
def test_jsbsim_thrust_and_torque_equal_the_python_reference(airspeed_mps):
    params = load_aircraft_params()
    driver = JsbsimDriver(InitialConditions(airspeed_mps=airspeed_mps), params=params)
    for delta_t in (0.0, 0.3, 0.67, 0.85, 1.0):
        driver.reset(controls=np.array([0.0, 0.0, 0.0, delta_t]), alpha_rad=0.0)
        rho = driver.get_property("atmosphere/rho-slugs_ft3") * SLUG_FT3_KG_M3
        va = driver.get_property("velocities/vt-fps") * 0.3048
        thrust_ref, torque_ref = propeller_thrust_torque(va, delta_t, rho, params)
        thrust = driver.get_property("propeller/thrust-n")
        torque = driver.get_property("propeller/torque-nm")
        print(
            f"Va {va:5.1f} m/s, delta_t {delta_t:4.2f}: JSBSim T {thrust:9.4f} N, "
            f"reference {float(thrust_ref):9.4f} N; Q {torque:7.4f} / {float(torque_ref):7.4f}"
        )
        assert thrust == pytest.approx(float(thrust_ref), rel=1e-9, abs=1e-9)
        assert torque == pytest.approx(float(torque_ref), rel=1e-9, abs=1e-9)
        # The external reaction JSBSim applies is that thrust, along body x, and -Q about x.
        applied_n = driver.get_property("forces/fbx-external-lbs") * LBF_N
        assert applied_n == pytest.approx(thrust, rel=1e-6, abs=1e-6)
        roll_nm = driver.get_property("moments/l-external-lbsft") * LBF_N * 0.3048
        assert roll_nm == pytest.approx(-torque, rel=1e-6, abs=1e-6)


@pytest.mark.slow
def test_thrust_is_negative_at_low_throttle_and_positive_at_full():
    driver = JsbsimDriver(InitialConditions(airspeed_mps=25.0))
    driver.reset(controls=np.array([0.0, 0.0, 0.0, 0.5]), alpha_rad=0.0)
    assert driver.get_property("propeller/thrust-n") < 0.0
    driver.reset(controls=np.array([0.0, 0.0, 0.0, 1.0]), alpha_rad=0.0)
    assert driver.get_property("propeller/thrust-n") > 20.0
