"""Bench of ``mcp2510_spi_master`` talking to the MCP2510 model: every MCP2510 instruction
through the real SPI engine and pins.

The DUT is only the SPI engine; the bench builds each instruction's bytes in Python and streams
them through the engine's byte interface (:mod:`tb.tblib.spi_stream`). On the pins sits the
behavioural MCP2510 model (:mod:`sim_models.mcp2510.chip`, strict: a data-sheet rule broken by
the host fails the test) behind the pin-level SPI checker with the MCP2510 timing; the chip is a
node of the CAN bus model with a ``QueueNode`` peer. Effects are checked on both sides: the
bytes the engine read back, and the model's registers through ``peek()`` (and, for RTS and
reception, the frames on the bus).

Instructions covered: RESET (with the oscillator start-up time), READ and WRITE with
auto-increment, BIT MODIFY on bit-modifiable and other registers, READ STATUS with repeated
output, RTS of one and of several buffers, reception (READ of the RX buffers, BIT MODIFY of
CANINTF). Tests that must fail prove that the model rejects an MCP2515-only opcode, a WRITE to
a configuration-only register in normal mode and an engine slower to select than the slave
demands; one normal test checks the text of the model's errors.
"""

from __future__ import annotations

import os
from pathlib import Path

import can
import cocotb
import pytest
from cocotb.triggers import FallingEdge, First, Timer

from sim_models.can_bus import CanBus, QueueNode
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.chip import Mcp2510, Mcp2510Error
from sim_models.mcp2510.testing import CNF_16MHZ
from sim_models.sim_time import PS_PER_NS, PS_PER_US, Scheduler
from sim_models.spi_slave import SpiTimingSpec, SpiViolation
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.mcp2510_pins import Mcp2510Pins
from tb.tblib.model_clock import ModelClock, sim_time_ps
from tb.tblib.runner import build_dir_for, param, run_cocotb
from tb.tblib.spi_stream import stream_transaction

OSC_HZ = 16_000_000
BITRATE = 1_000_000
TRACE_ENV = "MODEL_SPI_TRACE_DIR"
TRACE_NAME = "model_spi"


# ------------------------------------------------------------------------------ frame helpers
def id_regs(can_id: int, ext: bool) -> list[int]:
    """SIDH, SIDL, EID8, EID0 of an identifier (data-sheet layout, written out independently
    of the model's own encoder)."""
    if ext:
        sid, eid = can_id >> 18, can_id & 0x3FFFF
        return [sid >> 3, ((sid & 7) << 5) | R.TXBNSIDL_EXIDE | (eid >> 16), (eid >> 8) & 0xFF,
                eid & 0xFF]
    return [can_id >> 3, (can_id & 7) << 5, 0, 0]


def tx_bytes(msg: can.Message) -> list[int]:
    """TXBnSIDH .. last data byte for ``msg``."""
    dlc = msg.dlc | (R.TXBNDLC_RTR if msg.is_remote_frame else 0)
    data = [] if msg.is_remote_frame else list(msg.data)
    return id_regs(msg.arbitration_id, msg.is_extended_id) + [dlc] + data


def decode_rx(raw: bytes) -> can.Message:
    """RXBnSIDH .. RXBnD7 (13 bytes) to a frame."""
    sidh, sidl, eid8, eid0, dlc_reg = raw[:5]
    ext = bool(sidl & R.RXBNSIDL_IDE)
    sid = (sidh << 3) | (sidl >> 5)
    if ext:
        can_id = (sid << 18) | ((sidl & 0x03) << 16) | (eid8 << 8) | eid0
        remote = bool(dlc_reg & R.RXBNDLC_RTR)
    else:
        can_id, remote = sid, bool(sidl & R.RXBNSIDL_SRR)
    dlc = dlc_reg & 0x0F
    data = b"" if remote else bytes(raw[5:5 + min(dlc, 8)])
    return can.Message(arbitration_id=can_id, is_extended_id=ext, is_remote_frame=remote,
                       dlc=dlc, data=data)


def same_frame(a: can.Message, b: can.Message) -> bool:
    return (a.arbitration_id == b.arbitration_id and a.is_extended_id == b.is_extended_id
            and a.is_remote_frame == b.is_remote_frame and a.dlc == b.dlc
            and (a.is_remote_frame or bytes(a.data) == bytes(b.data)))


def std(can_id: int, data: bytes = b"", *, remote: bool = False, dlc: int | None = None):
    return can.Message(arbitration_id=can_id, is_extended_id=False, is_remote_frame=remote,
                       data=b"" if remote else data, dlc=len(data) if dlc is None else dlc)


def ext(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=True, data=data, dlc=len(data))


# ------------------------------------------------------------------------------------- bench
class TB:
    """SPI engine + MCP2510 model on its pins + CAN bus with one peer node."""

    def __init__(self, dut, *, spec: SpiTimingSpec | None = None, strict: bool = True) -> None:
        self.dut = dut
        start_clock(dut.clk_i, param("CLK_FREQ_HZ"))
        self.sched = Scheduler()
        self.sched.run_until(sim_time_ps())
        self.clock = ModelClock(self.sched)
        self.bus = CanBus(self.sched, BITRATE)
        self.chip = Mcp2510(self.sched, osc_hz=OSC_HZ, name="mcp2510", strict=strict)
        self.bus.attach(self.chip)
        self.peer = QueueNode("peer", BITRATE)
        self.bus.attach(self.peer)
        self.pins = Mcp2510Pins(self.chip, self.clock, cs_n=dut.spi_cs_n_o, sck=dut.spi_sck_o,
                                mosi=dut.spi_mosi_o, miso=dut.spi_miso_i, spec=spec,
                                released="Z")  # no pull-up: SO released reads as unknown
        for sig in (dut.tx_valid_i, dut.tx_data_i, dut.tx_last_i, dut.tx_end_i):
            sig.value = 0

    async def reset(self) -> None:
        """Reset the engine, then wait for the chip's power-on start-up time."""
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        await self.wait_ready()

    async def wait_ready(self) -> None:
        """Wait until the chip's oscillator start-up timer has expired."""
        now = sim_time_ps()
        if self.chip.ready_ps > now:
            await Timer(self.chip.ready_ps - now, "ps")

    def stop(self) -> None:
        self.pins.stop()
        self.clock.stop()

    # ------------------------------------------------------------------ instructions
    async def xfer(self, data) -> list[int | None]:
        return await stream_transaction(self.dut, bytes(data))

    async def reset_instr(self) -> None:
        so = await self.xfer([R.INSTR_RESET])
        assert so == [None], f"SO driven during RESET: {so}"

    async def read(self, addr: int, n: int) -> bytes:
        so = await self.xfer([R.INSTR_READ, addr] + [0] * n)
        assert so[:2] == [None, None], f"SO driven during READ instruction/address: {so[:2]}"
        assert None not in so[2:], f"SO not driven in a READ data byte: {so}"
        return bytes(so[2:])

    async def write(self, addr: int, values) -> None:
        so = await self.xfer([R.INSTR_WRITE, addr] + list(values))
        assert so == [None] * len(so), f"SO driven during WRITE: {so}"

    async def bit_modify(self, addr: int, mask: int, data: int) -> None:
        so = await self.xfer([R.INSTR_BIT_MODIFY, addr, mask, data])
        assert so == [None] * 4, f"SO driven during BIT MODIFY: {so}"

    async def rts(self, buffers: int) -> None:
        so = await self.xfer([R.INSTR_RTS | buffers])
        assert so == [None], f"SO driven during RTS: {so}"

    async def read_status(self, repeats: int = 1) -> list[int]:
        so = await self.xfer([R.INSTR_READ_STATUS] + [0] * repeats)
        assert so[0] is None and None not in so[1:], f"READ STATUS output {so}"
        return list(so[1:])

    # ------------------------------------------------------------------ sequences
    async def go_normal(self, bitrate: int = BITRATE) -> None:
        """Bit timing for ``bitrate`` at 16 MHz, then normal mode (polled through CANSTAT)."""
        cnf1, cnf2, cnf3 = CNF_16MHZ[bitrate]
        await self.write(R.CNF3, [cnf3, cnf2, cnf1])
        await self.bit_modify(R.CANCTRL, R.CANCTRL_REQOP_MASK,
                              R.OPMODE_NORMAL << R.CANCTRL_REQOP_SHIFT)
        for _ in range(10):
            (canstat,) = await self.read(R.CANSTAT, 1)
            if canstat & R.CANSTAT_OPMOD_MASK == R.OPMODE_NORMAL << R.CANSTAT_OPMOD_SHIFT:
                break
            await Timer(10, "us")
        else:
            raise AssertionError(f"chip did not enter normal mode (CANSTAT 0x{canstat:02X})")
        assert self.chip.mode == "normal" and self.chip.bitrate_bps == bitrate

    async def load_tx(self, n: int, msg: can.Message, txp: int | None = None) -> None:
        """WRITE buffer n from TXBnCTRL (with TXP, TXREQ = 0) or from TXBnSIDH."""
        base = R.TXB0CTRL + R.TXB_STRIDE * n
        if txp is None:
            await self.write(base + R.BUF_SIDH_OFFSET, tx_bytes(msg))
        else:
            await self.write(base, [txp] + tx_bytes(msg))

    async def wait_for(self, cond, timeout_us: int, step_us: int = 10) -> None:
        t_end = sim_time_ps() + timeout_us * PS_PER_US
        while not cond():
            assert sim_time_ps() < t_end, f"condition not met within {timeout_us} us"
            await Timer(step_us, "us")

    async def poll_status(self, bits: int, timeout_us: int = 2000) -> int:
        """READ STATUS every 10 us until all ``bits`` are set; returns the status byte."""
        t_end = sim_time_ps() + timeout_us * PS_PER_US
        while True:
            (st,) = await self.read_status()
            if st & bits == bits:
                return st
            assert sim_time_ps() < t_end, f"status bits 0x{bits:02X} not set (0x{st:02X})"
            await Timer(10, "us")

    def check_no_violations(self) -> None:
        assert self.chip.violations == [], self.chip.violations
        assert self.pins.slave.violations == [], self.pins.slave.violations


async def cs_fall_time(dut) -> int:
    await FallingEdge(dut.spi_cs_n_o)
    return sim_time_ps()


async def catch_pin_error(tb: TB, data) -> BaseException:
    """Run one transaction whose bytes the model must reject and return the exception.

    The model raises inside the pin bridge's coroutine (which then ends); waiting on that
    coroutine's completion keeps the error from failing the test, like ``pytest.raises``.
    """
    bridge = tb.pins.spi.task  # the coroutine a model error terminates
    xfer = cocotb.start_soon(stream_transaction(tb.dut, bytes(data)))
    await First(bridge.complete, xfer.complete)
    assert bridge.done(), f"the model accepted {bytes(data).hex(' ')} without an error"
    exc = bridge.exception()
    assert exc is not None, "pin bridge ended without an error"
    await xfer  # the engine still completes its transaction
    return exc


# ====================================================================================== tests
@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_reset_and_read_register_map(dut):
    """Purpose: RESET instruction, start-up time, READ auto-increment over the whole map.

    Verifies: registers written before RESET return to their reset values; RESET takes effect
    (last_reset = RESET instruction) and starts the 128-cycle oscillator start-up timer; the
    next access waits for it; one READ from 0x00 streams all 128 registers with auto-increment
    and every byte equals peek() and the data-sheet reset value (CANSTAT/CANCTRL mirrors,
    TXRTSCTRL BnRTS bits following the idle-high pins); SO is high impedance except during
    READ data bytes.
    """
    tb = TB(dut)
    await tb.reset()
    await tb.write(R.CANINTE, [0xA5])
    await tb.write(R.TXB0D0, [0x11, 0x22])
    assert tb.chip.peek(R.CANINTE) == 0xA5 and tb.chip.peek(R.TXB0D0 + 1) == 0x22
    t_before = sim_time_ps()
    await tb.reset_instr()
    t_reset, cause = tb.chip.last_reset
    assert cause == "RESET instruction" and t_reset > t_before
    assert tb.chip.ready_ps == t_reset + tb.chip.ost_ps
    assert tb.chip.ost_ps == 128 * 1_000_000 // 16  # 128 OSC1 cycles at 16 MHz = 8 us
    assert tb.chip.peek(R.CANINTE) == R.CANINTE_RESET and tb.chip.peek(R.TXB0D0) == 0
    await tb.wait_ready()
    regs = await tb.read(0x00, 128)
    t_read = tb.pins.slave.transactions[-1].t_start_ps
    assert t_read >= tb.chip.ready_ps, "READ started inside the start-up time"
    for a in range(128):
        assert regs[a] == tb.chip.peek(a), f"READ 0x{a:02X} = 0x{regs[a]:02X} != peek"
        if a & 0x0F == 0x0E:
            exp = R.CANSTAT_RESET
        elif a & 0x0F == 0x0F:
            exp = R.CANCTRL_RESET
        elif a == R.TXRTSCTRL:  # BnRTS read the pins (idle high) while BnRTSM = 0
            exp = R.TXRTSCTRL_B0RTS | R.TXRTSCTRL_B1RTS | R.TXRTSCTRL_B2RTS
        else:
            exp = 0
        assert regs[a] == exp, f"0x{a:02X} ({R.reg_name(a)}) = 0x{regs[a]:02X}, reset 0x{exp:02X}"
    assert tb.chip.mode == "configuration" and tb.chip.clkout_hz == OSC_HZ / 8
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_write_auto_increment(dut):
    """Purpose: WRITE with auto-increment into filters, bit timing and a TX buffer.

    Verifies: one WRITE fills consecutive registers (RXF0SIDH..RXF1EID0, CNF3..CANINTE, all 13
    bytes of TXB1 from SIDH), peek() and a READ back agree; write masks of the chip apply
    (TXBnSIDL bit 4/2, TXBnDLC bits 7/5/4 read 0); the decoded CNF gives 1 Mbit/s.
    """
    tb = TB(dut)
    await tb.reset()
    filt = [0x12, 0x34 & R.RXFNSIDL_WRITE_MASK, 0x56, 0x78, 0x9A, 0xA3, 0xDE, 0xF0]
    await tb.write(R.RXF0SIDH, filt)
    assert [tb.chip.peek(R.RXF0SIDH + i) for i in range(8)] == filt
    assert list(await tb.read(R.RXF0SIDH, 8)) == filt
    cnf1, cnf2, cnf3 = CNF_16MHZ[BITRATE]
    await tb.write(R.CNF3, [cnf3, cnf2, cnf1, 0x3C])
    assert [tb.chip.peek(a) for a in (R.CNF3, R.CNF2, R.CNF1, R.CANINTE)] == [cnf3, cnf2, cnf1,
                                                                            0x3C]
    assert tb.chip.configured_bitrate_bps == BITRATE
    assert list(await tb.read(R.CNF3, 4)) == [cnf3, cnf2, cnf1, 0x3C]
    raw = [0xA1, 0xFF, 0xB2, 0xC3, 0xFF, 1, 2, 3, 4, 5, 6, 7, 8]
    await tb.write(R.TXB1SIDH, raw)
    masked = list(raw)
    masked[1] &= R.TXBNSIDL_WRITE_MASK
    masked[4] &= R.TXBNDLC_WRITE_MASK
    assert masked[1] == 0xEB and masked[4] == 0x4F
    assert [tb.chip.peek(R.TXB1SIDH + i) for i in range(13)] == masked
    back = await tb.read(R.TXB1CTRL, 14)
    assert back[0] == R.TXBNCTRL_RESET and list(back[1:]) == masked
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_bit_modify(dut):
    """Purpose: BIT MODIFY on bit-modifiable registers and on one that is not.

    Verifies: on CANINTE, CNF1 (configuration mode), TXB0CTRL and CANCTRL only the mask bits
    change; on TXB0SIDH (not bit-modifiable) mask 0xFF is a plain write; with another mask the
    chip forces it to 0xFF and the data byte replaces the whole register, which the model
    applies and reports as a violation (checked with the model non-strict for that step).
    """
    tb = TB(dut)
    await tb.reset()
    await tb.write(R.CANINTE, [0xF0])
    await tb.bit_modify(R.CANINTE, 0x0F, 0x05)
    assert tb.chip.peek(R.CANINTE) == 0xF5
    await tb.bit_modify(R.CANINTE, 0x81, 0x00)
    assert tb.chip.peek(R.CANINTE) == 0x74
    assert list(await tb.read(R.CANINTE, 1)) == [0x74]
    await tb.write(R.CNF1, [0x03])
    await tb.bit_modify(R.CNF1, R.CNF1_SJW_MASK, 0x40)
    assert tb.chip.peek(R.CNF1) == 0x43
    await tb.bit_modify(R.TXB0CTRL, R.TXBNCTRL_TXP_MASK, 0x02)
    assert tb.chip.peek(R.TXB0CTRL) == 0x02
    await tb.bit_modify(R.CANCTRL, R.CANCTRL_CLKEN | R.CANCTRL_CLKPRE_MASK, 0x00)
    assert tb.chip.peek(R.CANCTRL) == 0x80 and tb.chip.clkout_hz is None
    assert tb.chip.mode == "configuration"
    # not bit-modifiable: a full mask is an ordinary write
    await tb.write(R.TXB0SIDH, [0x00])
    await tb.bit_modify(R.TXB0SIDH, 0xFF, 0x5A)
    assert tb.chip.peek(R.TXB0SIDH) == 0x5A
    tb.check_no_violations()
    # partial mask: the chip writes the whole data byte (mask forced to 0xFF)
    tb.chip.strict = False
    await tb.bit_modify(R.TXB0SIDH, 0x0F, 0xA3)
    assert tb.chip.peek(R.TXB0SIDH) == 0xA3, "mask not forced to 0xFF"
    assert len(tb.chip.violations) == 1
    v = tb.chip.violations[0]
    assert "BIT MODIFY @0x31 (TXB0SIDH)" in v and "not bit-modifiable" in v, v
    assert "forces the mask 0x0F to 0xFF" in v, v
    assert tb.pins.slave.violations == []
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_read_status_repeats(dut):
    """Purpose: READ STATUS returns the same status byte for as long as it is clocked.

    Verifies: for two combinations of CANINTF flags and TXREQ bits (set by the back door) the
    status byte is the data-sheet bit layout (RX0IF, RX1IF, TXB0 TXREQ, TX0IF, TXB1 TXREQ, ...)
    and repeats on every extra byte; SO is high impedance during the instruction byte.
    """
    tb = TB(dut)
    await tb.reset()
    assert await tb.read_status(2) == [0x00, 0x00]
    tb.chip.poke(R.CANINTF, R.CANINTF_RX0IF | R.CANINTF_TX1IF)
    tb.chip.poke(R.TXB2CTRL, R.TXBNCTRL_TXREQ)
    st = await tb.read_status(5)
    assert st == [0x61] * 5, [hex(s) for s in st]
    tb.chip.poke(R.CANINTF, R.CANINTF_RX1IF | R.CANINTF_TX0IF | R.CANINTF_TX2IF)
    tb.chip.poke(R.TXB0CTRL, R.TXBNCTRL_TXREQ)
    tb.chip.poke(R.TXB1CTRL, R.TXBNCTRL_TXREQ)
    tb.chip.poke(R.TXB2CTRL, 0)
    st = await tb.read_status(3)
    assert st == [0x9E] * 3 and tb.chip.read_status() == 0x9E, [hex(s) for s in st]
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_rts_one_and_several_buffers(dut):
    """Purpose: transmit through WRITE + RTS, one buffer and several at once.

    Verifies: CNF for 1 Mbit/s at 16 MHz and a BIT MODIFY of REQOP bring the chip to normal
    mode (CANSTAT polled); RTS 0x81 sends TXB0 (TXREQ visible in READ STATUS until the frame
    is acknowledged, then TX0IF); RTS 0x87 sends three buffers in TXP order; RTS 0x86 after a
    BIT MODIFY of TXB1CTRL.TXP sends TXB2 before TXB1; the peer receives every frame bit-exact.
    """
    tb = TB(dut)
    await tb.reset()
    await tb.go_normal()
    f0 = std(0x123, b"\x11\x22\x33")
    await tb.load_tx(0, f0)
    await tb.rts(0x01)
    (st,) = await tb.read_status()
    assert st & R.STATUS_TXB0_TXREQ, f"TXREQ not set after RTS (status 0x{st:02X})"
    await tb.wait_for(lambda: len(tb.peer.received) == 1, 1000)
    assert same_frame(tb.peer.received[0][1], f0)
    st = await tb.poll_status(R.STATUS_TX0IF)
    assert st == R.STATUS_TX0IF, f"status 0x{st:02X}"
    await tb.bit_modify(R.CANINTF, R.CANINTF_TX0IF, 0)
    assert await tb.read_status() == [0]
    # several buffers at once: bus order follows TXP (TXB1 3, TXB2 2, TXB0 1)
    frames = {0: (1, std(0x100, b"\x00")),
              1: (3, ext(0x1234567, bytes(range(8)))),
              2: (2, std(0x0F0, remote=True, dlc=4))}
    for n, (txp, f) in frames.items():
        await tb.load_tx(n, f, txp=txp)
    await tb.rts(0x07)
    await tb.wait_for(lambda: len(tb.peer.received) == 4, 2000)
    for (_, got), n in zip(tb.peer.received[1:], (1, 2, 0)):
        assert same_frame(got, frames[n][1]), f"{got} != TXB{n} {frames[n][1]}"
    assert [n for _, n, _ in tb.chip.tx_log] == [0, 1, 2, 0]
    st = await tb.poll_status(R.STATUS_TX0IF | R.STATUS_TX1IF | R.STATUS_TX2IF)
    assert st == 0xA8, f"status 0x{st:02X}"
    await tb.bit_modify(R.CANINTF, 0x1C, 0)
    # two buffers, priority of TXB1 lowered by BIT MODIFY: TXB2 goes first
    await tb.bit_modify(R.TXB1CTRL, R.TXBNCTRL_TXP_MASK, 0)
    assert tb.chip.peek(R.TXB1CTRL) == 0
    await tb.rts(0x06)
    await tb.wait_for(lambda: len(tb.peer.received) == 6, 2000)
    assert [n for _, n, _ in tb.chip.tx_log[4:]] == [2, 1]
    assert same_frame(tb.peer.received[4][1], frames[2][1])
    assert same_frame(tb.peer.received[5][1], frames[1][1])
    txbctrl = await tb.read(R.TXB1CTRL, 1)
    assert txbctrl[0] & R.TXBNCTRL_TXREQ == 0
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_receive(dut):
    """Purpose: receive path: READ of the RX buffers, BIT MODIFY of CANINTF.

    Verifies: RXB0CTRL set by BIT MODIFY (RXM = any, BUKT; BUKT1 follows); a frame from the
    peer sets RX0IF (seen by polling READ STATUS), one READ of RXB0CTRL..RXB0D7 returns its id,
    DLC and data; BIT MODIFY CANINTF clears only RX0IF; two back-to-back frames (extended data,
    standard remote) land in RXB0 and, by rollover, RXB1 (RXRTR set); nothing overflows.
    """
    tb = TB(dut)
    await tb.reset()
    await tb.bit_modify(R.RXB0CTRL, R.RXBNCTRL_RXM_MASK | R.RXB0CTRL_BUKT,
                        (R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT) | R.RXB0CTRL_BUKT)
    await tb.bit_modify(R.RXB1CTRL, R.RXBNCTRL_RXM_MASK, R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT)
    assert list(await tb.read(R.RXB0CTRL, 1)) == [0x66]
    await tb.go_normal()
    await tb.write(R.CANINTF, [R.CANINTF_TX0IF])  # a flag of our own, must survive the clear
    f1 = std(0x2A5, b"\x01\x02\x03")
    tb.peer.send(f1)
    st = await tb.poll_status(R.STATUS_RX0IF)
    assert st & R.STATUS_RX1IF == 0
    raw = await tb.read(R.RXB0CTRL, R.BUF_SIZE)
    assert same_frame(decode_rx(raw[1:]), f1), decode_rx(raw[1:])
    await tb.bit_modify(R.CANINTF, R.CANINTF_RX0IF, 0)
    assert tb.chip.peek(R.CANINTF) == R.CANINTF_TX0IF
    await tb.bit_modify(R.CANINTF, R.CANINTF_TX0IF, 0)
    f2 = ext(0x12345678, b"\xde\xad\xbe\xef\x00\x11\x22\x33")
    f3 = std(0x0F0, remote=True, dlc=2)
    tb.peer.send(f2, f3)
    await tb.poll_status(R.STATUS_RX0IF | R.STATUS_RX1IF)
    raw0 = await tb.read(R.RXB0CTRL, R.BUF_SIZE)
    raw1 = await tb.read(R.RXB1CTRL, R.BUF_SIZE)
    assert same_frame(decode_rx(raw0[1:]), f2), decode_rx(raw0[1:])
    assert same_frame(decode_rx(raw1[1:]), f3), decode_rx(raw1[1:])
    assert raw1[0] & R.RXBNCTRL_RXRTR and not raw0[0] & R.RXBNCTRL_RXRTR
    await tb.bit_modify(R.CANINTF, R.CANINTF_RX0IF | R.CANINTF_RX1IF, 0)
    assert tb.chip.peek(R.CANINTF) == 0 and await tb.read_status() == [0]
    assert [b for _, b, _ in tb.chip.rx_log] == [0, 0, 1]
    assert tb.chip.overflow_count == 0 and len(tb.peer.sent) == 3
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_bus_trace_files(dut):
    """Purpose: the bus trace of a short exchange is written as candump log and ASC.

    Verifies: after one frame from the peer and one sent by RTS, ``bus.write_trace`` writes
    ``model_spi.log`` and ``model_spi.asc`` in the build directory; ``can.LogReader`` reads
    both back with the frames' ids, types, data and start times (1 us resolution).
    """
    tb = TB(dut)
    await tb.reset()
    await tb.bit_modify(R.RXB0CTRL, R.RXBNCTRL_RXM_MASK, R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT)
    await tb.go_normal()
    tb.peer.send(ext(0x0ABCDEF, b"\x42"))
    await tb.poll_status(R.STATUS_RX0IF)
    await tb.load_tx(0, std(0x321, b"\x55\xaa"))
    await tb.rts(0x01)
    await tb.poll_status(R.STATUS_TX0IF)
    frames = [r for r in tb.bus.records if r.kind == "frame"]
    assert [r.sender for r in frames] == ["peer", "mcp2510"]
    out = Path(os.environ.get(TRACE_ENV, str(build_dir_for("test_mcp2510_model_spi"))))
    out.mkdir(parents=True, exist_ok=True)
    for suffix in (".log", ".asc"):
        path = out / f"{TRACE_NAME}{suffix}"
        tb.bus.write_trace(path)
        assert path.is_file() and path.stat().st_size > 0, path
        back = list(can.LogReader(str(path)))
        assert len(back) == len(frames), f"{path}: {len(back)} frames, bus had {len(frames)}"
        for msg, rec in zip(back, frames):
            assert same_frame(msg, rec.msg), f"{path}: {msg} != {rec.msg}"
            assert abs(msg.timestamp - rec.t_start_ps / 1e12) <= 1e-6, (msg.timestamp, rec)
    tb.check_no_violations()
    tb.stop()
    await Timer(1, "ns")


# ------------------------------------------------------------------ tests that must fail
@cocotb.test(timeout_time=2, timeout_unit="ms", expect_error=Mcp2510Error)
async def run_mcp2515_opcode_rejected(dut):
    """Purpose: prove the model rejects MCP2515-only instructions.

    Verifies: READ RX BUFFER (0x90), which exists on the MCP2515 only, raises Mcp2510Error.
    """
    tb = TB(dut)
    await tb.reset()
    await tb.xfer([R.INSTR_MCP2515_READ_RX_BUFFER, 0, 0, 0])
    await Timer(1, "ns")


@cocotb.test(timeout_time=2, timeout_unit="ms", expect_error=Mcp2510Error)
async def run_config_register_write_in_normal_mode_rejected(dut):
    """Purpose: prove the model rejects a WRITE to a configuration-only register.

    Verifies: WRITE CNF1 in normal mode raises Mcp2510Error (DS21291 section 10.1).
    """
    tb = TB(dut)
    await tb.reset()
    await tb.go_normal()
    await tb.write(R.CNF1, [0x01])
    await Timer(1, "ns")


@cocotb.test(timeout_time=2, timeout_unit="ms", expect_error=SpiViolation)
async def run_stricter_slave_spec_rejected(dut):
    """Purpose: prove the pin-level checker in front of the model can fail.

    Verifies: a slave demanding 3 x the engine's CS setup time (CS_SETUP_NS) raises
    SpiViolation on the first SCK edge of the first access.
    """
    tb = TB(dut, spec=SpiTimingSpec(t_cs_setup_ps=3 * param("CS_SETUP_NS") * PS_PER_NS))
    await tb.reset()
    await tb.read(R.CANSTAT, 1)
    await Timer(1, "ns")


@cocotb.test(timeout_time=5, timeout_unit="ms")
async def run_model_errors_are_clear(dut):
    """Purpose: the model's error messages locate the problem.

    Verifies (each error caught inside the test, pytest.raises style): for an MCP2515-only
    opcode, a WRITE to CNF1 in normal mode and an access inside the start-up time after RESET,
    the Mcp2510Error's message names the chip, the exact simulated time of the offending SCK
    edge or CS fall, the instruction (and register) and the reason; t_ps/instruction/address
    attributes match; the chip records the same text in ``violations``.
    """
    clk_ps = 1_000_000_000_000 // param("CLK_FREQ_HZ")
    half = -(-param("CLK_FREQ_HZ") // (2 * param("SPI_SCLK_HZ")))
    setup_ps = max(-(-param("CS_SETUP_NS") * PS_PER_NS // clk_ps), half) * clk_ps
    byte_ps = 16 * half * clk_ps

    def nth_byte_end(t_cs: int, k: int) -> int:
        """Time of the 8th rising SCK edge of byte k (0-based) of a gapless transaction."""
        return t_cs + setup_ps + (7 * 2 * half) * clk_ps + k * byte_ps

    def check(exc: BaseException, tb: TB, t_ps: int, instr: str, *parts: str) -> str:
        assert isinstance(exc, Mcp2510Error), f"expected Mcp2510Error, got {exc!r}"
        msg = str(exc)
        assert exc.t_ps == t_ps, f"t_ps {exc.t_ps} != {t_ps}"
        assert exc.instruction == instr
        assert msg.startswith(f"MCP2510 'mcp2510' at t={t_ps / 1e6:.4f} us, {instr}"), msg
        for p in parts:
            assert p in msg, f"{p!r} not in {msg!r}"
        assert tb.chip.violations == [msg]
        return msg

    # 1: MCP2515-only opcode, rejected at the instruction byte
    tb = TB(dut)
    await tb.reset()
    t_cs = cocotb.start_soon(cs_fall_time(dut))
    exc = await catch_pin_error(tb, [0x90, 0x00, 0x00])
    msg = check(exc, tb, nth_byte_end(await t_cs, 0), "opcode 0x90",
                "MCP2515-only instruction READ RX BUFFER (0x90)", "not supported by the MCP2510")
    dut._log.info("caught: %s", msg)
    tb.stop()
    # 2: WRITE to a configuration-only register in normal mode, rejected at the data byte
    tb = TB(dut)
    await tb.wait_ready()
    await tb.go_normal()
    t_cs = cocotb.start_soon(cs_fall_time(dut))
    exc = await catch_pin_error(tb, [R.INSTR_WRITE, R.CNF1, 0x01])
    msg = check(exc, tb, nth_byte_end(await t_cs, 2), "WRITE", "WRITE @0x2A (CNF1)",
                "configuration mode only (mode is normal)")
    assert exc.address == R.CNF1 and tb.chip.peek(R.CNF1) == CNF_16MHZ[BITRATE][0]
    dut._log.info("caught: %s", msg)
    tb.stop()
    # 3: an access during the oscillator start-up time after RESET, rejected at CS fall
    tb = TB(dut)
    await tb.wait_ready()
    await tb.reset_instr()
    t_cs = cocotb.start_soon(cs_fall_time(dut))
    exc = await catch_pin_error(tb, [R.INSTR_READ, R.CANSTAT, 0x00])
    msg = check(exc, tb, await t_cs, "SPI", "before the oscillator start-up timer expires",
                "after RESET instruction")
    dut._log.info("caught: %s", msg)
    tb.stop()
    await Timer(1, "ns")


# ============================================================================= pytest entry
PARAMS = {
    "CLK_FREQ_HZ": 20_000_000,
    "SPI_SCLK_HZ": 5_000_000,
    "CS_SETUP_NS": 100,
    "CS_HOLD_NS": 100,
    "CS_DISABLE_NS": 100,
}


@pytest.mark.sim
def test_mcp2510_model_spi(request):
    trace_dir = build_dir_for(request.node.name)
    run_cocotb(toplevel="mcp2510_spi_master", module="tb.test_mcp2510_model_spi",
               name=request.node.name, parameters=PARAMS,
               extra_env={TRACE_ENV: str(trace_dir)})
    for suffix in (".log", ".asc"):
        path = trace_dir / f"{TRACE_NAME}{suffix}"
        assert path.is_file(), f"bus trace {path} was not written"
        assert len(list(can.LogReader(str(path)))) == 2, path
