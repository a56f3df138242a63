"""Transaction-level Omni-ID master: the Python reference the RTL master is checked against.

:class:`OmniMaster` is a :class:`~sim_models.can_bus.CanNode` that runs the thesis' master
cycle (digest §3.4 "Platform MASTER", §6) on its own clock:

* ``start()``: NMT start to all (``00 01``); cycle 0 begins ``first_cycle_delay_ps`` later
  (default one period: the Fig 4-20 trace shows the first broadcast one period after NMT);
* cycle ``c`` at ``m_c = t_cycle0 + c·T_s`` (master's local time): the broadcast command whose
  slots carry :func:`~sim_models.omni.slave.setpoint_value` ``(c, axis)``; with
  ``sync_every = K`` the Omni SYNC (0x080, DLC 0) is queued first in every cycle with
  ``c % K == 0`` (option ii: SYNC at the cycle instant, the cycle's command right after it);
  a command still waiting for the bus at the next cycle instant is replaced by the new one
  (one TX buffer per message class, as the RTL will have; logged in ``aborted_log``);
* node query (RTR id 0) every ``query_every`` cycles, half a period after the cycle instant
  ("between two sampling periods"); one period later every expected node must have answered,
  otherwise the miss is logged and, with ``stop_on_missing``, NMT stop to all is sent and the
  cycles end (A11);
* ``send_parameter()``: fc 111 parameter frame ``[own id][type][value]``;
* as the thesis' master towards the PC: answers a node query with RTR 0x002, obeys NMT
  ``[02|00][1|0]`` and forwards a controller setting (type 0x0C) to every node of
  ``query_nodes`` as type 0x01 with a 2-byte value (Figs 4-18..4-20).

Before anything is sent the configuration is checked with :func:`check_feasibility` (AT-8),
the same rule as the RTL engine (``rtl/omni_engine.vhd``, OMNI_STATUS.INFEASIBLE /
OMNI_BUS_BITS): the worst-case bits of one cycle, broadcast + Omni SYNC (option ii) + one
frame per feedback slot, must fit in T_s. An infeasible configuration raises
:class:`InfeasibleConfiguration` unless ``allow_infeasible`` (used by the experiments that
show what happens then).
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Iterable
from dataclasses import dataclass

import can

from sim_models.can_bus import CanNode, NodeClock, arbitration_bits, worst_case_bits
from sim_models.canopen_slave.timers import LocalTimer
from sim_models.omni import codec as oc
from sim_models.omni.slave import setpoint_value
from sim_models.sim_time import PS_PER_S, Scheduler

__all__ = [
    "Feasibility",
    "InfeasibleConfiguration",
    "OmniMaster",
    "broadcast_dlc",
    "check_feasibility",
    "wc_bits",
]


class InfeasibleConfiguration(ValueError):
    """The periodic traffic does not fit in the sample period."""


def wc_bits(dlc: int) -> int:
    """Worst-case bits of a standard data frame with DLC ``dlc``, intermission included:
    :func:`~sim_models.can_bus.worst_case_bits` = 55 + 10·n; DLC 9..15 carry 8 bytes (ISO
    11898-1) and count as 8, as in the RTL's ``wc_of``."""
    if not 0 <= dlc <= 15:
        raise ValueError(f"DLC {dlc} out of range 0..15")
    return worst_case_bits(min(dlc, 8))


def broadcast_dlc(n_axes: int, fc: int = oc.FC_BCAST_8X1, with_sender: bool = True) -> int:
    """DLC of the broadcast the RTL engine sends for OMNI_CFG (N_AXES, BCAST_4X2, SENDER):
    fc 001: ``n_axes`` (+ 1 with the sender byte), 1..8 bytes; fc 100: ``2·n_axes``, the
    SENDER bit is ignored (no room, A1). Raises ``ValueError`` where the engine sets CFG_ERR
    (and OMNI_STATUS.INFEASIBLE): ``n_axes`` 0, more than 8 bytes, more than 4 axes of fc 100."""
    if fc == oc.FC_BCAST_4X2:
        with_sender = False
    offset, width, max_slots = oc.slot_layout(fc, with_sender)
    if not 1 <= n_axes <= max_slots:
        raise ValueError(f"{n_axes} axes: fc {fc:03b} {'with' if offset else 'without'} "
                         f"sender holds 1..{max_slots} (CFG_ERR)")
    return offset + width * n_axes


@dataclass(frozen=True)
class Feasibility:
    """Result of :func:`check_feasibility`: bit counts (OMNI_BUS_BITS = ``bits``) and times in
    ps (worst-case durations rounded up to whole ps)."""

    ok: bool
    reason: str
    bits: int  #: worst-case bits of one cycle (the RTL's OMNI_BUS_BITS)
    cmd_bits: int  #: broadcast (command) frame
    sync_bits: int  #: Omni SYNC (wc of DLC 0 = 55) or 0
    feedback_bits: int  #: sum over the feedback slots
    bitrate_bps: int
    margin_ps: int
    period_ps: int

    def _dur(self, bits: int) -> int:
        return -(-bits * PS_PER_S // self.bitrate_bps)

    @property
    def cmd_wc_ps(self) -> int:
        return self._dur(self.cmd_bits)

    @property
    def sync_ps(self) -> int:
        return self._dur(self.sync_bits)

    @property
    def busy_ps(self) -> int:
        """``bits · τ_bit``: the worst-case bus time of one cycle."""
        return self._dur(self.bits)

    @property
    def min_period_ps(self) -> int:
        """Smallest period that passes: ``bits · τ_bit + margin``."""
        return self.busy_ps + self.margin_ps


def check_feasibility(bitrate_bps: int, dlc: int, period_ps: int, *, sync: bool = False,
                      feedback_dlcs: Iterable[int] = (), margin_ps: int = 0) -> Feasibility:
    """The RTL engine's feasibility rule (docs/omni_engine.md "Feasibility"):

    ``bits = wc(dlc) [+ wc(0) for the Omni SYNC when sync] + Σ wc(d) for d in feedback_dlcs``
    with :func:`wc_bits` (worst-case stuffing, standard id, intermission included), and the
    cycle is feasible iff ``bits · τ_bit + margin_ps <= period_ps`` (exact integer arithmetic;
    ``τ_bit = 1 / bitrate_bps``). ``dlc`` is the broadcast's DLC as on the wire (sender byte
    included; :func:`broadcast_dlc`), ``feedback_dlcs`` the DLCs of the valid feedback slots.
    The RTL has no margin (``margin_ps`` = 0, the default); experiments may add one. The SYNC
    counts in every cycle (the worst case), whatever K is; node queries and replies are not
    counted (as in the RTL). Returns the reason either way."""
    if margin_ps < 0:
        raise ValueError("margin_ps must be >= 0")
    fb = [wc_bits(d) for d in feedback_dlcs]
    cmd_bits = wc_bits(dlc)
    sync_bits = wc_bits(0) if sync else 0
    bits = cmd_bits + sync_bits + sum(fb)
    ok = bits * PS_PER_S + margin_ps * bitrate_bps <= period_ps * bitrate_bps
    parts = f"command DLC {dlc} {cmd_bits}"
    if sync:
        parts += f" + SYNC {sync_bits}"
    if fb:
        parts += f" + feedback {'+'.join(map(str, fb))}"
    parts += f" = {bits} bits = {bits * PS_PER_S / bitrate_bps / 1e6:.1f} us"
    if margin_ps:
        parts += f" + margin {margin_ps / 1e6:.1f} us"
    verdict = (f"feasible at {bitrate_bps} bit/s: {parts} <= T_s" if ok else
               f"infeasible at {bitrate_bps} bit/s, DLC {dlc}: {parts} > T_s")
    return Feasibility(ok, f"{verdict} {period_ps / 1e6:.1f} us", bits, cmd_bits, sync_bits,
                       sum(fb), int(bitrate_bps), int(margin_ps), int(period_ps))


class OmniMaster(CanNode):
    """Reference Omni master. See the module docstring.

    Args:
        n_axes: number of slots in the broadcast.
        dlc: command frame length; None = the minimum for ``n_axes`` (fc 001 with sender
            byte: ``n_axes + 1``). A larger DLC is filled by slots of further (unused) axes.
        broadcast_fc / with_sender: broadcast class and layout (A1).
        sync_every: K of option ii (0 = no Omni SYNC).
        query_every: node query every M cycles (0 = never); ``query_nodes`` must answer.
        n_cycles: stop after this many cycles (None = run forever).
        feedback_dlcs: DLCs of the feedback frames one cycle carries (the RTL's valid node
            table slots), counted by :func:`check_feasibility`.
        margin_ps: feasibility margin (default 0, as the RTL).
        allow_infeasible: run even if :func:`check_feasibility` fails (experiments only).
    """

    def __init__(self, sched: Scheduler, *, bitrate_bps: int, period_ps: int,
                 node_id: int = oc.THESIS_MASTER_ID, clock: NodeClock | None = None,
                 name: str = "master", n_axes: int = 4, dlc: int | None = None,
                 broadcast_fc: int = oc.FC_BCAST_8X1, with_sender: bool | None = None,
                 sync_every: int = 0, query_every: int = 0,
                 query_nodes: tuple[int, ...] = (), stop_on_missing: bool = True,
                 first_cycle_delay_ps: int | None = None, n_cycles: int | None = None,
                 feedback_dlcs: tuple[int, ...] = (), margin_ps: int = 0,
                 allow_infeasible: bool = False) -> None:
        super().__init__(name, clock)
        self.sched = sched
        self.node_id = node_id
        self.bitrate_bps = int(bitrate_bps)
        self.period_ps = int(period_ps)
        self.broadcast_fc = broadcast_fc
        offset, width, max_slots = oc.slot_layout(broadcast_fc, with_sender)
        self.with_sender = bool(offset)
        self.slot_width = width
        if dlc is None:
            dlc = offset + n_axes * width
        n_slots, rest = divmod(dlc - offset, width)
        if rest or not n_axes <= n_slots <= max_slots:
            raise ValueError(f"DLC {dlc} cannot carry {n_axes} axes of {width} bytes")
        self.n_axes = n_axes
        self.n_slots = n_slots
        self.dlc = dlc
        self.sync_every = int(sync_every)
        self.query_every = int(query_every)
        self.query_nodes = tuple(query_nodes)
        self.stop_on_missing = stop_on_missing
        self.first_cycle_delay_ps = (self.period_ps if first_cycle_delay_ps is None
                                     else int(first_cycle_delay_ps))
        self.n_cycles = n_cycles
        self.feedback_dlcs = tuple(feedback_dlcs)
        self.feasibility = check_feasibility(self.bitrate_bps, dlc, self.period_ps,
                                             sync=self.sync_every > 0,
                                             feedback_dlcs=self.feedback_dlcs,
                                             margin_ps=margin_ps)
        if not self.feasibility.ok and not allow_infeasible:
            raise InfeasibleConfiguration(self.feasibility.reason)

        # --- records -----------------------------------------------------------------------
        #: (cycle, m_c true ps) every cycle instant
        self.cycle_log: list[tuple[int, int]] = []
        #: (t_ps, msg) own frames sent (end of EOF)
        self.tx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, msg) frames received
        self.rx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, sender, dtype, content) every process-data frame addressed to the master
        self.feedback_log: list[tuple[int, int, int, bytes]] = []
        #: (t_ps, sender, dtype, content) every parameter frame addressed to the master
        self.param_log: list[tuple[int, int, int, bytes]] = []
        #: (t_query, t_check, missing node ids) every completed node query
        self.query_log: list[tuple[int, int, tuple[int, ...]]] = []
        #: (t_ps, msg) commands replaced before they started (the bus was too busy)
        self.aborted_log: list[tuple[int, can.Message]] = []
        #: set when a node query found a missing node
        self.error = False

        self._txq: list[tuple[tuple[int, ...], int, can.Message]] = []
        self._txseq = itertools.count()
        self._cycle_timer = LocalTimer(sched, self.clock, self._on_cycle)
        self._query_timer = LocalTimer(sched, self.clock, self._on_query)
        self._check_timer = LocalTimer(sched, self.clock, self._on_query_check)
        self._replied: set[int] = set()
        self._t_query = 0
        self._running = False
        self._offered: can.Message | None = None
        self._in_flight: can.Message | None = None

    # =====================================================================================
    # API
    # =====================================================================================

    def command_values(self, cycle: int) -> list[int]:
        """Slot values of cycle ``cycle`` (index 0 = axis 1)."""
        return [setpoint_value(cycle, a, self.slot_width) for a in range(1, self.n_slots + 1)]

    def command_frame(self, cycle: int) -> can.Message:
        return oc.broadcast_frame(self.broadcast_fc, self.node_id, self.command_values(cycle),
                                  self.with_sender)

    def start(self) -> None:
        """NMT start to all now; the cycles begin ``first_cycle_delay_ps`` later."""
        self.queue_frame(oc.nmt_frame(0, oc.NMT_START))
        self._running = True
        self._cycle_timer.start(self.period_ps, self.first_cycle_delay_ps)
        if self.query_every:
            first = self.first_cycle_delay_ps + (self.query_every - 1) * self.period_ps
            self._query_timer.start(self.query_every * self.period_ps,
                                    first + self.period_ps // 2)

    def stop(self) -> None:
        """NMT stop to all; no further cycles or queries."""
        self.queue_frame(oc.nmt_frame(0, oc.NMT_STOP))
        self._halt()

    def send_parameter(self, receiver: int, dtype: int, value: int, size: int = 2,
                       signed: bool = True) -> None:
        """fc 111 frame to ``receiver``: ``[own id][dtype][value, size bytes big-endian]``."""
        self.queue_frame(oc.data_frame(oc.FC_PARAM, receiver, self.node_id, dtype, value, size,
                                       signed))

    def queue_frame(self, msg: can.Message) -> None:
        bisect.insort(self._txq, (arbitration_bits(msg), next(self._txseq), msg))
        if self.bus is not None:
            self.bus.request_tx(self)

    def cycle_time_ps(self, cycle: int) -> int:
        """True time of master cycle ``cycle`` (the master's own clock)."""
        return self._cycle_timer.expiry_true_ps(cycle)

    # =====================================================================================
    # CanNode hooks
    # =====================================================================================

    def tx_candidate(self) -> can.Message | None:
        msg = self._txq[0][2] if self._txq else None
        self._offered = msg
        return msg

    def on_bus_activity(self, t_ps: int) -> None:
        # called at every SOF after the round's tx_candidate calls: the offer is on the wire
        # unless on_arbitration_lost follows
        self._in_flight, self._offered = self._offered, None

    def on_arbitration_lost(self, msg: can.Message, t_ps: int) -> None:
        self._in_flight = None

    def on_tx_error(self, msg: can.Message, t_ps: int, reason: str) -> None:
        self._in_flight = None

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        self._in_flight = None
        for i, entry in enumerate(self._txq):
            if entry[2] is msg:
                del self._txq[i]
                break
        self.tx_log.append((t_ps, msg))

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        self.rx_log.append((t_ps, msg))
        if msg.is_extended_id:
            return
        if msg.is_remote_frame:
            if msg.arbitration_id == 0:  # a query from the PC (Table 4-2: reply 0x002)
                self.queue_frame(oc.query_reply_frame(self.node_id))
            elif msg.arbitration_id <= 255:
                self._replied.add(msg.arbitration_id)
            return
        if msg.arbitration_id == 0:  # NMT from the PC, e.g. ``02 01`` (Fig 4-20)
            try:
                target, state = oc.parse_nmt(msg)
            except oc.OmniFrameError:
                return
            if target in (0, self.node_id):
                if state == oc.NMT_START and not self._running:
                    self.start()
                elif state == oc.NMT_STOP and self._running:
                    self.stop()
            return
        fc, node = oc.decode_id(msg.arbitration_id)
        if node != self.node_id or msg.dlc < 2:
            return
        if fc in oc.PROCESS_DATA_FCS:
            f = oc.parse_data_frame(msg)
            self.feedback_log.append((t_ps, f.sender, f.dtype, f.content))
        elif fc == oc.FC_PARAM:
            f = oc.parse_data_frame(msg)
            self.param_log.append((t_ps, f.sender, f.dtype, f.content))
            if f.dtype == oc.DTYPE_CONTROLLER_SETTING:
                # Fig 4-19: forwarded to every slave as type 0x01 with a 2-byte value
                for n in self.query_nodes:
                    self.send_parameter(n, oc.DTYPE_PARAMETER, f.value() & 0xFFFF, 2,
                                        signed=False)

    # =====================================================================================
    # cycles and monitoring
    # =====================================================================================

    def _halt(self) -> None:
        self._running = False
        self._cycle_timer.stop()
        self._query_timer.stop()
        self._check_timer.stop()

    def _on_cycle(self, c: int) -> None:
        if self.n_cycles is not None and c >= self.n_cycles:
            self._cycle_timer.stop()
            return
        self.cycle_log.append((c, self.sched.now_ps))
        cmd_id = oc.omni_id(self.broadcast_fc, self.node_id)
        stale = [e for e in self._txq if e[2].arbitration_id == cmd_id
                 and not e[2].is_remote_frame and e[2] is not self._in_flight]
        for e in stale:  # one TX buffer per class: a command not started yet is replaced
            self._txq.remove(e)
            self.aborted_log.append((self.sched.now_ps, e[2]))
        if self.sync_every and c % self.sync_every == 0:
            self.queue_frame(oc.omni_sync_frame())
        self.queue_frame(self.command_frame(c))

    def _on_query(self, _k: int) -> None:
        self._replied.clear()
        self._t_query = self.sched.now_ps
        self.queue_frame(oc.node_query_frame())
        self._check_timer.start(None, self.period_ps)

    def _on_query_check(self, _k: int) -> None:
        missing = tuple(n for n in self.query_nodes if n not in self._replied)
        self.query_log.append((self._t_query, self.sched.now_ps, missing))
        if missing:
            self.error = True
            if self.stop_on_missing and self._running:
                self.stop()
