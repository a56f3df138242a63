"""Pin-level SPI slave with a timing and protocol checker, independent of any simulator.

:class:`SpiPinSlave` is fed pin events (CS, SCK and MOSI levels with their time in ps). It
measures what it sees instead of assuming it (SCK period and high/low times, CS setup, hold and
disable times, SPI mode, MOSI changes on the wrong edge, byte boundaries), assembles bytes MSB
first and forwards them to a byte-level *device* (the MCP2510 model, or a scripted device in
the SPI-engine bench). It computes the MISO level the device drives (``None`` = high impedance).

The cocotb bridge in ``tb/tblib/spi_pins.py`` only forwards pin edges to this class, so all the
checking logic is unit-tested in ``sim_models/tests/test_spi_slave.py`` without a simulator.

Supported modes are 0,0 and 1,1 (the MCP2510's): data is sampled on the SCK rising edge and
shifted out on the falling edge. Mode 0,1/1,0 behaviour (MOSI changing while SCK is high) is
reported as "data changing on the wrong edge".
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from sim_models.sim_time import PS_PER_NS


class SpiViolation(Exception):
    """The SPI master broke a timing or protocol rule of the slave."""


class SpiDevice(Protocol):
    """Byte-level device behind the pins (implemented by the MCP2510 model)."""

    def spi_select(self, t_ps: int) -> None: ...

    def spi_out_byte(self) -> int | None: ...

    def spi_in_byte(self, value: int, t_ps: int) -> None: ...

    def spi_deselect(self, t_ps: int, partial_bits: int = 0) -> None: ...


@dataclass(frozen=True)
class SpiTimingSpec:
    """Minimum/maximum timing the slave accepts (all in ps). Defaults: MCP2510 (DS21291) at
    VDD 4.5-5.5 V. Only SCK <= 5 MHz and modes 0,0/1,1 are confirmed from a stored copy of the
    data sheet; the CS and SCK times are the data sheet's as remembered, not re-checked
    (docs/mcp2510_model.md lists the sources), so the RTL defaults are at least as long."""

    sck_max_hz: int = 5_000_000
    t_cs_setup_ps: int = 100 * PS_PER_NS  # tCSS: CS fall to first SCK rising edge
    t_cs_hold_ps: int = 100 * PS_PER_NS  # tCSH: last SCK edge to CS rise
    t_cs_disable_ps: int = 50 * PS_PER_NS  # tCSD: CS high time between transactions
    t_sck_high_ps: int = 90 * PS_PER_NS  # minimum SCK high time
    t_sck_low_ps: int = 90 * PS_PER_NS  # minimum SCK low time
    allow_partial_bytes: bool = False  # CS rising mid-byte is a violation unless allowed


@dataclass
class SpiTransaction:
    """One CS-low period as seen on the pins."""

    t_start_ps: int
    t_end_ps: int | None = None
    mosi: bytearray = field(default_factory=bytearray)
    miso: list[int | None] = field(default_factory=list)
    partial_bits: int = 0
    mode: tuple[int, int] = (0, 0)

    @property
    def duration_ps(self) -> int:
        assert self.t_end_ps is not None, "transaction still open"
        return self.t_end_ps - self.t_start_ps


class SpiPinSlave:
    """Decode SPI pin events, check timing, and serve a byte-level :class:`SpiDevice`.

    Call :meth:`cs`, :meth:`sck` and :meth:`mosi` on every level change (duplicate levels are
    ignored). Read :attr:`miso` after each call to know what the slave drives.
    With ``strict=True`` the first violation raises :class:`SpiViolation`; all violations are
    also kept in :attr:`violations`.
    """

    def __init__(
        self,
        device: SpiDevice,
        spec: SpiTimingSpec | None = None,
        *,
        strict: bool = True,
        name: str = "spi",
    ) -> None:
        self.device = device
        self.spec = spec or SpiTimingSpec()
        self.strict = strict
        self.log = logging.getLogger(f"cocotb.tb.{name}")
        self.violations: list[str] = []
        self.transactions: list[SpiTransaction] = []
        #: every SCK rising-to-rising period measured inside a transaction, in ps
        self.sck_periods_ps: list[int] = []
        self._cs_n = 1
        self._sck = 0
        self._mosi = 0
        self._t_cs_rise: int | None = None
        self._t_sck_rise: int | None = None
        self._t_sck_fall: int | None = None
        self._t_last_sck_edge: int | None = None
        self._cur: SpiTransaction | None = None
        self._shift_in = 0
        self._bits_in = 0
        self._out_byte: int | None = None
        self._out_bit = 0
        self._rose_since_out = False
        self.miso: int | None = None

    # ------------------------------------------------------------------ helpers
    def _violate(self, t_ps: int, what: str) -> None:
        cur = self._cur
        where = ""
        if cur is not None and cur.mosi:
            where = f" (transaction started {cur.t_start_ps / 1e6:.3f} us, bytes so far "
            where += " ".join(f"{b:02X}" for b in cur.mosi[:4]) + ")"
        msg = f"SPI violation at {t_ps / 1e6:.4f} us: {what}{where}"
        self.violations.append(msg)
        self.log.error(msg)
        if self.strict:
            raise SpiViolation(msg)

    def _load_out_byte(self) -> None:
        self._out_byte = self.device.spi_out_byte()
        self._out_bit = 7
        self._drive()

    def _drive(self) -> None:
        if self._out_byte is None or self._cs_n:
            self.miso = None
        else:
            self.miso = (self._out_byte >> self._out_bit) & 1

    @property
    def measured_sck_hz(self) -> float | None:
        """Highest SCK frequency measured (from the shortest rising-to-rising period)."""
        if not self.sck_periods_ps:
            return None
        return 1e12 / min(self.sck_periods_ps)

    # ------------------------------------------------------------------ pin events
    def update(self, t_ps: int, *, cs_n: int, sck: int, mosi: int) -> None:
        """Apply simultaneous level changes in the order the slave's logic sees them.

        A CS fall comes first and a CS rise last (so a CS edge coinciding with an SCK edge
        shows up as a zero setup/hold time); a falling SCK edge is applied before MOSI (data may
        change with the falling edge); MOSI changing at the same instant as a rising SCK edge
        is a setup violation.
        """
        cs_n, sck, mosi = int(cs_n), int(sck), int(mosi)
        if cs_n == 0 and self._cs_n == 1:
            self.cs(0, t_ps)
        sck_rise = sck == 1 and self._sck == 0
        if sck == 0 and self._sck == 1:
            self.sck(0, t_ps)
        if mosi != self._mosi:
            if sck_rise and self._cs_n == 0:
                self._violate(t_ps, "MOSI changed at the same instant as the SCK rising edge")
            self.mosi(mosi, t_ps)
        if sck_rise:
            self.sck(1, t_ps)
        if cs_n == 1 and self._cs_n == 0:
            self.cs(1, t_ps)

    def cs(self, level: int, t_ps: int) -> None:
        level = int(level)
        if level == self._cs_n:
            return
        self._cs_n = level
        if level == 0:
            self._cs_fall(t_ps)
        else:
            self._cs_rise(t_ps)

    def _cs_fall(self, t_ps: int) -> None:
        spec = self.spec
        if self._t_cs_rise is not None and t_ps - self._t_cs_rise < spec.t_cs_disable_ps:
            self._violate(
                t_ps,
                f"CS high for {(t_ps - self._t_cs_rise) / 1e3:.1f} ns < tCSD "
                f"{spec.t_cs_disable_ps / 1e3:.1f} ns",
            )
        mode = (self._sck, self._sck)  # CPOL from the idle level; CPHA follows for 0,0 / 1,1
        self._cur = SpiTransaction(t_start_ps=t_ps, mode=mode)
        self._shift_in = 0
        self._bits_in = 0
        self._t_sck_rise = None
        self._t_last_sck_edge = None
        self._rose_since_out = False
        self.device.spi_select(t_ps)
        self._load_out_byte()

    def _cs_rise(self, t_ps: int) -> None:
        spec = self.spec
        cur = self._cur
        if cur is None:
            return
        if self._t_last_sck_edge is not None and t_ps - self._t_last_sck_edge < spec.t_cs_hold_ps:
            self._violate(
                t_ps,
                f"CS rose {(t_ps - self._t_last_sck_edge) / 1e3:.1f} ns after the last SCK "
                f"edge < tCSH {spec.t_cs_hold_ps / 1e3:.1f} ns",
            )
        if cur.mode == (0, 0) and self._sck != 0:
            self._violate(t_ps, "CS rose while SCK was high in mode 0,0")
        cur.partial_bits = self._bits_in
        cur.t_end_ps = t_ps
        self.transactions.append(cur)
        if self._bits_in and not spec.allow_partial_bytes:
            self._violate(
                t_ps, f"CS rose after {self._bits_in} bits of a byte (not on a byte boundary)"
            )
        self.device.spi_deselect(t_ps, self._bits_in)
        self._cur = None
        self._t_cs_rise = t_ps
        self._out_byte = None
        self._drive()

    def mosi(self, level: int, t_ps: int) -> None:
        level = int(level)
        if level == self._mosi:
            return
        self._mosi = level
        if self._cs_n == 0 and self._sck == 1:
            self._violate(
                t_ps, "MOSI changed while SCK was high (data changing on the wrong edge)"
            )

    def sck(self, level: int, t_ps: int) -> None:
        level = int(level)
        if level == self._sck:
            return
        self._sck = level
        if self._cs_n == 1:
            return  # SCK activity with CS high is ignored by the slave
        spec = self.spec
        cur = self._cur
        assert cur is not None
        if level == 1:
            if self._t_sck_rise is None and self._t_last_sck_edge is None:
                setup = t_ps - cur.t_start_ps
                if setup < spec.t_cs_setup_ps:
                    self._violate(
                        t_ps,
                        f"first SCK rise {setup / 1e3:.1f} ns after CS fall < tCSS "
                        f"{spec.t_cs_setup_ps / 1e3:.1f} ns",
                    )
            if self._t_sck_fall is not None and self._t_last_sck_edge is not None:
                low = t_ps - self._t_sck_fall
                if low < spec.t_sck_low_ps:
                    self._violate(
                        t_ps, f"SCK low for {low / 1e3:.1f} ns < {spec.t_sck_low_ps / 1e3:.1f} ns"
                    )
            if self._t_sck_rise is not None:
                period = t_ps - self._t_sck_rise
                self.sck_periods_ps.append(period)
                if period * spec.sck_max_hz < 1_000_000_000_000:
                    self._violate(
                        t_ps,
                        f"SCK period {period / 1e3:.1f} ns is faster than "
                        f"{spec.sck_max_hz / 1e6:.3f} MHz",
                    )
            self._t_sck_rise = t_ps
            self._t_last_sck_edge = t_ps
            # sample MOSI
            self._shift_in = ((self._shift_in << 1) | self._mosi) & 0xFF
            self._bits_in += 1
            self._rose_since_out = True
            if self._bits_in == 8:
                value = self._shift_in
                cur.mosi.append(value)
                cur.miso.append(self._out_byte)
                self._bits_in = 0
                self._shift_in = 0
                self.device.spi_in_byte(value, t_ps)
        else:
            if self._t_sck_rise is not None and self._t_last_sck_edge == self._t_sck_rise:
                high = t_ps - self._t_sck_rise
                if high < spec.t_sck_high_ps:
                    self._violate(
                        t_ps,
                        f"SCK high for {high / 1e3:.1f} ns < {spec.t_sck_high_ps / 1e3:.1f} ns",
                    )
            self._t_sck_fall = t_ps
            self._t_last_sck_edge = t_ps
            # shift out on the falling edge that follows a rising edge (mode 1,1's leading
            # falling edge does not advance the output)
            if self._rose_since_out:
                self._rose_since_out = False
                if self._bits_in == 0:
                    self._load_out_byte()
                else:
                    self._out_bit -= 1
                    self._drive()


class ScriptedSpiDevice:
    """A byte-level device for engine benches: records what it receives and answers with a
    deterministic byte sequence. ``on_byte(sent, received)`` is called for every complete byte,
    at the SCK edge that completes it (a scoreboard hook)."""

    def __init__(self, seed: int = 1) -> None:
        self._state = seed & 0xFFFFFFFF or 1
        self.on_byte: Callable[[int, int], None] | None = None
        self.received: list[bytes] = []
        self.sent: list[bytes] = []
        self._rx = bytearray()
        self._tx = bytearray()
        self._next: int | None = None

    def _prng(self) -> int:
        # xorshift32: deterministic, independent of Python's global random state
        x = self._state
        x ^= (x << 13) & 0xFFFFFFFF
        x ^= x >> 17
        x ^= (x << 5) & 0xFFFFFFFF
        self._state = x
        return x & 0xFF

    def spi_select(self, t_ps: int) -> None:
        self._rx = bytearray()
        self._tx = bytearray()

    def spi_out_byte(self) -> int | None:
        self._next = self._prng()
        self._tx.append(self._next)
        return self._next

    def spi_in_byte(self, value: int, t_ps: int) -> None:
        self._rx.append(value)
        if self.on_byte is not None:
            self.on_byte(self._tx[len(self._rx) - 1], value)

    def spi_deselect(self, t_ps: int, partial_bits: int = 0) -> None:
        # the byte prepared for the position after the last complete byte was never clocked
        self.received.append(bytes(self._rx))
        self.sent.append(bytes(self._tx[: len(self._rx)]))
