"""Unit tests of the pin-level SPI slave/checker, driven by synthetic pin waveforms."""

from __future__ import annotations

import pytest

from sim_models.spi_slave import ScriptedSpiDevice, SpiPinSlave, SpiTimingSpec, SpiViolation

NS = 1000  # ps


class Master:
    """Generates SPI pin events the way a (possibly faulty) master would."""

    def __init__(self, slave: SpiPinSlave, half_ns: int = 100, cpol: int = 0) -> None:
        self.s = slave
        self.t = 1_000 * NS
        self.half = half_ns * NS
        self.cpol = cpol
        self.cs_n, self.sck, self.mosi = 1, cpol, 0
        self.miso_bits: list[int | None] = []
        self._apply()

    def _apply(self) -> None:
        self.s.update(self.t, cs_n=self.cs_n, sck=self.sck, mosi=self.mosi)

    def wait(self, ns: int) -> None:
        self.t += ns * NS

    def set(self, **kw: int) -> None:
        for k, v in kw.items():
            setattr(self, k, v)
        self._apply()

    def select(self, setup_ns: int = 100) -> None:
        self.first = True
        self.set(cs_n=0)
        self.wait(setup_ns)

    def byte(self, value: int, mosi_change_while_high: bool = False) -> int:
        got = 0
        for i in range(7, -1, -1):
            if self.cpol == 0:
                self.set(mosi=(value >> i) & 1)  # SCK low: data may change
                if not self.first:
                    self.wait(self.half // NS)
                self.first = False
                self.set(sck=1)  # rising edge: sampled
                got = (got << 1) | (self.s.miso or 0)
                self.wait(self.half // NS)
                if mosi_change_while_high:
                    self.set(mosi=1 - self.mosi)
                self.set(sck=0)
            else:
                if not self.first:
                    self.wait(self.half // NS)
                self.first = False
                self.set(sck=0)  # leading falling edge: slave shifts out
                self.set(mosi=(value >> i) & 1)
                self.wait(self.half // NS)
                self.set(sck=1)
                got = (got << 1) | (self.s.miso or 0)
                self.wait(self.half // NS)
        return got

    def deselect(self, hold_ns: int = 100) -> None:
        self.wait(hold_ns)
        self.set(cs_n=1)
        self.wait(200)


def make(spec: SpiTimingSpec | None = None, strict: bool = True):
    dev = ScriptedSpiDevice(seed=7)
    return dev, SpiPinSlave(dev, spec or SpiTimingSpec(), strict=strict)


def test_mode00_bytes_both_directions_msb_first():
    dev, slave = make()
    m = Master(slave)
    m.select()
    got = [m.byte(b) for b in (0x03, 0x0E, 0xA5)]
    m.deselect()
    assert dev.received == [bytes([0x03, 0x0E, 0xA5])]
    assert got == list(dev.sent[0])
    assert slave.transactions[0].mode == (0, 0)
    assert slave.violations == []
    assert slave.measured_sck_hz == pytest.approx(5e6)


def test_mode11_is_accepted_and_decoded():
    dev, slave = make()
    m = Master(slave, cpol=1)
    m.select()
    got = [m.byte(b) for b in (0xC0, 0x5A)]
    m.deselect()
    assert dev.received == [bytes([0xC0, 0x5A])]
    assert got == list(dev.sent[0])
    assert slave.transactions[0].mode == (1, 1)


def test_sck_above_limit_is_flagged():
    _, slave = make()
    m = Master(slave, half_ns=90)  # 180 ns period = 5.56 MHz
    m.select()
    with pytest.raises(SpiViolation, match="faster than 5.000 MHz"):
        m.byte(0x03)


def test_short_cs_setup_is_flagged():
    _, slave = make(SpiTimingSpec(t_cs_setup_ps=150 * NS))
    m = Master(slave)
    m.select(setup_ns=100)
    with pytest.raises(SpiViolation, match="tCSS"):
        m.byte(0x03)


def test_short_cs_hold_is_flagged():
    _, slave = make()
    m = Master(slave)
    m.select()
    m.byte(0xA0)
    with pytest.raises(SpiViolation, match="tCSH"):
        m.deselect(hold_ns=10)


def test_short_cs_disable_is_flagged():
    _, slave = make()
    m = Master(slave)
    m.select()
    m.byte(0xA0)
    m.deselect()
    m.wait(-170)  # only 30 ns of CS high before the next fall (tCSD 50 ns)
    with pytest.raises(SpiViolation, match="tCSD"):
        m.select()


def test_mosi_changing_while_sck_high_is_flagged():
    _, slave = make()
    m = Master(slave)
    m.select()
    with pytest.raises(SpiViolation, match="wrong edge"):
        m.byte(0x55, mosi_change_while_high=True)


def test_mosi_changing_with_the_rising_edge_is_flagged():
    _, slave = make()
    m = Master(slave)
    m.select()
    m.set(mosi=0)
    with pytest.raises(SpiViolation, match="same instant as the SCK rising edge"):
        slave.update(m.t, cs_n=0, sck=1, mosi=1)


def test_partial_byte_is_flagged_and_reported_to_device():
    dev, slave = make(strict=False)
    m = Master(slave)
    m.select()
    m.byte(0x02)
    for _ in range(3):  # three more bits, then CS rises mid-byte
        m.set(sck=1)
        m.wait(100)
        m.set(sck=0)
        m.wait(100)
    m.deselect()
    assert slave.transactions[0].partial_bits == 3
    assert any("not on a byte boundary" in v for v in slave.violations)
    assert dev.received == [b"\x02"]


def test_partial_byte_allowed_when_configured():
    _, slave = make(SpiTimingSpec(allow_partial_bytes=True))
    m = Master(slave)
    m.select()
    m.set(sck=1)
    m.wait(100)
    m.set(sck=0)
    m.deselect()
    assert slave.transactions[0].partial_bits == 1
    assert slave.violations == []


def test_sck_toggling_with_cs_high_is_ignored():
    dev, slave = make()
    m = Master(slave)
    for _ in range(4):
        m.set(sck=1)
        m.wait(50)
        m.set(sck=0)
        m.wait(50)
    assert slave.transactions == [] and dev.received == []
