"""cocotb bridge between DUT SPI pins and a pure-Python :class:`~sim_models.spi_slave.SpiPinSlave`.

It wakes only on CS, SCK and MOSI changes (never per clock), forwards the levels with the
simulated time in ps, and drives MISO with what the slave model returns ('Z' when the device
does not drive SO). A violation raised by the model fails the running cocotb test.
"""

from __future__ import annotations

import cocotb
from cocotb.handle import SimHandleBase
from cocotb.triggers import First, ValueChange
from cocotb.types import Logic

from sim_models.spi_slave import SpiPinSlave, SpiViolation
from tb.tblib.model_clock import sim_time_ps

_HIGH_Z = Logic("Z")


class SpiPinBridge:
    """Connect ``cs_n``/``sck``/``mosi`` outputs and the ``miso`` input of a DUT to a slave."""

    def __init__(
        self,
        slave: SpiPinSlave,
        *,
        cs_n: SimHandleBase,
        sck: SimHandleBase,
        mosi: SimHandleBase,
        miso: SimHandleBase,
    ) -> None:
        self.slave = slave
        self._cs_n = cs_n
        self._sck = sck
        self._mosi = mosi
        self._miso = miso
        self._miso.value = _HIGH_Z
        #: the bridge coroutine (a test may await it to catch a violation it raises)
        self.task = cocotb.start_soon(self._run())

    def stop(self) -> None:
        self.task.cancel()

    def _level(self, sig: SimHandleBase, what: str, t_ps: int) -> int:
        v = sig.value
        if not v.is_resolvable:
            raise SpiViolation(f"SPI violation at {t_ps / 1e6:.4f} us: {what} is '{v}'")
        return int(v)

    async def _run(self) -> None:
        cs_n, sck, mosi = self._cs_n, self._sck, self._mosi
        while True:
            await First(ValueChange(cs_n), ValueChange(sck), ValueChange(mosi))
            t_ps = sim_time_ps()
            c = self._level(cs_n, "CS", t_ps)
            s = self._level(sck, "SCK", t_ps)
            if c == 0 or mosi.value.is_resolvable:
                m = self._level(mosi, "MOSI", t_ps)
            else:
                m = self.slave._mosi  # MOSI may float while CS is high
            self.slave.update(t_ps, cs_n=c, sck=s, mosi=m)
            out = self.slave.miso
            self._miso.value = _HIGH_Z if out is None else out
