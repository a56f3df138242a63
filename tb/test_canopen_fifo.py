"""Bench of ``canopen_fifo``: the generic first-word-fall-through FIFO on ``canopen_sdp_ram``.

A cycle-exact Python model (:class:`FifoModel`, written from the entity's header: push to
visible 2 rising edges, pop visible at the next edge, push refused when full unless a pop comes
in the same cycle, pop of an empty FIFO ignored) runs beside the DUT; every cycle the bench
compares ``count_o``, ``empty_o``, ``full_o``, the head ``data_o`` (when not empty) and the
combinational ``ovf_o``. A scoreboard checks that every accepted entry comes out once, in order.
"""

from __future__ import annotations

import random

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly, RisingEdge, Timer

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import param, run_cocotb

CLK_HZ = 20_000_000


class FifoModel:
    """Cycle model of canopen_fifo; ``visible_edges`` = rising edges from push to visible."""

    def __init__(self, depth: int, visible_edges: int = 2) -> None:
        self.depth = depth
        self.visible_edges = visible_edges
        self.q: list[int] = []  # stored entries, head first
        self.count = 0  # visible
        self.push_d = 0  # written at the previous edge, not yet visible

    def ovf(self, push: int, pop: int) -> int:
        pop_ok = pop and self.count > 0
        fill = self.count + self.push_d
        return int(bool(push) and not (fill < self.depth or pop_ok))

    def step(self, push: int, pop: int, data: int) -> tuple[bool, bool]:
        """One rising edge; returns (push accepted, pop accepted)."""
        pop_ok = bool(pop) and self.count > 0
        fill = self.count + self.push_d
        push_ok = bool(push) and (fill < self.depth or pop_ok)
        if pop_ok:
            self.q.pop(0)
        if push_ok:
            self.q.append(data)
        if self.visible_edges == 2:
            self.count += self.push_d - int(pop_ok)
            self.push_d = int(push_ok)
        else:  # a wrong model for the checker test: visible at the next edge
            self.count += int(push_ok) - int(pop_ok)
        return push_ok, pop_ok

    @property
    def full(self) -> int:
        return int(self.count + self.push_d >= self.depth)


class TB:
    def __init__(self, dut, visible_edges: int = 2) -> None:
        self.dut = dut
        self.depth = param("DEPTH")
        self.width = param("WIDTH")
        self.model = FifoModel(self.depth, visible_edges)
        self.pushed: list[int] = []  # accepted, in order
        self.popped: list[int] = []
        self.refused = 0
        self.cycles = 0

    async def start(self) -> None:
        dut = self.dut
        start_clock(dut.clk_i, CLK_HZ)
        dut.push_i.value = 0
        dut.pop_i.value = 0
        dut.data_i.value = 0
        await reset_active_low(dut.clk_i, dut.rst_n_i)
        await FallingEdge(dut.clk_i)
        self.check()

    def check(self) -> None:
        dut, m = self.dut, self.model
        assert int(dut.count_o.value) == m.count, f"cycle {self.cycles}: count_o"
        assert int(dut.empty_o.value) == int(m.count == 0), f"cycle {self.cycles}: empty_o"
        assert int(dut.full_o.value) == m.full, f"cycle {self.cycles}: full_o"
        if m.count:
            assert int(dut.data_o.value) == m.q[0], f"cycle {self.cycles}: head data_o"

    async def cycle(self, push: int, pop: int, data: int | None = None) -> None:
        """Drive one cycle (from a falling edge), check ovf_o, the edge and the outputs."""
        dut, m = self.dut, self.model
        if data is None:
            data = random.getrandbits(self.width)
        dut.push_i.value = push
        dut.pop_i.value = pop
        dut.data_i.value = data
        await Timer(1, "ns")
        assert int(dut.ovf_o.value) == m.ovf(push, pop), f"cycle {self.cycles}: ovf_o"
        head = m.q[0] if m.count else None
        await RisingEdge(dut.clk_i)
        push_ok, pop_ok = m.step(push, pop, data)
        if push_ok:
            self.pushed.append(data)
        elif push:
            self.refused += 1
        if pop_ok:
            self.popped.append(head)
        self.cycles += 1
        await ReadOnly()
        self.check()
        await FallingEdge(self.dut.clk_i)

    async def drain(self) -> None:
        for _ in range(2 * self.depth + 4):
            await self.cycle(0, 1)
        assert self.model.count == 0 and self.model.push_d == 0
        assert self.popped == self.pushed, "entries lost, duplicated or out of order"


@cocotb.test(timeout_time=2, timeout_unit="ms")
async def run_edges(dut):
    """Purpose: the full and empty edges.

    Verifies: pop of an empty FIFO ignored; push+pop on an empty FIFO (push accepted, pop
    ignored); pushes every cycle from empty to full, the (DEPTH+1)-th refused with ovf_o, the
    entries kept; push+pop at full accepted (no ovf_o); a pop every cycle drains in order.
    """
    tb = TB(dut)
    await tb.start()
    await tb.cycle(0, 1)  # empty: pop ignored
    await tb.cycle(1, 1)  # empty: push accepted, pop ignored
    assert tb.model.push_d == 1 and tb.popped == []
    await tb.drain()
    for _ in range(tb.depth):
        await tb.cycle(1, 0)
    assert tb.model.full
    await tb.cycle(1, 0)  # refused
    assert tb.refused == 1
    await tb.cycle(0, 0)
    await tb.cycle(1, 1)  # full: push with pop accepted
    assert tb.refused == 1 and tb.model.full
    await tb.cycle(0, 0)
    await tb.cycle(1, 0)  # still full (the push replaced the pop): refused
    assert tb.refused == 2
    await tb.drain()


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_random(dut):
    """Purpose: random traffic in filling, draining and balanced phases.

    Verifies: every cycle the outputs against the model; at the end every accepted entry came
    out once and in order, and pushes = pops + refused.
    """
    tb = TB(dut)
    await tb.start()
    for p_push, p_pop in ((0.9, 0.2), (0.5, 0.5), (0.2, 0.9), (0.8, 0.8), (1.0, 1.0)):
        for _ in range(300):
            await tb.cycle(int(random.random() < p_push), int(random.random() < p_pop))
    await tb.drain()
    assert tb.refused > 0, "the random run never reached full"
    dut._log.info(f"{len(tb.pushed)} entries through, {tb.refused} refused")


@cocotb.test(timeout_time=2, timeout_unit="ms", expect_fail=True)
async def run_checker_can_fail(dut):
    """Purpose: prove the checker fails on a wrong expectation.

    Verifies: with a model that shows a pushed entry one edge early the per-cycle check raises
    an AssertionError (cocotb expect_fail).
    """
    tb = TB(dut, visible_edges=1)
    await tb.start()
    await tb.cycle(1, 0)
    await tb.cycle(0, 0)


@pytest.mark.sim
@pytest.mark.parametrize("generics", [{"WIDTH": 12, "DEPTH": 1},
                                      {"WIDTH": 12, "DEPTH": 4, "MIN_RAM_WORDS": 16},
                                      {"WIDTH": 103, "DEPTH": 5}],
                         ids=["depth1", "depth4-ram16", "depth5-w103"])
def test_canopen_fifo(request, generics):
    run_cocotb(toplevel="canopen_fifo", module="tb.test_canopen_fifo", name=request.node.name,
               parameters=generics, stop_time_ms=20)
