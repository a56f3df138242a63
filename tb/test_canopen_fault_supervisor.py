"""Bench of ``canopen_fault_supervisor``: error latch, state watchdog, re-init, CAN status.

The bench drives ``tick_us_i`` itself (one strobe per clock where a test wants time to pass), so
microsecond timers run in clock cycles and every figure is exact: the watchdog after WATCHDOG_US
ticks in one state, the back-off re-initialisation every 1000 * REINIT_BACKOFF_MS ticks + 1
clock, the bus-off re-initialisation request after ceil(128 * 160 bits / bit rate) in µs, the
St0 entry RESET and the init_done mask, the latch sources and the St13 clear. Expected values
come from the entity's documented rules (docs/canopen_fault_supervisor.md), not from the RTL.
"""

from __future__ import annotations

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import param, run_cocotb
from tb.tblib.strobe_ports import StrobePorts

CLK_HZ = 20_000_000
EFLG_TXBO = 1 << 5

INPUTS = ("tick_us_i", "init_done_i", "init_fail_i", "chip_lost_i", "int_errif_i",
          "rx_overflow_i", "tx_fault_i", "host_reinit_i", "node_error_i", "state_change_i",
          "in_init_i", "in_error_i")
#: inputs that return to 0 after the cycles of one step (levels: init_done, init_fail, in_init)
STROBES = ("tick_us_i", "chip_lost_i", "int_errif_i", "rx_overflow_i", "tx_fault_i",
           "host_reinit_i", "node_error_i", "state_change_i", "in_error_i")
LATCH = ("err_can_o", "err_busoff_o", "err_reinit_o", "err_node_o", "err_chip_o")


def busoff_us(bitrate_bps: int) -> int:
    """128 longest frames (160 bits) at the bit rate, rounded up to whole µs."""
    return -(-128 * 160 * 1_000_000 // bitrate_bps)


class TB:
    def __init__(self, dut) -> None:
        self.dut = dut
        self.watchdog_us = param("WATCHDOG_US")
        self.backoff_us = 1000 * param("REINIT_BACKOFF_MS")
        self.busoff_us = busoff_us(param("CAN_BITRATE_BPS"))
        self.ports = StrobePorts(dut, dut.clk_i, STROBES)
        self.out = self.ports.out
        self.step = self.ports.step  # step(n, **inputs): n clocks, then strobes back to 0

    async def start(self) -> None:
        start_clock(self.dut.clk_i, CLK_HZ)
        self.ports.zero(*INPUTS, "tec_i", "rec_i", "eflg_i")
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        await FallingEdge(self.dut.clk_i)

    async def edges_until(self, name: str, limit: int, **inputs: int) -> int:
        """Clock edges (with ``inputs`` held) until output ``name`` is 1; fails after limit."""
        self.ports.apply(**inputs)
        for n in range(1, limit + 1):
            await FallingEdge(self.dut.clk_i)
            if self.out(name):
                return n
        raise AssertionError(f"{name} not set within {limit} clocks")


async def check_watchdog(dut, expected_ticks: int) -> None:
    tb = TB(dut)
    await tb.start()
    await tb.step(state_change_i=1)
    # no tick, no time: the watchdog stays low however long the state lasts
    await tb.step(3 * tb.watchdog_us)
    assert tb.out("watchdog_o") == 0
    await tb.step(expected_ticks - 1, tick_us_i=1)
    assert tb.out("watchdog_o") == 0, "watchdog set early"
    await tb.step(1, tick_us_i=1)
    assert tb.out("watchdog_o") == 1, f"watchdog not set after {expected_ticks} us"
    await tb.step(5, tick_us_i=1)
    assert tb.out("watchdog_o") == 1, "watchdog must stay set until the state changes"
    await tb.step(state_change_i=1)
    assert tb.out("watchdog_o") == 0, "a state change restarts the watchdog"


@cocotb.test(timeout_time=2, timeout_unit="ms")
async def run_watchdog(dut):
    """watchdog_o rises at the WATCHDOG_US-th µs tick after a state change, and only then."""
    await check_watchdog(dut, param("WATCHDOG_US"))


@cocotb.test(timeout_time=2, timeout_unit="ms", expect_fail=True)
async def run_watchdog_checker_can_fail(dut):
    """The watchdog check with a count one µs short must fail (the checker is live)."""
    await check_watchdog(dut, param("WATCHDOG_US") - 1)


@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_backoff_reinit(dut):
    """St0 with init_fail: a RESET every back-off period (ticks + 1 clock), none without it."""
    tb = TB(dut)
    await tb.start()
    dut.in_init_i.value = 1
    await tb.step(2 * tb.backoff_us, tick_us_i=1)
    assert tb.out("reinit_o") == 0, "no RESET while the initialisation has not failed"
    first = await tb.edges_until("reinit_o", 3 * tb.backoff_us, init_fail_i=1, tick_us_i=1)
    assert first == tb.backoff_us + 1, f"first RESET after {first} clocks"
    await tb.step(1, tick_us_i=1)
    assert tb.out("reinit_o") == 0, "reinit_o is a one-clock pulse"
    second = await tb.edges_until("reinit_o", 3 * tb.backoff_us, tick_us_i=1)
    assert second + 1 == tb.backoff_us + 1, f"RESET interval {second + 1} clocks"
    # leaving St0 stops the back-off
    dut.in_init_i.value = 0
    await tb.step(2 * tb.backoff_us, tick_us_i=1)
    assert tb.out("reinit_o") == 0


@cocotb.test(timeout_time=2, timeout_unit="ms")
async def run_entry_reinit_and_mask(dut):
    """Entering St0 with the chip initialised: one RESET, init_done masked until it restarted."""
    tb = TB(dut)
    await tb.start()
    dut.init_done_i.value = 1
    await tb.step(2)
    assert tb.out("ev_init_o") == 0 and tb.out("init_done_o") == 1
    dut.in_init_i.value = 1
    dut.state_change_i.value = 1
    await ReadOnly()
    assert tb.out("init_done_o") == 0, "masked in the entry cycle"
    await FallingEdge(dut.clk_i)
    dut.state_change_i.value = 0
    assert tb.out("reinit_o") == 1, "RESET pulse after the entry"
    assert tb.out("init_done_o") == 0
    await tb.step(10)
    assert tb.out("init_done_o") == 0, "the old init_done must not let St0 leave"
    dut.init_done_i.value = 0
    await tb.step(3)
    dut.init_done_i.value = 1
    await ReadOnly()
    assert tb.out("init_done_o") == 1 and tb.out("ev_init_o") == 1, "restart seen, event"
    await FallingEdge(dut.clk_i)
    # a chip reset found by the controller: St13 reports it, St0 asks for no second RESET
    dut.in_init_i.value = 0
    await tb.step(chip_lost_i=1)
    assert tb.out("err_chip_o") == 1
    await tb.step(in_error_i=1)
    assert tb.out("err_chip_o") == 0
    await tb.step(in_init_i=1, state_change_i=1)
    await tb.step(5)
    assert tb.out("reinit_o") == 0 and tb.out("init_done_o") == 1


@cocotb.test(timeout_time=2, timeout_unit="ms")
async def run_error_latch(dut):
    """Each source sets its flag at the next edge; St13 clears all; a clear wins a tie."""
    tb = TB(dut)
    await tb.start()
    sources = (("int_errif_i", "err_can_o"), ("rx_overflow_i", "err_can_o"),
               ("tx_fault_i", "err_can_o"), ("host_reinit_i", "err_reinit_o"),
               ("node_error_i", "err_node_o"), ("chip_lost_i", "err_chip_o"))
    for src, flag in sources:
        await tb.step(**{src: 1})
        for name in LATCH:
            assert tb.out(name) == int(name == flag), f"{src}: {name}"
        await tb.step(5)
        assert tb.out(flag) == 1, f"{flag} must stay latched"
        await tb.step(in_error_i=1)
        assert all(tb.out(name) == 0 for name in LATCH), "St13 clears the latch"
    await tb.step(int_errif_i=1, in_error_i=1)
    assert tb.out("err_can_o") == 0, "an error in the St13 clear cycle is cleared with it"


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_busoff(dut):
    """Bus-off (EFLG.TXBO, registered) for the recovery bound: err_busoff; init_done 0 resets."""
    tb = TB(dut)
    await tb.start()
    dut.tec_i.value = 0xA5
    dut.rec_i.value = 0x3C
    dut.init_done_i.value = 1
    dut.eflg_i.value = EFLG_TXBO
    await tb.step(1)
    assert (tb.out("tec_o"), tb.out("rec_o"), tb.out("eflg_o")) == (0xA5, 0x3C, EFLG_TXBO)
    # half the bound, then the controller restarts (init_done 0): the count starts again
    await tb.step(tb.busoff_us // 2, tick_us_i=1)
    await tb.step(1, init_done_i=0)
    dut.init_done_i.value = 1
    # the registered EFLG already shows TXBO: one edge per tick from here
    n = await tb.edges_until("err_busoff_o", 2 * tb.busoff_us, tick_us_i=1)
    assert n == tb.busoff_us, f"err_busoff after {n} us, bound {tb.busoff_us} us"
    await tb.step(in_error_i=1)
    await tb.step(3 * tb.busoff_us // 2, tick_us_i=1)
    assert tb.out("err_busoff_o") == 0, "once per bus-off: no second request while it lasts"


@pytest.mark.sim
@pytest.mark.parametrize("generics", [
    {"WATCHDOG_US": 7, "REINIT_BACKOFF_MS": 1, "CAN_BITRATE_BPS": 1_000_000},
    {"WATCHDOG_US": 40, "REINIT_BACKOFF_MS": 2, "CAN_BITRATE_BPS": 500_000},
], ids=["1M", "500k"])
def test_canopen_fault_supervisor(request, generics):
    run_cocotb(toplevel="canopen_fault_supervisor", module="tb.test_canopen_fault_supervisor",
               name=request.node.name, parameters=generics, stop_time_ms=40)
