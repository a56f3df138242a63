"""MCP2510 model: transmission (DS21291 section 3)."""

from __future__ import annotations

import can
import pytest

from sim_models.can_bus import CanBus, QueueNode
from sim_models.mcp2510 import Mcp2510, Mcp2510Error
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import configure, load_tx, new_chip, rts, same_frame, set_mode, std
from sim_models.sim_time import PS_PER_MS, Scheduler

BITRATE = 500_000


@pytest.fixture
def bus(sched: Scheduler) -> CanBus:
    return CanBus(sched, BITRATE)


@pytest.fixture
def peer(bus: CanBus) -> QueueNode:
    return bus.attach(QueueNode("peer", BITRATE))


@pytest.fixture
def chip(sched: Scheduler, bus: CanBus, peer: QueueNode) -> Mcp2510:
    c = bus.attach(new_chip(sched))
    configure(c, BITRATE, opmode=None)
    return c


def rts_now(chip: Mcp2510, n: int) -> None:
    """RTS from inside a scheduler callback (SPI byte times start now, time is not run)."""
    chip.spi_transfer(bytes([R.INSTR_RTS | (1 << n)]), advance=False)


def run_ms(sched: Scheduler, ms: float) -> None:
    sched.run_until(sched.now_ps + int(ms * PS_PER_MS))


def test_rts_sends_frame_sets_txif_and_clears_txreq(
    sched: Scheduler, chip: Mcp2510, peer: QueueNode
) -> None:
    chip.spi_write(R.CANINTE, [R.CANINTE_TX0IE])
    set_mode(chip, R.OPMODE_NORMAL)
    msg = std(0x181, b"\x11\x22\x33")
    load_tx(chip, 0, msg)
    rts(chip, 0)
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ
    assert chip.int_n == 1
    run_ms(sched, 1)
    assert len(peer.received) == 1 and same_frame(peer.received[0][1], msg)
    assert not chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ
    assert chip.peek(R.CANINTF) == R.CANINTF_TX0IF
    assert chip.int_n == 0
    assert chip.spi_read(R.CANSTAT)[0] & R.CANSTAT_ICOD_MASK == R.ICOD_TXB0 << 1


def test_extended_and_remote_frames(sched: Scheduler, chip: Mcp2510, peer: QueueNode) -> None:
    set_mode(chip, R.OPMODE_NORMAL)
    ext = can.Message(arbitration_id=0x1234567, is_extended_id=True, dlc=2, data=b"\xaa\x55")
    remote = can.Message(arbitration_id=0x701, is_extended_id=False, is_remote_frame=True, dlc=1)
    load_tx(chip, 1, ext)
    load_tx(chip, 2, remote)
    rts(chip, 1, 2)
    run_ms(sched, 1)
    got = [m for _, m in peer.received]
    assert len(got) == 2
    assert same_frame(got[0], remote) and same_frame(got[1], ext)  # equal TXP: TXB2 first


def test_txreq_by_write_and_by_bit_modify(sched: Scheduler, chip: Mcp2510, peer: QueueNode) -> None:
    set_mode(chip, R.OPMODE_NORMAL)
    load_tx(chip, 0, std(0x10))
    load_tx(chip, 1, std(0x11))
    chip.spi_write(R.TXB0CTRL, [R.TXBNCTRL_TXREQ])
    run_ms(sched, 0.5)
    chip.spi_bit_modify(R.TXB1CTRL, R.TXBNCTRL_TXREQ, R.TXBNCTRL_TXREQ)
    run_ms(sched, 0.5)
    assert [m.arbitration_id for _, m in peer.received] == [0x10, 0x11]


def test_priority_by_txp_then_higher_buffer_number(
    sched: Scheduler, chip: Mcp2510, peer: QueueNode
) -> None:
    load_tx(chip, 0, std(0x001), txp=1)  # lowest identifier, but not the highest TXP
    load_tx(chip, 1, std(0x002), txp=3)
    load_tx(chip, 2, std(0x003), txp=1)
    rts(chip, 0, 1, 2)  # pending in configuration mode, sent once normal
    assert chip.tx_candidate() is None
    set_mode(chip, R.OPMODE_NORMAL)
    run_ms(sched, 1)
    assert [m.arbitration_id for _, m in peer.received] == [0x002, 0x003, 0x001]
    assert chip.peek(R.CANINTF) == R.CANINTF_TX0IF | R.CANINTF_TX1IF | R.CANINTF_TX2IF


def test_txrts_pin_requests_transmission_when_enabled(
    sched: Scheduler, chip: Mcp2510, peer: QueueNode
) -> None:
    chip.spi_write(R.TXRTSCTRL, [R.TXRTSCTRL_B2RTSM])
    set_mode(chip, R.OPMODE_NORMAL)
    load_tx(chip, 2, std(0x080))  # SYNC
    load_tx(chip, 1, std(0x081))
    chip.set_txrts_n(1, 0, sched.now_ps)  # digital input only: nothing happens
    chip.set_txrts_n(1, 1, sched.now_ps)
    chip.set_txrts_n(2, 0, sched.now_ps)
    assert chip.peek(R.TXB2CTRL) & R.TXBNCTRL_TXREQ
    chip.set_txrts_n(2, 1, sched.now_ps)
    run_ms(sched, 1)
    assert [m.arbitration_id for _, m in peer.received] == [0x080]


def test_abat_aborts_pending_buffers(sched: Scheduler, chip: Mcp2510, peer: QueueNode) -> None:
    load_tx(chip, 0, std(0x20, b"\x00" * 8))
    load_tx(chip, 1, std(0x21))
    load_tx(chip, 2, std(0x22))
    set_mode(chip, R.OPMODE_NORMAL)
    rts(chip, 0)
    run_ms(sched, 0.05)  # TXB0's frame is on the wire now
    rts(chip, 1, 2)
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_ABAT, R.CANCTRL_ABAT)
    run_ms(sched, 1)
    assert [m.arbitration_id for _, m in peer.received] == [0x20]  # started: not aborted
    assert chip.peek(R.TXB0CTRL) & (R.TXBNCTRL_ABTF | R.TXBNCTRL_TXREQ) == 0
    for ctrl in (R.TXB1CTRL, R.TXB2CTRL):
        assert chip.peek(ctrl) & (R.TXBNCTRL_ABTF | R.TXBNCTRL_TXREQ) == R.TXBNCTRL_ABTF
    assert chip.peek(R.CANINTF) == R.CANINTF_TX0IF
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_ABAT, 0)
    rts(chip, 1)  # TXREQ clears ABTF
    assert chip.peek(R.TXB1CTRL) & R.TXBNCTRL_ABTF == 0
    run_ms(sched, 1)
    assert [m.arbitration_id for _, m in peer.received] == [0x20, 0x21]


def test_clearing_txreq_aborts_without_abtf(
    sched: Scheduler, chip: Mcp2510, peer: QueueNode
) -> None:
    load_tx(chip, 0, std(0x30))
    rts(chip, 0)
    chip.spi_bit_modify(R.TXB0CTRL, R.TXBNCTRL_TXREQ, 0)
    set_mode(chip, R.OPMODE_NORMAL)
    run_ms(sched, 1)
    assert peer.received == []
    assert chip.peek(R.TXB0CTRL) == 0


def test_tx_request_while_abat_set_is_flagged(chip: Mcp2510) -> None:
    load_tx(chip, 0, std(0x30))
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_ABAT, R.CANCTRL_ABAT)
    with pytest.raises(Mcp2510Error, match="ABAT is set"):
        rts(chip, 0)


def test_arbitration_lost_sets_mloa_and_retries(
    sched: Scheduler, chip: Mcp2510, peer: QueueNode
) -> None:
    set_mode(chip, R.OPMODE_NORMAL)
    load_tx(chip, 0, std(0x200))
    # both request at the same instant: the peer's lower identifier wins
    t = sched.now_ps + 10_000_000
    sched.call_at(t, rts_now, chip, 0)
    sched.call_at(t, peer.send, std(0x100))
    run_ms(sched, 0.1)
    assert chip.peek(R.TXB0CTRL) & (R.TXBNCTRL_MLOA | R.TXBNCTRL_TXREQ) == (
        R.TXBNCTRL_MLOA | R.TXBNCTRL_TXREQ
    )
    run_ms(sched, 1)
    assert not chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_MLOA  # stays until the next request
    assert chip.peek(R.CANINTF) & R.CANINTF_TX0IF
    assert [r.msg.arbitration_id for r in chip.bus.records] == [0x100, 0x200]


def test_two_chips_arbitrate(sched: Scheduler, bus: CanBus, chip: Mcp2510) -> None:
    other = bus.attach(new_chip(sched, name="other"))
    configure(other, BITRATE, opmode=None)
    load_tx(chip, 0, std(0x301))
    load_tx(other, 0, std(0x300))
    set_mode(chip, R.OPMODE_NORMAL)
    set_mode(other, R.OPMODE_NORMAL)
    t = sched.now_ps + 10_000_000
    sched.call_at(t, rts_now, chip, 0)
    sched.call_at(t, rts_now, other, 0)
    run_ms(sched, 1)
    assert [r.msg.arbitration_id for r in bus.records] == [0x300, 0x301]
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_MLOA
    assert not other.peek(R.TXB0CTRL) & R.TXBNCTRL_MLOA
    assert other.rx_log[-1][2].arbitration_id == 0x301
    assert chip.rx_log[-1][2].arbitration_id == 0x300


def test_writing_a_pending_buffer_is_a_violation(chip: Mcp2510) -> None:
    set_mode(chip, R.OPMODE_NORMAL)  # in configuration mode no frame can be on its way
    load_tx(chip, 0, std(0x40, b"\x01"))
    rts(chip, 0)
    with pytest.raises(Mcp2510Error, match="while TXB0CTRL.TXREQ is set"):
        chip.spi_write(R.TXB0D0, [0x02])


def test_uninitialised_buffer_and_bad_dlc(sched: Scheduler) -> None:
    chip = new_chip(sched, strict=False)
    set_mode(chip, R.OPMODE_LOOPBACK)
    chip.spi_write(R.TXB1SIDH, [0x10, 0x00])
    chip.spi_write(R.TXB1DLC, [0x02, 0xAA])  # D1 never written
    rts(chip, 1)
    assert "TXB1D1 not written since reset" in chip.violations[-1]
    chip.spi_write(R.TXB2SIDH, [0x10, R.TXBNSIDL_EXIDE])
    chip.spi_write(R.TXB2DLC, [R.TXBNDLC_RTR | 0x09])
    rts(chip, 2)
    assert any("TXB2EID8, TXB2EID0 not written" in v for v in chip.violations)
    assert "DLC > 8" in chip.violations[-1]


def test_tx_request_in_listen_only_mode_is_flagged(chip: Mcp2510) -> None:
    set_mode(chip, R.OPMODE_LISTEN_ONLY)
    load_tx(chip, 0, std(0x50))
    with pytest.raises(Mcp2510Error, match="cannot transmit"):
        rts(chip, 0)


def test_request_in_configuration_mode_is_checked_when_the_chip_can_send(sched: Scheduler) -> None:
    """A request of an unwritten buffer in configuration mode (e.g. an RTS that reached a chip
    reset behind the host's back) is harmless if a RESET clears it before the chip leaves
    configuration mode, and a violation if it is still pending when the chip can send."""
    chip = new_chip(sched, strict=False)
    configure(chip, BITRATE, opmode=None)
    chip.spi_write(R.TXB0SIDH, [0x10])  # SIDL and DLC never written
    rts(chip, 0)
    chip.spi_write(R.TXB0D0, [0x55])  # a pending buffer, but nothing can be on the wire
    assert chip.violations == []
    chip.spi_transfer(bytes([R.INSTR_RESET]))
    sched.run_until(max(sched.now_ps, chip.ready_ps))
    configure(chip, BITRATE, opmode=R.OPMODE_LOOPBACK)
    assert chip.violations == []  # the RESET cleared the request

    chip.spi_transfer(bytes([R.INSTR_RESET]))
    sched.run_until(max(sched.now_ps, chip.ready_ps))
    configure(chip, BITRATE, opmode=None)
    chip.spi_write(R.TXB0SIDH, [0x10])
    rts(chip, 0)
    assert chip.violations == []
    set_mode(chip, R.OPMODE_LOOPBACK)  # the request survives into a mode that transmits
    assert len(chip.violations) == 1
    assert "TXB0SIDL, TXB0DLC not written since reset" in chip.violations[0]
    assert "requested in configuration mode" in chip.violations[0]
