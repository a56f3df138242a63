"""Clock and reset helpers shared by all benches."""

from __future__ import annotations

from cocotb.clock import Clock
from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, RisingEdge

# cocotb's GPI clock outlives the test that started it: keep one per signal so that the next
# test in the same simulation replaces it instead of adding a second, phase-shifted driver.
_clocks: dict[str, Clock] = {}


def start_clock(clk: SimHandleBase, freq_hz: int) -> int:
    """Start a cocotb (GPI) clock on ``clk``, replacing one left by an earlier test.

    Returns the period in ps, which must be a whole number so simulated-time figures are exact.
    """
    period_ps = 1_000_000_000_000 // freq_hz
    if period_ps * freq_hz != 1_000_000_000_000:
        raise ValueError(f"{freq_hz} Hz has no whole-ps period; pick another bench frequency")
    old = _clocks.pop(clk._path, None)
    if old is not None:
        old.stop()
    clock = Clock(clk, period_ps, unit="ps")
    clock.start()
    _clocks[clk._path] = clock
    return period_ps


async def reset_active_low(clk: SimHandleBase, rst_n: SimHandleBase, cycles: int = 5) -> None:
    """Assert ``rst_n`` for ``cycles`` clock cycles, release it after a rising edge."""
    rst_n.value = 0
    await ClockCycles(clk, cycles)
    await RisingEdge(clk)
    rst_n.value = 1
    await RisingEdge(clk)
