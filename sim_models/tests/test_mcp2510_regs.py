"""MCP2510 model: register map, reset values, access rules (DS21291 sections 4-11)."""

from __future__ import annotations

import pytest

from sim_models.mcp2510 import Mcp2510, Mcp2510Error
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import configure, new_chip, set_mode
from sim_models.sim_time import Scheduler


@pytest.fixture
def chip(sched: Scheduler) -> Mcp2510:
    return new_chip(sched)


def test_constants_match_the_data_sheet() -> None:
    assert (R.INSTR_RESET, R.INSTR_READ, R.INSTR_WRITE) == (0xC0, 0x03, 0x02)
    assert (R.INSTR_RTS, R.INSTR_READ_STATUS, R.INSTR_BIT_MODIFY) == (0x80, 0xA0, 0x05)
    assert (R.BFPCTRL, R.TXRTSCTRL, R.CANSTAT, R.CANCTRL) == (0x0C, 0x0D, 0x0E, 0x0F)
    assert (R.TEC, R.REC, R.RXM0SIDH, R.RXM1SIDH) == (0x1C, 0x1D, 0x20, 0x24)
    assert (R.CNF3, R.CNF2, R.CNF1, R.CANINTE, R.CANINTF, R.EFLG) == (
        0x28,
        0x29,
        0x2A,
        0x2B,
        0x2C,
        0x2D,
    )
    assert (R.RXF3SIDH, R.RXF4SIDH, R.RXF5SIDH) == (0x10, 0x14, 0x18)
    assert (R.TXB0CTRL, R.TXB1CTRL, R.TXB2CTRL, R.RXB0CTRL, R.RXB1CTRL) == (
        0x30,
        0x40,
        0x50,
        0x60,
        0x70,
    )
    assert (R.TXB2D7, R.RXB0SIDH, R.RXB1D0) == (0x5D, 0x61, 0x76)
    assert R.reg_name(0x2C) == "CANINTF" and R.reg_name(0x7E) == "CANSTAT"
    assert R.reg_name(0x43) == "TXB1EID8"
    # the short names used by rtl/mcp2510_pkg.vhd
    assert (R.TXBCTRL_TXREQ, R.SIDL_SRR, R.SIDL_IDE, R.DLC_RTR) == (0x08, 0x10, 0x08, 0x40)
    # every bit index names the bit of its mask
    for name in (n for n in dir(R) if n.endswith("_BIT")):
        assert 1 << getattr(R, name) == getattr(R, name[: -len("_BIT")]), name


def test_oscillator_range() -> None:
    with pytest.raises(ValueError):
        Mcp2510(Scheduler(), osc_hz=40_000_000)


def test_reset_values_of_every_register(chip: Mcp2510) -> None:
    raw = chip.spi_read(0x00, 0x80)
    expected = bytearray(0x80)
    for row in range(8):
        expected[row * 0x10 + 0x0E] = R.CANSTAT_RESET
        expected[row * 0x10 + 0x0F] = R.CANCTRL_RESET
    expected[R.TXRTSCTRL] = R.TXRTSCTRL_B0RTS | R.TXRTSCTRL_B1RTS | R.TXRTSCTRL_B2RTS
    assert raw == bytes(expected)
    assert chip.mode == "configuration"


def test_canctrl_and_canstat_are_mirrored(chip: Mcp2510) -> None:
    chip.spi_write(0x5F, [R.CANCTRL_RESET & ~R.CANCTRL_CLKEN])  # CANCTRL through a mirror
    assert chip.peek(R.CANCTRL) == 0x83
    for row in range(8):
        assert chip.spi_read(row * 0x10 + 0x0F)[0] == 0x83
        assert chip.spi_read(row * 0x10 + 0x0E)[0] == 0x80
    assert chip.clkout_hz is None


@pytest.mark.parametrize("addr", [R.CANSTAT, 0x3E, R.TEC, R.REC, R.RXB0SIDH, R.RXB1D7])
def test_read_only_registers_reject_writes(sched: Scheduler, addr: int) -> None:
    chip = new_chip(sched, strict=False)
    before = chip.peek(addr)
    chip.spi_write(addr, [0x5A])
    assert chip.peek(addr) == before
    assert "read-only" in chip.violations[-1]


def test_read_only_bits_inside_writable_registers(chip: Mcp2510) -> None:
    chip.spi_write(R.TXB0CTRL, [0xFF & ~R.TXBNCTRL_TXREQ])
    assert chip.peek(R.TXB0CTRL) == 0x03  # only TXP is writable (TXREQ 0 here)
    chip.spi_write(R.RXB0CTRL, [0xFF])
    assert chip.peek(R.RXB0CTRL) == 0x60 | R.RXB0CTRL_BUKT | R.RXB0CTRL_BUKT1
    chip.spi_write(R.RXB0CTRL, [0x00])
    assert chip.peek(R.RXB0CTRL) == 0x00  # BUKT1 follows BUKT
    chip.spi_write(R.RXB1CTRL, [0xFF])
    assert chip.peek(R.RXB1CTRL) == 0x60
    chip.spi_write(R.BFPCTRL, [0xFF])
    assert chip.peek(R.BFPCTRL) == 0x3F


def test_eflg_overflow_bits_are_clear_only(chip: Mcp2510) -> None:
    chip.poke(R.EFLG, R.EFLG_RX0OVR | R.EFLG_RX1OVR | R.EFLG_EWARN)
    chip.spi_write(R.EFLG, [0xFF])  # cannot set anything
    assert chip.peek(R.EFLG) == R.EFLG_RX0OVR | R.EFLG_RX1OVR | R.EFLG_EWARN
    chip.spi_bit_modify(R.EFLG, R.EFLG_RX0OVR, 0)
    assert chip.peek(R.EFLG) == R.EFLG_RX1OVR | R.EFLG_EWARN
    chip.spi_write(R.EFLG, [0x00])  # EWARN is read-only
    assert chip.peek(R.EFLG) == R.EFLG_EWARN


@pytest.mark.parametrize(
    "addr", [R.CNF1, R.CNF2, R.CNF3, R.TXRTSCTRL, R.RXF0SIDH, R.RXF5EID0, R.RXM1SIDL]
)
def test_config_only_registers_outside_configuration(sched: Scheduler, addr: int) -> None:
    chip = new_chip(sched, strict=False)
    configure(chip)
    assert chip.mode == "normal"
    before = chip.peek(addr)
    chip.spi_write(addr, [0x01])
    assert chip.peek(addr) == before
    assert "configuration mode only" in chip.violations[-1]


def test_config_only_write_raises_in_strict_mode(chip: Mcp2510) -> None:
    configure(chip)
    with pytest.raises(Mcp2510Error, match=r"CNF1\).*configuration mode only"):
        chip.spi_bit_modify(R.CNF1, 0x3F, 0x01)


def test_filters_and_masks_read_zero_outside_configuration(sched: Scheduler) -> None:
    chip = new_chip(sched, strict=False)
    chip.spi_write(R.RXF1SIDH, [0xAB])
    assert chip.spi_read(R.RXF1SIDH)[0] == 0xAB
    configure(chip, opmode=R.OPMODE_LISTEN_ONLY)
    assert chip.spi_read(R.RXF1SIDH)[0] == 0x00
    assert "returns 0" in chip.violations[-1]
    assert chip.peek(R.RXF1SIDH) == 0xAB  # still stored
    set_mode(chip, R.OPMODE_CONFIG)
    assert chip.spi_read(R.RXF1SIDH)[0] == 0xAB


def test_mcp2515_only_register_bits(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="OSM"):
        chip.spi_write(R.CANCTRL, [R.CANCTRL_RESET | R.CANCTRL_OSM_MCP2515])
    assert chip.peek(R.CANCTRL) == R.CANCTRL_RESET  # bit 3 is unimplemented
    with pytest.raises(Mcp2510Error, match="SOF"):
        chip.spi_write(R.CNF3, [R.CNF3_SOF_MCP2515 | 0x02])
    assert chip.peek(R.CNF3) == 0x02


def test_txrtsctrl_reads_pin_levels_in_input_mode(chip: Mcp2510) -> None:
    chip.set_txrts_n(1, 0, chip.sched.now_ps)
    assert chip.spi_read(R.TXRTSCTRL)[0] == R.TXRTSCTRL_B0RTS | R.TXRTSCTRL_B2RTS
    chip.spi_write(R.TXRTSCTRL, [0xFF])
    assert chip.spi_read(R.TXRTSCTRL)[0] == 0x07  # RTS mode: BnRTS read 0


def test_write_clearing_unread_interrupt_flag_is_flagged(chip: Mcp2510) -> None:
    chip._set_intf(R.CANINTF_RX0IF)  # as if a frame arrived
    with pytest.raises(Mcp2510Error, match="RX0IF.*never read.*BIT MODIFY"):
        chip.spi_write(R.CANINTF, [0x00])


def test_write_clearing_a_flag_the_host_has_read_is_fine(chip: Mcp2510) -> None:
    chip._set_intf(R.CANINTF_RX0IF | R.CANINTF_TX1IF)
    assert chip.spi_read(R.CANINTF)[0] == 0x09
    chip.spi_write(R.CANINTF, [0x00])
    assert chip.peek(R.CANINTF) == 0
    chip._set_intf(R.CANINTF_TX0IF)
    status = chip.spi_transfer(bytes([R.INSTR_READ_STATUS, 0]))[1]
    assert status & R.STATUS_TX0IF
    chip.spi_write(R.CANINTF, [0x00])  # seen through READ STATUS
    chip._set_intf(R.CANINTF_ERRIF)
    chip.spi_bit_modify(R.CANINTF, 0xFF, 0x00)  # BIT MODIFY is always fine
    assert chip.violations == []


def test_peek_poke_have_no_side_effects(chip: Mcp2510) -> None:
    chip.poke(R.CANCTRL, 0x00)  # would request normal mode through SPI
    assert chip.mode == "configuration"
    chip.poke(R.TXB0CTRL, R.TXBNCTRL_TXREQ)
    assert chip.tx_candidate() is None
    chip.poke(R.TEC, 100)
    assert chip.tec == 100 and chip.peek(R.TEC) == 100
    with pytest.raises(ValueError):
        chip.poke(R.CANSTAT, 0)
