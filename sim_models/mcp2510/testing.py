"""Host-side helpers that drive an :class:`~sim_models.mcp2510.chip.Mcp2510` through its SPI
byte interface, the way a driver would (used by the unit tests and handy in benches).

Every helper goes through :meth:`Mcp2510.spi_transfer`, so the model's strictness applies.
"""

from __future__ import annotations

import can

from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.chip import Mcp2510
from sim_models.mcp2510.filters import decode_id_regs, encode_id_regs
from sim_models.sim_time import Scheduler

#: CNF1, CNF2, CNF3 for a 16 MHz oscillator (BTLMODE = 1, SJW = 1 TQ)
CNF_16MHZ: dict[int, tuple[int, int, int]] = {
    1_000_000: (0x00, 0x90, 0x02),  # 8 TQ: Prop 1, PS1 3, PS2 3 -> sample point 62.5 %
    500_000: (0x00, 0xBA, 0x03),  # 16 TQ: Prop 3, PS1 8, PS2 4 -> 75 %
    250_000: (0x01, 0xBA, 0x03),
    125_000: (0x03, 0xBA, 0x03),
}


def std(can_id: int, data: bytes = b"") -> can.Message:
    """A standard-ID data frame carrying ``data``."""
    return can.Message(arbitration_id=can_id, is_extended_id=False, dlc=len(data), data=data)


def new_chip(sched: Scheduler, **kwargs: object) -> Mcp2510:
    """A chip powered up now, with the scheduler run past the oscillator start-up time."""
    chip = Mcp2510(sched, **kwargs)  # type: ignore[arg-type]
    sched.run_until(max(sched.now_ps, chip.ready_ps))
    return chip


def set_mode(chip: Mcp2510, opmode: int) -> None:
    """Request a mode with BIT MODIFY on CANCTRL.REQOP (does not wait for it)."""
    chip.spi_bit_modify(R.CANCTRL, R.CANCTRL_REQOP_MASK, opmode << R.CANCTRL_REQOP_SHIFT)


def configure(
    chip: Mcp2510,
    bitrate: int = 500_000,
    *,
    opmode: int | None = R.OPMODE_NORMAL,
    rxb0ctrl: int = R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT,
    rxb1ctrl: int = R.RXM_ANY << R.RXBNCTRL_RXM_SHIFT,
    caninte: int = 0,
    bfpctrl: int = 0,
) -> None:
    """Typical initialisation (configuration mode is assumed): CNF, RX modes, interrupts,
    then the requested operation mode."""
    if chip.osc_hz != 16_000_000:
        raise ValueError("configure() knows CNF values for a 16 MHz oscillator only")
    cnf1, cnf2, cnf3 = CNF_16MHZ[bitrate]
    chip.spi_write(R.CNF3, [cnf3, cnf2, cnf1, caninte])
    chip.spi_write(R.BFPCTRL, [bfpctrl])
    chip.spi_write(R.RXB0CTRL, [rxb0ctrl])
    chip.spi_write(R.RXB1CTRL, [rxb1ctrl])
    if opmode is not None:
        set_mode(chip, opmode)


def write_id_group(chip: Mcp2510, base: int, can_id: int, extended: bool) -> None:
    """Write a filter or mask register group (SIDH..EID0) with an identifier."""
    chip.spi_write(base, list(encode_id_regs(can_id, extended)))


def load_tx(chip: Mcp2510, n: int, msg: can.Message, txp: int | None = None) -> None:
    """Write TXBn's SIDH..D7 from a message (and TXBnCTRL.TXP if given)."""
    base = R.TXB0CTRL + R.TXB_STRIDE * n
    sidh, sidl, eid8, eid0 = encode_id_regs(msg.arbitration_id, msg.is_extended_id)
    dlc = msg.dlc | (R.TXBNDLC_RTR if msg.is_remote_frame else 0)
    data = b"" if msg.is_remote_frame else bytes(msg.data[: min(msg.dlc, 8)])
    if txp is not None:
        chip.spi_write(base, [txp])
    chip.spi_write(base + R.BUF_SIDH_OFFSET, [sidh, sidl, eid8, eid0, dlc, *data])


def rts(chip: Mcp2510, *buffers: int) -> None:
    """RTS instruction for the given buffers."""
    op = R.INSTR_RTS
    for n in buffers:
        op |= 1 << n
    chip.spi_transfer(bytes([op]))


def read_rx(chip: Mcp2510, n: int) -> tuple[int, can.Message]:
    """READ RXBnCTRL..RXBnD7; returns (RXBnCTRL, decoded message)."""
    raw = chip.spi_read(R.RXB0CTRL + 0x10 * n, R.BUF_SIZE)
    ident = decode_id_regs(raw[1], raw[2], raw[3], raw[4])
    ext = bool(raw[2] & R.RXBNSIDL_IDE)
    dlc = raw[5] & 0x0F
    remote = bool(raw[5] & R.RXBNDLC_RTR) if ext else bool(raw[2] & R.RXBNSIDL_SRR)
    data = b"" if remote else bytes(raw[6 : 6 + min(dlc, 8)])
    msg = can.Message(
        arbitration_id=ident.id29 if ext else ident.sid,
        is_extended_id=ext,
        is_remote_frame=remote,
        dlc=dlc,
        data=data,
    )
    return raw[0], msg


def same_frame(a: can.Message, b: can.Message) -> bool:
    """Identifier, type, DLC and data equal."""
    return (
        a.arbitration_id == b.arbitration_id
        and bool(a.is_extended_id) == bool(b.is_extended_id)
        and bool(a.is_remote_frame) == bool(b.is_remote_frame)
        and a.dlc == b.dlc
        and (a.is_remote_frame or bytes(a.data) == bytes(b.data))
    )
