"""Put the MCP2510 model (:class:`sim_models.mcp2510.chip.Mcp2510`) on a DUT's pins.

* SPI: CS/SCK/MOSI are decoded by :class:`~sim_models.spi_slave.SpiPinSlave` with the MCP2510
  timing spec, which drives MISO from the chip's byte-level interface.
* INT, RX0BF, RX1BF: driven from the chip's pin properties whenever they may have changed.
* TX0RTS..TX2RTS and RESET: sampled on change and forwarded to the chip.

The adapter only wakes on pin edges (never per clock); the models' own events run through
:class:`tb.tblib.model_clock.ModelClock`.
"""

from __future__ import annotations

import cocotb
from cocotb.handle import SimHandleBase
from cocotb.triggers import ValueChange

from sim_models.mcp2510.chip import Mcp2510
from sim_models.spi_slave import SpiPinSlave, SpiTimingSpec
from tb.tblib.model_clock import ModelClock
from tb.tblib.spi_pins import SpiPinBridge


class _SyncedDevice:
    """Byte-level view of the chip that first brings the models up to the current time."""

    def __init__(self, chip: Mcp2510, clock: ModelClock) -> None:
        self.chip = chip
        self.clock = clock

    def spi_select(self, t_ps: int) -> None:
        self.clock.sync()
        self.chip.spi_select(t_ps)

    def spi_out_byte(self) -> int | None:
        return self.chip.spi_out_byte()

    def spi_in_byte(self, value: int, t_ps: int) -> None:
        self.clock.sync()
        self.chip.spi_in_byte(value, t_ps)

    def spi_deselect(self, t_ps: int, partial_bits: int = 0) -> None:
        self.clock.sync()
        self.chip.spi_deselect(t_ps, partial_bits)


class Mcp2510Pins:
    """Connect ``chip`` to the DUT signals; any signal may be None when the DUT lacks it."""

    def __init__(
        self,
        chip: Mcp2510,
        clock: ModelClock,
        *,
        cs_n: SimHandleBase,
        sck: SimHandleBase,
        mosi: SimHandleBase,
        miso: SimHandleBase,
        int_n: SimHandleBase | None = None,
        rx0bf_n: SimHandleBase | None = None,
        rx1bf_n: SimHandleBase | None = None,
        txrts_n: SimHandleBase | None = None,
        reset_n: SimHandleBase | None = None,
        spec: SpiTimingSpec | None = None,
        released: str = "H",
    ) -> None:
        self.chip = chip
        self.clock = clock
        self.slave = SpiPinSlave(_SyncedDevice(chip, clock), spec or SpiTimingSpec(),
                                 name=f"{chip.name}.spi")
        self.spi = SpiPinBridge(self.slave, cs_n=cs_n, sck=sck, mosi=mosi, miso=miso,
                                released=released)
        self._int_n, self._rx0bf_n, self._rx1bf_n = int_n, rx0bf_n, rx1bf_n
        chip.on_pins_changed = self._drive_outputs
        self._drive_outputs()
        self._tasks = []
        if txrts_n is not None:
            self._tasks.append(cocotb.start_soon(self._watch_txrts(txrts_n)))
        if reset_n is not None:
            self._tasks.append(cocotb.start_soon(self._watch_reset(reset_n)))

    def _drive_outputs(self) -> None:
        for sig, level in ((self._int_n, self.chip.int_n), (self._rx0bf_n, self.chip.rx0bf_n),
                           (self._rx1bf_n, self.chip.rx1bf_n)):
            if sig is not None:
                sig.value = level

    async def _watch_txrts(self, txrts_n: SimHandleBase) -> None:
        last = [1, 1, 1]
        while True:
            await ValueChange(txrts_n)
            t_ps = self.clock.sync()
            v = txrts_n.value
            for n in range(3):
                level = int(v[n]) if v[n].is_resolvable else 1
                if level != last[n]:
                    last[n] = level
                    self.chip.set_txrts_n(n, level, t_ps)

    async def _watch_reset(self, reset_n: SimHandleBase) -> None:
        while True:
            await ValueChange(reset_n)
            if reset_n.value.is_resolvable and int(reset_n.value) == 0:
                self.chip.reset_pin(self.clock.sync())

    def stop(self) -> None:
        self.spi.stop()
        for t in self._tasks:
            t.cancel()
