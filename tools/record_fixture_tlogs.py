#!/usr/bin/env python3
"""Record the flight tlogs CI replays (tests/data/): fault-free and q gyro zeroed.

Runs the real chain (``immukf-sitl run``: sim -> proxy -> serve over loopback UDP, lock-step)
for 40 s of each scenario (the q fault starts at 30 s and shows from about 30.6 s), truth at
the full 100 Hz so that ``observable_t_s`` is exact, and copies each run's flight.tlog into
tests/data/; both logs together stay under 2 MB.

Usage: python tools/record_fixture_tlogs.py
"""

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = {
    "fault_free.tlog": "scenarios/fault_free.yaml",
    "q_gyro_zeroed.tlog": "scenarios/q_gyro_zeroed.yaml",
}
DURATION_S = 40


def main() -> int:
    data = ROOT / "tests" / "data"
    data.mkdir(parents=True, exist_ok=True)
    total = 0
    for name, scenario in FIXTURES.items():
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run(
                [sys.executable, "-m", "immukf_sitl.cli", "run", str(ROOT / scenario),
                 "--duration", str(DURATION_S), "--out-dir", tmp],
                check=True,
            )  # fmt: skip
            shutil.copy(Path(tmp) / "flight.tlog", data / name)
        size = (data / name).stat().st_size
        total += size
        print(f"{name}: {size / 1e6:.2f} MB", file=sys.stderr)
    print(f"total {total / 1e6:.2f} MB", file=sys.stderr)
    return 0 if total <= 2_000_000 else 1


if __name__ == "__main__":
    sys.exit(main())
