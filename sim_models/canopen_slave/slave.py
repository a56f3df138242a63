"""CiA 301 reference slave for the simulated CAN bus, built on python ``canopen``'s LocalNode.

One :class:`CanopenSlave` is a :class:`~sim_models.can_bus.CanNode`. Its object dictionary
comes from an EDS through ``canopen.import_od`` and is served by a ``canopen.LocalNode``
attached to a :class:`~sim_models.canopen_slave.network.SimNetwork`: the library's SDO server
answers expedited and segmented transfers and aborts synchronously from ``network.notify()``.
Everything the library does not do for a local node, or does with threads and wall-clock time,
is written here on the simulation scheduler: NMT slave state machine and boot-up, heartbeat
producer on the node's local clock, node-guarding responder, heartbeat consumer, SYNC consumer,
TPDO/RPDO engine for every transmission type, EMCY producer, a minimal CiA 402 drive, a local
control loop for clock-drift experiments and fault-injection switches.

See ``docs/reference_slaves.md`` for the service table, the API and the limitations.
"""

from __future__ import annotations

import bisect
import itertools
import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

import can
import canopen
from canopen import objectdictionary as cod
from canopen.sdo import SdoAbortedError

from sim_models.can_bus import CanBus, CanNode, NodeClock, arbitration_bits
from sim_models.canopen_slave import pdo as P
from sim_models.canopen_slave.cia402 import STATUSWORD, DriveState, next_state
from sim_models.canopen_slave.network import SimNetwork, make_message
from sim_models.canopen_slave.timers import LocalTimer, true_after_local
from sim_models.sim_time import PS_PER_MS, PS_PER_S, PS_PER_US, Scheduler

__all__ = [
    "CONTROL_RESYNC_MODES",
    "DEFAULT_BOOT_TIME_PS",
    "DEFAULT_EDS",
    "CanopenSlave",
    "ControlTick",
    "EmcyRecord",
    "NmtState",
    "build_slaves",
]

#: The committed CiA 402 drive EDS (default object dictionary of every slave).
DEFAULT_EDS = Path(__file__).resolve().parent / "eds" / "cia402_drive.eds"
#: Power-on / reset -> boot-up delay (local clock) unless configured otherwise.
DEFAULT_BOOT_TIME_PS = 1 * PS_PER_MS

#: NMT command specifiers (byte 0 of COB-ID 0).
NMT_START = 0x01
NMT_STOP = 0x02
NMT_ENTER_PREOP = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMM = 0x82

#: SDO abort codes used by the checks written here (the library raises its own as well).
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_RO = 0x06010002
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_INVALID_VALUE = 0x06090030

#: Re-alignment of the local control loop (``control_resync``): free-running from power-on,
#: re-anchored at every K-th SYNC, or anchored once at the first SYNC and free-running after it.
CONTROL_RESYNC_MODES = ("none", "sync", "first_sync")

#: EMCY error codes.
EMCY_LIFE_GUARD_HEARTBEAT = 0x8130
EMCY_PDO_LENGTH = 0x8210
EMCY_PDO_LENGTH_EXCEEDED = 0x8220
EMCY_ERROR_RESET = 0x0000
#: Error register (1001h) bits.
ERR_GENERIC = 0x01
ERR_COMMUNICATION = 0x10


class NmtState(IntEnum):
    """NMT states; the value is the heartbeat / guarding state byte. ``OFF`` is not a CANopen
    state: it marks a powered-off slave in :attr:`CanopenSlave.state_log`."""

    OFF = -1
    INITIALISING = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


_ERROR_CONTROL_STATES = (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL, NmtState.STOPPED)
_SDO_STATES = (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL)


@dataclass(frozen=True)
class EmcyRecord:
    """One EMCY frame queued by the slave."""

    t_ps: int
    code: int
    register: int
    msef: bytes


@dataclass(frozen=True)
class ControlTick:
    """One tick of the local control loop.

    ``status``: ``"new"`` exactly one set-point arrived since the previous tick, ``"overwritten"``
    more than one arrived (all but the last were never sampled), ``"missing"`` none arrived
    (``value`` is the stale previous one, or None if none ever arrived).
    """

    tick: int  #: index since power-on or the last resync() (a SYNC re-phase continues it)
    epoch: int  #: number of re-alignments (resync() calls and SYNC re-phases) before it
    t_ps: int  #: true time
    t_local_ps: int  #: slave's local time
    value: Any  #: sampled set-point
    value_t_ps: int | None  #: true time the sampled value arrived
    status: str  #: "new" | "overwritten" | "missing"
    arrivals: int  #: set-points arrived since the previous tick


class CanopenSlave(CanNode):
    """CiA 301 slave (CiA 402 drive profile subset) on a :class:`~sim_models.can_bus.CanBus`.

    Args:
        sched: the shared scheduler.
        node_id: CANopen node-ID 1..127.
        eds_path: object dictionary (default :data:`DEFAULT_EDS`).
        clock: local oscillator (default ideal); all slave timing runs on it.
        bitrate_bps: CAN bit rate of the node's controller.
        name: bus node name (default ``"slave<id>"``).
        boot_time_ps: power-on -> boot-up delay, local time.
        reset_time_ps: NMT reset node / reset communication -> boot-up delay (default
            ``boot_time_ps``).
        response_delay_ps: local-time latency between receiving a frame and queuing the frames
            it causes (SDO responses, guarding replies, SYNC- and RTR-triggered TPDOs, EMCYs
            caused by a frame).
        control_period_ps: period of the local control loop (local time); None = no loop.
        control_source: set-point the control loop samples: an RPDO number 1..4 (the raw
            payload, on reception), ``("applied", n)`` (the raw payload of RPDO n when it is
            written into the OD: for a synchronous RPDO at the SYNC after its reception, which
            is what a CiA 301 drive works with) or an ``(index, subindex)`` object (its decoded
            value, whenever it is written by SDO, RPDO or :meth:`write`).
        control_offset_ps: local time from power-on (or resync) to tick 0.
        control_resync: re-alignment of the tick grid on the SYNC (see
            :data:`CONTROL_RESYNC_MODES`): ``"none"`` free-running from power-on; ``"sync"``
            every ``control_resync_k``-th SYNC consumed (the first one included) re-anchors the
            grid at its reception + ``control_phase_ps``; ``"first_sync"`` only the first SYNC
            does (a drive that locks once and then runs on its own crystal). The tick index
            continues through a re-phase (``epoch`` + 1); a re-phase is logged in
            ``rephase_log``.
        control_resync_k: K of ``"sync"``.
        control_phase_ps: local time from the SYNC's reception to the re-anchored tick,
            0 <= phase < control_period_ps.
        pdo_length_emcy: send EMCY 0x8210 / 0x8220 when an RPDO length error starts.
        guarding_with_heartbeat: answer node-guarding RTRs even while 1017h != 0 (CiA 301
            says heartbeat replaces guarding, so the default is False).
        powered: power on at construction (at the current scheduler time).
    """

    def __init__(self, sched: Scheduler, node_id: int, *, bitrate_bps: int,
                 eds_path: str | Path | None = None, clock: NodeClock | None = None,
                 name: str | None = None, boot_time_ps: int = DEFAULT_BOOT_TIME_PS,
                 reset_time_ps: int | None = None, response_delay_ps: int = 0,
                 control_period_ps: int | None = None,
                 control_source: int | tuple[int, int] | tuple[str, int] = 1,
                 control_offset_ps: int = 0, control_resync: str = "none",
                 control_resync_k: int = 1, control_phase_ps: int = 0,
                 pdo_length_emcy: bool = True, guarding_with_heartbeat: bool = False,
                 powered: bool = True) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node_id {node_id} out of range 1..127")
        if control_resync not in CONTROL_RESYNC_MODES:
            raise ValueError(f"control_resync must be one of {CONTROL_RESYNC_MODES}, "
                             f"got {control_resync!r}")
        if control_resync_k < 1:
            raise ValueError(f"control_resync_k must be >= 1, got {control_resync_k}")
        if control_resync != "none":
            if not control_period_ps:
                raise ValueError("control_resync needs a control loop (control_period_ps)")
            if not 0 <= control_phase_ps < control_period_ps:
                raise ValueError("control_phase_ps must lie in [0, control_period_ps)")
        super().__init__(name or f"slave{node_id}", clock)
        self.sched = sched
        self.node_id = node_id
        self.nominal_bitrate_bps = int(bitrate_bps)
        self.eds_path = Path(eds_path) if eds_path is not None else DEFAULT_EDS
        self.boot_time_ps = int(boot_time_ps)
        self.reset_time_ps = int(boot_time_ps if reset_time_ps is None else reset_time_ps)
        self.response_delay_ps = int(response_delay_ps)
        self.pdo_length_emcy = pdo_length_emcy
        self.guarding_with_heartbeat = guarding_with_heartbeat

        # --- library objects -------------------------------------------------------------
        self.od: cod.ObjectDictionary = canopen.import_od(str(self.eds_path), node_id)
        self.node = canopen.LocalNode(node_id, self.od)
        self.network = SimNetwork(self)
        self.network.add_node(self.node)
        # NMT and heartbeat are done here on sim time: detach the library's NMT slave (its
        # heartbeat uses send_periodic and it has no reset semantics) and wrap the SDO server
        # so that it only answers in pre-operational / operational.
        self.network.unsubscribe(0, self.node.nmt.on_command)
        self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)
        self.node._write_callbacks.remove(self.node.nmt.on_write)
        self.node.add_write_callback(self._on_sdo_write)
        self.network.subscribe(0, self._on_nmt)
        self.network.subscribe(self.node.sdo.rx_cobid, self._on_sdo_request)
        # The library's abort() packs the last index; give it one before any request.
        self.node.sdo._index = 0
        self.node.sdo._subindex = 0

        # --- records (public, append-only) -------------------------------------------------
        #: (t_ps, NmtState) every state change seen inside the slave
        self.state_log: list[tuple[int, NmtState]] = []
        #: (t_ps, msg) every own frame sent successfully (t = end of EOF)
        self.tx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, msg) every frame received
        self.rx_log: list[tuple[int, can.Message]] = []
        #: (t_ps, counter or None) every SYNC consumed (pre-operational and operational)
        self.sync_log: list[tuple[int, int | None]] = []
        self.emcy_log: list[EmcyRecord] = []
        self.rpdo_length_errors: list[P.RpdoLengthError] = []
        #: (t_ps, pdo, payload) every RPDO payload written into the OD
        self.rpdo_applied: list[tuple[int, int, bytes]] = []
        #: (t_ps, reply byte) every node-guarding reply queued
        self.guarding_log: list[tuple[int, int]] = []
        #: t_ps of every slave-side life-guarding timeout
        self.life_guard_events: list[int] = []
        #: (t_ps, node-ID) every heartbeat-consumer timeout
        self.heartbeat_timeouts: list[tuple[int, int]] = []
        self.control_log: list[ControlTick] = []
        #: (t_ps, t_local_ps) every resync() call
        self.resync_log: list[tuple[int, int]] = []
        #: (t_ps, t_local_ps, cause) every SYNC re-phase of the control loop ("sync" /
        #: "first_sync"; t = the SYNC's reception, the re-anchored tick is phase later)
        self.rephase_log: list[tuple[int, int, str]] = []
        #: (t_ps, DriveState) CiA 402 state changes
        self.drive_log: list[tuple[int, DriveState]] = []

        # --- hooks for benches ---------------------------------------------------------------
        #: called as fn(slave, t_ps, counter) after each SYNC has been processed
        self.sync_listeners: list[Callable[[CanopenSlave, int, int | None], Any]] = []
        #: called as fn(slave, tick) after each control-loop tick
        self.control_listeners: list[Callable[[CanopenSlave, ControlTick], Any]] = []

        # --- run-time state --------------------------------------------------------------------
        self._state = NmtState.OFF
        self._powered = False
        self._txq: list[tuple[tuple[int, ...], int, can.Message]] = []
        self._txseq = itertools.count()
        self._rx_depth = 0
        self._comm_epoch = 0  # bumped by resets / power: stale delayed callbacks are dropped
        self._heartbeat_muted = False
        self._guard_toggle = 0
        self._guard_bad_next = False
        self._boot_handle = None
        self._heartbeat = LocalTimer(sched, self.clock, self._heartbeat_fire)
        self._life_timer = LocalTimer(sched, self.clock, self._life_guard_expired)
        self._hb_consumers: dict[int, LocalTimer] = {}
        self._hb_consumer_cbs: dict[int, Callable[..., None]] = {}
        self._sync_cob: int | None = None
        self._rpdo_cbs: dict[int, tuple[int, Callable[..., None]]] = {}
        self._tpdo = [P.TpdoRuntime() for _ in range(P.N_PDO)]
        self._rpdo = [P.RpdoRuntime() for _ in range(P.N_PDO)]
        self._drive_state = DriveState.NOT_READY_TO_SWITCH_ON
        self._prev_cw = 0
        # control loop
        self.control_period_ps = control_period_ps
        self.control_source = control_source
        self.control_offset_ps = int(control_offset_ps)
        self.control_resync = control_resync
        self.control_resync_k = int(control_resync_k)
        self.control_phase_ps = int(control_phase_ps)
        self._control_timer = LocalTimer(sched, self.clock, self._control_tick)
        self._control_epoch = 0
        self._tick_base = 0  # tick index of the current timer run's expiry 0
        self._last_tick: tuple[int, int] | None = None  # (tick index, local ps) of the last
        self._control_syncs = 0  # SYNCs consumed since the loop (re)started
        self._sp_value: Any = None
        self._sp_t: int | None = None
        self._sp_arrivals = 0

        if powered:
            self.power_on()

    # =====================================================================================
    # Public API
    # =====================================================================================

    @property
    def nmt_state(self) -> NmtState:
        return self._state

    @property
    def powered(self) -> bool:
        return self._powered

    @property
    def drive_state(self) -> DriveState:
        return self._drive_state

    @property
    def tx_queue(self) -> list[can.Message]:
        """Frames waiting for transmission, in the order they will compete (copy)."""
        return [m for _, _, m in self._txq]

    def read(self, index: int, subindex: int = 0) -> Any:
        """Decoded value of an object (data store, else EDS default)."""
        raw = self.node.get_data(index, subindex)
        return self._var(index, subindex).decode_raw(raw)

    def read_raw(self, index: int, subindex: int = 0) -> bytes:
        return bytes(self.node.get_data(index, subindex))

    def write(self, index: int, subindex: int, value: Any) -> None:
        """Application write (no access check): e.g. a measured value. Triggers event TPDOs
        mapping the object and the CiA 402 logic like any other write."""
        var = self._var(index, subindex)
        self._store(index, subindex, bytes(var.encode_raw(value)), "app")

    def emcy(self, code: int, register: int, msef: bytes = b"") -> bool:
        """Send an EMCY ``[code lo, code hi, register, msef(5)]`` on 1014h and set 1001h.

        Returns False (nothing sent; 1001h still updated) when the state forbids EMCY
        (initialising, stopped), the slave is off or 1014h is invalid (bit 31)."""
        if not self._powered:
            return False
        self._store(0x1001, 0, bytes([register & 0xFF]), "app")
        cob = self.read(0x1014)
        if self._state not in _SDO_STATES or cob & P.COB_INVALID:
            return False
        self.emcy_log.append(EmcyRecord(self.sched.now_ps, code, register & 0xFF,
                                        bytes(msef[:5])))
        self.node.emcy.cob_id = cob & 0x7FF
        self.node.emcy.send(code, register & 0xFF, bytes(msef[:5]).ljust(5, b"\0"))
        return True

    def queue_frame(self, msg: can.Message, *, reply: bool | None = None) -> None:
        """Put a frame into the TX queue (id priority, FIFO among equal ids).

        ``reply`` (default: "called while processing a received frame") applies
        ``response_delay_ps`` first. Dropped when the slave is off."""
        if not self._powered:
            return
        if reply is None:
            reply = self._rx_depth > 0
        if reply and self.response_delay_ps > 0:
            t = true_after_local(self.sched, self.clock, self.response_delay_ps)
            self.sched.call_at(t, self._enqueue_if, self._comm_epoch, msg)
        else:
            self._enqueue(msg)

    def send_raw(self, msg: can.Message) -> None:
        """Queue any frame now, whatever the NMT state (misbehaviour injection)."""
        self.queue_frame(msg, reply=False)

    def power_off(self) -> None:
        """Disappear from the bus: no frames, no ACKs, every timer stopped."""
        if not self._powered:
            return
        self._powered = False
        self._comm_epoch += 1
        self._stop_comm_timers()
        self._control_timer.stop()
        self._txq.clear()
        self.bitrate_bps = None
        self._set_state(NmtState.OFF)

    def power_on(self) -> None:
        """Power-on reset: back on the bus, application + communication reset, boot-up after
        ``boot_time_ps``. Does nothing when already on."""
        if self._powered:
            return
        self._powered = True
        self.reset_fault_confinement()
        self.bitrate_bps = self.nominal_bitrate_bps
        self._enter_reset(application=True, delay_ps=self.boot_time_ps)
        self._restart_control_loop()

    def mute_heartbeat(self, muted: bool = True) -> None:
        """Suppress (True) or resume heartbeat frames; the timer keeps running."""
        self._heartbeat_muted = bool(muted)

    def guarding_bad_toggle(self) -> None:
        """The next node-guarding reply repeats the previous toggle bit."""
        self._guard_bad_next = True

    def request_tpdo(self, pdo: int) -> None:
        """Application event for TPDO ``pdo`` (1..4): type 0 sends at the next SYNC, types
        254/255 send now (inhibit time permitting)."""
        self._tpdo_event(pdo - 1)

    def drive_fault(self, code: int = 0x1000, msef: bytes = b"") -> None:
        """CiA 402 fault: state *fault*, EMCY ``code`` with error register bit 0."""
        self._set_drive_state(DriveState.FAULT)
        reg = int(self.read(0x1001)) | ERR_GENERIC
        if not self.emcy(code, reg, msef):
            self._store(0x1001, 0, bytes([reg]), "app")

    def drive_update(self) -> None:
        """In *operation enabled*: actual position/velocity/torque := targets. Called at every
        SYNC in operational (after the synchronous RPDOs are applied)."""
        if self._drive_state is not DriveState.OPERATION_ENABLED:
            return
        for src, dst in ((0x607A, 0x6064), (0x60FF, 0x606C), (0x6071, 0x6077)):
            if src in self.od and dst in self.od:
                self._store(dst, 0, self.read_raw(src), "app")

    def resync(self) -> None:
        """Zero the control-loop phase: tick 0 of a new grid happens now (tick index reset).

        The manual hard restart; the SYNC re-phase (``control_resync``) keeps the index."""
        self.resync_log.append((self.sched.now_ps, self.clock.local_ps(self.sched.now_ps)))
        self._control_epoch += 1
        if self._powered and self.control_period_ps:
            self._tick_base = 0
            self._control_timer.start(self.control_period_ps, 0)

    def tpdo_log(self, pdo: int) -> list[tuple[int, bytes]]:
        """(t_ps queued, payload) of every frame TPDO ``pdo`` (1..4) queued."""
        return self._tpdo[pdo - 1].log

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
        if not self._powered:
            return
        self.rx_log.append((t_ps, msg))
        if self._state is NmtState.INITIALISING or msg.is_extended_id:
            return
        with self._rx_context():
            if msg.is_remote_frame:
                self._on_rtr(msg.arbitration_id)
            else:
                self.network.notify(msg.arbitration_id, bytes(msg.data), t_ps / PS_PER_S)

    # =====================================================================================
    # TX queue
    # =====================================================================================

    def _enqueue(self, msg: can.Message) -> None:
        if not self._powered:
            return
        bisect.insort(self._txq, (arbitration_bits(msg), next(self._txseq), msg))
        if self.bus is not None:
            self.bus.request_tx(self)

    def _enqueue_if(self, epoch: int, msg: can.Message) -> None:
        if epoch == self._comm_epoch:
            self._enqueue(msg)

    @contextmanager
    def _rx_context(self) -> Iterator[None]:
        self._rx_depth += 1
        try:
            yield
        finally:
            self._rx_depth -= 1

    # =====================================================================================
    # NMT
    # =====================================================================================

    def _set_state(self, new: NmtState) -> None:
        old = self._state
        if new == old:
            return
        self._state = new
        self.node.nmt._state = max(0, int(new))
        self.state_log.append((self.sched.now_ps, new))
        if old is NmtState.OPERATIONAL:
            self._leave_operational()
        if new is NmtState.OPERATIONAL:
            self._enter_operational()

    def _on_nmt(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        cs = data[0]
        if cs == NMT_START:
            self._set_state(NmtState.OPERATIONAL)
        elif cs == NMT_STOP:
            self._set_state(NmtState.STOPPED)
        elif cs == NMT_ENTER_PREOP:
            self._set_state(NmtState.PRE_OPERATIONAL)
        elif cs == NMT_RESET_NODE:
            self._enter_reset(application=True, delay_ps=self.reset_time_ps)
        elif cs == NMT_RESET_COMM:
            self._enter_reset(application=False, delay_ps=self.reset_time_ps)

    def _enter_reset(self, *, application: bool, delay_ps: int) -> None:
        """Initialisation: flush TX, stop timers, restore defaults, boot-up after delay."""
        self._comm_epoch += 1
        self._stop_comm_timers()
        self._txq.clear()
        self._set_state(NmtState.INITIALISING)
        if application:
            self.node.data_store.clear()
            self._reset_drive()
        else:
            for index in [i for i in self.node.data_store if 0x1000 <= i <= 0x1FFF]:
                del self.node.data_store[index]
        self._guard_toggle = 0
        self._guard_bad_next = False
        self._tpdo = [P.TpdoRuntime() for _ in range(P.N_PDO)]
        self._rpdo = [P.RpdoRuntime() for _ in range(P.N_PDO)]
        t = true_after_local(self.sched, self.clock, delay_ps)
        self._boot_handle = self.sched.call_at(t, self._boot_up, self._comm_epoch)

    def _boot_up(self, epoch: int) -> None:
        if epoch != self._comm_epoch:
            return
        self._boot_handle = None
        self._rebuild_subscriptions()
        self._enqueue(make_message(0x700 + self.node_id, b"\x00"))
        self._set_state(NmtState.PRE_OPERATIONAL)
        self._restart_heartbeat()

    def _stop_comm_timers(self) -> None:
        if self._boot_handle is not None:
            self._boot_handle.cancel()
            self._boot_handle = None
        self._heartbeat.stop()
        self._life_timer.stop()
        for timer in self._hb_consumers.values():
            timer.stop()
        for rt in self._tpdo:
            self._stop_tpdo_timers(rt)

    # =====================================================================================
    # Error control: heartbeat producer, node guarding, heartbeat consumer
    # =====================================================================================

    def _restart_heartbeat(self, period_ms: int | None = None) -> None:
        if period_ms is None:
            period_ms = int(self.read(0x1017))
        if period_ms > 0 and self._state in _ERROR_CONTROL_STATES:
            self._heartbeat.start(period_ms * PS_PER_MS)
        else:
            self._heartbeat.stop()

    def _heartbeat_fire(self, _k: int) -> None:
        if self._heartbeat_muted or self._state not in _ERROR_CONTROL_STATES:
            return
        self._enqueue(make_message(0x700 + self.node_id, bytes([int(self._state)])))

    def _on_rtr(self, can_id: int) -> None:
        if can_id == 0x700 + self.node_id:
            self._on_guarding_rtr()
            return
        if self._state is not NmtState.OPERATIONAL:
            return
        for n in range(P.N_PDO):
            cob = self._u32(0x1800 + n, 1)
            if cob & (P.COB_INVALID | P.COB_NO_RTR) or (cob & 0x7FF) != can_id:
                continue
            tt = self._u8(0x1800 + n, 2)
            rt = self._tpdo[n]
            if tt == P.TT_RTR_SYNC and rt.sampled is not None:
                self._send_tpdo(n, rt.sampled)
            else:
                self._send_tpdo(n)

    def _on_guarding_rtr(self) -> None:
        if self._state not in _ERROR_CONTROL_STATES:
            return
        if int(self.read(0x1017)) != 0 and not self.guarding_with_heartbeat:
            return
        if self._guard_bad_next:
            self._guard_bad_next = False
            toggle = self._guard_toggle ^ 1
        else:
            toggle = self._guard_toggle
            self._guard_toggle ^= 1
        byte = (toggle << 7) | int(self._state)
        self.guarding_log.append((self.sched.now_ps, byte))
        self.queue_frame(make_message(0x700 + self.node_id, bytes([byte])))
        guard_ms = int(self.read(0x100C))
        factor = int(self.read(0x100D))
        if guard_ms and factor:
            self._life_timer.start(None, guard_ms * factor * PS_PER_MS)

    def _life_guard_expired(self, _k: int) -> None:
        self.life_guard_events.append(self.sched.now_ps)
        reg = int(self.read(0x1001)) | ERR_COMMUNICATION
        if not self.emcy(EMCY_LIFE_GUARD_HEARTBEAT, reg):
            self._store(0x1001, 0, bytes([reg]), "app")

    def _on_consumer_heartbeat(self, producer: int, can_id: int, data: bytes,
                               timestamp: float) -> None:
        if self._state not in _ERROR_CONTROL_STATES or not data:
            return
        timer = self._hb_consumers.get(producer)
        if timer is None:
            return
        ms = self._consumer_time_ms(producer)
        if ms:
            timer.start(None, ms * PS_PER_MS)

    def _consumer_time_ms(self, producer: int) -> int:
        for sub in range(1, self._array_len(0x1016) + 1):
            entry = self._u32(0x1016, sub)
            if (entry >> 16) & 0xFF == producer:
                return entry & 0xFFFF
        return 0

    def _heartbeat_timeout(self, producer: int, _k: int) -> None:
        self.heartbeat_timeouts.append((self.sched.now_ps, producer))
        reg = int(self.read(0x1001)) | ERR_COMMUNICATION
        if not self.emcy(EMCY_LIFE_GUARD_HEARTBEAT, reg, bytes([producer])):
            self._store(0x1001, 0, bytes([reg]), "app")

    # =====================================================================================
    # Subscriptions (SYNC, RPDOs, heartbeat consumer) follow the OD
    # =====================================================================================

    def _rebuild_subscriptions(self) -> None:
        net = self.network
        if self._sync_cob is not None:
            net.unsubscribe(self._sync_cob, self._on_sync)
            self._sync_cob = None
        for cob, cb in self._rpdo_cbs.values():
            net.unsubscribe(cob, cb)
        self._rpdo_cbs.clear()
        for producer, cb in self._hb_consumer_cbs.items():
            net.unsubscribe(0x700 + producer, cb)
            self._hb_consumers[producer].stop()
        self._hb_consumer_cbs.clear()
        self._hb_consumers.clear()

        if 0x1005 in self.od:
            self._sync_cob = self._u32(0x1005, 0) & 0x7FF
            net.subscribe(self._sync_cob, self._on_sync)
        for n in range(P.N_PDO):
            if 0x1400 + n not in self.od:
                continue
            cob = self._u32(0x1400 + n, 1)
            if cob & P.COB_INVALID:
                continue
            rpdo_cb = self._make_rpdo_cb(n)
            net.subscribe(cob & 0x7FF, rpdo_cb)
            self._rpdo_cbs[n] = (cob & 0x7FF, rpdo_cb)
        if 0x1016 in self.od:
            for sub in range(1, self._array_len(0x1016) + 1):
                entry = self._u32(0x1016, sub)
                producer, ms = (entry >> 16) & 0xFF, entry & 0xFFFF
                if not (1 <= producer <= 127 and ms) or producer in self._hb_consumer_cbs:
                    continue
                hb_cb = self._make_hb_cb(producer)
                self._hb_consumer_cbs[producer] = hb_cb
                self._hb_consumers[producer] = LocalTimer(
                    self.sched, self.clock, self._make_hb_timeout(producer))
                net.subscribe(0x700 + producer, hb_cb)

    def _make_rpdo_cb(self, n: int) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, timestamp: float) -> None:
            self._on_rpdo(n, can_id, data)
        return cb

    def _make_hb_cb(self, producer: int) -> Callable[[int, bytes, float], None]:
        def cb(can_id: int, data: bytes, timestamp: float) -> None:
            self._on_consumer_heartbeat(producer, can_id, data, timestamp)
        return cb

    def _make_hb_timeout(self, producer: int) -> Callable[[int], None]:
        def cb(k: int) -> None:
            self._heartbeat_timeout(producer, k)
        return cb

    # =====================================================================================
    # SDO server (library) with state gating and the checks the library lacks
    # =====================================================================================

    def _on_sdo_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self._state not in _SDO_STATES or len(data) != 8:
            return
        sdo = self.node.sdo
        command = data[0]
        if command & 0xE0 == 0x20 and not command & 0x02:
            # Initiate segmented download: the library checks the object only after the last
            # segment; check existence and write access now, as CiA 301 servers do.
            _, index, subindex = struct.unpack_from("<BHB", data)
            try:
                obj = self.node._find_object(index, subindex)
                if not obj.writable:
                    raise SdoAbortedError(ABORT_WRITE_RO)
            except SdoAbortedError as exc:
                sdo._index, sdo._subindex = index, subindex
                sdo.abort(exc.code)
                return
        sdo.on_request(can_id, bytearray(data), timestamp)

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes,
                      **_kw: Any) -> None:
        """Library write callback (runs before the library stores the value): check CiA 301
        rules (raising SdoAbortedError aborts the transfer), then store and apply."""
        self._check_write(index, subindex, bytes(data))
        self._store(index, subindex, bytes(data), "sdo")

    def _check_write(self, index: int, subindex: int, data: bytes) -> None:
        value = int.from_bytes(data, "little") if len(data) <= 4 else 0
        if index == 0x1005:
            if value & ((1 << 30) | P.COB_EXTENDED):
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # no SYNC producer, no 29-bit
        elif 0x1400 <= index < 0x1400 + P.N_PDO or 0x1800 <= index < 0x1800 + P.N_PDO:
            self._check_comm_write(index, subindex, value)
        elif 0x1600 <= index < 0x1600 + P.N_PDO or 0x1A00 <= index < 0x1A00 + P.N_PDO:
            self._check_map_write(index, subindex, value)

    def _check_comm_write(self, index: int, subindex: int, value: int) -> None:
        valid_now = not self._u32(index, 1) & P.COB_INVALID
        if subindex == 1:
            if value & P.COB_EXTENDED:
                raise SdoAbortedError(ABORT_INVALID_VALUE)
            if valid_now and not value & P.COB_INVALID and \
                    (value & 0x7FF) != (self._u32(index, 1) & 0x7FF):
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # change CAN-ID only when invalid
            if not value & P.COB_INVALID and self._u8(index + 0x200, 0) == 0:
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # a PDO with no mapping
        elif subindex == 2:
            if 241 <= value <= 251 or (index < 0x1800 and value in (252, 253)):
                raise SdoAbortedError(ABORT_INVALID_VALUE)
        elif subindex in (3, 6) and valid_now:
            raise SdoAbortedError(ABORT_INVALID_VALUE)  # inhibit / start value: PDO invalid

    def _check_map_write(self, index: int, subindex: int, value: int) -> None:
        comm = index - 0x200
        if not self._u32(comm, 1) & P.COB_INVALID:
            raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # PDO must be invalid
        rpdo = index < 0x1A00
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            entries = [P.decode_map_entry(self._u32(index, s)) for s in range(1, value + 1)]
            for e in entries:
                self._check_map_entry(e, rpdo)
            if P.mapping_bits(entries) > P.MAX_PDO_BITS:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
        else:
            if self._u8(index, 0) != 0:
                raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # sub0 must be 0 first
            if value != 0:
                self._check_map_entry(P.decode_map_entry(value), rpdo)

    def _check_map_entry(self, e: P.MapEntry, rpdo: bool) -> None:
        if e.bits == 0:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        if P.is_dummy(e):
            if e.index in self.od:  # the EDS declares the dummy in [DummyUsage]
                return
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)
        try:
            var = self.node._find_object(e.index, e.subindex)
        except SdoAbortedError as exc:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE) from exc
        access_ok = var.writable if rpdo else var.readable
        if not var.pdo_mappable or not access_ok or e.bits > len(var) or \
                var.data_type not in cod.NUMBER_TYPES:
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)

    # =====================================================================================
    # Object store: every write (SDO, RPDO, application) ends here
    # =====================================================================================

    def _store(self, index: int, subindex: int, data: bytes, source: str) -> None:
        try:
            old: bytes | None = bytes(self.node.get_data(index, subindex))
        except SdoAbortedError:
            old = None
        self.node.data_store.setdefault(index, {})[subindex] = bytes(data)
        self._after_write(index, subindex, bytes(data), old, source)

    def _after_write(self, index: int, subindex: int, data: bytes, old: bytes | None,
                     source: str) -> None:
        if index == 0x1017:
            self._restart_heartbeat(int.from_bytes(data, "little"))
        elif index in (0x1005, 0x1016) or (0x1400 <= index < 0x1400 + P.N_PDO
                                            and subindex == 1):
            if self._state is not NmtState.INITIALISING:
                self._rebuild_subscriptions()
        elif 0x1800 <= index < 0x1800 + P.N_PDO:
            self._tpdo_config_changed(index - 0x1800)
        elif 0x1A00 <= index < 0x1A00 + P.N_PDO and subindex == 0:
            self._tpdo_config_changed(index - 0x1A00)
        elif index == 0x6040:
            self._on_controlword(int.from_bytes(data, "little"))
        elif index == 0x6060 and 0x6061 in self.od:
            self._store(0x6061, 0, data, "app")

        if self.control_source == (index, subindex):
            self._setpoint_arrived(self._var(index, subindex).decode_raw(data))
        if data != old:
            for n in range(P.N_PDO):
                if any(e.index == index and e.subindex == subindex
                       for e in self._tpdo_mapping(n)):
                    self._tpdo_event(n)

    # =====================================================================================
    # SYNC consumer, TPDOs, RPDOs
    # =====================================================================================

    def _on_sync(self, can_id: int, data: bytes, timestamp: float) -> None:
        if self._state not in _SDO_STATES:
            return
        counter = data[0] if len(data) >= 1 else None
        t = self.sched.now_ps
        self.sync_log.append((t, counter))
        if self._state is NmtState.OPERATIONAL:
            for n in range(P.N_PDO):
                self._tpdo_on_sync(n, counter)
            for n in range(P.N_PDO):
                rt = self._rpdo[n]
                if rt.pending is not None:
                    payload, _t_rx = rt.pending
                    rt.pending = None
                    self._apply_rpdo(n, payload)
            self.drive_update()
        self._control_on_sync()
        for fn in list(self.sync_listeners):
            fn(self, t, counter)

    def _tpdo_valid(self, n: int) -> bool:
        return 0x1800 + n in self.od and not self._u32(0x1800 + n, 1) & P.COB_INVALID

    def _tpdo_mapping(self, n: int) -> list[P.MapEntry]:
        index = 0x1A00 + n
        if index not in self.od:
            return []
        return [P.decode_map_entry(self._u32(index, s))
                for s in range(1, self._u8(index, 0) + 1)]

    def _rpdo_mapping(self, n: int) -> list[P.MapEntry]:
        index = 0x1600 + n
        return [P.decode_map_entry(self._u32(index, s))
                for s in range(1, self._u8(index, 0) + 1)]

    def _tpdo_payload(self, n: int) -> bytes:
        return P.pack_pdo(self._tpdo_mapping(n), self.read_raw)

    def _send_tpdo(self, n: int, payload: bytes | None = None) -> None:
        if payload is None:
            payload = self._tpdo_payload(n)
        cob = self._u32(0x1800 + n, 1) & 0x7FF
        rt = self._tpdo[n]
        rt.pending = False
        rt.sent += 1
        rt.last_tx_local_ps = self.clock.local_ps(self.sched.now_ps)
        rt.log.append((self.sched.now_ps, payload))
        self.queue_frame(make_message(cob, payload))
        tt = self._u8(0x1800 + n, 2)
        if tt >= P.TT_EVENT_MANUF:
            self._restart_event_timer(n)

    def _tpdo_on_sync(self, n: int, counter: int | None) -> None:
        if not self._tpdo_valid(n):
            return
        tt = self._u8(0x1800 + n, 2)
        rt = self._tpdo[n]
        if tt == P.TT_SYNC_ACYCLIC:
            if rt.pending:
                self._send_tpdo(n)
        elif tt <= P.TT_SYNC_MAX:
            if rt.waiting_start:
                if counter is None or counter != self._u8(0x1800 + n, 6):
                    return
                rt.waiting_start = False
                rt.sync_count = 0
                self._send_tpdo(n)
                return
            rt.sync_count += 1
            if rt.sync_count >= tt:
                rt.sync_count = 0
                self._send_tpdo(n)
        elif tt == P.TT_RTR_SYNC:
            rt.sampled = self._tpdo_payload(n)

    def _tpdo_event(self, n: int) -> None:
        """A mapped object changed (or the application asked): act per transmission type."""
        if self._state is not NmtState.OPERATIONAL or not self._tpdo_valid(n):
            return
        tt = self._u8(0x1800 + n, 2)
        rt = self._tpdo[n]
        if tt == P.TT_SYNC_ACYCLIC:
            rt.pending = True
        elif tt >= P.TT_EVENT_MANUF:
            rt.pending = True
            self._tpdo_try_event_send(n)

    def _tpdo_try_event_send(self, n: int) -> None:
        rt = self._tpdo[n]
        if not rt.pending:
            return
        inhibit_local = self._u16(0x1800 + n, 3) * 100 * PS_PER_US
        now_local = self.clock.local_ps(self.sched.now_ps)
        if rt.last_tx_local_ps is not None and inhibit_local:
            wait = rt.last_tx_local_ps + inhibit_local - now_local
            if wait > 0:
                if rt.inhibit_timer is None:
                    rt.inhibit_timer = LocalTimer(self.sched, self.clock,
                                                  lambda _k, n=n: self._tpdo_try_event_send(n))
                if not rt.inhibit_timer.active:
                    rt.inhibit_timer.start(None, wait)
                return
        self._send_tpdo(n)

    def _restart_event_timer(self, n: int) -> None:
        rt = self._tpdo[n]
        ms = self._u16(0x1800 + n, 5) if 5 in self.od[0x1800 + n] else 0
        if rt.event_timer is None:
            rt.event_timer = LocalTimer(self.sched, self.clock,
                                        lambda _k, n=n: self._event_timer_expired(n))
        if ms and self._state is NmtState.OPERATIONAL and self._tpdo_valid(n):
            rt.event_timer.start(None, ms * PS_PER_MS)
        else:
            rt.event_timer.stop()

    def _event_timer_expired(self, n: int) -> None:
        self._tpdo[n].pending = True
        self._tpdo_try_event_send(n)

    @staticmethod
    def _stop_tpdo_timers(rt: P.TpdoRuntime) -> None:
        for timer in (rt.inhibit_timer, rt.event_timer):
            if timer is not None:
                timer.stop()

    def _tpdo_config_changed(self, n: int) -> None:
        old = self._tpdo[n]
        self._stop_tpdo_timers(old)
        rt = P.TpdoRuntime(log=old.log, sent=old.sent)
        self._tpdo[n] = rt
        if self._state is NmtState.OPERATIONAL:
            self._start_tpdo(n)

    def _start_tpdo(self, n: int) -> None:
        """Entering operational (or reconfigured while in it)."""
        if not self._tpdo_valid(n):
            return
        rt = self._tpdo[n]
        tt = self._u8(0x1800 + n, 2)
        rt.sync_count = 0
        rt.waiting_start = 1 <= tt <= P.TT_SYNC_MAX and self._u8(0x1800 + n, 6) != 0
        if tt == P.TT_SYNC_ACYCLIC:
            rt.pending = True
        elif tt >= P.TT_EVENT_MANUF:
            rt.pending = True
            self._tpdo_try_event_send(n)

    def _enter_operational(self) -> None:
        for n in range(P.N_PDO):
            self._tpdo_config_changed(n)

    def _leave_operational(self) -> None:
        for n in range(P.N_PDO):
            self._stop_tpdo_timers(self._tpdo[n])
            self._tpdo[n].pending = False
            self._rpdo[n].pending = None

    def _on_rpdo(self, n: int, can_id: int, data: bytes) -> None:
        if self._state is not NmtState.OPERATIONAL:
            return
        rt = self._rpdo[n]
        rt.received += 1
        entries = self._rpdo_mapping(n)
        expected = (P.mapping_bits(entries) + 7) // 8
        t = self.sched.now_ps
        if len(data) != expected:
            applied = len(data) > expected
            self.rpdo_length_errors.append(P.RpdoLengthError(
                t, n + 1, can_id, len(data), expected, applied))
            if not rt.length_error and self.pdo_length_emcy:
                code = EMCY_PDO_LENGTH_EXCEEDED if applied else EMCY_PDO_LENGTH
                reg = int(self.read(0x1001)) | ERR_COMMUNICATION
                self.emcy(code, reg, (can_id & 0x7FF).to_bytes(2, "little"))
            rt.length_error = True
            if not applied:
                return
        else:
            rt.length_error = False
        payload = bytes(data[:expected])
        if self.control_source == n + 1:
            self._setpoint_arrived(payload)
        tt = self._u8(0x1400 + n, 2)
        if tt <= P.TT_SYNC_MAX:
            rt.pending = (payload, t)
        else:
            self._apply_rpdo(n, payload)

    def _apply_rpdo(self, n: int, payload: bytes) -> None:
        self._rpdo[n].applied += 1
        self.rpdo_applied.append((self.sched.now_ps, n + 1, payload))
        if self.control_source == ("applied", n + 1):
            self._setpoint_arrived(payload)
        parts = P.unpack_pdo(self._rpdo_mapping(n), payload,
                             lambda i, s: len(self._var(i, s)) // 8)
        for index, subindex, raw in parts:
            self._store(index, subindex, raw, "rpdo")

    # =====================================================================================
    # CiA 402
    # =====================================================================================

    def _reset_drive(self) -> None:
        self._prev_cw = 0
        self._drive_state = DriveState.NOT_READY_TO_SWITCH_ON
        self._set_drive_state(DriveState.SWITCH_ON_DISABLED)

    def _set_drive_state(self, new: DriveState) -> None:
        if new is not self._drive_state or not self.drive_log:
            self._drive_state = new
            self.drive_log.append((self.sched.now_ps, new))
        if 0x6041 in self.od:
            self._store(0x6041, 0, STATUSWORD[new].to_bytes(2, "little"), "app")

    def _on_controlword(self, cw: int) -> None:
        new = next_state(self._drive_state, cw, self._prev_cw)
        was_fault = self._drive_state is DriveState.FAULT
        self._prev_cw = cw
        if new is not self._drive_state:
            self._set_drive_state(new)
            if was_fault:
                reg = int(self.read(0x1001)) & ~ERR_GENERIC
                if not self.emcy(EMCY_ERROR_RESET, reg):
                    self._store(0x1001, 0, bytes([reg]), "app")

    # =====================================================================================
    # Local control loop
    # =====================================================================================

    def _restart_control_loop(self) -> None:
        self._sp_value, self._sp_t, self._sp_arrivals = None, None, 0
        self._tick_base = 0
        self._last_tick = None
        self._control_syncs = 0
        if self.control_period_ps:
            self._control_timer.start(self.control_period_ps, self.control_offset_ps)

    def _control_on_sync(self) -> None:
        """SYNC re-phase of the control loop (after the synchronous RPDOs were applied).

        Grid point g = reception + phase (local time). If the last tick lies less than half a
        period before g, this cycle has been sampled already (a fast clock) and the next tick
        is at g + period; otherwise the pending tick is moved to g (earlier for a slow clock,
        later for a fast one). The tick index continues: the first tick of the new grid gets
        the index after the last tick's."""
        if not (self._powered and self.control_period_ps) or self.control_resync == "none":
            return
        self._control_syncs += 1
        if self.control_resync == "first_sync":
            if self._control_syncs != 1:
                return
        elif (self._control_syncs - 1) % self.control_resync_k:
            return
        now = self.sched.now_ps
        now_local = self.clock.local_ps(now)
        period = self.control_period_ps
        first = self.control_phase_ps
        if self._last_tick is not None and now_local + first - self._last_tick[1] < period // 2:
            first += period
        self._tick_base = 0 if self._last_tick is None else self._last_tick[0] + 1
        self._control_epoch += 1
        self.rephase_log.append((now, now_local, self.control_resync))
        self._control_timer.start(period, first)

    def _setpoint_arrived(self, value: Any) -> None:
        self._sp_value = value
        self._sp_t = self.sched.now_ps
        self._sp_arrivals += 1

    def _control_tick(self, k: int) -> None:
        arrivals = self._sp_arrivals
        self._sp_arrivals = 0
        status = "new" if arrivals == 1 else "overwritten" if arrivals > 1 else "missing"
        t = self.sched.now_ps
        t_local = self.clock.local_ps(t)
        index = self._tick_base + k
        tick = ControlTick(index, self._control_epoch, t, t_local, self._sp_value,
                           self._sp_t, status, arrivals)
        self._last_tick = (index, t_local)
        self.control_log.append(tick)
        for fn in list(self.control_listeners):
            fn(self, tick)

    # =====================================================================================
    # OD helpers
    # =====================================================================================

    def _var(self, index: int, subindex: int) -> cod.ODVariable:
        obj = self.od[index]
        if isinstance(obj, cod.ODVariable):
            return obj
        return obj[subindex]

    def _uint(self, index: int, subindex: int) -> int:
        try:
            return int.from_bytes(self.node.get_data(index, subindex), "little")
        except (SdoAbortedError, KeyError):
            return 0

    _u8 = _u16 = _u32 = _uint

    def _array_len(self, index: int) -> int:
        return self._u8(index, 0)


def build_slaves(sched: Scheduler, bus: CanBus, node_ids: list[int], *,
                 ppm: list[float] | None = None, **kwargs: Any) -> list[CanopenSlave]:
    """Create one :class:`CanopenSlave` per node-ID, attach each to ``bus`` (same bit rate),
    optionally with per-slave clock offsets ``ppm``; ``kwargs`` go to every constructor."""
    slaves = []
    for i, node_id in enumerate(node_ids):
        clock = NodeClock(ppm[i]) if ppm is not None else None
        slave = CanopenSlave(sched, node_id, bitrate_bps=bus.bitrate_bps, clock=clock,
                             **kwargs)
        bus.attach(slave)
        slaves.append(slave)
    return slaves
