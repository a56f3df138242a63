"""MCP2510 model: operation modes and bit timing (DS21291 sections 5, 8, 10)."""

from __future__ import annotations

import can
import pytest

from sim_models.can_bus import CanBus, QueueNode
from sim_models.mcp2510 import Mcp2510, Mcp2510Error, decode_cnf, encode_cnf
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import configure, load_tx, new_chip, read_rx, rts, set_mode
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler


@pytest.fixture
def chip(sched: Scheduler) -> Mcp2510:
    return new_chip(sched)


# ------------------------------------------------------------------------------ bit timing
@pytest.mark.parametrize(
    ("bitrate", "sample_point"),
    [(1_000_000, 0.625), (500_000, 0.75), (250_000, 0.75), (125_000, 0.75)],
)
def test_cnf_to_bitrate_at_16mhz(chip: Mcp2510, bitrate: int, sample_point: float) -> None:
    configure(chip, bitrate)
    assert chip.mode == "normal"
    assert chip.bitrate_bps == bitrate
    assert chip.sample_point == pytest.approx(sample_point)


def test_bitrate_formula_and_btlmode_zero() -> None:
    # BTLMODE = 0: PS2 = max(PS1, IPT); PHSEG2 bits are ignored
    bt = decode_cnf(0x01, 0x2A, 0x07, 20_000_000)  # BRP 1, PS1 6, Prop 3
    assert (bt.brp, bt.prop_tq, bt.ps1_tq, bt.ps2_tq) == (1, 3, 6, 6)
    assert bt.tq_per_bit == 16
    assert bt.bitrate_exact == pytest.approx(20e6 / (2 * 2 * 16))
    assert decode_cnf(0x00, 0x00, 0x00, 16_000_000).ps2_tq == R.IPT_TQ  # PS1 = 1 -> PS2 = 2
    assert encode_cnf(3, 3, 8, 4) == (0x03, 0xBA, 0x03)


@pytest.mark.parametrize(
    ("cnf", "reason"),
    [
        ((0x00, 0x80, 0x00), "information processing time"),  # PS2 = 1 TQ
        ((0x00, 0x88, 0x07), "PropSeg \\+ PS1"),  # Prop 1 + PS1 2 < PS2 8
        ((0xC0, 0xBA, 0x03), "must be > SJW"),  # SJW 4, PS2 4
        ((0x00, 0x81, 0x01), "outside 8..25 TQ"),  # 1 + 2 + 1 + 2 = 6 TQ
    ],
)
def test_invalid_cnf_rejected_when_leaving_configuration(
    chip: Mcp2510, cnf: tuple[int, int, int], reason: str
) -> None:
    chip.spi_write(R.CNF3, [cnf[2], cnf[1], cnf[0]])
    with pytest.raises(Mcp2510Error, match=reason):
        set_mode(chip, R.OPMODE_NORMAL)


def test_invalid_cnf_non_strict_still_changes_mode(sched: Scheduler) -> None:
    chip = new_chip(sched, strict=False)
    set_mode(chip, R.OPMODE_NORMAL)  # CNF all zero: PS2 = 2, 5 TQ per bit
    assert chip.mode == "normal"
    assert "invalid bit timing" in chip.violations[-1]


def test_bitrate_is_none_off_the_bus(chip: Mcp2510) -> None:
    configure(chip, opmode=None)
    assert chip.bitrate_bps is None and chip.configured_bitrate_bps == 500_000
    set_mode(chip, R.OPMODE_LOOPBACK)
    assert chip.mode == "loopback" and chip.bitrate_bps is None
    set_mode(chip, R.OPMODE_LISTEN_ONLY)
    assert chip.listen_only and chip.bitrate_bps == 500_000
    set_mode(chip, R.OPMODE_SLEEP)
    assert chip.mode == "sleep" and chip.bitrate_bps is None


# ------------------------------------------------------------------------------ modes
def test_opmod_confirms_reqop(chip: Mcp2510) -> None:
    configure(chip, opmode=R.OPMODE_LISTEN_ONLY)
    assert chip.spi_read(R.CANSTAT)[0] >> 5 == R.OPMODE_LISTEN_ONLY
    assert chip.spi_read(R.CANCTRL)[0] >> 5 == R.OPMODE_LISTEN_ONLY


def test_invalid_reqop_is_ignored(sched: Scheduler) -> None:
    chip = new_chip(sched, strict=False)
    chip.spi_write(R.CANCTRL, [0b101 << 5])
    assert chip.mode == "configuration"
    assert "not a valid mode request" in chip.violations[-1]


def test_configuration_mode_clears_error_counters(chip: Mcp2510) -> None:
    configure(chip)
    chip.set_error_counters(tec=130, rec=100)
    assert chip.spi_read(R.TEC, 2) == bytes([130, 100])
    set_mode(chip, R.OPMODE_CONFIG)
    assert chip.spi_read(R.TEC, 2) == bytes([0, 0])
    assert chip.error_state == "error_active"


def test_listen_only_request_with_pending_tx_is_flagged(chip: Mcp2510) -> None:
    configure(chip, opmode=None)
    load_tx(chip, 0, can.Message(arbitration_id=0x123, is_extended_id=False, dlc=0))
    rts(chip, 0)  # allowed in configuration mode: sent once the chip is on the bus
    with pytest.raises(Mcp2510Error, match="listen_only mode requested while a transmission"):
        set_mode(chip, R.OPMODE_LISTEN_ONLY)


def test_mode_change_waits_for_the_frame_on_the_wire(sched: Scheduler) -> None:
    bus = CanBus(sched, 125_000)
    chip = bus.attach(new_chip(sched))
    peer = bus.attach(QueueNode("peer", 125_000))
    configure(chip, 125_000)
    load_tx(chip, 0, can.Message(arbitration_id=0x100, is_extended_id=False, dlc=8, data=bytes(8)))
    rts(chip, 0)
    sched.run_until(sched.now_ps + 100 * PS_PER_US)  # the frame (~1 ms) is on the wire
    set_mode(chip, R.OPMODE_CONFIG)
    assert chip.mode == "normal"  # not yet
    sched.run_until(sched.now_ps + 2 * PS_PER_MS)
    assert chip.mode == "configuration"
    assert len(peer.received) == 1
    assert chip.peek(R.CANINTF) & R.CANINTF_TX0IF


# ------------------------------------------------------------------------------ sleep
def test_sleep_wakes_on_bus_activity_into_listen_only(sched: Scheduler) -> None:
    bus = CanBus(sched, 500_000)
    chip = bus.attach(new_chip(sched))
    peer = bus.attach(QueueNode("peer", 500_000))
    listener = bus.attach(QueueNode("ack", 500_000))
    configure(chip, caninte=R.CANINTE_WAKIE | R.CANINTE_RX0IE, opmode=R.OPMODE_SLEEP)
    assert chip.mode == "sleep" and chip.int_n == 1
    peer.send(can.Message(arbitration_id=0x10, is_extended_id=False, dlc=1, data=b"\x01"))
    sched.run_until(sched.now_ps + 20 * PS_PER_US)
    assert chip.peek(R.CANINTF) & R.CANINTF_WAKIF and chip.int_n == 0
    assert chip.spi_read(R.CANSTAT)[0] & R.CANSTAT_ICOD_MASK == R.ICOD_WAKE << 1
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    assert chip.mode == "listen_only"
    assert not chip.peek(R.CANINTF) & R.CANINTF_RX0IF  # the waking frame is lost
    assert len(listener.received) == 1
    peer.send(can.Message(arbitration_id=0x11, is_extended_id=False, dlc=0))
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    assert read_rx(chip, 0)[1].arbitration_id == 0x11


def test_sleep_without_wakie_stays_asleep(sched: Scheduler) -> None:
    bus = CanBus(sched, 500_000)
    chip = bus.attach(new_chip(sched))
    peer = bus.attach(QueueNode("peer", 500_000))
    bus.attach(QueueNode("ack", 500_000))
    configure(chip, opmode=R.OPMODE_SLEEP)
    peer.send(can.Message(arbitration_id=0x10, is_extended_id=False, dlc=0))
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    assert chip.mode == "sleep" and chip.peek(R.CANINTF) == 0


def test_leaving_sleep_by_reqop_takes_the_oscillator_start_up_time(chip: Mcp2510) -> None:
    configure(chip, opmode=R.OPMODE_SLEEP)
    t0 = chip.sched.now_ps
    set_mode(chip, R.OPMODE_NORMAL)
    assert chip.mode == "sleep"
    chip.sched.run_until(t0 + chip.ost_ps + 10 * PS_PER_US)
    assert chip.mode == "normal"


def test_host_can_wake_the_chip_by_setting_wakif(chip: Mcp2510) -> None:
    configure(chip, caninte=R.CANINTE_WAKIE, opmode=R.OPMODE_SLEEP)
    chip.spi_bit_modify(R.CANINTF, R.CANINTF_WAKIF, R.CANINTF_WAKIF)
    chip.sched.run_until(chip.sched.now_ps + chip.ost_ps)
    assert chip.mode == "listen_only"


# ------------------------------------------------------------------------------ loopback
def test_loopback_receives_own_frames_without_sending_them(sched: Scheduler) -> None:
    bus = CanBus(sched, 500_000)
    chip = bus.attach(new_chip(sched))
    peer = bus.attach(QueueNode("peer", 500_000))
    configure(chip, opmode=R.OPMODE_LOOPBACK, caninte=R.CANINTE_RX0IE | R.CANINTE_TX1IE)
    msg = can.Message(arbitration_id=0x1ABCDE, is_extended_id=True, dlc=3, data=b"\x01\x02\x03")
    load_tx(chip, 1, msg)
    rts(chip, 1)
    sched.run_until(sched.now_ps + 1 * PS_PER_MS)
    intf = chip.peek(R.CANINTF)
    assert intf & R.CANINTF_TX1IF and intf & R.CANINTF_RX0IF
    ctrl, got = read_rx(chip, 0)
    assert got.arbitration_id == 0x1ABCDE and got.is_extended_id and bytes(got.data) == b"\1\2\3"
    assert not chip.peek(R.TXB1CTRL) & R.TXBNCTRL_TXREQ
    assert bus.records == [] and peer.received == []
    # ICOD: TXB1 (4) has priority over RXB0 (6)
    assert chip.spi_read(R.CANSTAT)[0] == (R.OPMODE_LOOPBACK << 5) | (R.ICOD_TXB1 << 1)


def test_loopback_frame_takes_a_frame_time(chip: Mcp2510) -> None:
    configure(chip, 125_000, opmode=R.OPMODE_LOOPBACK)
    load_tx(chip, 0, can.Message(arbitration_id=0x7FF, is_extended_id=False, dlc=8, data=bytes(8)))
    t0 = chip.sched.now_ps
    rts(chip, 0)
    chip.sched.run_until(t0 + 500 * PS_PER_US)
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ  # 8-byte frame at 125k is ~1 ms
    chip.sched.run_until(t0 + 2 * PS_PER_MS)
    assert not chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ
    t_done = chip.tx_log[-1][0]
    assert 0.8 * PS_PER_MS < t_done - t0 < 1.2 * PS_PER_MS
