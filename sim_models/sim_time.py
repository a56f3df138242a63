"""Discrete-event scheduler shared by every Python model (bus, MCP2510, reference slaves).

Time is an integer number of picoseconds. A model never sleeps: it asks the scheduler to call
it back at a time (``call_at``/``call_later``). Outside a simulator a test drives the scheduler
with :meth:`Scheduler.run_until`; inside cocotb, ``tb/tblib/model_clock.py`` advances it in step
with the HDL simulator's time, so models and RTL share one time axis.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

PS_PER_NS = 1_000
PS_PER_US = 1_000_000
PS_PER_MS = 1_000_000_000
PS_PER_S = 1_000_000_000_000


@dataclass(order=True)
class _Event:
    t_ps: int
    seq: int
    fn: Callable[..., Any] = field(compare=False)
    args: tuple = field(compare=False, default=())
    cancelled: bool = field(compare=False, default=False)


class EventHandle:
    """Returned by ``call_at``; ``cancel()`` removes the event if it has not run yet."""

    __slots__ = ("_event",)

    def __init__(self, event: _Event) -> None:
        self._event = event

    @property
    def t_ps(self) -> int:
        return self._event.t_ps

    @property
    def pending(self) -> bool:
        return not self._event.cancelled

    def cancel(self) -> None:
        self._event.cancelled = True


class Scheduler:
    """Ordered event queue with a monotonic ``now_ps``.

    Events at the same time run in the order they were scheduled (FIFO), which makes every
    model run reproducible.
    """

    def __init__(self) -> None:
        self.now_ps: int = 0
        self._queue: list[_Event] = []
        self._seq = itertools.count()
        #: called (with no argument) whenever an event is scheduled earlier than the previous
        #: earliest one; the cocotb bridge uses it to shorten its current wait.
        self.on_new_earliest: Callable[[], None] | None = None

    def call_at(self, t_ps: int, fn: Callable[..., Any], *args: Any) -> EventHandle:
        if t_ps < self.now_ps:
            raise ValueError(f"cannot schedule in the past: {t_ps} ps < now {self.now_ps} ps")
        previous = self.next_event_ps()
        ev = _Event(int(t_ps), next(self._seq), fn, args)
        heapq.heappush(self._queue, ev)
        if self.on_new_earliest is not None and (previous is None or ev.t_ps < previous):
            self.on_new_earliest()
        return EventHandle(ev)

    def call_later(self, dt_ps: int, fn: Callable[..., Any], *args: Any) -> EventHandle:
        if dt_ps < 0:
            raise ValueError(f"negative delay {dt_ps} ps")
        return self.call_at(self.now_ps + int(dt_ps), fn, *args)

    def next_event_ps(self) -> int | None:
        """Time of the earliest pending event, or None when nothing is scheduled."""
        while self._queue and self._queue[0].cancelled:
            heapq.heappop(self._queue)
        return self._queue[0].t_ps if self._queue else None

    def run_until(self, t_ps: int) -> None:
        """Run every event with time <= ``t_ps`` in order, then set ``now_ps = t_ps``."""
        if t_ps < self.now_ps:
            raise ValueError(f"time cannot go backwards: {t_ps} ps < now {self.now_ps} ps")
        while True:
            nxt = self.next_event_ps()
            if nxt is None or nxt > t_ps:
                break
            ev = heapq.heappop(self._queue)
            self.now_ps = ev.t_ps
            ev.fn(*ev.args)
        self.now_ps = t_ps

    def run(self, max_ps: int) -> None:
        """Run until the queue is empty or ``now_ps`` would pass ``max_ps``."""
        while True:
            nxt = self.next_event_ps()
            if nxt is None or nxt > max_ps:
                return
            self.run_until(nxt)
