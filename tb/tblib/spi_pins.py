"""cocotb bridge between DUT SPI pins and a pure-Python :class:`~sim_models.spi_slave.SpiPinSlave`.

It wakes only on CS, SCK and MOSI changes (never per clock), forwards the levels with the
simulated time in ps, and drives MISO with what the slave model returns; when the device does
not drive SO the pin is pulled up, as the integration requires (weak high 'H', read as '1' by the
master's input register; 'Z' would model a board without the pull-up). A violation raised by the
model fails the running cocotb test.

Each pin has its own watcher coroutine waiting on one ``ValueChange``: a ``First`` over the
three triggers would start and cancel a task per trigger on every edge, which made the bridge
the largest cost of the system simulations (three times the Python time of everything else).
The watchers hand a model error to :attr:`SpiPinBridge.task`, which raises it.
"""

from __future__ import annotations

import cocotb
from cocotb.handle import SimHandleBase
from cocotb.triggers import Event, ValueChange
from cocotb.types import Logic

from sim_models.spi_slave import SpiPinSlave, SpiViolation
from tb.tblib.model_clock import sim_time_ps


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
        released: str = "H",
    ) -> None:
        """``released``: the level of SO when the slave does not drive it, 'H' (the board's
        pull-up, the default) or 'Z' (no pull-up: lets a bench see where the slave releases SO,
        which the master's input register then reads as 'X')."""
        self.slave = slave
        self._released = Logic(released)
        self._cs_n = cs_n
        self._sck = sck
        self._mosi = mosi
        self._miso = miso
        self._miso.value = self._released
        #: levels and time of the last update (two pins changing together wake two watchers)
        self._last: tuple[int, int, int, int] | None = None
        self._error: BaseException | None = None
        #: the model only sees transfers that start after it was attached: a bridge created
        #: while CS is low (a transfer of the DUT that began before this test's model existed,
        #: e.g. between two tests of one simulation) ignores the pins until CS has risen
        cs_now = cs_n.value
        self._armed = cs_now.is_resolvable and int(cs_now) == 1
        self._failed = Event()
        self._watchers = [cocotb.start_soon(self._watch(sig)) for sig in (cs_n, sck, mosi)]
        #: the bridge coroutine: ends with the error the model raised (a test may await it to
        #: catch a violation); it never ends otherwise
        self.task = cocotb.start_soon(self._run())

    def stop(self) -> None:
        for w in self._watchers:
            w.cancel()
        self.task.cancel()

    def _level(self, sig: SimHandleBase, what: str, t_ps: int) -> int:
        v = sig.value
        if not v.is_resolvable:
            raise SpiViolation(f"SPI violation at {t_ps / 1e6:.4f} us: {what} is '{v}'")
        return int(v)

    async def _run(self) -> None:
        await self._failed.wait()
        assert self._error is not None
        raise self._error

    async def _watch(self, sig: SimHandleBase) -> None:
        while self._error is None:
            await ValueChange(sig)
            if self._error is not None:
                return
            try:
                self._on_change()
            except Exception as e:  # handed to self.task, which raises it
                self._error = e
                self._failed.set()

    def _on_change(self) -> None:
        cs_n, sck, mosi = self._cs_n, self._sck, self._mosi
        t_ps = sim_time_ps()
        c = self._level(cs_n, "CS", t_ps)
        if not self._armed:
            if c == 0:
                return
            self._armed = True
        s = self._level(sck, "SCK", t_ps)
        if c == 0 or mosi.value.is_resolvable:
            m = self._level(mosi, "MOSI", t_ps)
        else:
            m = self.slave._mosi  # MOSI may float while CS is high
        key = (t_ps, c, s, m)
        if key == self._last:
            return
        self._last = key
        self.slave.update(t_ps, cs_n=c, sck=s, mosi=m)
        out = self.slave.miso
        self._miso.value = self._released if out is None else out
