"""Bench of ``mcp2510_spi_master``: byte streaming, SPI timing and framing, measured on the pins.

The SPI slave on the pins is the independent Python model :class:`sim_models.spi_slave.SpiPinSlave`
with the MCP2510 datasheet timing (SCK <= 5 MHz, CS setup/hold/disable, SCK high/low, mode 0,0,
MOSI changing only with SCK low, whole bytes). It measures SCK instead of assuming it. A
scripted device behind it answers with a deterministic byte sequence, so both directions are
checked: what the slave received equals what the bench streamed in, and what the DUT presents
on rx_data_o equals what the slave sent (cocotb-bus Scoreboard).

Exact timing (in clock cycles, from the generics) is asserted per transaction: CS fall to first
SCK rise, every SCK period (also across byte boundaries: no gaps), last SCK fall to CS rise,
CS high time. The pytest wrapper runs several (CLK_FREQ_HZ, SPI_SCLK_HZ) pairs including
50 MHz / 5 MHz and the smallest legal divider (4 clocks per SCK period).
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import time

import cocotb
import pytest
from cocotb.triggers import ClockCycles, ReadOnly, RisingEdge, Timer
from cocotb_bus.monitors import BusMonitor
from cocotb_bus.scoreboard import Scoreboard

from sim_models.spi_slave import ScriptedSpiDevice, SpiPinSlave, SpiTimingSpec, SpiViolation
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.metrics import record
from tb.tblib.runner import HDL_LIBRARY, build_dir_for, param, rtl_sources, run_cocotb
from tb.tblib.spi_pins import SpiPinBridge

PS_PER_NS = 1000


# ------------------------------------------------------------------------------------- model
class ExpectedTiming:
    """The engine's timing in clock cycles, derived from the generics exactly as documented."""

    def __init__(self, clk_hz: int, sclk_hz: int, setup_ns: int, hold_ns: int, dis_ns: int):
        def cycles(ns: int) -> int:
            khz = (clk_hz + 999) // 1000
            return (ns * khz + 999_999) // 1_000_000

        self.clk_ps = 1_000_000_000_000 // clk_hz
        self.half = -(-clk_hz // (2 * sclk_hz))
        self.setup = max(cycles(setup_ns), self.half, 1)
        self.hold = max(cycles(hold_ns), 1)
        self.disable = max(cycles(dis_ns), 1)

    @property
    def sck_period_ps(self) -> int:
        return 2 * self.half * self.clk_ps

    def transaction_ps(self, n_bytes: int) -> int:
        """CS low time of a gapless transaction of ``n_bytes``."""
        cyc = self.setup + (8 * n_bytes - 1) * 2 * self.half + self.half + self.hold
        return cyc * self.clk_ps


def _expected_from_params() -> ExpectedTiming:
    return ExpectedTiming(
        param("CLK_FREQ_HZ"),
        param("SPI_SCLK_HZ"),
        param("CS_SETUP_NS"),
        param("CS_HOLD_NS"),
        param("CS_DISABLE_NS"),
    )


class RxStreamMonitor(BusMonitor):
    """Collects the bytes the DUT presents on rx_valid_o/rx_data_o (one-cycle strobes)."""

    _signals = ["valid_o", "data_o"]

    async def _monitor_recv(self) -> None:
        while True:
            await RisingEdge(self.bus.valid_o)
            await ReadOnly()
            self._recv(int(self.bus.data_o.value))


class TB:
    def __init__(self, dut, spec: SpiTimingSpec | None = None) -> None:
        self.dut = dut
        self.exp = _expected_from_params()
        start_clock(dut.clk_i, param("CLK_FREQ_HZ"))
        self.device = ScriptedSpiDevice(seed=0xC0FFEE)
        self.slave = SpiPinSlave(self.device, spec or SpiTimingSpec(), name="spi_slave")
        self.bridge = SpiPinBridge(
            self.slave,
            cs_n=dut.spi_cs_n_o,
            sck=dut.spi_sck_o,
            mosi=dut.spi_mosi_o,
            miso=dut.spi_miso_i,
        )
        self.expected_rx: list[int] = []
        self.device.on_byte = lambda sent, _received: self.expected_rx.append(sent)
        self.scoreboard = Scoreboard(dut, fail_immediately=True)
        self.rx_mon = RxStreamMonitor(dut, "rx", dut.clk_i)
        self.scoreboard.add_interface(self.rx_mon, self.expected_rx)
        self.done_count = 0
        cocotb.start_soon(self._count_done())
        dut.tx_valid_i.value = 0
        dut.tx_last_i.value = 0
        dut.tx_data_i.value = 0
        dut.tx_end_i.value = 0

    async def _count_done(self) -> None:
        while True:
            await RisingEdge(self.dut.done_o)
            self.done_count += 1

    async def reset(self) -> None:
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)

    async def transaction(self, data: bytes, max_gap: int = 0) -> None:
        """Stream ``data`` as one transaction; ``max_gap`` > 0 inserts random idle cycles."""
        dut = self.dut
        for i, b in enumerate(data):
            if max_gap:
                gap = random.randint(0, max_gap)
                if gap:
                    dut.tx_valid_i.value = 0
                    await ClockCycles(dut.clk_i, gap)
            dut.tx_valid_i.value = 1
            dut.tx_data_i.value = b
            dut.tx_last_i.value = int(i == len(data) - 1)
            while True:
                await RisingEdge(dut.clk_i)
                if dut.tx_ready_o.value == 1:
                    break
        dut.tx_valid_i.value = 0
        dut.tx_last_i.value = 0

    async def wait_idle(self) -> None:
        while True:
            await RisingEdge(self.dut.clk_i)
            if self.dut.busy_o.value == 0 and self.dut.tx_valid_i.value == 0:
                return

    def check_transactions(self, sent: list[bytes], gapless: bool) -> None:
        exp = self.exp
        got = self.slave.transactions
        assert len(got) == len(sent), f"{len(got)} transactions on the pins, {len(sent)} sent"
        assert self.device.received == sent, "slave received different bytes than streamed"
        for tr, data in zip(got, sent):
            assert tr.partial_bits == 0
            assert tr.mode == (0, 0)
            if gapless:
                assert tr.duration_ps == exp.transaction_ps(len(data)), (
                    f"{len(data)}-byte transaction lasted {tr.duration_ps} ps, "
                    f"expected {exp.transaction_ps(len(data))} ps"
                )
        starts = [t.t_start_ps for t in got]
        ends = [t.t_end_ps for t in got]
        for prev_end, nxt in zip(ends, starts[1:]):
            assert nxt - prev_end >= exp.disable * exp.clk_ps, "CS high time below tCSD"
        assert self.done_count == len(sent), f"done_o pulsed {self.done_count}x for {len(sent)}"


# ------------------------------------------------------------------------------------- tests
@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_gapless_streaming(dut):
    """Purpose: back-to-back bytes of 1..16-byte transactions with no gap.

    Verifies: bit order both ways, SCK measured = CLK/(2*half) on every period including byte
    boundaries, exact CS setup/hold, CS disable time, one done_o pulse per transaction, every
    byte the slave sent appears on rx_data_o in order.
    Sequence: 60 transactions of random length and content, caller always ready.
    """
    tb = TB(dut)
    await tb.reset()
    assert dut.spi_cs_n_o.value == 1 and dut.spi_sck_o.value == 0, "idle levels after reset"
    assert dut.busy_o.value == 0
    sent: list[bytes] = []
    for _ in range(60):
        n = random.randint(1, 16)
        data = bytes(random.getrandbits(8) for _ in range(n))
        await tb.transaction(data)
        await tb.wait_idle()
        sent.append(data)
    await ClockCycles(dut.clk_i, 4)
    tb.check_transactions(sent, gapless=True)
    periods = set(tb.slave.sck_periods_ps)
    assert periods == {tb.exp.sck_period_ps}, f"SCK periods seen: {sorted(periods)} ps"
    measured = tb.slave.measured_sck_hz
    assert abs(measured - 1e12 / tb.exp.sck_period_ps) < 1e-6 * measured
    assert measured <= 5_000_000
    assert not tb.expected_rx, f"{len(tb.expected_rx)} received bytes never appeared on rx"
    assert tb.rx_mon.stats.received_transactions == sum(len(s) for s in sent)
    await Timer(1, "ns")


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_stalled_streaming(dut):
    """Purpose: a slow caller (random idle cycles between bytes) still gets correct frames.

    Verifies: SCK holds low while the next byte is missing (no violation, no lost byte), data
    and answers still match, CS stays low until the last byte.
    """
    tb = TB(dut)
    await tb.reset()
    sent: list[bytes] = []
    for _ in range(25):
        data = bytes(random.getrandbits(8) for _ in range(random.randint(1, 12)))
        await tb.transaction(data, max_gap=3 * 2 * tb.exp.half * 8)
        await tb.wait_idle()
        sent.append(data)
    await ClockCycles(dut.clk_i, 4)
    tb.check_transactions(sent, gapless=False)
    assert min(tb.slave.sck_periods_ps) == tb.exp.sck_period_ps
    assert not tb.expected_rx
    await Timer(1, "ns")


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_end_after_received_byte(dut):
    """Purpose: a transaction whose length is decided from received data (tx_end_i).

    Verifies: the caller streams bytes without tx_last_i, withholds the next byte when it
    decides to stop and pulses tx_end_i on the rx_valid_o strobe of byte k; CS rises after
    byte k with no extra byte clocked and no gap before it (exact duration), done_o pulses.
    Sequence: 30 transactions, each stopped after a random number of bytes.
    """
    tb = TB(dut)
    await tb.reset()
    sent: list[bytes] = []
    for _ in range(30):
        n = random.randint(1, 14)
        data = bytes(random.getrandbits(8) for _ in range(n))
        received = 0
        idx = 0
        while True:
            await RisingEdge(dut.clk_i)
            if dut.tx_valid_i.value == 1 and dut.tx_ready_o.value == 1:
                idx += 1
            if dut.rx_valid_o.value == 1:
                received += 1
            dut.tx_end_i.value = 0
            if received == n:
                break
            if received == n - 1 and idx == n:
                # all n bytes streamed, byte n-1 received: stop after the one now shifting
                dut.tx_valid_i.value = 0
                dut.tx_end_i.value = 1
                continue
            if idx < n:
                dut.tx_valid_i.value = 1
                dut.tx_data_i.value = data[idx]
                dut.tx_last_i.value = 0
            else:
                dut.tx_valid_i.value = 0
        dut.tx_valid_i.value = 0
        dut.tx_end_i.value = 0
        await tb.wait_idle()
        sent.append(data)
    await ClockCycles(dut.clk_i, 4)
    tb.check_transactions(sent, gapless=True)
    assert not tb.expected_rx
    await Timer(1, "ns")


@cocotb.test(timeout_time=5, timeout_unit="ms", expect_error=SpiViolation)
async def run_checker_rejects_fast_sck(dut):
    """Purpose: prove the timing checker can fail.

    The slave is told the maximum SCK is 10 % below what the DUT produces: the first
    SCK period must raise SpiViolation.
    """
    actual_hz = 1e12 / _expected_from_params().sck_period_ps
    tb = TB(dut, SpiTimingSpec(sck_max_hz=int(actual_hz * 0.9)))
    await tb.reset()
    await tb.transaction(b"\x03\x0e\x00")
    await tb.wait_idle()


@cocotb.test(timeout_time=5, timeout_unit="ms", expect_error=SpiViolation)
async def run_checker_rejects_short_cs_setup(dut):
    """Purpose: prove the CS setup check can fail (slave demands 10 x the DUT's setup time)."""
    e = _expected_from_params()
    tb = TB(dut, SpiTimingSpec(t_cs_setup_ps=10 * e.setup * e.clk_ps))
    await tb.reset()
    await tb.transaction(b"\xa0\x00")
    await tb.wait_idle()


@cocotb.test(timeout_time=20, timeout_unit="ms", skip=os.environ.get("BENCH") != "1")
async def run_bench_transactions(dut):
    """Benchmark (``make bench`` only): exact SPI cost of MCP2510-sized transactions.

    Measures on the pins, from simulated time: SCK, CS-low time of a 15-byte transaction (READ
    of a full 8-byte RX buffer: instruction + address + 13 bytes) and of a 4-byte BIT MODIFY,
    the fixed per-transaction overhead (CS-low time minus 8 SCK periods per byte) and the
    shortest CS-high time between back-to-back transactions. Wall-clock simulation speed is
    reported as *_wall_*.
    """
    tb = TB(dut)
    await tb.reset()
    t_wall = time.perf_counter()
    sizes = [15, 4] * 20
    for n in sizes:
        await tb.transaction(bytes(random.getrandbits(8) for _ in range(n)))
    await tb.wait_idle()
    wall = time.perf_counter() - t_wall
    trs = tb.slave.transactions
    assert len(trs) == len(sizes)
    period = tb.exp.sck_period_ps
    d15 = {t.duration_ps for t in trs if len(t.mosi) == 15}
    d4 = {t.duration_ps for t in trs if len(t.mosi) == 4}
    assert len(d15) == 1 and len(d4) == 1, "gapless transactions must have one exact duration"
    (t15,), (t4,) = d15, d4
    gaps = [b.t_start_ps - a.t_end_ps for a, b in zip(trs, trs[1:])]
    sim_ps = trs[-1].t_end_ps - trs[0].t_start_ps
    clk_hz = param("CLK_FREQ_HZ")
    tag = f"{clk_hz // 1_000_000}mhz"
    record(
        f"spi_master_{tag}",
        {
            f"spi_sck_hz_measured_clk{tag}": round(tb.slave.measured_sck_hz),
            f"spi_read_rxbuf_15byte_us_clk{tag}": t15 / 1e6,
            f"spi_bit_modify_4byte_us_clk{tag}": t4 / 1e6,
            f"spi_overhead_ns_per_transaction_clk{tag}": (t15 - 15 * 8 * period) / 1e3,
            f"spi_min_cs_high_ns_clk{tag}": min(gaps) / 1e3,
            f"spi_sim_wall_clk_cycles_per_s_clk{tag}": round(sim_ps / tb.exp.clk_ps / wall),
        },
    )
    await Timer(1, "ns")


# ------------------------------------------------------------------------------- pytest entry
SPI_PAIRS = [
    # (CLK_FREQ_HZ, SPI_SCLK_HZ): the reference 50/5 MHz, the smallest legal divider (4 clocks
    # per SCK period) at two clocks, and a rate that is rounded down (50 MHz / 4.5 -> 4.17 MHz)
    (50_000_000, 5_000_000),
    (20_000_000, 5_000_000),
    (16_000_000, 4_000_000),
    (50_000_000, 4_500_000),
]


@pytest.mark.sim
@pytest.mark.parametrize("clk_hz,sclk_hz", SPI_PAIRS, ids=lambda v: f"{v / 1e6:g}MHz")
def test_mcp2510_spi_master(request, clk_hz, sclk_hz):
    run_cocotb(
        toplevel="mcp2510_spi_master",
        module="tb.test_mcp2510_spi_master",
        name=request.node.name,
        parameters={
            "CLK_FREQ_HZ": clk_hz,
            "SPI_SCLK_HZ": sclk_hz,
            "CS_SETUP_NS": 100,
            "CS_HOLD_NS": 100,
            "CS_DISABLE_NS": 100,
        },
    )


@pytest.mark.sim
@pytest.mark.bench
@pytest.mark.parametrize("clk_hz,sclk_hz", SPI_PAIRS[:2], ids=lambda v: f"{v / 1e6:g}MHz")
def test_bench_mcp2510_spi_master(request, clk_hz, sclk_hz):
    run_cocotb(
        toplevel="mcp2510_spi_master",
        module="tb.test_mcp2510_spi_master",
        name=request.node.name,
        testcase="run_bench_transactions",
        extra_env={"BENCH": "1"},
        parameters={
            "CLK_FREQ_HZ": clk_hz,
            "SPI_SCLK_HZ": sclk_hz,
            "CS_SETUP_NS": 100,
            "CS_HOLD_NS": 100,
            "CS_DISABLE_NS": 100,
        },
    )


# -------------------------------------------------------------- elaboration-time checks (no cocotb)
def _elaborate(request, generics: dict[str, int]) -> subprocess.CompletedProcess:
    """Analyse, elaborate and start the engine alone with overridden generics."""
    ghdl = shutil.which("ghdl")
    assert ghdl, "ghdl not installed: run make setup"
    work = build_dir_for(request.node.name)
    work.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, GHDL_BACKEND=os.environ.get("GHDL_BACKEND", "llvm"))
    srcs = [str(p) for p in rtl_sources()]
    lib = f"--work={HDL_LIBRARY}"
    subprocess.run([ghdl, "-a", "--std=08", lib, *srcs], cwd=work, env=env, check=True)
    subprocess.run([ghdl, "-e", "--std=08", lib, "mcp2510_spi_master"], cwd=work, env=env,
                   check=True)
    gen = [f"-g{k}={v}" for k, v in generics.items()]
    return subprocess.run(
        [ghdl, "-r", "--std=08", lib, "mcp2510_spi_master", *gen, "--stop-time=1ns"],
        cwd=work, env=env, capture_output=True, text=True,
    )


@pytest.mark.parametrize(
    "generics,message",
    [
        ({"CLK_FREQ_HZ": 50_000_000, "SPI_SCLK_HZ": 6_000_000}, "exceeds the MCP2510 maximum"),
        ({"CLK_FREQ_HZ": 12_000_000, "SPI_SCLK_HZ": 5_000_000}, "divider not achievable"),
    ],
    ids=["sck_above_5MHz", "divider_below_4"],
)
def test_mcp2510_spi_master_rejects_bad_generics(request, generics, message):
    res = _elaborate(request, generics)
    out = res.stdout + res.stderr
    assert res.returncode != 0, f"elaboration should fail for {generics}:\n{out}"
    assert message in out, out


def test_mcp2510_spi_master_reports_divider(request):
    res = _elaborate(request, {"CLK_FREQ_HZ": 50_000_000, "SPI_SCLK_HZ": 4_500_000})
    out = res.stdout + res.stderr
    assert res.returncode == 0, out
    assert "SCK = 4166666 Hz (half period 6 clocks)" in out, out

