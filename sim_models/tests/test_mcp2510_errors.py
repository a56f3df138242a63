"""MCP2510 model: error counters, EFLG, TXERR/MERRF driven by the CAN bus model
(DS21291 sections 6 and 7)."""

from __future__ import annotations

import pytest

from sim_models.can_bus import CanBus, QueueNode
from sim_models.mcp2510 import Mcp2510
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import configure, load_tx, new_chip, rts, set_mode, std
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler

BITRATE = 500_000


@pytest.fixture
def bus(sched: Scheduler) -> CanBus:
    return CanBus(sched, BITRATE)


@pytest.fixture
def chip(sched: Scheduler, bus: CanBus) -> Mcp2510:
    c = bus.attach(new_chip(sched))
    configure(c, BITRATE, caninte=R.CANINTE_ERRIE | R.CANINTE_MERRE)
    return c


def attempts(bus: CanBus) -> int:
    return len([r for r in bus.records if r.kind == "error"])


def test_lone_node_ack_errors_drive_tec_eflg_and_txerr(
    sched: Scheduler, bus: CanBus, chip: Mcp2510
) -> None:
    load_tx(chip, 0, std(0x123, b"\x01"))
    rts(chip, 0)
    while attempts(bus) < 1:
        sched.run_until(sched.now_ps + 10 * PS_PER_US)
    assert chip.spi_read(R.TEC)[0] == 8
    ctrl = chip.peek(R.TXB0CTRL)
    assert ctrl & R.TXBNCTRL_TXERR and ctrl & R.TXBNCTRL_TXREQ  # retried automatically
    assert chip.peek(R.CANINTF) & R.CANINTF_MERRF and chip.int_n == 0
    assert chip.peek(R.EFLG) == 0
    while attempts(bus) < 12:
        sched.run_until(sched.now_ps + 10 * PS_PER_US)
    assert chip.spi_read(R.TEC)[0] == 96
    assert chip.peek(R.EFLG) == R.EFLG_EWARN | R.EFLG_TXWAR
    assert chip.peek(R.CANINTF) & R.CANINTF_ERRIF
    assert chip.spi_read(R.CANSTAT)[0] & R.CANSTAT_ICOD_MASK == R.ICOD_ERROR << 1
    while attempts(bus) < 20:
        sched.run_until(sched.now_ps + 10 * PS_PER_US)
    # error-passive: ACK errors no longer count (CAN fault confinement exception)
    assert chip.spi_read(R.TEC, 2) == bytes([128, 0])
    assert chip.peek(R.EFLG) == R.EFLG_EWARN | R.EFLG_TXWAR | R.EFLG_TXEP
    assert chip.error_state == "error_passive"


def test_abat_ends_an_endless_retry(sched: Scheduler, bus: CanBus, chip: Mcp2510) -> None:
    load_tx(chip, 1, std(0x55))
    rts(chip, 1)
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_ABAT, R.CANCTRL_ABAT)
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    ctrl = chip.peek(R.TXB1CTRL)
    assert ctrl & R.TXBNCTRL_ABTF and ctrl & R.TXBNCTRL_TXERR
    assert not ctrl & R.TXBNCTRL_TXREQ
    n = attempts(bus)
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    assert attempts(bus) == n


def test_crc_error_on_received_frame(sched: Scheduler, bus: CanBus, chip: Mcp2510) -> None:
    peer = bus.attach(QueueNode("peer", BITRATE))
    chip.spi_bit_modify(R.CANINTF, 0xFF, 0)
    bus.corrupt_next_frame("peer")
    peer.send(std(0x181, b"\x42"))
    sched.run_until(sched.now_ps + 150 * PS_PER_US)  # first attempt destroyed
    assert chip.spi_read(R.REC)[0] == 1
    assert chip.peek(R.CANINTF) == R.CANINTF_MERRF
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)  # retransmitted successfully
    assert chip.spi_read(R.REC)[0] == 0
    assert chip.peek(R.CANINTF) == R.CANINTF_MERRF | R.CANINTF_RX0IF
    assert chip.spi_read(R.RXB0D0)[0] == 0x42


def test_receive_error_flags(chip: Mcp2510) -> None:
    chip.set_error_counters(rec=96)
    chip.on_bus_idle(chip.sched.now_ps)
    assert chip.peek(R.EFLG) == R.EFLG_EWARN | R.EFLG_RXWAR
    chip.set_error_counters(rec=128)
    assert chip.peek(R.EFLG) == R.EFLG_EWARN | R.EFLG_RXWAR | R.EFLG_RXEP
    assert chip.spi_read(R.REC)[0] == 128
    chip.spi_bit_modify(R.CANINTF, R.CANINTF_ERRIF, 0)
    chip.set_error_counters(rec=0)
    assert chip.peek(R.EFLG) == 0
    assert chip.peek(R.CANINTF) & R.CANINTF_ERRIF  # leaving a state is a change too


def test_bus_off_and_recovery(sched: Scheduler, bus: CanBus, chip: Mcp2510) -> None:
    bus.force_bus_off(chip)
    assert chip.peek(R.EFLG) & (R.EFLG_TXBO | R.EFLG_TXEP) == R.EFLG_TXBO | R.EFLG_TXEP
    assert chip.spi_read(R.TEC)[0] == 255
    assert chip.int_n == 0
    load_tx(chip, 0, std(0x1))
    rts(chip, 0)
    sched.run_until(sched.now_ps + 2 * PS_PER_MS)
    assert bus.records == []  # bus-off: nothing is sent
    sched.run_until(sched.now_ps + 2 * PS_PER_MS)  # 128 x 11 bits at 500 kbit/s = 2.8 ms
    assert chip.error_state != "bus_off"
    assert not chip.peek(R.EFLG) & R.EFLG_TXBO
    # recovered with TEC = 0; the pending frame is then retried (lone node: ACK errors)
    tec = chip.spi_read(R.TEC)[0]
    assert tec == chip.tec and tec % 8 == 0 and tec <= 128
    assert bus.records and bus.records[0].reason == "ack"


def test_config_request_during_retry_is_deferred_to_frame_end(
    sched: Scheduler, bus: CanBus, chip: Mcp2510
) -> None:
    load_tx(chip, 0, std(0x7, b"\x00" * 8))
    rts(chip, 0)
    sched.run_until(sched.now_ps + 30 * PS_PER_US)  # an attempt is on the wire
    set_mode(chip, R.OPMODE_CONFIG)
    assert chip.mode == "normal"  # the attempt on the wire finishes first
    sched.run_until(sched.now_ps + 300 * PS_PER_US)
    assert chip.mode == "configuration"
    assert attempts(bus) == 1
    assert chip.spi_read(R.TEC)[0] == 0  # cleared in configuration mode
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ  # still pending, not sent in config
    n = attempts(bus)
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    assert attempts(bus) == n
