"""Small pieces several benches share: a bus node that hands received frames to the bench,
and a recorder of the DUT's one-cycle event strobes."""

from __future__ import annotations

from collections.abc import Callable

import can
import cocotb
from cocotb.handle import SimHandleBase
from cocotb.triggers import ValueChange

from sim_models.can_bus import QueueNode
from tb.tblib.model_clock import sim_time_ps


class ForwardingNode(QueueNode):
    """A ``QueueNode`` that also calls ``on_frame(msg)`` for every frame it receives: the bench's
    stand-in for the master's CAN controller when a service block is tested alone."""

    def __init__(self, name: str, bitrate_bps: int, on_frame: Callable[[can.Message], None]):
        super().__init__(name, bitrate_bps)
        self._on_frame = on_frame

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        super().on_rx(msg, t_ps)
        self._on_frame(msg)


class StrobeMonitor:
    """Records ``(t_ps, value)`` each time one of the DUT's strobe outputs is non-zero.

    ``events[name]`` for every ``<name>_o`` signal given; wakes on value changes only.
    """

    def __init__(self, dut: SimHandleBase, names: list[str]) -> None:
        self.events: dict[str, list[tuple[int, int]]] = {n: [] for n in names}
        for n in names:
            cocotb.start_soon(self._watch(n, getattr(dut, f"{n}_o")))

    async def _watch(self, name: str, sig: SimHandleBase) -> None:
        while True:
            await ValueChange(sig)
            v = sig.value
            if v.is_resolvable and int(v):
                self.events[name].append((sim_time_ps(), int(v)))
