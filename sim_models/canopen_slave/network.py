"""A :class:`canopen.Network` that lives in simulated time.

The python ``canopen`` library normally talks to a python-can bus through a
:class:`can.Notifier` thread and sends periodic frames with python-can's wall-clock
broadcast manager. Here neither exists: :class:`SimNetwork` has no bus, ``send_message()``
hands the frame to the owning slave's TX queue, ``notify()`` is called by the slave for every
received frame, and ``send_periodic()`` returns a :class:`SimPeriodicTask` driven by the
simulation scheduler on the slave's local clock.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import can
import canopen

from sim_models.canopen_slave.timers import LocalTimer

if TYPE_CHECKING:  # pragma: no cover
    from sim_models.canopen_slave.slave import CanopenSlave

__all__ = ["SimNetwork", "SimPeriodicTask", "make_message"]


def make_message(can_id: int, data: bytes | bytearray | list[int] | None,
                 remote: bool = False, dlc: int | None = None) -> can.Message:
    """A classical CAN frame; ids above 0x7FF become extended frames (as the library does)."""
    payload = bytes(data or b"")
    if remote:
        return can.Message(arbitration_id=can_id, is_extended_id=can_id > 0x7FF,
                           is_remote_frame=True, dlc=len(payload) if dlc is None else dlc)
    return can.Message(arbitration_id=can_id, is_extended_id=can_id > 0x7FF, data=payload,
                       dlc=len(payload))


class SimPeriodicTask:
    """Sim-time replacement of :class:`canopen.network.PeriodicMessageTask`.

    Sends ``can_id``/``data`` every ``period`` seconds of the slave's local clock, first frame
    after one period. ``stop()`` and ``update(data)`` behave like the library's task.
    """

    def __init__(self, slave: CanopenSlave, can_id: int, data: Any, period: float,
                 remote: bool = False) -> None:
        self._slave = slave
        self.can_id = can_id
        self.data = bytes(data or b"")
        self.remote = remote
        self.period = period
        period_ps = round(period * 1e12)
        self._timer = LocalTimer(slave.sched, slave.clock, self._fire)
        self._timer.start(period_ps)

    def _fire(self, _k: int) -> None:
        self._slave.queue_frame(make_message(self.can_id, self.data, self.remote))

    def stop(self) -> None:
        self._timer.stop()

    def update(self, data: Any) -> None:
        self.data = bytes(data or b"")


class SimNetwork(canopen.Network):
    """``canopen.Network`` without a python-can bus, owned by one :class:`CanopenSlave`."""

    def __init__(self, slave: CanopenSlave) -> None:
        super().__init__(bus=None)
        self._slave = slave
        #: frames the library asked to send (can_id, data, remote), for debugging
        self.sent_by_library = 0

    def connect(self, *args: Any, **kwargs: Any) -> SimNetwork:
        raise RuntimeError("SimNetwork has no python-can bus; frames go through the CanBus model")

    def disconnect(self) -> None:
        """Nothing to shut down (no bus, no notifier thread)."""

    def check(self) -> None:
        """No notifier thread whose exception could be re-raised."""

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        self.sent_by_library += 1
        self._slave.queue_frame(make_message(can_id, bytes(data or b""), remote))

    def send_periodic(self, can_id: int, data: Any, period: float,
                      remote: bool = False) -> SimPeriodicTask:  # type: ignore[override]
        return SimPeriodicTask(self._slave, can_id, data, period, remote)
