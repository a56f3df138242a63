"""Behavioural model of the Microchip MCP2510 stand-alone CAN controller (DS21291).

The model is stricter than the chip: where the host breaks a data-sheet rule, or where the
chip would silently do something the host almost certainly did not intend, it records a
violation in :attr:`Mcp2510.violations` and (with ``strict=True``, the default) raises
:class:`Mcp2510Error`. The chip's own behaviour is applied first, so with ``strict=False`` the
model continues exactly as the chip would. See ``docs/mcp2510_model.md`` for every rule, its
data-sheet section and the decisions taken where the data sheet is silent.

Interfaces:

* SPI at byte level (:meth:`Mcp2510.spi_select`, :meth:`~Mcp2510.spi_out_byte`,
  :meth:`~Mcp2510.spi_in_byte`, :meth:`~Mcp2510.spi_deselect`), driven by
  :class:`sim_models.spi_slave.SpiPinSlave` in cocotb benches, or by
  :meth:`~Mcp2510.spi_transfer` in unit tests;
* the CAN side as a :class:`sim_models.can_bus.CanNode`;
* pins INT, RX0BF, RX1BF (outputs), TX0RTS..TX2RTS and RESET (inputs).

All times are integer picoseconds on the shared :class:`~sim_models.sim_time.Scheduler`.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import can

from sim_models.can_bus import BUS_OFF, CanNode, NodeClock, frame_length_bits
from sim_models.mcp2510 import regs as R
from sim_models.mcp2510.bittiming import BitTiming, decode_cnf
from sim_models.mcp2510.filters import buffer_accepts, decode_id_regs, encode_id_regs
from sim_models.sim_time import PS_PER_S, EventHandle, Scheduler

__all__ = ["Mcp2510", "Mcp2510Error", "MODE_NAMES"]

MODE_NAMES: dict[int, str] = {
    R.OPMODE_NORMAL: "normal",
    R.OPMODE_SLEEP: "sleep",
    R.OPMODE_LOOPBACK: "loopback",
    R.OPMODE_LISTEN_ONLY: "listen_only",
    R.OPMODE_CONFIG: "configuration",
}

_INSTR_NAMES = {
    R.INSTR_RESET: "RESET",
    R.INSTR_READ: "READ",
    R.INSTR_WRITE: "WRITE",
    R.INSTR_READ_STATUS: "READ STATUS",
    R.INSTR_BIT_MODIFY: "BIT MODIFY",
}

#: Registers on which BIT MODIFY works as a masked write (DS21291 register map, shaded cells).
#: On every other register the chip forces the mask to 0xFF.
BIT_MODIFIABLE: frozenset[int] = frozenset(
    {
        R.BFPCTRL,
        R.TXRTSCTRL,
        R.CNF3,
        R.CNF2,
        R.CNF1,
        R.CANINTE,
        R.CANINTF,
        R.EFLG,
        R.TXB0CTRL,
        R.TXB1CTRL,
        R.TXB2CTRL,
        R.RXB0CTRL,
        R.RXB1CTRL,
    }
    | {row * 0x10 + 0x0E for row in range(8)}
    | {row * 0x10 + 0x0F for row in range(8)}
)

_FILTER_BASES = (R.RXF0SIDH, R.RXF1SIDH, R.RXF2SIDH, R.RXF3SIDH, R.RXF4SIDH, R.RXF5SIDH)
_MASK_BASES = (R.RXM0SIDH, R.RXM1SIDH)
#: Filter and mask addresses: writable in configuration mode only, read as 0 elsewhere.
FILTER_MASK_ADDRS: frozenset[int] = frozenset(
    b + i for b in _FILTER_BASES + _MASK_BASES for i in range(4)
)
#: Registers writable in configuration mode only (DS21291 section 10.1).
CONFIG_ONLY_ADDRS: frozenset[int] = FILTER_MASK_ADDRS | {R.CNF1, R.CNF2, R.CNF3, R.TXRTSCTRL}

_TXB_BASES = (R.TXB0CTRL, R.TXB1CTRL, R.TXB2CTRL)
_RXB_BASES = (R.RXB0CTRL, R.RXB1CTRL)
_TXIF = (R.CANINTF_TX0IF, R.CANINTF_TX1IF, R.CANINTF_TX2IF)
_RXIF = (R.CANINTF_RX0IF, R.CANINTF_RX1IF)
_RXOVR = (R.EFLG_RX0OVR, R.EFLG_RX1OVR)
_SCK_PERIOD_MIN_PS = -(-PS_PER_S // R.SPI_SCK_MAX_HZ)  # 200 ns at 5 MHz

# SPI transaction states
_IDLE = "idle"
_INSTR = "instruction"
_READ_ADDR = "READ address"
_READ_DATA = "READ data"
_WRITE_ADDR = "WRITE address"
_WRITE_DATA = "WRITE data"
_STATUS = "READ STATUS"
_BM_ADDR = "BIT MODIFY address"
_BM_MASK = "BIT MODIFY mask"
_BM_DATA = "BIT MODIFY data"
_DONE = "done"
_IGNORE = "ignore"


class Mcp2510Error(Exception):
    """A data-sheet rule was broken by the host (or the model was used wrongly).

    ``t_ps``, ``instruction`` and ``address`` locate the violation; they are also in the text.
    """

    def __init__(
        self,
        message: str,
        *,
        t_ps: int | None = None,
        instruction: str | None = None,
        address: int | None = None,
    ) -> None:
        super().__init__(message)
        self.t_ps = t_ps
        self.instruction = instruction
        self.address = address


def _fmt_t(t_ps: int) -> str:
    return f"{t_ps / 1e6:.4f} us"


class Mcp2510(CanNode):
    """MCP2510 model: register file, SPI instruction decoder, CAN node, pins.

    Parameters:
        sched: the shared scheduler; construction is the power-on reset at ``sched.now_ps``
            (the oscillator start-up timer runs from there).
        osc_hz: oscillator frequency on OSC1 (F_OSC).
        name: node name on the CAN bus.
        strict: raise :class:`Mcp2510Error` on the first violation (else only record it).
        clock: local oscillator offset for the CAN bus model (ppm, phase).
        check_byte_timing: check at byte level that SPI bytes do not arrive faster than the
            5 MHz SCK limit allows (the pin-level checker in ``spi_slave.py`` checks the
            individual SCK edges; keep this on when driving the byte API directly).
    """

    def __init__(
        self,
        sched: Scheduler,
        *,
        osc_hz: int = 16_000_000,
        name: str = "mcp2510",
        strict: bool = True,
        clock: NodeClock | None = None,
        check_byte_timing: bool = True,
    ) -> None:
        super().__init__(name, clock)
        if not 0 < osc_hz <= R.OSC_MAX_HZ:
            raise ValueError(f"osc_hz {osc_hz} outside 1 Hz..{R.OSC_MAX_HZ} Hz")
        self.sched = sched
        self.osc_hz = int(osc_hz)
        self.strict = strict
        self.check_byte_timing = check_byte_timing
        #: every violation, in order (also those that raised)
        self.violations: list[str] = []
        #: frames lost because their receive buffer was still full (EFLG.RXnOVR events)
        self.overflow_count = 0
        #: ``(t_ps, buffer, msg)`` of every lost frame
        self.overflows: list[tuple[int, int, can.Message]] = []
        #: ``(t_ps, buffer, msg)`` of every frame stored in a receive buffer
        self.rx_log: list[tuple[int, int, can.Message]] = []
        #: ``(t_ps, buffer, msg)`` of every frame transmitted successfully
        self.tx_log: list[tuple[int, int, can.Message]] = []
        #: called whenever int_n / rx0bf_n / rx1bf_n changed
        self.on_pins_changed: Callable[[], None] | None = None
        self._regs = bytearray(128)
        self._txrts_pins = [1, 1, 1]
        self._opmode = R.OPMODE_CONFIG
        self._ost_until_ps = 0
        self._bit_timing: BitTiming | None = None
        self._mode_pending: int | None = None
        self._mode_event: EventHandle | None = None
        self._loopback_event: EventHandle | None = None
        self._tx_msgs: list[can.Message | None] = [None, None, None]
        self._outstanding: dict[int, tuple[int, can.Message]] = {}
        self._last_offered: tuple[int, can.Message] | None = None
        self._inflight: tuple[int, can.Message] | None = None
        self._abat_abort: set[int] = set()
        self._tx_written: list[set[int]] = [set(), set(), set()]
        # buffers requested in configuration mode: their contents are checked when the chip
        # can first transmit them (normal or loopback mode), not at the request
        self._tx_check_deferred: set[int] = set()
        self._intf_unseen = 0
        self._pins = (1, 1, 1)
        # SPI
        self._cs_active = False
        self._spi_state = _IDLE
        self._spi_instr = ""
        self._spi_opcode = 0
        self._spi_addr = 0
        self._spi_count = 0
        self._spi_data_count = 0
        self._bm_mask = 0
        self._so_latch: dict[int, int | None] = {}
        self._t_select: int | None = None
        self._t_last_byte: int | None = None
        #: (t_ps, cause) of the last reset
        self.last_reset: tuple[int, str] = (sched.now_ps, "power-on reset")
        self._reset(sched.now_ps, "power-on reset")

    # ======================================================================== properties
    @property
    def mode(self) -> str:
        """Current operation mode (CANSTAT.OPMOD) as a name."""
        return MODE_NAMES[self._opmode]

    @property
    def opmode(self) -> int:
        """Current CANSTAT.OPMOD value."""
        return self._opmode

    @property
    def bit_timing(self) -> BitTiming:
        """Bit timing decoded from the current CNF1..CNF3 (valid or not)."""
        r = self._regs
        return decode_cnf(r[R.CNF1], r[R.CNF2], r[R.CNF3], self.osc_hz)

    @property
    def configured_bitrate_bps(self) -> int:
        """Bit rate the CNF registers select, whatever the mode."""
        return self.bit_timing.bitrate_bps

    @property
    def bitrate_bps(self) -> int | None:  # type: ignore[override]
        """Bit rate on the bus; None in configuration, sleep and loopback mode."""
        if self._opmode in (R.OPMODE_NORMAL, R.OPMODE_LISTEN_ONLY):
            bt = self._bit_timing or self.bit_timing
            return bt.bitrate_bps
        return None

    @property
    def listen_only(self) -> bool:  # type: ignore[override]
        return self._opmode == R.OPMODE_LISTEN_ONLY

    @property
    def sample_point(self) -> float:
        """Sample point (fraction of the bit time) of the current CNF setting."""
        return self.bit_timing.sample_point

    @property
    def clkout_hz(self) -> float | None:
        """CLKOUT frequency (CANCTRL.CLKEN/CLKPRE), None when disabled."""
        ctrl = self._regs[R.CANCTRL]
        if not ctrl & R.CANCTRL_CLKEN:
            return None
        return self.osc_hz / (1 << (ctrl & R.CANCTRL_CLKPRE_MASK))

    @property
    def ost_ps(self) -> int:
        """Oscillator start-up time: 128 OSC1 cycles (DS21291 section 8)."""
        return -(-R.OST_OSC_CYCLES * PS_PER_S // self.osc_hz)

    @property
    def ready_ps(self) -> int:
        """Time from which SPI access is allowed (end of the oscillator start-up timer)."""
        return self._ost_until_ps

    @property
    def int_n(self) -> int:
        """INT pin (active low): 0 while any enabled interrupt flag is set."""
        return 0 if self._regs[R.CANINTE] & self._regs[R.CANINTF] else 1

    @property
    def rx0bf_n(self) -> int:
        return self._rxbf_level(0)

    @property
    def rx1bf_n(self) -> int:
        return self._rxbf_level(1)

    def _rxbf_level(self, n: int) -> int:
        bfp = self._regs[R.BFPCTRL]
        if not bfp & (R.BFPCTRL_B0BFE << n):
            return 1  # high impedance, modelled as pulled up
        if bfp & (R.BFPCTRL_B0BFM << n):
            return 0 if self._regs[R.CANINTF] & _RXIF[n] else 1
        return 1 if bfp & (R.BFPCTRL_B0BFS << n) else 0

    # ======================================================================== violations
    def _violation(
        self, t_ps: int, text: str, instr: str | None = None, addr: int | None = None
    ) -> None:
        where = ""
        if instr:
            where += f", {instr}"
        if addr is not None:
            where += f" @0x{addr:02X} ({R.reg_name(addr & 0x7F)})"
        msg = f"MCP2510 {self.name!r} at t={_fmt_t(t_ps)}{where}: {text}"
        self.violations.append(msg)
        if self.strict:
            raise Mcp2510Error(msg, t_ps=t_ps, instruction=instr, address=addr)

    # ======================================================================== backdoor
    def peek(self, addr: int) -> int:
        """Register value without side effects or mode checks (filters/masks read raw)."""
        a = addr & 0x7F
        if a in FILTER_MASK_ADDRS:
            return self._regs[a]
        return self._read_reg(a)

    def poke(self, addr: int, value: int) -> None:
        """Store a raw register value: no side effects (no TX start, no mode change) and no
        checks. TEC/REC set the error counters; CANSTAT cannot be poked."""
        a = addr & 0x7F
        value &= 0xFF
        low = a & 0x0F
        if low == 0x0E:
            raise ValueError("CANSTAT is computed from the mode and the interrupt flags")
        if a == R.TEC:
            self.tec = value
        elif a == R.REC:
            self.rec = value
        else:
            self._regs[R.CANCTRL if low == 0x0F else a] = value
        if R.TXB0CTRL <= a <= R.TXB2D7 and low not in (0x0E, 0x0F):
            n, off = (a - R.TXB0CTRL) >> 4, a & 0x0F
            if off != R.BUF_CTRL_OFFSET:
                self._tx_written[n].add(off)
        self._update_pins()

    # ======================================================================== reset
    def _reset(self, t_ps: int, cause: str) -> None:
        for ev in (self._mode_event, self._loopback_event):
            if ev is not None:
                ev.cancel()
        self._mode_event = None
        self._loopback_event = None
        self._regs[:] = bytes(128)
        self._regs[R.CANCTRL] = R.CANCTRL_RESET
        self._opmode = R.OPMODE_CONFIG
        self._bit_timing = None
        self._mode_pending = None
        self._tx_msgs = [None, None, None]
        self._outstanding.clear()
        self._last_offered = None
        self._inflight = None
        self._abat_abort.clear()
        self._tx_written = [set(), set(), set()]
        self._tx_check_deferred.clear()
        self._intf_unseen = 0
        self.reset_fault_confinement()
        self._ost_until_ps = t_ps + self.ost_ps
        self.last_reset = (t_ps, cause)
        self._update_pins()

    def reset_pin(self, t_ps: int) -> None:
        """Pulse on the RESET pin: same as the RESET instruction (DS21291 section 9). An SPI
        transaction in progress is abandoned (its remaining bytes are ignored)."""
        if self._cs_active:
            self._spi_state = _IGNORE
        self._reset(t_ps, "RESET pin")

    # ======================================================================== registers
    def _canstat(self) -> int:
        return (self._opmode << R.CANSTAT_OPMOD_SHIFT) | (self._icod() << R.CANSTAT_ICOD_SHIFT)

    def _icod(self) -> int:
        pending = self._regs[R.CANINTE] & self._regs[R.CANINTF]
        for flag, code in (
            (R.CANINTF_ERRIF, R.ICOD_ERROR),
            (R.CANINTF_WAKIF, R.ICOD_WAKE),
            (R.CANINTF_TX0IF, R.ICOD_TXB0),
            (R.CANINTF_TX1IF, R.ICOD_TXB1),
            (R.CANINTF_TX2IF, R.ICOD_TXB2),
            (R.CANINTF_RX0IF, R.ICOD_RXB0),
            (R.CANINTF_RX1IF, R.ICOD_RXB1),
        ):
            if pending & flag:
                return code
        return R.ICOD_NONE

    def _read_reg(self, a: int) -> int:
        """Register value as the host reads it (filters/masks: 0 outside configuration)."""
        a &= 0x7F
        low = a & 0x0F
        if low == 0x0E:
            return self._canstat()
        if low == 0x0F:
            return self._regs[R.CANCTRL]
        if a == R.TEC:
            return min(self.tec, 255)
        if a == R.REC:
            return min(self.rec, 255)
        if a == R.TXRTSCTRL:
            v = self._regs[R.TXRTSCTRL] & R.TXRTSCTRL_WRITE_MASK
            for n in range(3):
                if not v & (R.TXRTSCTRL_B0RTSM << n) and self._txrts_pins[n]:
                    v |= R.TXRTSCTRL_B0RTS << n
            return v
        if a in FILTER_MASK_ADDRS and self._opmode != R.OPMODE_CONFIG:
            return 0
        return self._regs[a]

    def _read_status(self) -> int:
        f = self._regs[R.CANINTF]
        v = f & (R.CANINTF_RX0IF | R.CANINTF_RX1IF)
        for n, (req_bit, if_bit) in enumerate(
            (
                (R.STATUS_TXB0_TXREQ, R.STATUS_TX0IF),
                (R.STATUS_TXB1_TXREQ, R.STATUS_TX1IF),
                (R.STATUS_TXB2_TXREQ, R.STATUS_TX2IF),
            )
        ):
            if self._regs[_TXB_BASES[n]] & R.TXBNCTRL_TXREQ:
                v |= req_bit
            if f & _TXIF[n]:
                v |= if_bit
        return v

    def read_status(self) -> int:
        """The byte READ STATUS returns now (no side effects)."""
        return self._read_status()

    def _set_intf(self, bits: int) -> None:
        """The chip sets interrupt flags (the host has not seen them yet)."""
        self._regs[R.CANINTF] |= bits
        self._intf_unseen |= bits
        self._update_pins()

    def _update_pins(self) -> None:
        pins = (self.int_n, self.rx0bf_n, self.rx1bf_n)
        if pins != self._pins:
            self._pins = pins
            if self.on_pins_changed is not None:
                self.on_pins_changed()

    def _write_reg(self, a: int, value: int, t: int, instr: str) -> None:
        """Host write of one register (WRITE, or BIT MODIFY after masking)."""
        a &= 0x7F
        value &= 0xFF
        low = a & 0x0F
        if low == 0x0E or a in (R.TEC, R.REC):
            self._violation(t, "write to a read-only register is ignored", instr, a)
            return
        if low == 0x0F:
            self._write_canctrl(value, t, instr, a)
            return
        if a in CONFIG_ONLY_ADDRS and self._opmode != R.OPMODE_CONFIG:
            self._violation(
                t,
                f"register is writable in configuration mode only (mode is {self.mode}); "
                "write ignored (DS21291 section 10.1)",
                instr,
                a,
            )
            return
        if a in FILTER_MASK_ADDRS:
            if a % 4 == R.ID_SIDL_OFFSET:  # every filter/mask group is 4-byte aligned
                value &= R.RXMNSIDL_WRITE_MASK if a >= R.RXM0SIDH else R.RXFNSIDL_WRITE_MASK
            self._regs[a] = value
        elif a == R.BFPCTRL:
            self._regs[a] = value & R.BFPCTRL_WRITE_MASK
        elif a == R.TXRTSCTRL:
            self._regs[a] = value & R.TXRTSCTRL_WRITE_MASK
        elif a in (R.CNF1, R.CNF2):
            self._regs[a] = value
        elif a == R.CNF3:
            self._regs[a] = value & R.CNF3_WRITE_MASK
            if value & R.CNF3_SOF_MCP2515:
                self._violation(
                    t,
                    "CNF3.SOF (bit 7) is an MCP2515-only feature; unimplemented on the "
                    "MCP2510 (reads 0)",
                    instr,
                    a,
                )
        elif a == R.CANINTE:
            self._regs[a] = value
        elif a == R.CANINTF:
            self._write_canintf(value, t, instr)
        elif a == R.EFLG:
            # RXnOVR can be cleared by the host, never set; the rest is read-only
            self._regs[a] &= ~R.EFLG_OVR_MASK | (value & R.EFLG_OVR_MASK)
        elif R.TXB0CTRL <= a <= R.TXB2D7:
            self._write_txb(a, value, t, instr)
        elif low == 0:  # RXB0CTRL / RXB1CTRL
            n = (a - R.RXB0CTRL) >> 4
            if n == 0:
                keep = self._regs[a] & (R.RXBNCTRL_RXRTR | R.RXB0CTRL_FILHIT0)
                new = keep | (value & R.RXB0CTRL_WRITE_MASK)
                if new & R.RXB0CTRL_BUKT:
                    new |= R.RXB0CTRL_BUKT1
                self._regs[a] = new
            else:
                keep = self._regs[a] & (R.RXBNCTRL_RXRTR | R.RXB1CTRL_FILHIT_MASK)
                self._regs[a] = keep | (value & R.RXB1CTRL_WRITE_MASK)
        else:  # receive buffer contents
            self._violation(t, "receive buffers are read-only; write ignored", instr, a)
            return
        self._update_pins()

    def _write_canctrl(self, value: int, t: int, instr: str, a: int) -> None:
        old = self._regs[R.CANCTRL]
        new = value & R.CANCTRL_WRITE_MASK
        self._regs[R.CANCTRL] = new
        problems: list[str] = []
        if value & R.CANCTRL_OSM_MCP2515:
            problems.append(
                "CANCTRL.OSM (bit 3, one-shot mode) exists on the MCP2515 only; on the MCP2510 "
                "the bit is unimplemented and frames are retransmitted until they succeed"
            )
        if new & R.CANCTRL_ABAT and not old & R.CANCTRL_ABAT:
            self._abort_all(t)
        elif old & R.CANCTRL_ABAT and not new & R.CANCTRL_ABAT:
            self._kick_tx()
        reqop = (new & R.CANCTRL_REQOP_MASK) >> R.CANCTRL_REQOP_SHIFT
        if reqop > R.OPMODE_CONFIG:
            problems.append(f"REQOP = {reqop:03b} is not a valid mode request (ignored)")
        else:
            problems += self._request_mode(reqop, t)
        for p in problems:
            self._violation(t, p, instr, a)

    def _write_canintf(self, value: int, t: int, instr: str) -> None:
        old = self._regs[R.CANINTF]
        cleared = old & ~value
        lost = cleared & self._intf_unseen
        self._regs[R.CANINTF] = value
        self._intf_unseen &= value
        self._update_pins()
        if (
            value & R.CANINTF_WAKIF
            and not old & R.CANINTF_WAKIF
            and self._opmode == R.OPMODE_SLEEP
            and self._regs[R.CANINTE] & R.CANINTE_WAKIE
        ):
            self._start_wakeup(t)
        if lost and instr == "WRITE":
            names = [n for n, b in _INTF_NAMES if lost & b]
            self._violation(
                t,
                f"WRITE clears interrupt flag(s) {', '.join(names)} that the chip set and the "
                "host never read: an interrupt is lost. Clear flags with BIT MODIFY "
                "(DS21291 section 7)",
                instr,
                R.CANINTF,
            )

    # ======================================================================== TX buffers
    def _write_txb(self, a: int, value: int, t: int, instr: str) -> None:
        n, off = (a - R.TXB0CTRL) >> 4, a & 0x0F
        ctrl_addr = _TXB_BASES[n]
        if off == R.BUF_CTRL_OFFSET:
            self._write_txbctrl(n, value, t, instr)
            return
        if off == R.BUF_SIDL_OFFSET:
            value &= R.TXBNSIDL_WRITE_MASK
        elif off == R.BUF_DLC_OFFSET:
            value &= R.TXBNDLC_WRITE_MASK
        pending = bool(self._regs[ctrl_addr] & R.TXBNCTRL_TXREQ)
        self._regs[a] = value
        self._tx_written[n].add(off)
        if pending:
            # the chip sends whatever the registers hold when the frame starts
            self._tx_msgs[n] = self._build_tx_msg(n)
            if self._opmode == R.OPMODE_CONFIG:
                # no frame can be on its way in configuration mode: the contents are checked
                # when the chip can first transmit them
                self._tx_check_deferred.add(n)
                return
            self._violation(
                t,
                f"TXB{n} is written while TXB{n}CTRL.TXREQ is set; the buffer must not be "
                "modified while a transmission is pending (DS21291 section 3)",
                instr,
                a,
            )

    def _write_txbctrl(self, n: int, value: int, t: int, instr: str) -> None:
        ctrl_addr = _TXB_BASES[n]
        old = self._regs[ctrl_addr]
        txp = value & R.TXBNCTRL_TXP_MASK
        self._regs[ctrl_addr] = (old & ~R.TXBNCTRL_TXP_MASK) | txp
        if value & R.TXBNCTRL_TXREQ and not old & R.TXBNCTRL_TXREQ:
            self._tx_request(n, t, f"{instr} TXB{n}CTRL.TXREQ")
        elif old & R.TXBNCTRL_TXREQ and not value & R.TXBNCTRL_TXREQ:
            # abort request by the host: only a frame that has not started can be aborted;
            # ABTF is set only by ABAT aborts (DS21291 section 3.4 "Aborting transmission")
            self._regs[ctrl_addr] &= ~R.TXBNCTRL_TXREQ

    def _tx_problems(self, n: int) -> list[str]:
        base = _TXB_BASES[n]
        written = self._tx_written[n]
        sidl = self._regs[base + R.BUF_SIDL_OFFSET]
        dlc_reg = self._regs[base + R.BUF_DLC_OFFSET]
        needed = [R.BUF_SIDH_OFFSET, R.BUF_SIDL_OFFSET, R.BUF_DLC_OFFSET]
        if sidl & R.TXBNSIDL_EXIDE:
            needed += [R.BUF_EID8_OFFSET, R.BUF_EID0_OFFSET]
        dlc = dlc_reg & R.TXBNDLC_DLC_MASK
        if not dlc_reg & R.TXBNDLC_RTR:
            needed += [R.BUF_D0_OFFSET + i for i in range(min(dlc, 8))]
        missing = [R.reg_name(base + off) for off in needed if off not in written]
        out: list[str] = []
        if missing:
            out.append(
                f"TXB{n} transmission requested but {', '.join(missing)} not written since "
                "reset (the chip would send undefined contents)"
            )
        if dlc > 8:
            out.append(
                f"TXB{n}DLC = {dlc}: DLC > 8 sends 8 data bytes with a non-standard DLC code"
            )
        return out

    def _tx_request(self, n: int, t: int, source: str) -> None:
        ctrl_addr = _TXB_BASES[n]
        if self._regs[ctrl_addr] & R.TXBNCTRL_TXREQ:
            return
        if self._opmode == R.OPMODE_CONFIG:
            # configuration mode does not transmit: a RESET (instruction or pin) before the
            # chip leaves it clears the request, so undefined contents matter only if the
            # request is still pending when the chip enters a transmitting mode
            problems = []
            self._tx_check_deferred.add(n)
        else:
            problems = self._tx_problems(n)
        ctrl = self._regs[ctrl_addr]
        ctrl &= ~(R.TXBNCTRL_ABTF | R.TXBNCTRL_MLOA | R.TXBNCTRL_TXERR)
        self._regs[ctrl_addr] = ctrl | R.TXBNCTRL_TXREQ
        self._abat_abort.discard(n)
        self._tx_msgs[n] = self._build_tx_msg(n)
        if self._opmode in (R.OPMODE_LISTEN_ONLY, R.OPMODE_SLEEP):
            problems.append(
                f"transmission requested in {self.mode} mode: the chip cannot transmit, the "
                "request stays pending (and blocks later mode changes)"
            )
        if self._regs[R.CANCTRL] & R.CANCTRL_ABAT:
            problems.append(
                "transmission requested while CANCTRL.ABAT is set: nothing is sent until ABAT "
                "is cleared"
            )
        self._kick_tx()
        for p in problems:
            self._violation(t, p, source, ctrl_addr)

    def _build_tx_msg(self, n: int) -> can.Message:
        base = _TXB_BASES[n]
        r = self._regs
        ident = decode_id_regs(
            r[base + R.BUF_SIDH_OFFSET],
            r[base + R.BUF_SIDL_OFFSET],
            r[base + R.BUF_EID8_OFFSET],
            r[base + R.BUF_EID0_OFFSET],
        )
        dlc_reg = r[base + R.BUF_DLC_OFFSET]
        dlc = dlc_reg & R.TXBNDLC_DLC_MASK
        remote = bool(dlc_reg & R.TXBNDLC_RTR)
        n_data = 0 if remote else min(dlc, 8)
        data = bytes(r[base + R.BUF_D0_OFFSET : base + R.BUF_D0_OFFSET + n_data])
        return can.Message(
            arbitration_id=ident.id29 if ident.exide else ident.sid,
            is_extended_id=ident.exide,
            is_remote_frame=remote,
            dlc=dlc,
            data=data,
        )

    def _highest_pending(self) -> int | None:
        best: tuple[int, int] | None = None
        for n in range(3):
            ctrl = self._regs[_TXB_BASES[n]]
            if ctrl & R.TXBNCTRL_TXREQ:
                key = (ctrl & R.TXBNCTRL_TXP_MASK, n)  # equal TXP: higher buffer number wins
                if best is None or key > best:
                    best = key
        return None if best is None else best[1]

    def _kick_tx(self) -> None:
        if self._highest_pending() is None:
            return
        if self._opmode == R.OPMODE_NORMAL and self.bus is not None:
            self.bus.request_tx()
        elif self._opmode == R.OPMODE_LOOPBACK:
            self._schedule_loopback()

    def _abort_all(self, t: int) -> None:
        """CANCTRL.ABAT rising edge: abort every pending buffer that has not started."""
        inflight_n = self._inflight[0] if self._inflight is not None else None
        for n in range(3):
            ctrl_addr = _TXB_BASES[n]
            if not self._regs[ctrl_addr] & R.TXBNCTRL_TXREQ:
                continue
            if n == inflight_n:
                self._abat_abort.add(n)  # decided when the frame ends
            else:
                self._regs[ctrl_addr] = (self._regs[ctrl_addr] & ~R.TXBNCTRL_TXREQ) | (
                    R.TXBNCTRL_ABTF
                )

    def _lookup(self, msg: can.Message) -> int | None:
        entry = self._outstanding.get(id(msg))
        if entry is None or entry[1] is not msg:
            return None
        return entry[0]

    def _tx_success(self, n: int, msg: can.Message, t: int) -> None:
        self._outstanding.pop(id(msg), None)
        self._inflight = None
        self._abat_abort.discard(n)
        ctrl_addr = _TXB_BASES[n]
        if self._tx_msgs[n] is msg:
            self._regs[ctrl_addr] &= ~R.TXBNCTRL_TXREQ
        self.tx_log.append((t, n, msg))
        self._set_intf(_TXIF[n])

    def _tx_failed(self, n: int, msg: can.Message, flag: int) -> None:
        self._inflight = None
        ctrl_addr = _TXB_BASES[n]
        self._regs[ctrl_addr] |= flag
        aborted = n in self._abat_abort or (
            self._regs[ctrl_addr] & R.TXBNCTRL_TXREQ and self._regs[R.CANCTRL] & R.CANCTRL_ABAT
        )
        if aborted:
            self._abat_abort.discard(n)
            if self._tx_msgs[n] is msg:
                self._regs[ctrl_addr] = (self._regs[ctrl_addr] & ~R.TXBNCTRL_TXREQ) | (
                    R.TXBNCTRL_ABTF
                )
        if not self._regs[ctrl_addr] & R.TXBNCTRL_TXREQ or self._tx_msgs[n] is not msg:
            self._outstanding.pop(id(msg), None)

    # ======================================================================== modes
    def _request_mode(self, reqop: int, t: int) -> list[str]:
        """Handle a REQOP write; returns violations to report."""
        problems: list[str] = []
        if reqop == self._opmode and self._mode_event is None:
            self._mode_pending = None
            return problems
        if reqop in (R.OPMODE_SLEEP, R.OPMODE_LISTEN_ONLY) and self._highest_pending() is not None:
            problems.append(
                f"{MODE_NAMES[reqop]} mode requested while a transmission is pending: the chip "
                "cannot send it in that mode (abort it first)"
            )
        if self._opmode == R.OPMODE_SLEEP:
            # leaving sleep restarts the oscillator: OST before the new mode is active
            if self._mode_event is not None:
                self._mode_event.cancel()
            when = max(t, self.sched.now_ps) + self.ost_ps
            self._mode_event = self.sched.call_at(when, self._mode_timer, reqop)
            return problems
        if self._mode_event is not None:  # a wake-up in progress is overridden
            self._mode_event.cancel()
            self._mode_event = None
        if self._inflight is not None:
            self._mode_pending = reqop  # applied when the frame on the wire ends
            return problems
        problems += self._apply_mode(reqop, t)
        return problems

    def _mode_timer(self, reqop: int) -> None:
        self._mode_event = None
        for p in self._apply_mode(reqop, self.sched.now_ps):
            self._violation(self.sched.now_ps, p, "mode change", R.CANCTRL)

    def _apply_pending_mode(self, t: int) -> None:
        if self._mode_pending is not None and self._inflight is None:
            reqop, self._mode_pending = self._mode_pending, None
            for p in self._apply_mode(reqop, t):
                self._violation(t, p, "mode change", R.CANCTRL)

    def _apply_mode(self, new: int, t: int) -> list[str]:
        problems: list[str] = []
        old = self._opmode
        self._mode_pending = None
        if new == old:
            return problems
        if old == R.OPMODE_CONFIG:
            bt = self.bit_timing
            self._bit_timing = bt
            bad = bt.problems()
            if bad:
                problems.append(
                    f"leaving configuration mode with invalid bit timing {bt.describe()}: "
                    + "; ".join(bad)
                    + " (DS21291 section 5)"
                )
        self._opmode = new
        if old == R.OPMODE_LOOPBACK and self._loopback_event is not None:
            self._loopback_event.cancel()
            self._loopback_event = None
        if new == R.OPMODE_CONFIG:
            # DS21291 section 10.1: error counters are cleared in configuration mode
            self.reset_fault_confinement()
            self._refresh_eflg(t, raise_errif=False)
        if old == R.OPMODE_CONFIG and new in (R.OPMODE_NORMAL, R.OPMODE_LOOPBACK):
            for n in sorted(self._tx_check_deferred):
                if self._regs[_TXB_BASES[n]] & R.TXBNCTRL_TXREQ:
                    problems += [
                        f"{p} (requested in configuration mode, pending at the change to "
                        f"{MODE_NAMES[new]} mode)"
                        for p in self._tx_problems(n)
                    ]
            self._tx_check_deferred.clear()
        if new == R.OPMODE_NORMAL and self.bus is not None:
            self.bus.request_tx()
        elif new == R.OPMODE_LOOPBACK:
            self._schedule_loopback()
        self._update_pins()
        return problems

    def _start_wakeup(self, t: int) -> None:
        """Wake-up from sleep (bus activity or WAKIF set by the host): the chip wakes into
        listen-only mode after the oscillator start-up time (DS21291 section 10.2)."""
        if self._mode_event is not None:
            return
        when = max(t, self.sched.now_ps) + self.ost_ps
        self._mode_event = self.sched.call_at(when, self._wake_done)

    def _wake_done(self) -> None:
        self._mode_event = None
        ctrl = self._regs[R.CANCTRL] & ~R.CANCTRL_REQOP_MASK
        self._regs[R.CANCTRL] = ctrl | (R.OPMODE_LISTEN_ONLY << R.CANCTRL_REQOP_SHIFT)
        self._apply_mode(R.OPMODE_LISTEN_ONLY, self.sched.now_ps)

    # ======================================================================== loopback
    def _schedule_loopback(self) -> None:
        if self._loopback_event is not None or self._inflight is not None:
            return
        self._loopback_event = self.sched.call_at(self.sched.now_ps, self._loopback_start)

    def _loopback_start(self) -> None:
        self._loopback_event = None
        if self._opmode != R.OPMODE_LOOPBACK or self._regs[R.CANCTRL] & R.CANCTRL_ABAT:
            return
        n = self._highest_pending()
        if n is None:
            return
        msg = self._tx_msgs[n]
        assert msg is not None
        self._outstanding[id(msg)] = (n, msg)
        self._inflight = (n, msg)
        bt = self._bit_timing or self.bit_timing
        duration = round(frame_length_bits(msg) * bt.tq_ps * bt.tq_per_bit)
        self._loopback_event = self.sched.call_later(duration, self._loopback_done, n, msg)

    def _loopback_done(self, n: int, msg: can.Message) -> None:
        self._loopback_event = None
        t = self.sched.now_ps
        self._tx_success(n, msg, t)
        rx = copy.copy(msg)
        rx.timestamp = t / PS_PER_S
        rx.is_rx = True
        self._receive(rx, t)
        self._apply_pending_mode(t)
        if self._opmode == R.OPMODE_LOOPBACK:
            self._schedule_loopback()

    # ======================================================================== receive
    def _receive(self, msg: can.Message, t: int) -> None:
        """Acceptance filtering and buffer selection (DS21291 section 4, receive flowchart)."""
        ext = bool(msg.is_extended_id)
        cid = int(msg.arbitration_id)
        r = self._regs
        rxm0 = (r[R.RXB0CTRL] & R.RXBNCTRL_RXM_MASK) >> R.RXBNCTRL_RXM_SHIFT
        rxm1 = (r[R.RXB1CTRL] & R.RXBNCTRL_RXM_MASK) >> R.RXBNCTRL_RXM_SHIFT
        filters = [decode_id_regs(*r[b : b + 4]) for b in _FILTER_BASES]
        m0 = decode_id_regs(*r[R.RXM0SIDH : R.RXM0SIDH + 4])
        m1 = decode_id_regs(*r[R.RXM1SIDH : R.RXM1SIDH + 4])
        hit0 = buffer_accepts(rxm0, m0, [(0, filters[0]), (1, filters[1])], cid, ext)
        hit1 = None
        if hit0 is None:
            hit1 = buffer_accepts(rxm1, m1, [(i, filters[i]) for i in range(2, 6)], cid, ext)
        intf = r[R.CANINTF]
        if hit0 is not None:
            if not intf & R.CANINTF_RX0IF:
                self._store_rx(0, msg, hit0, t)
            elif r[R.RXB0CTRL] & R.RXB0CTRL_BUKT:
                if not intf & R.CANINTF_RX1IF:
                    self._store_rx(1, msg, hit0, t)
                else:
                    self._overflow(1, msg, t)
            else:
                self._overflow(0, msg, t)
        elif hit1 is not None:
            if not intf & R.CANINTF_RX1IF:
                self._store_rx(1, msg, hit1, t)
            else:
                self._overflow(1, msg, t)

    def _store_rx(self, n: int, msg: can.Message, filhit: int, t: int) -> None:
        base = _RXB_BASES[n]
        r = self._regs
        ext = bool(msg.is_extended_id)
        remote = bool(msg.is_remote_frame)
        sidh, sidl, eid8, eid0 = encode_id_regs(int(msg.arbitration_id), ext)
        if not ext and remote:
            sidl |= R.RXBNSIDL_SRR
        dlc = int(msg.dlc) & 0x0F
        r[base + R.BUF_SIDH_OFFSET] = sidh
        r[base + R.BUF_SIDL_OFFSET] = sidl
        r[base + R.BUF_EID8_OFFSET] = eid8
        r[base + R.BUF_EID0_OFFSET] = eid0
        r[base + R.BUF_DLC_OFFSET] = dlc | (R.RXBNDLC_RTR if ext and remote else 0)
        if not remote:
            data = bytes(msg.data[: min(dlc, 8)])
            r[base + R.BUF_D0_OFFSET : base + R.BUF_D0_OFFSET + len(data)] = data
        ctrl = r[base]
        if n == 0:
            ctrl &= R.RXBNCTRL_RXM_MASK | R.RXB0CTRL_BUKT | R.RXB0CTRL_BUKT1
            ctrl |= filhit & R.RXB0CTRL_FILHIT0
        else:
            ctrl &= R.RXBNCTRL_RXM_MASK
            ctrl |= filhit & R.RXB1CTRL_FILHIT_MASK
        if remote:
            ctrl |= R.RXBNCTRL_RXRTR
        r[base] = ctrl
        self.rx_log.append((t, n, msg))
        self._set_intf(_RXIF[n])

    def _overflow(self, n: int, msg: can.Message, t: int) -> None:
        self._regs[R.EFLG] |= _RXOVR[n]
        self.overflow_count += 1
        self.overflows.append((t, n, msg))
        self._set_intf(R.CANINTF_ERRIF)

    # ======================================================================== error flags
    def _refresh_eflg(self, t: int, *, raise_errif: bool = True) -> None:
        """Derive EFLG's error-state bits from TEC/REC/bus-off (DS21291 section 6); a change
        sets CANINTF.ERRIF (section 7 "Error interrupt")."""
        tec, rec = self.tec, self.rec
        bits = 0
        if tec >= R.ERROR_WARNING_LIMIT or rec >= R.ERROR_WARNING_LIMIT:
            bits |= R.EFLG_EWARN
        if rec >= R.ERROR_WARNING_LIMIT:
            bits |= R.EFLG_RXWAR
        if tec >= R.ERROR_WARNING_LIMIT:
            bits |= R.EFLG_TXWAR
        if rec >= R.ERROR_PASSIVE_LIMIT:
            bits |= R.EFLG_RXEP
        if tec >= R.ERROR_PASSIVE_LIMIT:
            bits |= R.EFLG_TXEP
        if self.error_state == BUS_OFF:
            bits |= R.EFLG_TXBO
        old = self._regs[R.EFLG]
        new = (old & R.EFLG_OVR_MASK) | bits
        if new != old:
            self._regs[R.EFLG] = new
            if raise_errif:
                self._set_intf(R.CANINTF_ERRIF)

    # ======================================================================== CanNode hooks
    def tx_candidate(self) -> can.Message | None:
        self._last_offered = None
        if self._opmode != R.OPMODE_NORMAL or self._regs[R.CANCTRL] & R.CANCTRL_ABAT:
            return None
        n = self._highest_pending()
        if n is None:
            return None
        msg = self._tx_msgs[n]
        assert msg is not None
        self._outstanding[id(msg)] = (n, msg)
        self._last_offered = (n, msg)
        return msg

    def on_bus_activity(self, t_ps: int) -> None:
        # The bus calls this at SOF right after asking every contender; if we offered a frame
        # in that round we are on the wire until a tx callback says otherwise.
        if self._last_offered is not None:
            self._inflight = self._last_offered
            self._last_offered = None
        if self._opmode == R.OPMODE_SLEEP and self._regs[R.CANINTE] & R.CANINTE_WAKIE:
            if self._mode_event is None:
                self._set_intf(R.CANINTF_WAKIF)
                self._start_wakeup(t_ps)

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        n = self._lookup(msg)
        if n is None:
            return
        self._tx_success(n, msg, t_ps)
        self._refresh_eflg(t_ps)
        self._apply_pending_mode(t_ps)

    def on_arbitration_lost(self, msg: can.Message, t_ps: int) -> None:
        n = self._lookup(msg)
        if n is None:
            return
        self._tx_failed(n, msg, R.TXBNCTRL_MLOA)
        self._apply_pending_mode(t_ps)

    def on_tx_error(self, msg: can.Message, t_ps: int, reason: str) -> None:
        n = self._lookup(msg)
        if n is None:
            return
        self._tx_failed(n, msg, R.TXBNCTRL_TXERR)
        self._set_intf(R.CANINTF_MERRF)
        self._refresh_eflg(t_ps)
        self._apply_pending_mode(t_ps)

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        if self._opmode in (R.OPMODE_NORMAL, R.OPMODE_LISTEN_ONLY):
            self._receive(msg, t_ps)
        self._refresh_eflg(t_ps)

    def on_bus_error(self, t_ps: int, reason: str) -> None:
        if self._opmode in (R.OPMODE_NORMAL, R.OPMODE_LISTEN_ONLY):
            self._set_intf(R.CANINTF_MERRF)
        self._refresh_eflg(t_ps)

    def on_error_state_change(self, old: str, new: str, t_ps: int) -> None:
        self._refresh_eflg(t_ps)

    def on_bus_idle(self, t_ps: int) -> None:
        self._refresh_eflg(t_ps)

    # ======================================================================== TXnRTS pins
    def set_txrts_n(self, n: int, level: int, t_ps: int) -> None:
        """Drive the TXnRTS input pin. A falling edge requests transmission of TXBn when
        TXRTSCTRL.BnRTSM = 1; otherwise the level is readable as TXRTSCTRL.BnRTS."""
        if n not in (0, 1, 2):
            raise ValueError(f"no TX{n}RTS pin")
        level = 1 if level else 0
        old = self._txrts_pins[n]
        self._txrts_pins[n] = level
        if old == 1 and level == 0 and self._regs[R.TXRTSCTRL] & (R.TXRTSCTRL_B0RTSM << n):
            if t_ps < self._ost_until_ps:
                self._violation(
                    t_ps,
                    "TXnRTS edge during the oscillator start-up time is lost",
                    f"TX{n}RTS pin",
                    R.TXRTSCTRL,
                )
                return
            self._tx_request(n, t_ps, f"TX{n}RTS pin")
        self._update_pins()

    # ======================================================================== SPI
    def spi_select(self, t_ps: int) -> None:
        """CS falling edge."""
        if self._cs_active:
            self._violation(t_ps, "CS fell while already selected", "SPI")
        self._cs_active = True
        self._spi_state = _INSTR
        self._spi_instr = ""
        self._spi_count = 0
        self._spi_data_count = 0
        self._so_latch = {}
        self._t_select = t_ps
        self._t_last_byte = None
        if t_ps < self._ost_until_ps:
            self._spi_state = _IGNORE
            cause = self.last_reset[1]
            self._violation(
                t_ps,
                f"SPI access {(self._ost_until_ps - t_ps) / 1e6:.3f} us before the oscillator "
                f"start-up timer expires (128 OSC1 cycles after {cause}, DS21291 section 8); "
                "the chip is still in reset and ignores it",
                "SPI",
            )

    def spi_out_byte(self) -> int | None:
        """Byte shifted out on SO during the next byte (None = high impedance)."""
        if not self._cs_active:
            return None
        idx = self._spi_count
        if idx not in self._so_latch:
            self._so_latch[idx] = self._so_value()
        return self._so_latch[idx]

    def _so_value(self) -> int | None:
        if self._spi_state == _READ_DATA:
            return self._read_reg(self._spi_addr & 0x7F)
        if self._spi_state == _STATUS:
            return self._read_status()
        return None

    def spi_in_byte(self, value: int, t_ps: int) -> None:
        """A complete byte shifted in on SI (8th rising SCK edge)."""
        value &= 0xFF
        if not self._cs_active:
            self._violation(t_ps, f"SPI byte 0x{value:02X} clocked with CS high", "SPI")
            return
        idx = self._spi_count
        so = self._so_latch[idx] if idx in self._so_latch else self._so_value()
        self._spi_count += 1
        if self.check_byte_timing and self._spi_state != _IGNORE:
            self._check_byte_time(t_ps)
        self._t_last_byte = t_ps
        if t_ps < self._ost_until_ps and self._spi_state not in (_IGNORE, _DONE):
            self._spi_state = _IGNORE
            self._violation(t_ps, "SPI byte during the oscillator start-up time", "SPI")
            return
        state = self._spi_state
        if state == _INSTR:
            self._decode_instruction(value, t_ps)
        elif state in (_READ_ADDR, _WRITE_ADDR, _BM_ADDR):
            addr = value
            if addr > R.REG_ADDR_MAX:
                self._violation(
                    t_ps,
                    f"address 0x{addr:02X} is outside the register map 0x00-0x7F (A7 ignored)",
                    self._spi_instr,
                )
            self._spi_addr = addr & 0x7F
            self._spi_state = {
                _READ_ADDR: _READ_DATA,
                _WRITE_ADDR: _WRITE_DATA,
                _BM_ADDR: _BM_MASK,
            }[state]
        elif state == _READ_DATA:
            a = self._wrap_check(t_ps)
            self._spi_data_count += 1
            if a == R.CANINTF and so is not None:
                self._intf_unseen &= ~so
            if a in FILTER_MASK_ADDRS and self._opmode != R.OPMODE_CONFIG:
                self._spi_addr = a + 1
                self._violation(
                    t_ps,
                    f"filter/mask register read in {self.mode} mode returns 0 "
                    "(readable in configuration mode only)",
                    "READ",
                    a,
                )
                return
            self._spi_addr = a + 1
        elif state == _WRITE_DATA:
            a = self._wrap_check(t_ps)
            self._spi_data_count += 1
            self._spi_addr = a + 1
            self._write_reg(a, value, t_ps, "WRITE")
        elif state == _STATUS:
            self._spi_data_count += 1
            if so is not None:
                seen = so & (R.CANINTF_RX0IF | R.CANINTF_RX1IF)
                for n, bit in enumerate((R.STATUS_TX0IF, R.STATUS_TX1IF, R.STATUS_TX2IF)):
                    if so & bit:
                        seen |= _TXIF[n]
                self._intf_unseen &= ~seen
        elif state == _BM_MASK:
            self._bm_mask = value
            self._spi_state = _BM_DATA
        elif state == _BM_DATA:
            self._spi_state = _DONE
            self._bit_modify(self._spi_addr, self._bm_mask, value, t_ps)
        elif state == _DONE:
            self._spi_state = _IGNORE
            self._violation(
                t_ps,
                f"extra byte 0x{value:02X} after a complete {self._spi_instr} instruction "
                "(ignored by the chip)",
                self._spi_instr,
            )
        # _IGNORE: nothing
        self._update_pins()

    def _check_byte_time(self, t_ps: int) -> None:
        if self._t_last_byte is not None:
            gap = t_ps - self._t_last_byte
            if gap < 8 * _SCK_PERIOD_MIN_PS:
                self._violation(
                    t_ps,
                    f"byte completed {gap / 1e3:.1f} ns after the previous one: SCK faster than "
                    f"{R.SPI_SCK_MAX_HZ / 1e6:g} MHz",
                    self._spi_instr or "SPI",
                )
        elif self._t_select is not None:
            gap = t_ps - self._t_select
            if gap < 7 * _SCK_PERIOD_MIN_PS:
                self._violation(
                    t_ps,
                    f"first byte completed {gap / 1e3:.1f} ns after CS fell: SCK faster than "
                    f"{R.SPI_SCK_MAX_HZ / 1e6:g} MHz",
                    "SPI",
                )

    def _wrap_check(self, t_ps: int) -> int:
        a = self._spi_addr
        if a > R.REG_ADDR_MAX:
            a &= 0x7F
            self._spi_addr = a
            self._violation(
                t_ps,
                "address pointer auto-incremented past 0x7F and wrapped to 0x00 "
                "(wrap-around is not documented)",
                self._spi_instr,
                a,
            )
        return a

    def _decode_instruction(self, op: int, t: int) -> None:
        self._spi_opcode = op
        if op == R.INSTR_RESET:
            self._spi_instr = "RESET"
            self._spi_state = _DONE
            self._reset(t, "RESET instruction")
        elif op == R.INSTR_READ:
            self._spi_instr = "READ"
            self._spi_state = _READ_ADDR
        elif op == R.INSTR_WRITE:
            self._spi_instr = "WRITE"
            self._spi_state = _WRITE_ADDR
        elif op == R.INSTR_READ_STATUS:
            self._spi_instr = "READ STATUS"
            self._spi_state = _STATUS
        elif op == R.INSTR_BIT_MODIFY:
            self._spi_instr = "BIT MODIFY"
            self._spi_state = _BM_ADDR
        elif op & R.INSTR_RTS_MASK == R.INSTR_RTS:
            self._spi_instr = f"RTS 0x{op:02X}"
            self._spi_state = _DONE
            if op & 0x07 == 0:
                self._violation(t, "RTS with no buffer selected (0x80) does nothing", "RTS")
            for n in range(3):
                if op & (1 << n):
                    self._tx_request(n, t, f"RTS 0x{op:02X}")
        else:
            self._spi_state = _IGNORE
            self._spi_instr = f"opcode 0x{op:02X}"
            if op & R.INSTR_MCP2515_READ_RX_BUFFER_MASK == R.INSTR_MCP2515_READ_RX_BUFFER:
                what = "READ RX BUFFER"
            elif R.INSTR_MCP2515_LOAD_TX_BUFFER <= op <= R.INSTR_MCP2515_LOAD_TX_BUFFER_LAST:
                what = "LOAD TX BUFFER"
            elif op == R.INSTR_MCP2515_RX_STATUS:
                what = "RX STATUS"
            else:
                what = ""
            if what:
                text = (
                    f"MCP2515-only instruction {what} (0x{op:02X}) is not supported by the "
                    "MCP2510 (use READ/WRITE on the buffer addresses); the chip ignores it"
                )
            else:
                text = f"undefined opcode 0x{op:02X}; the chip ignores the transaction"
            self._violation(t, text, f"opcode 0x{op:02X}")

    def _bit_modify(self, a: int, mask: int, data: int, t: int) -> None:
        a &= 0x7F
        if a not in BIT_MODIFIABLE and mask != 0xFF:
            # DS21291 section 11 (BIT MODIFY): the mask is forced to 0xFF on registers that
            # are not bit-modifiable, i.e. the data byte is written as a whole
            self._write_reg(a, data, t, "BIT MODIFY")
            self._violation(
                t,
                f"BIT MODIFY on a register that is not bit-modifiable: the chip forces the "
                f"mask 0x{mask:02X} to 0xFF and writes 0x{data:02X} to the whole register",
                "BIT MODIFY",
                a,
            )
            return
        current = self._bm_current(a)
        value = (current & ~mask) | (data & mask)
        self._write_reg(a, value, t, "BIT MODIFY")

    def _bm_current(self, a: int) -> int:
        """Register contents a BIT MODIFY starts from (the stored bits, not pin states)."""
        low = a & 0x0F
        if low == 0x0F:
            return self._regs[R.CANCTRL]
        if low == 0x0E:
            return self._canstat()
        return self._regs[a] if a not in (R.TEC, R.REC) else self._read_reg(a)

    def spi_deselect(self, t_ps: int, partial_bits: int = 0) -> None:
        """CS rising edge. ``partial_bits`` bits of an incomplete byte are discarded, as on the
        chip; every byte completed before (and written by WRITE) stays."""
        if not self._cs_active:
            return
        self._cs_active = False
        state = self._spi_state
        instr = self._spi_instr
        self._spi_state = _IDLE
        self._so_latch = {}
        problems: list[str] = []
        if partial_bits:
            problems.append(
                f"CS rose after {partial_bits} bit(s) of a byte; that byte is discarded"
            )
        if state in (_READ_ADDR, _WRITE_ADDR, _BM_ADDR, _BM_MASK, _BM_DATA):
            problems.append(f"CS rose in the {state} byte: the {instr} instruction is aborted")
        elif state in (_READ_DATA, _WRITE_DATA, _STATUS) and self._spi_data_count == 0:
            problems.append(f"{instr} ended without a data byte")
        elif state == _INSTR and self._spi_count == 0 and partial_bits == 0:
            pass  # a CS pulse without clocks does nothing
        for p in problems:
            self._violation(t_ps, p, instr or "SPI")

    def spi_transfer(
        self,
        data: bytes | list[int],
        t_ps: int | None = None,
        *,
        advance: bool = True,
        sck_hz: int = R.SPI_SCK_MAX_HZ,
    ) -> bytes:
        """Select, exchange every byte at ``sck_hz``, deselect; returns what SO carried
        (0xFF where SO was high impedance, i.e. a pulled-up line).

        Times start at ``t_ps`` (default: now). With ``advance=True`` the scheduler is run up
        to each SPI event, so bus activity interleaves realistically; do not call it from a
        scheduler callback then.
        """
        period = -(-PS_PER_S // sck_hz)
        t = self.sched.now_ps if t_ps is None else int(t_ps)

        def at(time: int) -> None:
            if advance and time > self.sched.now_ps:
                self.sched.run_until(time)

        at(t)
        out = bytearray()
        try:
            self.spi_select(t)
            t_byte = t + 100_000 + 7 * period + period // 2  # tCSS + 7.5 SCK periods
            for b in data:
                at(t_byte)
                so = self.spi_out_byte()
                self.spi_in_byte(int(b), t_byte)
                out.append(0xFF if so is None else so)
                t_byte += 8 * period
        except Mcp2510Error:
            # a strict violation ends the transfer: release CS without further checks
            self._cs_active = False
            self._spi_state = _IDLE
            raise
        t_end = t_byte - 8 * period + period // 2 + 100_000 if data else t + 200_000
        at(t_end)
        self.spi_deselect(t_end)
        return bytes(out)

    # ---------------------------------------------------------------- convenience helpers
    def spi_read(self, addr: int, n: int = 1, t_ps: int | None = None) -> bytes:
        """READ ``n`` registers from ``addr`` (via :meth:`spi_transfer`)."""
        return self.spi_transfer(bytes([R.INSTR_READ, addr]) + bytes(n), t_ps)[2:]

    def spi_write(self, addr: int, values: bytes | list[int], t_ps: int | None = None) -> None:
        """WRITE ``values`` from ``addr`` (via :meth:`spi_transfer`)."""
        self.spi_transfer(bytes([R.INSTR_WRITE, addr]) + bytes(values), t_ps)

    def spi_bit_modify(self, addr: int, mask: int, data: int, t_ps: int | None = None) -> None:
        """BIT MODIFY ``addr`` (via :meth:`spi_transfer`)."""
        self.spi_transfer(bytes([R.INSTR_BIT_MODIFY, addr, mask, data]), t_ps)


_INTF_NAMES = (
    ("RX0IF", R.CANINTF_RX0IF),
    ("RX1IF", R.CANINTF_RX1IF),
    ("TX0IF", R.CANINTF_TX0IF),
    ("TX1IF", R.CANINTF_TX1IF),
    ("TX2IF", R.CANINTF_TX2IF),
    ("ERRIF", R.CANINTF_ERRIF),
    ("WAKIF", R.CANINTF_WAKIF),
    ("MERRF", R.CANINTF_MERRF),
)
