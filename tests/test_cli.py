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
    forms = {row["form"]: row for row in result["results"]}
    assert set(forms) == {"augmented", "additive"}
    for row in forms.values():
        assert row["modes"] == 7
        assert 0 < row["median_us"] <= row["p99_us"]
        assert row["diagnostics"]["steps"] >= row["steps"]
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
