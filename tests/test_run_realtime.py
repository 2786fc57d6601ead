"""``immukf-sitl run --realtime``: an estimator behind the air still estimates the whole flight.

Paced at 100 times the wall clock the sim sends 10 000 IMU samples a second, far more than serve
steps (about 0.4 ms a step), so serve ends the flight hundreds of steps behind with the rest
waiting in its socket. ``run`` must let it work through that backlog before stopping it: before
it did, serve was stopped 0.3 s after the sim and estimated 534 of the 1201 samples of this
flight, with no word of the rest.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from udp_tools import REPO

from immukf_sitl.mavlink.flightlog import read_estimator_log

# flies JSBSim and the estimator chain
pytestmark = pytest.mark.slow

DURATION_S = 12.0
IMU_HZ = 100.0
RUN_TIMEOUT_S = 240.0
#: The sim paced at 100x sends a sample every 0.1 ms, a few times faster than serve steps, so
#: most of the 1201 samples queue; 100 steps of backlog leaves a margin of about ten.
BEHIND_STEPS = 100


def test_every_sample_sent_is_estimated_when_the_estimator_is_behind(tmp_path: Path) -> None:
    argv = [sys.executable, "-m", "immukf_sitl.cli", "run",
            str(REPO / "scenarios" / "q_gyro_zeroed.yaml"),
            "--duration", f"{DURATION_S:g}", "--realtime", "--speed", "100",
            "--json", "--out-dir", str(tmp_path)]  # fmt: skip
    run = subprocess.run(
        argv,
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])

    sent = summary["stream"]["sim"]["HIGHRES_IMU"]
    assert sent == round(DURATION_S * IMU_HZ) + 1, summary["stream"]["sim"]
    # the path under test: serve was behind the air when the sim sent its last sample, by a
    # backlog of many steps (in step times, not seconds: a faster machine steps faster)
    backlog_steps = summary["lag_us"]["max"] / summary["step_us"]["median"]
    assert backlog_steps > BEHIND_STEPS, (summary["lag_us"], summary["step_us"])
    assert summary["stream"]["estimator"]["imu_samples"] == sent, summary["stream"]["estimator"]
    assert summary["stream"]["estimator"]["steps"] == sent
    # "the estimator catching up" is printed only if serve is still behind when run starts to
    # wait for it, after the sim has exited; how long that exit takes is the machine's (a CI
    # run whose serve lagged 0.39-0.50 s through the flight had caught up by then), so the
    # contract is the samples estimated above and the output to the flight's end below
    assert "output stopped at" not in run.stderr, run.stderr[-2000:]
    est = read_estimator_log(str(tmp_path / "estimator.tlog"))
    assert est.attitude_t_s[-1] == pytest.approx(DURATION_S, abs=0.5 / IMU_HZ)
