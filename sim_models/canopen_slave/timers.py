"""Timers that run on a node's local oscillator (:class:`~sim_models.can_bus.NodeClock`).

A slave measures every period (heartbeat, event timer, inhibit time, control loop) with its own
clock: a period of ``P`` local picoseconds lasts ``P / (1 + ppm * 1e-6)`` true picoseconds. The
k-th expiry of a periodic timer started at true time ``t0`` is scheduled at
``clock.true_ps(clock.local_ps(t0) + first + k * period)``, computed from the anchor each time,
so rounding never accumulates.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sim_models.can_bus import NodeClock
from sim_models.sim_time import EventHandle, Scheduler

__all__ = ["LocalTimer", "true_after_local"]


def true_after_local(sched: Scheduler, clock: NodeClock, dt_local_ps: int) -> int:
    """True time at which ``dt_local_ps`` of local time has elapsed from now (never < now)."""
    if dt_local_ps < 0:
        raise ValueError(f"negative local delay {dt_local_ps} ps")
    now = sched.now_ps
    return max(now, clock.true_ps(clock.local_ps(now) + int(dt_local_ps)))


class LocalTimer:
    """One-shot or periodic callback measured on a local clock.

    ``start(period, first)`` anchors the timer at the current instant: expiry ``k`` (k = 0, 1,
    ...) happens at local time ``anchor + first + k * period`` (``first`` defaults to
    ``period``; ``period`` None = one-shot). ``fn(k)`` receives the expiry index. ``stop()``
    cancels; starting again re-anchors.
    """

    def __init__(self, sched: Scheduler, clock: NodeClock, fn: Callable[[int], Any]) -> None:
        self.sched = sched
        self.clock = clock
        self.fn = fn
        self._handle: EventHandle | None = None
        self._anchor_local = 0
        self._first = 0
        self._period: int | None = None
        self._k = 0

    @property
    def active(self) -> bool:
        """A future expiry is scheduled."""
        return self._handle is not None and self._handle.pending

    @property
    def period_local_ps(self) -> int | None:
        return self._period

    @property
    def anchor_local_ps(self) -> int:
        """Local time at which the timer was (re)started."""
        return self._anchor_local

    def expiry_true_ps(self, k: int) -> int:
        """True time of expiry ``k`` of the current run (whether or not it is still pending)."""
        period = self._period or 0
        local = self._anchor_local + self._first + k * period
        return self.clock.true_ps(local)

    def start(self, period_local_ps: int | None, first_local_ps: int | None = None) -> None:
        """(Re)start at the current instant. ``first_local_ps`` may be 0 (expire now)."""
        self.stop()
        if period_local_ps is not None and period_local_ps <= 0:
            raise ValueError(f"period must be positive, got {period_local_ps}")
        first = period_local_ps if first_local_ps is None else first_local_ps
        if first is None or first < 0:
            raise ValueError("a one-shot timer needs first_local_ps >= 0")
        self._anchor_local = self.clock.local_ps(self.sched.now_ps)
        self._first = int(first)
        self._period = None if period_local_ps is None else int(period_local_ps)
        self._k = 0
        self._arm()

    def stop(self) -> None:
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _arm(self) -> None:
        t = max(self.sched.now_ps, self.expiry_true_ps(self._k))
        self._handle = self.sched.call_at(t, self._fire)

    def _fire(self) -> None:
        k = self._k
        self._handle = None
        if self._period is not None:
            self._k += 1
            self._arm()
        self.fn(k)
