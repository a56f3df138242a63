"""Bench of ``canopen_sync_timebase``: time base, SYNC producer, SYNC counter, window.

A cycle-exact Python model (:class:`TimebaseModel`, written from the entity's header with plain
32-bit arithmetic: ``sync_timer + 1 >= period`` ends a period (the DUT shows ``sync_timer + 1``
as ``sync_next_o``), ``window_us < window`` keeps the
window open, the counters count by one) runs beside the DUT and every output is compared after
every rising edge. The RTL counts in 16-bit halves with registered "lower half all ones" flags
and splits the 32-bit compares (``inc_split`` / ``lt_split`` of ``canopen_util_pkg``); these
runs take every counter across the 16-bit boundary, where a wrong flag or a wrong split shows.

``CLK_FREQ_HZ`` = 1 MHz makes one microsecond one clock cycle, so 65 536 us are 65 536 cycles.
Not reached here: the ms counter's upper half (65 536 ms = 65.5 M cycles) and the window's
saturation at 2**32 - 1 us (71 min). They are the same ``inc_split`` / ``lo_ones_after_inc``
code as the counters checked here (the saturation adds the upper-half compare). A deposit does
not help on GHDL: a VPI write to an internal signal acts as a force that outlives the test
(measured: the value stayed through the next test's reset).
"""

from __future__ import annotations

import random

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly, RisingEdge

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import param, run_cocotb

M32 = 0xFFFF_FFFF


class TimebaseModel:
    """Cycle model of canopen_sync_timebase (the registers after each rising edge)."""

    def __init__(self, clk_hz: int) -> None:
        self.cycles_per_us = (clk_hz + 999_999) // 1_000_000
        self.us_div = self.ms_div = 0
        self.tick_us = self.tick_ms = 0
        self.time_us = self.time_ms = 0
        self.timer = 0
        self.loaded = self.late = 0
        self.counter = 1
        self.count = 0
        self.sent = 0
        self.fire = self.fire_q = 0
        self.ovf_q = 0
        self.stale = 0
        self.window_us = 0

    def step(self, i: dict[str, int]) -> None:
        """One rising edge with the inputs ``i`` present before it."""
        tick_us = self.tick_us  # registered strobes as the edge sees them
        # time base
        self.tick_us = self.tick_ms = 0
        if self.us_div == self.cycles_per_us - 1:
            self.us_div = 0
            self.tick_us = 1
            self.time_us = (self.time_us + 1) & M32
            if self.ms_div == 999:
                self.ms_div = 0
                self.tick_ms = 1
                self.time_ms = (self.time_ms + 1) & M32
            else:
                self.ms_div += 1
        else:
            self.us_div += 1
        # SYNC producer (current register values on the right, last assignment wins)
        fire, loaded, late = self.fire, self.loaded, self.late
        n_fire, n_loaded, n_late = 0, loaded, late
        n_timer, n_window = self.timer, self.window_us
        n_count, n_sent, n_counter, n_stale = self.count, self.sent, self.counter, self.stale
        if i["load_done"]:
            n_loaded = int(not self.stale)
        if not i["init_done"]:
            n_loaded = 0
        if not i["sync_en"] or i["period"] == 0:
            n_timer, n_late = 0, 0
        elif tick_us:
            if self.timer + 1 >= i["period"]:
                n_timer = 0
                if loaded:
                    n_fire = 1
                else:
                    n_late = 1
            else:
                n_timer = self.timer + 1
        if late and loaded and not fire:
            n_late, n_fire = 0, 1
        if fire:
            n_window = 0
        elif tick_us and self.window_us != M32:
            n_window = self.window_us + 1
        ovf = i["overflow"]
        if fire:
            n_loaded = 0
            n_count = (self.count + 1) & M32
            n_sent = self.counter if ovf >= 2 else (self.count + 1) & 0xFF
            if ovf >= 2 and self.counter >= ovf:
                n_counter = 1
            elif ovf >= 2:
                n_counter = (self.counter + 1) & 0xFF
        if i["encap_sync"]:
            n_stale = 0
        if ovf != self.ovf_q:
            n_counter, n_loaded, n_stale = 1, 0, 1
        self.ovf_q = ovf
        self.fire_q = fire
        self.fire, self.loaded, self.late = n_fire, n_loaded, n_late
        self.timer, self.window_us = n_timer, n_window
        self.count, self.sent, self.counter, self.stale = n_count, n_sent, n_counter, n_stale

    def window_open(self, window: int) -> int:
        return int(window == 0 or self.window_us < window)

    def outputs(self, i: dict[str, int]) -> dict[str, int]:
        return {
            "tick_us_o": self.tick_us, "tick_ms_o": self.tick_ms,
            "time_us_o": self.time_us, "time_ms_o": self.time_ms,
            "sync_loaded_o": self.loaded, "sync_fire_o": self.fire,
            "sync_fire_q_o": self.fire_q, "sync_counter_o": self.counter,
            "sync_sent_o": self.sent, "sync_count_o": self.count,
            "sync_next_o": self.timer + 1, "window_open_o": self.window_open(i["window"]),
        }


PORTS = {"sync_en": "sync_en_i", "period": "sync_period_us_i", "overflow": "sync_overflow_i",
         "window": "sync_window_us_i", "load_done": "load_done_i",
         "encap_sync": "encap_sync_i", "init_done": "init_done_i"}


class TB:
    def __init__(self, dut, model: TimebaseModel | None = None) -> None:
        self.dut = dut
        self.clk_hz = param("CLK_FREQ_HZ")
        self.model = model or TimebaseModel(self.clk_hz)
        self.i = {"sync_en": 0, "period": 0, "overflow": 0, "window": 0, "load_done": 0,
                  "encap_sync": 0, "init_done": 1}
        self.cycles = 0
        self.fires = 0
        self.preload_in = -1  # cycles until the bench's "FSM" preloads the SYNC (-1: none)

    async def start(self) -> None:
        start_clock(self.dut.clk_i, self.clk_hz)
        self.drive()
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        # reset_active_low returns after the first edge with the reset released: the registers
        # took one edge of the time base already
        self.model.step(dict(self.i, load_done=0))
        await ReadOnly()
        self.check()

    def drive(self) -> None:
        for k, port in PORTS.items():
            getattr(self.dut, port).value = self.i[k]

    def check(self) -> None:
        exp = self.model.outputs(self.i)
        for port, val in exp.items():
            got = int(getattr(self.dut, port).value)
            assert got == val, (f"cycle {self.cycles}: {port} = {got:#x}, model {val:#x} "
                                f"(inputs {self.i})")

    async def cycle(self) -> None:
        await FallingEdge(self.dut.clk_i)
        # a preloading FSM: a few cycles after the fire (or at once) the SYNC is in TXB2
        self.i["load_done"] = 0
        if self.preload_in > 0:
            self.preload_in -= 1
        elif self.preload_in == 0:
            self.i["load_done"] = 1
            self.preload_in = -1
        self.drive()
        await RisingEdge(self.dut.clk_i)
        self.model.step(self.i)
        self.cycles += 1
        await ReadOnly()
        self.check()
        if self.model.fire:
            self.fires += 1
        if not self.model.loaded and self.preload_in < 0 and not self.i["load_done"]:
            self.preload_in = random.randint(0, 3)

    async def run(self, n: int) -> None:
        for _ in range(n):
            await self.cycle()


@cocotb.test(timeout_time=400, timeout_unit="ms")
async def run_long_period_across_16_bits(dut):
    """Purpose: the period timer, its next value, the us counter and the window cross 65 535.

    Verifies: every output equals the 32-bit model in every cycle over two periods of 70 001 us
    with a window of 65 540 us (period end and window close lie above the 16-bit boundary); two
    SYNCs fired.
    """
    tb = TB(dut)
    await tb.start()
    tb.i.update(sync_en=1, period=70_001, window=65_540, overflow=0)
    await tb.run(2 * 70_001 + 20)
    assert tb.fires == 2, f"{tb.fires} SYNCs fired"
    assert tb.model.time_us > 0x1_0000


@cocotb.test(timeout_time=400, timeout_unit="ms")
async def run_sync_count_across_16_bits(dut):
    """Purpose: the SYNC count crosses 65 535 (fires every few cycles at a 1 us period).

    Verifies: every output equals the model in every cycle; sync_count_o passes 0x10000.
    """
    tb = TB(dut)
    await tb.start()
    tb.i.update(sync_en=1, period=1, window=0, overflow=0)
    while tb.model.count < 0x1_0004:
        await tb.run(1000)
    assert int(dut.sync_count_o.value) >= 0x1_0004


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_random_configuration(dut):
    """Purpose: period, window, overflow, enable, init and encapsulation change at random.

    Verifies: every output equals the model in every cycle over 40 000 cycles, including
    periods set below the running timer (the period ends at the next tick), late SYNCs and
    SYNC_OVERFLOW changes.
    """
    random.seed(1019)
    tb = TB(dut)
    await tb.start()
    tb.i.update(sync_en=1, period=40, window=10, overflow=3)
    for _ in range(400):
        r = random.random()
        if r < 0.2:
            tb.i["period"] = random.choice([0, 1, 2, 3, 7, 25, 60, 0x1_0003, 0xFFFF_FFFF])
        elif r < 0.3:
            tb.i["window"] = random.choice([0, 1, 5, 30, 0x1_0000, 0xFFFF_FFFF])
        elif r < 0.4:
            tb.i["overflow"] = random.choice([0, 1, 2, 5, 240])
        elif r < 0.45:
            tb.i["sync_en"] ^= 1
        tb.i["init_done"] = int(random.random() > 0.05)
        tb.i["encap_sync"] = int(random.random() < 0.1)
        await tb.run(100)
    assert tb.fires > 50, f"{tb.fires} SYNCs fired"


@cocotb.test(timeout_time=50, timeout_unit="ms", expect_fail=True)
async def run_checker_can_fail(dut):
    """Purpose: prove the per-cycle check fails on a wrong model.

    Verifies: a model whose period ends one tick late (timer + 1 > period) raises an
    AssertionError at the first period end (cocotb expect_fail).
    """

    class LateModel(TimebaseModel):
        def step(self, i: dict[str, int]) -> None:
            super().step(dict(i, period=i["period"] + 1 if i["period"] else 0))

    tb = TB(dut, LateModel(param("CLK_FREQ_HZ")))
    await tb.start()
    tb.i.update(sync_en=1, period=50)
    await tb.run(200)


@pytest.mark.sim
def test_canopen_sync_timebase(request):
    run_cocotb(toplevel="canopen_sync_timebase", module="tb.test_canopen_sync_timebase",
               name=request.node.name, parameters={"CLK_FREQ_HZ": 1_000_000}, stop_time_ms=2000)
