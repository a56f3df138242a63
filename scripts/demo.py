#!/usr/bin/env python3
"""``make demo``: run the system demo (tb/test_demo.py) and print its report.

The simulation writes build/demo/report.txt (timeline and summary), summary.json and the bus
trace demo_bus.log (candump -L format: `canplayer`, `python -m can.player`) and demo_bus.asc.
`make demo WAVES=1` also writes a GHDL waveform and prints its path.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "build" / "demo"


def main() -> int:
    for f in ("report.txt", "summary.json"):
        (OUT / f).unlink(missing_ok=True)
    waves = ROOT / "build" / "sim" / "last_waves.txt"
    waves.unlink(missing_ok=True)
    print("running the system simulation (master RTL + MCP2510 model + 4 drives) ...",
          flush=True)
    rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:xdist",
                          "tb/test_demo.py::test_demo"], cwd=ROOT)
    report = OUT / "report.txt"
    if report.exists():
        print()
        print(report.read_text())
        print(f"bus trace: {OUT / 'demo_bus.log'} (candump), {OUT / 'demo_bus.asc'}")
        if os.environ.get("WAVES", "0") not in ("", "0") and waves.exists():
            print(f"waveform: {waves.read_text().strip()}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
