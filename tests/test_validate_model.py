"""validate-model: the function's report and the subcommand's JSON."""

from __future__ import annotations

import argparse
import json
import math

import pytest

from immukf_sitl.experiments import validate_model as vm

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def report():
    return vm.validate_model(duration_s=25.0, seed=2)  # includes the first turn


def test_report_has_every_metric_and_is_json(report):
    json.dumps(report)
    assert report["steps"] == 2501
    entries = [report["specific_force_mps2"], report["angular_acceleration_radps2"]]
    entries += list(report["one_step_prediction"].values())
    assert set(report["one_step_prediction"]) == {
        "position_m",
        "velocity_mps",
        "attitude_rad",
        "rates_radps",
    }
    for entry in entries:
        for key in ("rms_error", "max_error", "signal_rms"):
            assert len(entry[key]) == 3
            assert all(math.isfinite(v) and v >= 0.0 for v in entry[key])
        assert entry["rms_error_norm"] <= max(entry["max_error"]) * math.sqrt(3) + 1e-15


def test_same_parameters_predict_jsbsim_closely(report):
    assert report["specific_force_mps2"]["relative_rms_error"] < 1e-3
    one = report["one_step_prediction"]
    assert max(one["position_m"]["max_error"]) < 1e-3
    for name in ("velocity_mps", "attitude_rad", "rates_radps"):
        entry = one[name]
        # the one-step error is far below the state's change in one step
        assert entry["rms_error_norm"] < 0.2 * math.sqrt(
            sum(c**2 for c in entry["step_change_rms"])
        )


def test_a_parameter_mismatch_shows(tmp_path):
    from immukf_sitl.models.params import default_params_path

    text = default_params_path().read_text(encoding="utf-8")
    assert "C_D_alpha: 0.030" in text
    mismatched = tmp_path / "params.yaml"
    mismatched.write_text(text.replace("C_D_alpha: 0.030", "C_D_alpha: 0.132"), encoding="utf-8")
    result = vm.validate_model(duration_s=3.0, seed=0, params_path=mismatched)
    assert result["params"] == str(mismatched)
    assert result["specific_force_mps2"]["rms_error"][0] > 0.01  # more drag on x


def test_subcommand_prints_one_json_object(capsys):
    parser = argparse.ArgumentParser()
    vm.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["validate-model", "--json", "--duration", "2", "--seed", "4"])
    assert args.handler(args) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert result["seed"] == 4 and result["duration_s"] == pytest.approx(2.0)
    assert "specific force" in captured.err


def test_subcommand_rejects_a_short_duration():
    from immukf_sitl.errors import UserError

    parser = argparse.ArgumentParser()
    vm.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["validate-model", "--duration", "0.5"])
    with pytest.raises(UserError, match="--duration"):
        args.handler(args)
    with pytest.raises(ValueError, match="duration_s"):
        vm.validate_model(duration_s=0.0)
