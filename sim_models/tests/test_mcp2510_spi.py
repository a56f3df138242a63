"""MCP2510 model: SPI instruction set, framing, strictness (DS21291 section 11)."""

from __future__ import annotations

import pytest

from sim_models.mcp2510 import Mcp2510, Mcp2510Error
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.testing import new_chip
from sim_models.sim_time import PS_PER_US, Scheduler


@pytest.fixture
def chip(sched: Scheduler) -> Mcp2510:
    return new_chip(sched)


def lax(sched: Scheduler) -> Mcp2510:
    return new_chip(sched, strict=False)


# ------------------------------------------------------------------------------ READ / WRITE
def test_read_returns_reset_values_with_autoincrement(chip: Mcp2510) -> None:
    # BFPCTRL, TXRTSCTRL (pins idle high -> BnRTS = 1), CANSTAT, CANCTRL
    assert chip.spi_read(R.BFPCTRL, 4) == bytes([0x00, 0x38, 0x80, 0x87])


def test_so_is_high_impedance_during_instruction_and_address(chip: Mcp2510) -> None:
    chip.spi_select(chip.sched.now_ps)
    assert chip.spi_out_byte() is None
    chip.spi_in_byte(R.INSTR_READ, chip.sched.now_ps + 2 * PS_PER_US)
    assert chip.spi_out_byte() is None
    chip.spi_in_byte(R.CANCTRL, chip.sched.now_ps + 4 * PS_PER_US)
    assert chip.spi_out_byte() == 0x87
    chip.spi_in_byte(0x00, chip.sched.now_ps + 6 * PS_PER_US)
    chip.spi_deselect(chip.sched.now_ps + 7 * PS_PER_US)


def test_write_autoincrement_then_read_back(chip: Mcp2510) -> None:
    chip.spi_write(R.TXB0SIDH, [0x12, 0x34, 0x56, 0x78, 0x08, 1, 2, 3, 4, 5, 6, 7, 8])
    raw = chip.spi_read(R.TXB0SIDH, 13)
    # SIDL bits 4 and 2 and DLC bits 7/5/4 are unimplemented and read 0
    assert raw == bytes([0x12, 0x34 & 0xEB, 0x56, 0x78, 0x08, 1, 2, 3, 4, 5, 6, 7, 8])


def test_write_cs_rise_mid_byte_keeps_earlier_bytes(sched: Scheduler) -> None:
    chip = lax(sched)
    t = sched.now_ps
    chip.spi_select(t)
    for i, b in enumerate([R.INSTR_WRITE, R.TXB1D0, 0xA1, 0xA2]):
        chip.spi_in_byte(b, t + (i + 1) * 2 * PS_PER_US)
    chip.spi_deselect(t + 10 * PS_PER_US, partial_bits=5)  # third data byte aborted
    assert chip.peek(R.TXB1D0) == 0xA1
    assert chip.peek(R.TXB1D0 + 1) == 0xA2
    assert chip.peek(R.TXB1D0 + 2) == 0x00
    assert "that byte is discarded" in chip.violations[-1]


def test_partial_byte_raises_in_strict_mode_after_applying_chip_behaviour(chip: Mcp2510) -> None:
    t = chip.sched.now_ps
    chip.spi_select(t)
    for i, b in enumerate([R.INSTR_WRITE, R.CANINTE, 0x05]):
        chip.spi_in_byte(b, t + (i + 1) * 2 * PS_PER_US)
    with pytest.raises(Mcp2510Error, match="discarded"):
        chip.spi_deselect(t + 8 * PS_PER_US, partial_bits=3)
    assert chip.peek(R.CANINTE) == 0x05


def test_write_aborted_before_first_data_byte_changes_nothing(sched: Scheduler) -> None:
    chip = lax(sched)
    chip.spi_transfer(bytes([R.INSTR_WRITE, R.CANINTE]))
    assert chip.peek(R.CANINTE) == 0
    assert "without a data byte" in chip.violations[-1]


def test_read_address_wrap_is_a_violation(sched: Scheduler) -> None:
    chip = lax(sched)
    out = chip.spi_read(R.RXB1D7 + 2, 3)  # 0x7F (CANCTRL), then wraps to 0x00
    assert out[0] == 0x87
    assert any("wrapped" in v for v in chip.violations)


def test_address_with_a7_set_is_a_violation(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match=r"outside the register map"):
        chip.spi_read(0x8F)


# ------------------------------------------------------------------------------ READ STATUS
def test_read_status_layout_and_repeat(chip: Mcp2510) -> None:
    chip.poke(R.CANINTF, R.CANINTF_RX1IF | R.CANINTF_TX2IF)
    chip.poke(R.TXB0CTRL, R.TXBNCTRL_TXREQ)
    out = chip.spi_transfer(bytes([R.INSTR_READ_STATUS, 0, 0, 0]))
    expected = R.STATUS_RX1IF | R.STATUS_TX2IF | R.STATUS_TXB0_TXREQ
    assert expected == 0x86
    assert out == bytes([0xFF, expected, expected, expected])


def test_read_status_without_data_byte_is_flagged(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="without a data byte"):
        chip.spi_transfer(bytes([R.INSTR_READ_STATUS]))


# ------------------------------------------------------------------------------ BIT MODIFY
def test_bit_modify_on_bit_modifiable_register(chip: Mcp2510) -> None:
    chip.spi_write(R.CANINTE, [0b1010_1010])
    chip.spi_bit_modify(R.CANINTE, 0b0000_1111, 0b0101_0101)
    assert chip.spi_read(R.CANINTE)[0] == 0b1010_0101


def test_bit_modify_on_other_register_forces_mask_ff(sched: Scheduler) -> None:
    chip = lax(sched)
    chip.spi_write(R.TXB0D0, [0xF0])
    chip.spi_bit_modify(R.TXB0D0, 0x0F, 0x05)
    assert chip.peek(R.TXB0D0) == 0x05  # whole byte written, not 0xF5
    assert "forces the mask" in chip.violations[-1]


def test_bit_modify_with_mask_ff_on_other_register_is_fine(chip: Mcp2510) -> None:
    chip.spi_bit_modify(R.TXB0D0, 0xFF, 0x5A)
    assert chip.peek(R.TXB0D0) == 0x5A
    assert chip.violations == []


def test_bit_modify_incomplete_is_aborted(sched: Scheduler) -> None:
    chip = lax(sched)
    chip.spi_transfer(bytes([R.INSTR_BIT_MODIFY, R.CANINTE, 0xFF]))
    assert chip.peek(R.CANINTE) == 0
    assert "aborted" in chip.violations[-1]


def test_extra_byte_after_bit_modify(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="extra byte"):
        chip.spi_transfer(bytes([R.INSTR_BIT_MODIFY, R.CANINTE, 0xFF, 0x01, 0x00]))
    assert chip.peek(R.CANINTE) == 0x01


# ------------------------------------------------------------------------------ RESET / RTS
def test_reset_instruction_restores_defaults_and_starts_ost(chip: Mcp2510) -> None:
    chip.spi_write(R.CANINTE, [0xFF])
    chip.spi_write(R.CNF1, [0x3F])
    t0 = chip.sched.now_ps
    chip.spi_transfer(bytes([R.INSTR_RESET]))
    assert chip.peek(R.CANINTE) == 0 and chip.peek(R.CNF1) == 0
    assert chip.ready_ps > t0
    assert chip.ost_ps == 8 * PS_PER_US  # 128 cycles of 16 MHz
    with pytest.raises(Mcp2510Error, match="oscillator start-up"):
        chip.spi_read(R.CANSTAT)


def test_spi_before_power_up_ost_is_a_violation(sched: Scheduler) -> None:
    chip = Mcp2510(sched)
    with pytest.raises(Mcp2510Error, match="before the oscillator start-up timer"):
        chip.spi_read(R.CANSTAT, t_ps=7 * PS_PER_US)


def test_extra_byte_after_reset(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="extra byte 0x00 after a complete RESET"):
        chip.spi_transfer(bytes([R.INSTR_RESET, 0x00]))


def test_extra_byte_after_rts(chip: Mcp2510) -> None:
    for off in (R.BUF_SIDH_OFFSET, R.BUF_SIDL_OFFSET, R.BUF_DLC_OFFSET):
        chip.poke(R.TXB0CTRL + off, 0)
    with pytest.raises(Mcp2510Error, match="extra byte 0x55 after a complete RTS"):
        chip.spi_transfer(bytes([R.INSTR_RTS_TXB0, 0x55]))
    assert chip.peek(R.TXB0CTRL) & R.TXBNCTRL_TXREQ


def test_rts_without_buffer_is_flagged(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="no buffer"):
        chip.spi_transfer(bytes([R.INSTR_RTS]))


# ------------------------------------------------------------------------------ opcodes
@pytest.mark.parametrize("op", [0x90, 0x92, 0x94, 0x96, 0x40, 0x41, 0x45, 0xB0])
def test_mcp2515_only_instructions_are_rejected(chip: Mcp2510, op: int) -> None:
    with pytest.raises(Mcp2510Error, match="MCP2515-only instruction") as info:
        chip.spi_transfer(bytes([op, 0, 0]))
    assert "not supported by the MCP2510" in str(info.value)
    assert f"0x{op:02X}" in str(info.value)
    assert info.value.t_ps is not None


@pytest.mark.parametrize("op", [0x00, 0x01, 0x04, 0x46, 0x88, 0x91, 0xA1, 0xFF])
def test_undefined_opcodes_are_rejected(chip: Mcp2510, op: int) -> None:
    with pytest.raises(Mcp2510Error, match="undefined opcode"):
        chip.spi_transfer(bytes([op]))


def test_non_strict_mode_records_and_ignores_the_transaction(sched: Scheduler) -> None:
    chip = lax(sched)
    out = chip.spi_transfer(bytes([0x90, 0x00, 0x00]))
    assert out == b"\xff\xff\xff"  # SO stays high impedance
    assert len(chip.violations) == 1 and "READ RX BUFFER" in chip.violations[0]
    # the chip still works afterwards
    assert chip.spi_read(R.CANSTAT)[0] == 0x80


def test_message_names_time_instruction_and_address(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error) as info:
        chip.spi_write(R.TEC, [1])
    text = str(info.value)
    assert "t=" in text and " us" in text
    assert "WRITE" in text and "@0x1C (TEC)" in text
    assert info.value.address == R.TEC and info.value.instruction == "WRITE"


# ------------------------------------------------------------------------------ timing
def test_bytes_faster_than_5mhz_are_flagged(chip: Mcp2510) -> None:
    with pytest.raises(Mcp2510Error, match="SCK faster than 5 MHz"):
        chip.spi_transfer(bytes([R.INSTR_READ, R.CANSTAT, 0]), sck_hz=8_000_000)


def test_byte_timing_check_can_be_disabled(sched: Scheduler) -> None:
    chip = new_chip(sched, check_byte_timing=False)
    assert chip.spi_transfer(bytes([R.INSTR_READ, R.CANSTAT, 0]), sck_hz=10_000_000)[2] == 0x80


def test_spi_transfer_advances_time(chip: Mcp2510) -> None:
    t0 = chip.sched.now_ps
    chip.spi_transfer(bytes([R.INSTR_READ, R.CANSTAT, 0]))
    # 3 bytes at 5 MHz = 4.8 us plus CS setup/hold
    assert 4.8 * PS_PER_US < chip.sched.now_ps - t0 < 5.5 * PS_PER_US
