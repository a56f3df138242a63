"""Advance the Python models' :class:`~sim_models.sim_time.Scheduler` in step with HDL time.

One coroutine sleeps (cocotb ``Timer``) until the scheduler's next event, runs everything due,
and sleeps again. When a model schedules something earlier than the current wake-up time (for
example the MCP2510 model asking the bus for an arbitration round right after an RTS), the
scheduler's ``on_new_earliest`` hook wakes the coroutine so it re-plans. Pin adapters call
:meth:`ModelClock.sync` before they touch a model, so models always see the current time.
"""

from __future__ import annotations

import cocotb
from cocotb.triggers import Event, First, Timer
from cocotb.utils import get_sim_time

from sim_models.sim_time import Scheduler


def sim_time_ps() -> int:
    """Current simulated time as an integer number of ps (cocotb returns a float)."""
    return round(get_sim_time("ps"))


class ModelClock:
    def __init__(self, sched: Scheduler) -> None:
        self.sched = sched
        self._wake = Event()
        sched.on_new_earliest = self._wake.set
        self._task = cocotb.start_soon(self._run())

    def sync(self) -> int:
        """Run every model event due up to now; returns now in ps."""
        now = sim_time_ps()
        if now > self.sched.now_ps:
            self.sched.run_until(now)
        return now

    def stop(self) -> None:
        self._task.cancel()
        self.sched.on_new_earliest = None

    async def _run(self) -> None:
        while True:
            now = self.sync()
            nxt = self.sched.next_event_ps()
            self._wake.clear()
            if nxt is None:
                await self._wake.wait()
            elif nxt <= now:
                self.sched.run_until(now)  # due at this very instant
                await Timer(1, "ps")
            else:
                await First(Timer(nxt - now, "ps"), self._wake.wait())
