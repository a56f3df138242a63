#!/usr/bin/env python3
"""``make demo``: run the two system demos and print their reports.

1. CANopen (tb/test_demo.py): the master configures four CiA 402 drives by SDO, starts them and
   runs a PDO cycle at 2 ms SYNC; one drive drops out and is reported.
2. Omni-ID (tb/test_demo_omni.py): the same master in Omni-ID mode runs the NCTU thesis'
   four-wheel robot network (broadcast set-points, Omni SYNC re-phasing the wheels' drifting
   clocks, node queries); one wheel drops out and the master stops all nodes.

Each writes a timeline and summary (build/demo/report.txt, omni_report.txt), a JSON summary and
the bus trace (candump -L format: `canplayer`, `python -m can.player`). Both simulations run in
parallel (two processes). `make demo WAVES=1` also writes GHDL waveforms and prints their paths.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "build" / "demo"
DEMOS = (
    ("CANopen: 4 drives, SDO configuration list, PDO cycle", "tb/test_demo.py::test_demo",
     "report.txt", ("demo_bus.log", "demo_bus.asc")),
    ("Omni-ID: NCTU 4-wheel robot network", "tb/test_demo_omni.py::test_demo_omni",
     "omni_report.txt", ("omni_bus.log",)),
)


def main() -> int:
    for _, _, report, _ in DEMOS:
        (OUT / report).unlink(missing_ok=True)
    waves = ROOT / "build" / "sim" / "last_waves.txt"
    waves.unlink(missing_ok=True)
    print("running the system simulations (master RTL + MCP2510 model + slave models) ...",
          flush=True)
    rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-n", "2",
                          *(test for _, test, _, _ in DEMOS)], cwd=ROOT)
    for title, _, report, traces in DEMOS:
        path = OUT / report
        print(f"\n=== {title} ===\n")
        if path.exists():
            print(path.read_text())
            print("bus trace: " + ", ".join(str(OUT / t) for t in traces))
        else:
            print(f"(no report: {path} missing, see the test output above)")
    if os.environ.get("WAVES", "0") not in ("", "0") and waves.exists():
        print(f"waveform(s): {waves.read_text().strip()}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
