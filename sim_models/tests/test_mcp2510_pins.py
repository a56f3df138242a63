"""MCP2510 model behind the pin-level SPI slave (sim_models.spi_slave), modes 0,0 and 1,1."""

from __future__ import annotations

import pytest

from sim_models.mcp2510 import Mcp2510, Mcp2510Error
from sim_models.mcp2510 import regs as R
from sim_models.sim_time import PS_PER_NS, PS_PER_US, Scheduler
from sim_models.spi_slave import SpiPinSlave


class PinMaster:
    """Drives CS/SCK/MOSI edges at 5 MHz (100 ns half period) in SPI mode 0,0 or 1,1."""

    def __init__(self, slave: SpiPinSlave, cpol: int, t_ps: int) -> None:
        self.s, self.cpol, self.t = slave, cpol, t_ps
        self.cs_n, self.sck, self.mosi = 1, cpol, 0
        self._apply()

    def _apply(self) -> None:
        self.s.update(self.t, cs_n=self.cs_n, sck=self.sck, mosi=self.mosi)

    def _edge(self, **kw: int) -> None:
        for k, v in kw.items():
            setattr(self, k, v)
        self._apply()

    def transfer(self, data: bytes) -> bytes:
        half = 100 * PS_PER_NS
        self._edge(cs_n=0)
        self.t += half
        out = bytearray()
        for value in data:
            got = 0
            for i in range(7, -1, -1):
                if self.cpol:
                    self._edge(sck=0)  # falling edge: slave shifts out
                self._edge(mosi=(value >> i) & 1)
                self.t += half
                self._edge(sck=1)  # rising edge: both sides sample
                got = (got << 1) | (self.s.miso if self.s.miso is not None else 1)
                self.t += half
                if not self.cpol:
                    self._edge(sck=0)
            out.append(got)
        self.t += half
        self._edge(cs_n=1)
        self.t += 200 * PS_PER_NS
        return bytes(out)


@pytest.mark.parametrize("cpol", [0, 1])
def test_read_and_write_through_pins(cpol: int) -> None:
    sched = Scheduler()
    chip = Mcp2510(sched)
    slave = SpiPinSlave(chip)
    m = PinMaster(slave, cpol, 10 * PS_PER_US)
    assert m.transfer(bytes([R.INSTR_READ, R.CANSTAT, 0, 0])) == bytes([0xFF, 0xFF, 0x80, 0x87])
    m.transfer(bytes([R.INSTR_WRITE, R.CANINTE, 0xA5]))
    assert chip.peek(R.CANINTE) == 0xA5
    status = m.transfer(
        bytes(
            [
                R.INSTR_BIT_MODIFY,
                R.CANINTF,
                0x02,
                0x02,
            ]
        )
    )
    assert status == b"\xff\xff\xff\xff"
    assert m.transfer(bytes([R.INSTR_READ_STATUS, 0, 0])) == bytes([0xFF, 0x02, 0x02])
    assert chip.violations == [] and slave.violations == []


def test_mcp2515_opcode_through_pins_fails_the_transaction() -> None:
    sched = Scheduler()
    chip = Mcp2510(sched)
    m = PinMaster(SpiPinSlave(chip), 0, 10 * PS_PER_US)
    with pytest.raises(Mcp2510Error, match="READ RX BUFFER"):
        m.transfer(bytes([0x90, 0x00]))
