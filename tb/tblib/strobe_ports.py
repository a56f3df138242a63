"""Cycle-by-cycle input driving for unit benches that play an entity's neighbours.

Inputs change at falling edges only (never in the time step of an active edge). Names listed as
strobes are single-cycle pulses or "being in a state" levels that the caller sets for the cycles
of one call: they return to 0 after it, so a test states only what is active in a cycle.
"""

from __future__ import annotations

from collections.abc import Iterable

from cocotb.handle import SimHandleBase
from cocotb.triggers import FallingEdge


class StrobePorts:
    """Drive ``dut`` inputs at the falling edges of ``clk``; ``strobes`` fall back to 0."""

    def __init__(self, dut, clk: SimHandleBase, strobes: Iterable[str]) -> None:
        self.dut = dut
        self.clk = clk
        self.strobes = frozenset(strobes)

    def apply(self, **inputs: int) -> None:
        for name, value in inputs.items():
            getattr(self.dut, name).value = value

    def zero(self, *names: str) -> None:
        for name in names:
            getattr(self.dut, name).value = 0

    def release(self, names: Iterable[str]) -> None:
        """Strobes among ``names`` back to 0 (levels that are not strobes keep their value)."""
        self.zero(*(name for name in names if name in self.strobes))

    def out(self, name: str) -> int:
        return int(getattr(self.dut, name).value)

    async def step(self, n: int = 1, **inputs: int) -> None:
        """Hold ``inputs`` for ``n`` clock edges (set at a falling edge), then release strobes."""
        self.apply(**inputs)
        for _ in range(n):
            await FallingEdge(self.clk)
        self.release(inputs)
