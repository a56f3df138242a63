"""An interrupted simulation leaves no process behind (``tb/tblib/runner.py``).

``ghdl -r`` runs the elaborated simulation binary as its own child. When pytest's per-test
``timeout`` (or Ctrl-C) interrupts a test, the stock cocotb runner kills only ``ghdl``, and the
simulation goes on without a parent, holding a core while the rest of the suite runs (it made
more tests time out on a loaded machine). ``run_cocotb`` runs each command in its own process
group and kills the group. The test interrupts a running simulation the way the timeout does
(a signal whose handler raises in the main thread) and checks that the simulation binary is
gone; the same check on the stock runner must find it still running (then it is killed here).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import cocotb
import pytest
from cocotb.triggers import Timer

from tb.tblib import runner
from tb.tblib.clkrst import start_clock

TOPLEVEL = "canopen_sdp_ram"


@cocotb.test(timeout_time=200, timeout_unit="sec")
async def run_long_simulation(dut):
    """Purpose: a simulation that runs for many seconds of wall time unless it is stopped.

    Verifies: the clock runs for 100 s of simulated time (2 G cycles, minutes of wall time);
    the pytest side interrupts it long before. (With 1 s, an orphaned simulation of the stock
    runner could finish within the test's 5 s wait on a fast machine, and the check that it
    is left running failed now and then.)
    """
    start_clock(dut.clk_i, 20_000_000)
    dut.we_i.value = 0
    dut.re_i.value = 0
    await Timer(100, "sec")
    assert dut.we_i.value == 0


class Interrupted(Exception):
    """Raised by the signal handler, as pytest-timeout raises its failure."""


def _simulation_pids(build_dir: Path) -> list[int]:
    """Live (not zombie) processes of the simulation binary running in ``build_dir``."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            cwd = os.readlink(f"/proc/{entry}/cwd")
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")[0].decode()
            state = next(line for line in Path(f"/proc/{entry}/status").read_text().splitlines()
                         if line.startswith("State:"))
        except (OSError, StopIteration):
            continue
        if cwd == str(build_dir) and Path(cmd).name == TOPLEVEL and "Z" not in state.split()[1]:
            pids.append(int(entry))
    return pids


@pytest.mark.sim
@pytest.mark.parametrize("flavour", ["run_cocotb", "stock_runner"])
def test_interrupted_simulation_leaves_no_process(request, monkeypatch, flavour):
    if flavour == "stock_runner":
        from cocotb_tools.runner import get_runner

        monkeypatch.setattr(runner, "_ghdl_runner", lambda: get_runner("ghdl"))
    build_dir = runner.build_dir_for(request.node.name)
    seen: list[int] = []
    done = threading.Event()

    def interrupt_when_running() -> None:
        while not done.is_set():
            pids = _simulation_pids(build_dir)
            if pids:
                seen.extend(pids)
                os.kill(os.getpid(), signal.SIGUSR1)
                return
            time.sleep(0.05)

    def raise_interrupted(signum, frame):
        raise Interrupted

    old = signal.signal(signal.SIGUSR1, raise_interrupted)
    watcher = threading.Thread(target=interrupt_when_running, daemon=True)
    watcher.start()
    try:
        with pytest.raises(Interrupted):
            runner.run_cocotb(toplevel=TOPLEVEL, module="tb.test_runner_cleanup",
                              name=request.node.name, stop_time_ms=150_000.0)
    finally:
        done.set()
        watcher.join()
        signal.signal(signal.SIGUSR1, old)
    assert seen, "the simulation binary was never seen running"
    deadline = time.monotonic() + 5.0
    while _simulation_pids(build_dir) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = _simulation_pids(build_dir)
    if flavour == "run_cocotb":
        assert left == [], f"simulation still running after the interrupt: {left}"
    else:
        for pid in left:
            os.kill(pid, signal.SIGKILL)
        assert left == seen, "the stock runner was expected to leave the simulation running"
