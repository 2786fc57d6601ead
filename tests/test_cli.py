"""The command line: help texts, JSON output, one-line user errors."""

import json
import subprocess
import sys

import pytest

from immukf_sitl.cli import build_parser, main


def test_every_subcommand_has_help(capsys):
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert "bench" in commands
    for name in commands:
        with pytest.raises(SystemExit) as exc:
            main([name, "--help"])
        assert exc.value.code == 0
        assert len(capsys.readouterr().out) > 200, name


@pytest.mark.slow
def test_bench_json_has_the_promised_fields():
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "immukf_sitl.cli",
            "bench",
            "--json",
            "--steps",
            "40",
            "--filterpy-steps",
            "5",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    result = json.loads(out.stdout)
    rows = {(row["form"], row["filter_model"]): row for row in result["results"]}
    assert set(rows) == {
        (form, model) for form in ("augmented", "additive") for model in ("paper", "real-air")
    }
    for (_, model), row in rows.items():
        assert row["modes"] == 7
        assert row["states"] == (12 if model == "paper" else 30)
        assert 0 < row["median_us"] <= row["p99_us"]
        assert row["diagnostics"]["steps"] >= row["steps"]
    ratio = rows["augmented", "real-air"]["median_us"] / rows["augmented", "paper"]["median_us"]
    assert result["real_air_ratio"] == ratio
    assert result["filterpy_ratio"] > 0
    assert "median us" in out.stderr  # the human table goes to stderr


def test_bad_argument_is_one_line_without_traceback():
    out = subprocess.run(
        [sys.executable, "-m", "immukf_sitl.cli", "bench", "--steps", "3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert out.stderr.strip() == "immukf-sitl bench: error: --steps must be at least 20, got 3"
