"""Bench of ``canopen_counter_bank``: RAM-backed saturating counters against a Python model.

Every cycle the bench drives an amount for every counter (``inc_i``), ``clr_i`` and a read
address, and keeps a cycle-exact reference model: the saturated count of each counter after
every clock edge, cleared (amounts of the clear cycle dropped) by ``clr_i`` and by reset. Each
read is checked against the documented lag (docs/canopen_counter_bank.md): a read with the
address in cycle r returns the model's count of the events before cycle c for one c with
r - (S + 2) <= c <= r (S = max(N_CNT, 3), the sweep period), and c after the last clear before
cycle r; an address >= N_CNT reads 0. After a quiet tail of S + 3 cycles every counter must read
exactly its model count.
"""

from __future__ import annotations

import random

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly, RisingEdge

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import param, run_cocotb

CLK_HZ = 50_000_000


class Model:
    """Cycle-exact counts: ``hist[n]`` holds every count after clock edge n."""

    def __init__(self, n_cnt: int, bits: int, clear_wins: bool = True) -> None:
        self.n = n_cnt
        self.top = (1 << bits) - 1
        self.clear_wins = clear_wins
        self.counts = [0] * n_cnt
        self.hist: list[tuple[int, ...]] = []
        self.clears: list[int] = []  # edges that cleared (clr_i or reset)

    def step(self, amounts: list[int], clr: bool) -> None:
        """One clock edge with these inputs."""
        if clr:
            self.counts = [0] * self.n
            if not self.clear_wins:  # deliberately wrong model (checker test)
                self.counts = [min(a, self.top) for a in amounts]
            self.clears.append(len(self.hist))
        else:
            self.counts = [min(c + a, self.top) for c, a in zip(self.counts, amounts)]
        self.hist.append(tuple(self.counts))

    def before(self, c: int, k: int) -> int:
        """Count of counter k over the events of the cycles before cycle c (edges < c)."""
        return self.hist[c - 1][k] if c >= 1 else 0

    def allowed(self, r: int, k: int, lag: int) -> dict[int, int]:
        """value -> smallest lag r - c giving it, for a read with the address at edge r."""
        last_clear = max((x for x in self.clears if x < r), default=-1)
        out: dict[int, int] = {}
        for c in range(r, max(r - lag, last_clear + 1) - 1, -1):
            out.setdefault(self.before(c, k), r - c)
        return out


class TB:
    def __init__(self, dut, lag_slack: int = 0, clear_wins: bool = True) -> None:
        self.dut = dut
        self.n = param("N_CNT")
        self.bits = param("CNT_BITS")
        self.inc_bits = param("INC_BITS")
        self.slots = max(self.n, 3)
        #: documented read lag bound S + 2 (a checker test narrows it)
        self.lag = self.slots + 2 + lag_slack
        self.amt_max = (1 << self.inc_bits) - 1
        self.addr_span = 1 << max(1, (self.n - 1).bit_length())
        self.model = Model(self.n, self.bits, clear_wins)
        self.max_lag_seen = 0
        self.reads = 0
        #: (edge of the address, address, value read) of every checked read
        self.log: list[tuple[int, int, int]] = []
        start_clock(dut.clk_i, CLK_HZ)
        dut.rst_n_i.value = 0
        dut.inc_i.value = 0
        dut.clr_i.value = 0
        dut.rd_addr_i.value = 0

    async def reset(self) -> None:
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        # the first edge with rst_n_i = 1 has passed (inputs 0): the model starts cleared there
        self.model.step([0] * self.n, True)

    async def run(self, cycles: int, amounts, clr_prob: float = 0.0, addr=None,
                  exact: bool = False) -> None:
        """``cycles`` clock cycles: ``amounts(k)`` per counter and cycle, clr_i with
        probability ``clr_prob``, read address ``addr()`` (random by default). Every read
        result is checked against the model within the lag bound (``exact``: equal to the
        model's count now)."""
        dut = self.dut
        for _ in range(cycles):
            await FallingEdge(dut.clk_i)
            am = [amounts(k) for k in range(self.n)]
            clr = random.random() < clr_prob
            a = addr() if addr is not None else random.randrange(self.addr_span)
            word = 0
            for k, v in enumerate(am):
                word |= v << (k * self.inc_bits)
            dut.inc_i.value = word
            dut.clr_i.value = int(clr)
            dut.rd_addr_i.value = a
            await RisingEdge(dut.clk_i)
            await ReadOnly()
            # rd_data_o now holds the read of the address sampled at this edge
            self.check(len(self.model.hist), a, exact, int(dut.rd_data_o.value))
            self.model.step(am, clr)

    def check(self, r: int, a: int, exact: bool, got: int) -> None:
        self.reads += 1
        self.log.append((r, a, got))
        if a >= self.n:
            assert got == 0, f"edge {r}: address {a} >= N_CNT read {got}, expected 0"
            return
        if exact:
            assert got == self.model.counts[a], f"counter {a}: {got} != {self.model.counts[a]}"
            return
        ok = self.model.allowed(r, a, self.lag)
        recent = [self.model.before(c, a) for c in range(max(0, r - self.lag - 3), r + 1)]
        assert got in ok, (
            f"edge {r}: counter {a} read {got}; the model allows {sorted(ok)} "
            f"(lag <= {self.lag} cycles; counts before edges {r - len(recent) + 1}..{r}: "
            f"{recent})")
        self.max_lag_seen = max(self.max_lag_seen, ok[got])

    async def read_all_exact(self) -> None:
        """Quiet tail of S + 3 cycles, then every counter read once: the exact model count."""
        quiet = lambda k: 0  # noqa: E731
        await self.run(self.slots + 3, quiet, addr=lambda: 0)
        for k in range(self.n):
            await self.run(1, quiet, addr=lambda k=k: k, exact=True)


def storm_amounts(tb: TB, density: float, full: bool = False):
    """Amount generator: every counter gets its largest amount (``full``) or a random one
    with probability ``density``."""
    m = tb.amt_max
    if full:
        return lambda k: m
    return lambda k: random.randint(1, m) if random.random() < density else 0


async def storm_sequence(tb: TB) -> None:
    """Full storms (every counter, largest amount, every cycle), random and sparse traffic,
    with random clears and reads every cycle."""
    for _ in range(10):
        await tb.run(4 * tb.slots + 20, storm_amounts(tb, 1.0, full=True))
        await tb.run(300, storm_amounts(tb, 0.7), clr_prob=0.02)
        await tb.run(200, storm_amounts(tb, 0.05), clr_prob=0.01)
        await tb.run(4 * tb.slots + 20, storm_amounts(tb, 1.0, full=True), clr_prob=0.03)
    await tb.run(200, storm_amounts(tb, 1.0), clr_prob=0.0)


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_storm_reads_within_lag(dut):
    """Purpose: no event is lost under event storms, reads stay within the lag bound.

    Verifies: random amounts on all counters at once (also the largest amount on every
    counter in every cycle), random clears and one read per cycle: every read is one of the
    model's counts of the last S + 2 cycles (never older, never before the last clear); with
    counters that count in every cycle the bound S + 2 is reached (it is exact); a quiet tail
    then reads every counter exactly.
    """
    tb = TB(dut)
    await tb.reset()
    await storm_sequence(tb)
    await tb.read_all_exact()
    dut._log.info(f"{tb.reads} reads checked, largest lag seen {tb.max_lag_seen} "
                  f"(bound {tb.lag})")
    if tb.bits >= 8:
        assert tb.max_lag_seen == tb.lag, (tb.max_lag_seen, tb.lag)


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_saturation_and_clear(dut):
    """Purpose: saturation at 2**CNT_BITS - 1 and the clear semantics.

    Verifies: with narrow counters, full storms drive every counter to its top value, where it
    stays under further events (read back exactly); a clear with events on every counter in the
    same cycle: the read of every counter with the address in the cycle after the clear returns
    0 (the events of the clear cycle are dropped), the events after it count from 0. With 32-bit
    counters the same clear checks run on large counts.
    """
    tb = TB(dut)
    await tb.reset()
    full = storm_amounts(tb, 1.0, full=True)
    # narrow counters: up to the top; 32 bits: past 2**16 (carry into the high half)
    cycles = min(tb.model.top // tb.amt_max + 2 * tb.slots + 4, (1 << 16) // tb.amt_max + 100)
    await tb.run(cycles, full)
    if tb.bits > 16:
        assert min(tb.model.counts) > 1 << 16
    if tb.bits <= 12:
        await tb.read_all_exact()
        assert tb.model.counts == [tb.model.top] * tb.n, tb.model.counts
        await tb.run(3 * tb.slots, full)  # stays at the top
        await tb.read_all_exact()
        assert tb.model.counts == [tb.model.top] * tb.n
    for k in range(tb.n):
        # clear in a storm cycle; read counter k with the address in the next cycle
        await tb.run(2 * tb.slots + random.randrange(tb.slots), full)
        before = tb.model.counts[k]
        await tb.run(1, full, clr_prob=1.0, addr=lambda k=k: k)
        x = len(tb.model.hist) - 1  # the clear edge
        await tb.run(1, full, addr=lambda k=k: k)
        reads = {r: got for r, a, got in tb.log if r in (x, x + 1)}
        assert before > 0 and reads[x] > 0, (before, reads)  # the read in the clear cycle
        assert reads[x + 1] == 0, f"counter {k}: read after the clear {reads[x + 1]}"
    await tb.read_all_exact()


@cocotb.test(timeout_time=20, timeout_unit="ms", expect_fail=True)
async def run_checker_detects_lag_bound_too_small(dut):
    """Purpose: prove the read checker can fail: told that the lag is one cycle shorter
    (S + 1) than documented, it must reject a read while every counter counts 1 per cycle
    (cleared every S + 9 cycles, so that narrow counters do not saturate) (expect_fail)."""
    tb = TB(dut, lag_slack=-1)
    await tb.reset()
    for _ in range(10):
        await tb.run(tb.slots + 8, lambda k: 1)
        await tb.run(1, lambda k: 1, clr_prob=1.0)


@cocotb.test(timeout_time=20, timeout_unit="ms", expect_fail=True)
async def run_checker_detects_wrong_clear_model(dut):
    """Purpose: prove the clear check can fail: a model in which the events of the clear
    cycle still count must disagree with the RTL after a clear during a full storm
    (expect_fail)."""
    tb = TB(dut, clear_wins=False)
    await tb.reset()
    full = storm_amounts(tb, 1.0, full=True)
    await tb.run(2 * tb.slots, full)
    await tb.run(1, full, clr_prob=1.0)
    await tb.run(4 * tb.slots, lambda k: 0)
    await tb.read_all_exact()


# ============================================================================ pytest entry
#: name -> (N_CNT, CNT_BITS, INC_BITS, cocotb tests or None for all): the host register file's
#: bank, the PDO engine's bank, one counter (sweep padded to 3 slots) with narrow counters and
#: large amounts, an odd width, a 12-bit width. The checker tests need counts that do not
#: saturate within a lag window: not with 3-bit counters.
CONFIGS = {
    "host_regs": (11, 32, 2, None),
    "pdo_engine": (7, 32, 1, None),
    "n1_b4_i3": (1, 4, 3, None),
    "n5_b3_i2": (5, 3, 2, ["run_storm_reads_within_lag", "run_saturation_and_clear"]),
    "n4_b12_i2": (4, 12, 2, None),
}


@pytest.mark.sim
@pytest.mark.parametrize("config", list(CONFIGS))
def test_canopen_counter_bank(request, config):
    n_cnt, bits, inc_bits, tests = CONFIGS[config]
    run_cocotb(toplevel="canopen_counter_bank", module="tb.test_canopen_counter_bank",
               name=request.node.name,
               parameters={"N_CNT": n_cnt, "CNT_BITS": bits, "INC_BITS": inc_bits},
               testcase=tests)
