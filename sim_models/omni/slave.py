"""Omni-ID reference slave: a drifting sampled-data node with the thesis' re-synchronisation.

:class:`OmniSlave` is a :class:`~sim_models.can_bus.CanNode` that speaks the NCTU thesis'
application protocol (``sim_models.omni.codec``) and runs a local sample loop on its own
oscillator (:class:`~sim_models.can_bus.NodeClock` through
:class:`~sim_models.canopen_slave.timers.LocalTimer`), so that data dropout caused by clock drift
(thesis Eq 2-2 / 2-3) and its removal by re-synchronisation can be measured exactly. The slave
only looks at frames on the bus; it does not know who the master is.

Behaviour (digest §2.3, §3.4, §6):

* two NMT states, stopped (power-up default) and started; NMT ``[target][1|0]`` on id 0;
* a node query (RTR id 0) is answered with an RTR carrying the own node id, in both states;
* parameter frames (fc 111 addressed to this node) are stored by data type (A4);
* every broadcast from the master (fc 001 or 100, node field = master id) updates the set-point
  with this node's slot (A1);
* when started, a tick every ``period_ps`` of local time: the current set-point is sampled and
  recorded as an :class:`OmniTick`, and a feedback frame is queued (fc per node, Table 4-2).

Which command a sample needs (the thesis' dropout definition, Eq 2-2): the master's command of
cycle ``c`` carries :func:`setpoint_value` ``(c, axis)``. Sample ``n`` (the n-th tick since NMT
start, counted through every re-phase) needs the command of cycle ``n + cycle_offset``; it is a
dropout when the sampled value is not that cycle's value (stale, missing or too new).

Re-synchronisation (``resync``):

* ``"none"``: free-running grid from NMT start (first tick ``start_delay_ps`` after it).
* ``"thesis"`` (digest §3.4, Fig 3-19): after tick ``n`` with ``(n + 1) % K == 0`` the timer is
  stopped and the slave is *armed*; the next broadcast from the master is sample ``n + 1``
  (taken ``sample_phase_ps`` after its reception, 0 = inside the reception interrupt as in the
  thesis) and the timer restarts from there (phase zeroed). With ``rephase_at_start`` the
  slave is armed at NMT start, so sample 0 is the first broadcast.
* ``"sync_frame"`` (option ii, A6): every Omni SYNC (id 0x080) re-anchors the grid at its
  reception + ``sample_phase_ps``. If the slave's last tick lies within half a period before
  that grid point (a fast slave already sampled this cycle) the next tick is one period later,
  otherwise the pending tick is pulled in to the grid point.

Times are true picoseconds unless a field says local. Reception time = end of frame (the bus'
``on_rx`` time) + ``t_post_ps`` of local time.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from sim_models.can_bus import CanNode, NodeClock, arbitration_bits
from sim_models.canopen_slave.slave import ControlTick
from sim_models.canopen_slave.timers import LocalTimer, true_after_local
from sim_models.omni import codec as oc
from sim_models.sim_time import Scheduler

__all__ = [
    "FEEDBACK_DLC",
    "RESYNC_MODES",
    "OmniSlave",
    "OmniTick",
    "clock_for_period_error",
    "setpoint_value",
]

RESYNC_MODES = ("none", "thesis", "sync_frame")
#: DLC of the feedback frame: ``[own id][type 0x00][echo int16][sample index uint16]``
FEEDBACK_DLC = 6


def setpoint_value(cycle: int, axis: int, width: int = 1) -> int:
    """The set-point the reference master sends to ``axis`` in cycle ``cycle``.

    ``(cycle + 37 * (axis - 1)) mod 2^(8·width)`` read as a signed ``width``-byte integer: it
    changes every cycle (so a stale or early value is recognised) and differs between axes (so
    a wrong slot is recognised). It repeats after 256 (1-byte slots) or 65 536 cycles: a slave
    that is off by a whole multiple of that is not detected (documented limitation)."""
    bits = 8 * width
    raw = (cycle + 37 * (axis - 1)) % (1 << bits)
    return raw - (1 << bits) if raw >= 1 << (bits - 1) else raw


def clock_for_period_error(rho_ppm: float, phase_ps: int = 0) -> NodeClock:
    """Clock whose periods last ``(1 + rho·1e-6)`` times the nominal in true time.

    The digest writes drift as a *period error* ρ (positive: the slave's period is longer, its
    ticks lag more and more, as measured in the thesis: +3618 ppm). ``NodeClock`` takes a
    *frequency* offset; a local period ``P`` lasts ``P / (1 + ppm·1e-6)``, hence
    ``ppm = -ρ / (1 + ρ)`` (exact in float to well below 1e-12)."""
    rho = rho_ppm * 1e-6
    return NodeClock(ppm=-rho / (1.0 + rho) * 1e6, phase_ps=phase_ps)


@dataclass(frozen=True)
class OmniTick(ControlTick):
    """One sample of an :class:`OmniSlave` (fields of ``ControlTick`` plus the dropout decision).

    ``tick`` is the sample index since NMT start (not reset by a re-phase); ``epoch`` counts
    the re-phases before it; ``value`` is this node's slot of the last broadcast."""

    expected_cycle: int  #: master cycle whose command this sample needs
    dropout: bool | None  #: value != that cycle's set-point; None when expected_cycle < 0
    rephase: bool  #: this tick was placed by a re-phase event (reference frame)


class OmniSlave(CanNode):
    """Omni-ID slave with a drifting local sample loop. See the module docstring.

    Args:
        sched: the simulation scheduler.
        node_id: 1..255 (A13); the thesis' slaves are 0x04, 0x08, 0x10, 0x20.
        bitrate_bps: controller bit rate (must match the bus).
        period_ps: sample period T_s in local time.
        clock: the node's oscillator (see :func:`clock_for_period_error`).
        master_id: node field of the broadcasts this slave obeys (thesis 0x02).
        axis: 1-based slot in the broadcast (default: index of ``node_id`` in the thesis ids).
        feedback_fc: function code of the feedback frame (default per Table 4-2).
        broadcast_fc: which broadcast class carries the set-point (fc 001 or fc 100).
        broadcast_with_sender: layout of fc 001 (A1); None = with sender byte.
        feedback: queue a feedback frame at every tick while started.
        resync: ``"none"`` | ``"thesis"`` | ``"sync_frame"``.
        resync_k: K of the thesis mode (every K-th tick arms the re-phase).
        sample_phase_ps: local time from the reference reception to the re-phased tick.
        start_delay_ps: local time from NMT start reception to tick 0 (default one period).
        rephase_at_start: thesis mode: sample 0 is the first broadcast after NMT start.
        cycle_offset: sample n needs cycle n + cycle_offset; default -1 for ``sync_frame``
            (the tick at the SYNC samples the command sent in the previous cycle, CANopen
            style) and 0 otherwise (the tick samples the command of its own cycle).
        t_post_ps: local time from end of frame to the reception timestamp (thesis T_post).
        value_fn: ``(cycle, axis) -> set-point``; default :func:`setpoint_value`.
    """

    def __init__(self, sched: Scheduler, node_id: int, *, bitrate_bps: int, period_ps: int,
                 clock: NodeClock | None = None, name: str | None = None,
                 master_id: int = oc.THESIS_MASTER_ID, axis: int | None = None,
                 feedback_fc: int | None = None, broadcast_fc: int = oc.FC_BCAST_8X1,
                 broadcast_with_sender: bool | None = None, feedback: bool = True,
                 resync: str = "none", resync_k: int = 10, sample_phase_ps: int = 0,
                 start_delay_ps: int | None = None, rephase_at_start: bool = True,
                 cycle_offset: int | None = None, t_post_ps: int = 0,
                 value_fn: Callable[[int, int], int] | None = None) -> None:
        if not 1 <= node_id <= 255:
            raise ValueError(f"node_id {node_id} out of range 1..255")
        if resync not in RESYNC_MODES:
            raise ValueError(f"resync must be one of {RESYNC_MODES}, got {resync!r}")
        if period_ps <= 0 or resync_k < 1:
            raise ValueError("period_ps and resync_k must be positive")
        if not 0 <= sample_phase_ps < period_ps:
            raise ValueError("sample_phase_ps must lie in [0, period_ps)")
        super().__init__(name or f"omni{node_id:02x}", clock)
        self.sched = sched
        self.node_id = node_id
        self.bitrate_bps = int(bitrate_bps)
        self.period_ps = int(period_ps)
        self.master_id = master_id
        if axis is None:
            if node_id not in oc.THESIS_SLAVE_IDS:
                raise ValueError("axis must be given for a node id outside the thesis' ids")
            axis = oc.THESIS_SLAVE_IDS.index(node_id) + 1
        self.axis = axis
        if feedback_fc is None and feedback:
            if node_id not in oc.THESIS_FEEDBACK_FC:
                raise ValueError("feedback_fc must be given for a node id outside Table 4-2")
            feedback_fc = oc.THESIS_FEEDBACK_FC[node_id]
        self.feedback_fc = feedback_fc
        self.broadcast_fc = broadcast_fc
        self.broadcast_with_sender = broadcast_with_sender
        _, self.slot_width, _ = oc.slot_layout(broadcast_fc, broadcast_with_sender)
        self.feedback = feedback
        self.resync_mode = resync  #: "none" | "thesis" | "sync_frame" (resync() is the method)
        self.resync_k = int(resync_k)
        self.sample_phase_ps = int(sample_phase_ps)
        self.start_delay_ps = self.period_ps if start_delay_ps is None else int(start_delay_ps)
        self.rephase_at_start = rephase_at_start
        if cycle_offset is None:
            cycle_offset = -1 if resync == "sync_frame" else 0
        self.cycle_offset = cycle_offset
        self.t_post_ps = int(t_post_ps)
        width = self.slot_width
        self.value_fn = value_fn or (lambda c, a: setpoint_value(c, a, width))

        # --- records (public, append-only; true ps unless local) ------------------------------
        #: (t_ps, msg) every frame received (t = end of EOF, before T_post)
        self.rx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, msg) own frames sent (t = end of EOF)
        self.tx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, started) every NMT state change
        self.state_log: list[tuple[int, bool]] = []
        #: every sample
        self.control_log: list[OmniTick] = []
        #: (t_ps, t_local_ps, cause) every re-phase ("thesis" / "sync_frame" / "resync")
        self.rephase_log: list[tuple[int, int, str]] = []
        #: (t_ps, dtype, content) every parameter frame accepted
        self.param_log: list[tuple[int, int, bytes]] = []
        #: data type -> content bytes of the last parameter frame of that type
        self.parameters: dict[int, bytes] = {}
        #: (t_ps) every node query answered
        self.query_log: list[int] = []
        #: (t_ps, msg, reason) frames addressed to this node that were not understood
        self.rejected: list[tuple[int, can.Message, str]] = []
        #: called as fn(slave, tick) after every sample
        self.control_listeners: list[Callable[[OmniSlave, OmniTick], Any]] = []

        self._started = False
        self._txq: list[tuple[tuple[int, ...], int, can.Message]] = []
        self._txseq = itertools.count()
        self._timer = LocalTimer(sched, self.clock, self._on_timer)
        self._n = 0
        self._epoch = 0
        self._armed = False
        self._next_is_rephase = False
        self._last_tick_local: int | None = None
        self._sp_value: int | None = None
        self._sp_t: int | None = None
        self._sp_arrivals = 0

    # =====================================================================================
    # public API
    # =====================================================================================

    @property
    def started(self) -> bool:
        return self._started

    @property
    def armed(self) -> bool:
        """Thesis mode: waiting for the next broadcast to place the next sample."""
        return self._armed

    @property
    def tx_queue(self) -> list[can.Message]:
        return [e[2] for e in self._txq]

    def resync(self) -> None:
        """Re-anchor the tick grid now (the ``sync_frame`` rule), e.g. from a test."""
        if self._started:
            self._rephase_grid("resync")

    def queue_frame(self, msg: can.Message) -> None:
        """TX queue: id priority, FIFO among equal ids."""
        bisect.insort(self._txq, (arbitration_bits(msg), next(self._txseq), msg))
        if self.bus is not None:
            self.bus.request_tx(self)

    # =====================================================================================
    # CanNode hooks
    # =====================================================================================

    def tx_candidate(self) -> can.Message | None:
        return self._txq[0][2] if self._txq else None

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        for i, entry in enumerate(self._txq):
            if entry[2] is msg:
                del self._txq[i]
                break
        self.tx_log.append((t_ps, msg))

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        self.rx_log.append((t_ps, msg))
        if msg.is_extended_id:
            return
        if self.t_post_ps > 0:
            t = true_after_local(self.sched, self.clock, self.t_post_ps)
            self.sched.call_at(t, self._process, msg)
        else:
            self._process(msg)

    # =====================================================================================
    # reception
    # =====================================================================================

    def _process(self, msg: can.Message) -> None:
        now = self.sched.now_ps
        can_id = msg.arbitration_id
        if oc.is_omni_sync(msg):
            if self._started and self.resync_mode == "sync_frame":
                self._rephase_grid("sync_frame")
            return
        if can_id == 0:
            if msg.is_remote_frame:
                self.query_log.append(now)
                self.queue_frame(oc.query_reply_frame(self.node_id))
            else:
                self._on_nmt(msg)
            return
        if msg.is_remote_frame:
            return  # another node's query reply
        fc, node = oc.decode_id(can_id)
        if fc == self.broadcast_fc and node == self.master_id:
            self._on_broadcast(msg)
        elif fc == oc.FC_PARAM and node == self.node_id:
            try:
                frame = oc.parse_data_frame(msg)
            except oc.OmniFrameError as exc:
                self.rejected.append((now, msg, str(exc)))
                return
            self.parameters[frame.dtype] = frame.content
            self.param_log.append((now, frame.dtype, frame.content))

    def _on_nmt(self, msg: can.Message) -> None:
        try:
            target, state = oc.parse_nmt(msg)
        except oc.OmniFrameError as exc:
            if msg.dlc >= 1 and msg.data[0] in (0, self.node_id):
                self.rejected.append((self.sched.now_ps, msg, str(exc)))
            return
        if target not in (0, self.node_id):
            return
        if state == oc.NMT_START and not self._started:
            self._start()
        elif state == oc.NMT_STOP and self._started:
            self._stop()

    def _on_broadcast(self, msg: can.Message) -> None:
        try:
            bc = oc.parse_broadcast(msg, self.broadcast_with_sender)
        except oc.OmniFrameError as exc:
            self.rejected.append((self.sched.now_ps, msg, str(exc)))
            return
        if len(bc.values) < self.axis:
            self.rejected.append((self.sched.now_ps, msg, f"no slot for axis {self.axis}"))
            return
        self._sp_value = bc.values[self.axis - 1]
        self._sp_t = self.sched.now_ps
        self._sp_arrivals += 1
        if self._armed:
            self._armed = False
            self._epoch += 1
            self._next_is_rephase = True
            now = self.sched.now_ps
            self.rephase_log.append((now, self.clock.local_ps(now), "thesis"))
            self._timer.start(self.period_ps, self.sample_phase_ps)

    # =====================================================================================
    # NMT states and the sample loop
    # =====================================================================================

    def _start(self) -> None:
        self._started = True
        self.state_log.append((self.sched.now_ps, True))
        self._n = 0
        self._epoch = 0
        self._last_tick_local = None
        self._sp_value, self._sp_t, self._sp_arrivals = None, None, 0
        if self.resync_mode == "thesis" and self.rephase_at_start:
            self._armed = True
        else:
            self._timer.start(self.period_ps, self.start_delay_ps)

    def _stop(self) -> None:
        self._started = False
        self._armed = False
        self._timer.stop()
        self.state_log.append((self.sched.now_ps, False))

    def _rephase_grid(self, cause: str) -> None:
        now = self.sched.now_ps
        now_local = self.clock.local_ps(now)
        grid = now_local + self.sample_phase_ps
        first = self.sample_phase_ps
        if (self._last_tick_local is not None
                and grid - self._last_tick_local < self.period_ps // 2):
            first += self.period_ps  # this cycle was already sampled (fast slave)
        self._epoch += 1
        self._next_is_rephase = True
        self.rephase_log.append((now, now_local, cause))
        self._timer.start(self.period_ps, first)

    def _on_timer(self, _k: int) -> None:
        self._tick()
        if self.resync_mode == "thesis" and self._n % self.resync_k == 0:
            self._timer.stop()
            self._armed = True

    def _tick(self) -> None:
        t = self.sched.now_ps
        t_local = self.clock.local_ps(t)
        n = self._n
        self._n += 1
        arrivals = self._sp_arrivals
        self._sp_arrivals = 0
        status = "new" if arrivals == 1 else "overwritten" if arrivals > 1 else "missing"
        expected = n + self.cycle_offset
        dropout: bool | None = None
        if expected >= 0:
            dropout = self._sp_value is None or self._sp_value != self.value_fn(expected,
                                                                                self.axis)
        rephase, self._next_is_rephase = self._next_is_rephase, False
        tick = OmniTick(n, self._epoch, t, t_local, self._sp_value, self._sp_t, status,
                        arrivals, expected, dropout, rephase)
        self._last_tick_local = t_local
        self.control_log.append(tick)
        if self.feedback and self.feedback_fc is not None:
            echo = 0 if self._sp_value is None else self._sp_value
            content = (echo & 0xFFFF).to_bytes(2, "big") + (n & 0xFFFF).to_bytes(2, "big")
            self.queue_frame(oc.data_frame(self.feedback_fc, self.master_id, self.node_id,
                                           oc.DTYPE_FEEDBACK, content))
        for fn in list(self.control_listeners):
            fn(self, tick)
