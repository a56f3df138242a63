"""Timing-accurate, frame-level model of a classical CAN bus (CAN 2.0A/2.0B).

Every participant is a :class:`CanNode` attached to one :class:`CanBus`. The bus runs on the
shared :class:`~sim_models.sim_time.Scheduler` (integer picoseconds): it never sleeps, it
schedules callbacks. Per frame it models

* arbitration, bit-exact on the arbitration field (standard and extended identifiers, RTR,
  SRR, IDE), among every node that offers a frame at an arbitration point;
* the exact frame length on the wire, including stuff bits, computed from the real bit stream
  (SOF .. CRC, CRC-15), so frame durations are bit-exact;
* acknowledgement, ACK errors, injected CRC errors and bit-rate mismatches, each ending in an
  error frame at a documented bit position;
* CAN 2.0B fault confinement (TEC/REC, error-active/error-passive/bus-off, suspend
  transmission, bus-off recovery);
* per-node oscillators (:class:`NodeClock`): a transmitter with a +ppm clock sends shorter bits.

It does not model individual bit sampling, resynchronisation (SJW), overload frames or error
flag superposition. See ``docs/can_bus_model.md`` for the exact rules and formulas.
"""

from __future__ import annotations

import bisect
import copy
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from typing import Any

import can

from sim_models.sim_time import PS_PER_S, EventHandle, Scheduler

__all__ = [
    "BITRATE_ERROR_BIT",
    "BUS_OFF_RECOVERY_BITS",
    "ERROR_FRAME_BITS",
    "SUSPEND_TRANSMISSION_BITS",
    "BusRecord",
    "CanBus",
    "CanBusProtocolError",
    "CanNode",
    "NodeClock",
    "QueueNode",
    "arbitration_bits",
    "crc15",
    "frame_bits",
    "frame_length_bits",
    "stuff",
    "stuffed_length",
    "worst_case_bits",
]

#: CRC-15 generator polynomial of CAN (x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1).
CRC15_POLY = 0x4599
#: CRC delimiter + ACK slot + ACK delimiter + 7 EOF + 3 intermission.
TRAILER_BITS = 1 + 1 + 1 + 7 + 3
#: error flag (6) + error delimiter (8) + intermission (3).
ERROR_FRAME_BITS = 6 + 8 + 3
#: Bit index (SOF = bit 0) at which a bit-rate mismatch is detected; the error flag starts at
#: the next bit. 19 is the last bit of the first 20 bits of every frame (an upper bound of the
#: "first stuff or form error" a node sampling at a wrong rate would see).
BITRATE_ERROR_BIT = 19
#: Extra recessive bits an error-passive node waits after its own transmission.
SUSPEND_TRANSMISSION_BITS = 8
#: 128 occurrences of 11 consecutive recessive bits.
BUS_OFF_RECOVERY_BITS = 128 * 11
#: Error-passive limit (TEC or REC >= this) and bus-off limit (TEC > BUS_OFF_LIMIT).
ERROR_PASSIVE_LIMIT = 128
BUS_OFF_LIMIT = 255
#: Receive error counter saturation (8-bit register in real controllers).
REC_MAX = 255
#: Round-robin deferrals of an arbitration round behind other events of the same instant.
_MAX_ROUND_DEFERRALS = 16

ERROR_ACTIVE = "error_active"
ERROR_PASSIVE = "error_passive"
BUS_OFF = "bus_off"


class CanBusProtocolError(RuntimeError):
    """Raised when the simulated bus sees something CANopen forbids (and the model rejects)."""


# ------------------------------------------------------------------------------------------
# Bit-level helpers (pure functions)
# ------------------------------------------------------------------------------------------


def crc15(bits: Iterable[int]) -> int:
    """CAN CRC-15 (polynomial 0x4599, initial value 0) of a bit sequence, MSB first."""
    crc = 0
    for bit in bits:
        feedback = (bit & 1) ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= CRC15_POLY
    return crc


def _int_bits(value: int, width: int) -> list[int]:
    """``width`` bits of ``value``, MSB first."""
    return [(value >> i) & 1 for i in range(width - 1, -1, -1)]


def _check_message(msg: can.Message) -> None:
    if msg.is_fd:
        raise ValueError("CAN FD frames are not supported by the classical CAN bus model")
    if msg.is_error_frame:
        raise ValueError("error frames cannot be transmitted as messages")
    limit = 1 << (29 if msg.is_extended_id else 11)
    if not 0 <= msg.arbitration_id < limit:
        raise ValueError(f"arbitration_id 0x{msg.arbitration_id:X} out of range")
    if not 0 <= msg.dlc <= 15:
        raise ValueError(f"DLC {msg.dlc} out of range 0..15")
    if not msg.is_remote_frame and len(msg.data) < min(msg.dlc, 8):
        raise ValueError(f"DLC {msg.dlc} but only {len(msg.data)} data bytes")


def _content_key(msg: can.Message) -> tuple[bool, int, bool, int, bytes]:
    """Everything that defines the bits of a frame on the wire."""
    n_data = 0 if msg.is_remote_frame else min(msg.dlc, 8)
    return (
        bool(msg.is_extended_id),
        int(msg.arbitration_id),
        bool(msg.is_remote_frame),
        int(msg.dlc),
        bytes(msg.data[:n_data]),
    )


def arbitration_bits(msg: can.Message) -> tuple[int, ...]:
    """The arbitration field as sent on the wire (after SOF, before stuffing).

    Standard: ID10..ID0, RTR, IDE(=0). Extended: ID28..ID18, SRR(=1), IDE(=1), ID17..ID0, RTR.
    The lexicographically smallest tuple wins arbitration (dominant = 0).
    """
    rtr = 1 if msg.is_remote_frame else 0
    if msg.is_extended_id:
        ident = msg.arbitration_id
        return tuple(_int_bits(ident >> 18, 11) + [1, 1] + _int_bits(ident & 0x3FFFF, 18)
                     + [rtr])
    return tuple(_int_bits(msg.arbitration_id, 11) + [rtr, 0])


@lru_cache(maxsize=4096)
def _frame_bits_cached(key: tuple[bool, int, bool, int, bytes]) -> tuple[int, ...]:
    extended, ident, remote, dlc, data = key
    rtr = 1 if remote else 0
    bits = [0]  # SOF
    if extended:
        bits += _int_bits(ident >> 18, 11) + [1, 1] + _int_bits(ident & 0x3FFFF, 18)
        bits += [rtr, 0, 0]  # RTR, r1, r0
    else:
        bits += _int_bits(ident, 11) + [rtr, 0, 0]  # RTR, IDE, r0
    bits += _int_bits(dlc, 4)
    for byte in data:
        bits += _int_bits(byte, 8)
    bits += _int_bits(crc15(bits), 15)
    return tuple(bits)


def frame_bits(msg: can.Message) -> list[int]:
    """Unstuffed bits of a frame from SOF to the end of the CRC sequence.

    Standard: SOF, ID10..0, RTR, IDE, r0, DLC3..0, data, CRC14..0.
    Extended: SOF, ID28..18, SRR, IDE, ID17..0, RTR, r1, r0, DLC3..0, data, CRC14..0.
    Remote frames carry no data field; a data frame with DLC 9..15 carries 8 bytes.
    """
    _check_message(msg)
    return list(_frame_bits_cached(_content_key(msg)))


def stuff(bits: Iterable[int]) -> list[int]:
    """Insert a complementary stuff bit after every run of 5 equal bits.

    A stuff bit starts a new run (it can itself be the first of the next 5 equal bits), so
    runs crossing field boundaries are counted exactly as on the wire.
    """
    out: list[int] = []
    run_value = -1
    run_length = 0
    for bit in bits:
        out.append(bit)
        if bit == run_value:
            run_length += 1
        else:
            run_value, run_length = bit, 1
        if run_length == 5:
            run_value = 1 - bit
            out.append(run_value)
            run_length = 1
    return out


@lru_cache(maxsize=4096)
def _stuffed_length_cached(key: tuple[bool, int, bool, int, bytes]) -> int:
    return len(stuff(_frame_bits_cached(key)))


def stuffed_length(msg: can.Message) -> int:
    """Number of bits from SOF to the end of the CRC sequence, stuff bits included."""
    _check_message(msg)
    return _stuffed_length_cached(_content_key(msg))


def frame_length_bits(msg: can.Message) -> int:
    """Bits on the wire for a complete frame: stuffed SOF..CRC + CRC delimiter + ACK slot +
    ACK delimiter + 7 EOF + 3 intermission."""
    return stuffed_length(msg) + TRAILER_BITS


def worst_case_bits(n_data: int, extended: bool = False) -> int:
    """Classical upper bound of :func:`frame_length_bits` for ``n_data`` data bytes.

    Standard: 47 + 8n + floor((34 + 8n - 1) / 4); extended: 67 + 8n + floor((54 + 8n - 1) / 4).
    """
    if not 0 <= n_data <= 8:
        raise ValueError(f"n_data {n_data} out of range 0..8")
    if extended:
        return 67 + 8 * n_data + (54 + 8 * n_data - 1) // 4
    return 47 + 8 * n_data + (34 + 8 * n_data - 1) // 4


def _round_half_up(value: Fraction) -> int:
    return math.floor(value + Fraction(1, 2))


# ------------------------------------------------------------------------------------------
# Nodes
# ------------------------------------------------------------------------------------------


class NodeClock:
    """Local oscillator of a node: frequency offset in ppm and initial phase.

    ``local = phase_ps + true * (1 + ppm * 1e-6)``, rounded to the nearest picosecond. The
    mapping is evaluated with exact rational arithmetic (the float ``ppm`` is taken exactly),
    so it is deterministic and free of float accumulation. Changing ``ppm`` later changes the
    whole mapping (it is not integrated over time).
    """

    def __init__(self, ppm: float = 0.0, phase_ps: int = 0) -> None:
        self.ppm: float = ppm
        self.phase_ps: int = int(phase_ps)

    @property
    def scale(self) -> Fraction:
        """Exact ``1 + ppm * 1e-6``."""
        return 1 + Fraction(self.ppm) / 1_000_000

    def local_ps(self, true_ps: int) -> int:
        """Local time of this oscillator at true (bus) time ``true_ps``."""
        return self.phase_ps + _round_half_up(true_ps * self.scale)

    def true_ps(self, local_ps: int) -> int:
        """Inverse of :meth:`local_ps` (rounded; exact round trip for ppm >= 0)."""
        return _round_half_up((local_ps - self.phase_ps) / self.scale)

    def __repr__(self) -> str:
        return f"NodeClock(ppm={self.ppm!r}, phase_ps={self.phase_ps!r})"


class CanNode:
    """Base class of every bus participant. Subclasses override the hooks.

    The fault-confinement state (``tec``, ``rec``, :attr:`error_state`) is maintained by the
    bus through this base class; subclasses should only read it (or use
    :meth:`reset_fault_confinement` / :meth:`set_error_counters`).

    ``bitrate_bps`` and ``listen_only`` are properties; the base class stores plain values
    that can be assigned, a subclass may override them with computed properties (e.g. from
    CNF registers and the operating mode). When a node comes onto the bus or gains a frame to
    send it must call ``self.bus.request_tx()``.
    """

    #: REC after a successful reception when REC was above 127 (CAN allows 119..127).
    rec_after_passive_rx: int = 127
    #: Recover from bus-off automatically after 1408 bit times (class default; may be
    #: overridden per class or per instance).
    auto_bus_off_recovery: bool = True

    def __init__(self, name: str, clock: NodeClock | None = None) -> None:
        self.name: str = name
        self.clock: NodeClock = clock if clock is not None else NodeClock()
        self.bus: CanBus | None = None
        self.tec: int = 0
        self.rec: int = 0
        self._bus_off = False
        self._reported_state = ERROR_ACTIVE
        self._recovery: EventHandle | None = None
        self._suspend_until_ps = 0
        self._bitrate_bps: int | None = None
        self._listen_only = False

    # --- configuration (overridable properties) --------------------------------------------

    @property
    def bitrate_bps(self) -> int | None:
        """Nominal bit rate; None = not on the bus (neither transmits, receives nor ACKs)."""
        return self._bitrate_bps

    @bitrate_bps.setter
    def bitrate_bps(self, value: int | None) -> None:
        self._bitrate_bps = value
        if value is not None and self.bus is not None:
            self.bus.request_tx()

    @property
    def listen_only(self) -> bool:
        """Receives, never ACKs, never transmits, never signals errors."""
        return self._listen_only

    @listen_only.setter
    def listen_only(self, value: bool) -> None:
        self._listen_only = bool(value)
        if not value and self.bus is not None:
            self.bus.request_tx()

    # --- fault confinement ---------------------------------------------------------------

    @property
    def error_state(self) -> str:
        """``"error_active"`` | ``"error_passive"`` | ``"bus_off"``."""
        if self._bus_off:
            return BUS_OFF
        if self.tec >= ERROR_PASSIVE_LIMIT or self.rec >= ERROR_PASSIVE_LIMIT:
            return ERROR_PASSIVE
        return ERROR_ACTIVE

    @property
    def error_warning(self) -> bool:
        """TEC or REC >= 96 (the usual warning limit, e.g. MCP2510 EFLG.EWARN)."""
        return self.tec >= 96 or self.rec >= 96

    @property
    def bus_off_recovery_pending(self) -> bool:
        """True while a bus-off recovery timer runs."""
        return self._recovery is not None and self._recovery.pending

    def reset_fault_confinement(self) -> None:
        """Counters to 0, error-active, recovery timer cancelled (e.g. a controller reset).

        Does not call :meth:`on_error_state_change`; the caller is resetting itself.
        """
        self.tec = 0
        self.rec = 0
        self._bus_off = False
        self._reported_state = ERROR_ACTIVE
        self._cancel_recovery()
        self._suspend_until_ps = 0

    def set_error_counters(self, tec: int | None = None, rec: int | None = None) -> None:
        """Set TEC/REC directly (test helper); reports state changes, may enter bus-off."""
        if tec is not None:
            self.tec = int(tec)
        if rec is not None:
            self.rec = int(rec)
        self._fc_update(self._now())

    def request_bus_off_recovery(self) -> None:
        """Start the bus-off recovery sequence (needed when ``auto_bus_off_recovery`` is
        False). Does nothing when the node is not bus-off or recovery already runs."""
        if self._bus_off and not self.bus_off_recovery_pending:
            self._start_recovery(self._now())

    # --- hooks for subclasses ------------------------------------------------------------

    def tx_candidate(self) -> can.Message | None:
        """Frame this node wants to send now (asked at every arbitration point). Must be cheap
        and free of side effects; return the same object until it is sent or withdrawn."""
        return None

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        """Own frame sent successfully; ``msg`` is the object returned by tx_candidate,
        ``t_ps`` the end of EOF."""

    def on_arbitration_lost(self, msg: can.Message, t_ps: int) -> None:
        """Lost arbitration (``t_ps`` = SOF); asked again at the next arbitration point."""

    def on_tx_error(self, msg: can.Message, t_ps: int, reason: str) -> None:
        """Own frame destroyed (``t_ps`` = start of the error flag); it is asked again."""

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        """Valid frame from another node (a private copy; ``t_ps`` = end of EOF)."""

    def on_bus_error(self, t_ps: int, reason: str) -> None:
        """An error frame occurred on the bus (``t_ps`` = start of the error flag)."""

    def on_error_state_change(self, old: str, new: str, t_ps: int) -> None:
        """Fault-confinement state changed."""

    def on_bus_idle(self, t_ps: int) -> None:
        """Bus became idle (end of intermission)."""

    def on_bus_activity(self, t_ps: int) -> None:
        """SOF seen on the bus; called on every attached node, also those off the bus."""

    # --- internals -----------------------------------------------------------------------

    def _now(self) -> int:
        return self.bus.sched.now_ps if self.bus is not None else 0

    def _fc_update(self, t_ps: int) -> None:
        """Enter bus-off if needed and report a state change."""
        if not self._bus_off and self.tec > BUS_OFF_LIMIT:
            self._bus_off = True
            if self.auto_bus_off_recovery:
                self._start_recovery(t_ps)
        new = self.error_state
        old = self._reported_state
        if new != old:
            self._reported_state = new
            self.on_error_state_change(old, new, t_ps)

    def _start_recovery(self, t_ps: int) -> None:
        self._cancel_recovery()
        if self.bus is None:
            return
        t_done = t_ps + self.bus.duration_ps(BUS_OFF_RECOVERY_BITS, self.clock)
        self._recovery = self.bus.sched.call_at(t_done, self._recover)

    def _cancel_recovery(self) -> None:
        if self._recovery is not None:
            self._recovery.cancel()
            self._recovery = None

    def _recover(self) -> None:
        self._recovery = None
        if not self._bus_off:
            return
        self.tec = 0
        self.rec = 0
        self._bus_off = False
        assert self.bus is not None
        self._fc_update(self.bus.sched.now_ps)
        self.bus.request_tx()

    def __repr__(self) -> str:
        return (f"<{type(self).__name__} {self.name!r} bitrate={self.bitrate_bps} "
                f"tec={self.tec} rec={self.rec} {self.error_state}>")


class QueueNode(CanNode):
    """Simple node for tests and benches: sends queued frames in order, records what it got.

    ``send()`` appends to the queue and requests transmission; ``received`` holds
    ``(t_ps, msg)`` for every valid frame, ``sent`` ``(t_ps, msg)`` for every own frame,
    ``errors`` ``(t_ps, reason)`` for own frames destroyed, ``events`` every hook call.
    """

    def __init__(self, name: str, bitrate_bps: int | None = None,
                 clock: NodeClock | None = None, listen_only: bool = False) -> None:
        super().__init__(name, clock)
        self._bitrate_bps = bitrate_bps
        self._listen_only = listen_only
        self.queue: list[can.Message] = []
        self.received: list[tuple[int, can.Message]] = []
        self.sent: list[tuple[int, can.Message]] = []
        self.errors: list[tuple[int, str]] = []
        self.lost: list[tuple[int, can.Message]] = []
        self.state_changes: list[tuple[int, str, str]] = []
        self.bus_errors: list[tuple[int, str]] = []
        self.activity: list[int] = []

    def send(self, *msgs: can.Message) -> None:
        self.queue.extend(msgs)
        if self.bus is not None:
            self.bus.request_tx()

    def tx_candidate(self) -> can.Message | None:
        return self.queue[0] if self.queue else None

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        if self.queue and self.queue[0] is msg:
            self.queue.pop(0)
        self.sent.append((t_ps, msg))

    def on_arbitration_lost(self, msg: can.Message, t_ps: int) -> None:
        self.lost.append((t_ps, msg))

    def on_tx_error(self, msg: can.Message, t_ps: int, reason: str) -> None:
        self.errors.append((t_ps, reason))

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        self.received.append((t_ps, msg))

    def on_bus_error(self, t_ps: int, reason: str) -> None:
        self.bus_errors.append((t_ps, reason))

    def on_error_state_change(self, old: str, new: str, t_ps: int) -> None:
        self.state_changes.append((t_ps, old, new))

    def on_bus_activity(self, t_ps: int) -> None:
        self.activity.append(t_ps)


# ------------------------------------------------------------------------------------------
# Bus
# ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BusRecord:
    """One completed frame or error frame."""

    kind: str  #: "frame" | "error"
    msg: can.Message  #: copy of the frame; timestamp = t_start_ps / 1e12 (seconds)
    sender: str  #: transmitter name ("a+b" for merged identical frames)
    t_start_ps: int  #: SOF
    t_end_ps: int  #: end of intermission (bus idle again)
    n_bits: int  #: bits on the wire (stuff bits, EOF, intermission / bits until error + 17)
    reason: str = ""  #: error reason ("ack", "crc", "bitrate")
    receivers: tuple[str, ...] = ()  #: nodes that got on_rx
    detector: str = ""  #: node whose error flag destroyed the frame ("" = transmitter/all)

    @property
    def duration_ps(self) -> int:
        return self.t_end_ps - self.t_start_ps


@dataclass
class _Transfer:
    """The frame on the wire."""

    senders: list[CanNode]
    msgs: list[can.Message]  # per sender, the object returned by tx_candidate
    record_msg: can.Message
    t_start_ps: int
    t_event_ps: int  # end of EOF (success) or start of the error flag
    t_end_ps: int
    n_bits: int
    reason: str  # "" = success
    detector: str
    on_bus: list[CanNode]  # other nodes on the bus at SOF (bitrate not None, not bus-off)
    receivers: tuple[str, ...] = ()


class CanBus:
    """Frame-level CAN bus on a :class:`Scheduler`.

    Nodes within ``bitrate_tolerance`` (relative) of ``bitrate_bps`` can decode frames; all
    timing uses the bus bit rate scaled by the transmitter's :class:`NodeClock`.
    """

    def __init__(self, sched: Scheduler, bitrate_bps: int, *, name: str = "can0",
                 bitrate_tolerance: float = 0.005) -> None:
        if bitrate_bps <= 0:
            raise ValueError("bitrate_bps must be positive")
        self.sched = sched
        self.bitrate_bps = int(bitrate_bps)
        self.name = name
        self.bitrate_tolerance = bitrate_tolerance
        self.records: list[BusRecord] = []
        self.stats: dict[str, int] = {
            "frames_ok": 0,
            "error_frames": 0,
            "arbitration_rounds": 0,
            "arbitration_lost": 0,
            "merged_frames": 0,
            "errors_ack": 0,
            "errors_crc": 0,
            "errors_bitrate": 0,
            "bits_ok": 0,
            "bits_error": 0,
            "busy_ps": 0,
        }
        self._nodes: list[CanNode] = []
        self._listeners: list[Callable[[BusRecord], Any]] = []
        self._current: _Transfer | None = None
        self._round: EventHandle | None = None
        self._deferrals = 0
        self._corrupt: list[list[Any]] = []  # [sender name | None, remaining count]
        self._record_ends: list[int] = []

    # --- configuration -------------------------------------------------------------------

    @property
    def nodes(self) -> tuple[CanNode, ...]:
        return tuple(self._nodes)

    def attach(self, node: CanNode) -> CanNode:
        """Connect ``node`` to the bus (sets ``node.bus``); returns it."""
        if node.bus is not None:
            raise ValueError(f"node {node.name!r} is already attached to a bus")
        if any(n.name == node.name for n in self._nodes):
            raise ValueError(f"duplicate node name {node.name!r}")
        node.bus = self
        self._nodes.append(node)
        self.request_tx()
        return node

    def add_listener(self, cb: Callable[[BusRecord], Any]) -> None:
        """``cb(record)`` is called after each frame / error frame completes."""
        self._listeners.append(cb)

    def bitrate_matches(self, node: CanNode) -> bool:
        """Node is on the bus and its bit rate is within the tolerance of the bus."""
        rate = node.bitrate_bps
        if rate is None:
            return False
        return abs(rate - self.bitrate_bps) <= self.bitrate_tolerance * self.bitrate_bps

    def duration_ps(self, n_bits: int, clock: NodeClock | None = None) -> int:
        """``n_bits`` bit times at the bus bit rate on ``clock``, rounded to 1 ps."""
        scale = clock.scale if clock is not None else Fraction(1)
        return _round_half_up(Fraction(n_bits * PS_PER_S, self.bitrate_bps) / scale)

    def frame_duration_ps(self, msg: can.Message, clock: NodeClock | None = None) -> int:
        """Duration of ``msg`` from SOF to the end of the intermission."""
        return self.duration_ps(frame_length_bits(msg), clock)

    # --- control -------------------------------------------------------------------------

    @property
    def idle(self) -> bool:
        """No frame or error frame on the wire."""
        return self._current is None

    def request_tx(self, node: CanNode | None = None) -> None:
        """A node gained or changed its tx_candidate. If the bus is idle an arbitration round
        runs at the current time (after the other events of this instant), else the node
        competes at the next idle point. ``node`` is accepted for readability and ignored."""
        if self._current is None:
            self._schedule_round(self.sched.now_ps)

    def corrupt_next_frame(self, sender: str | None = None, count: int = 1) -> None:
        """The next ``count`` frames (of ``sender``, or any) get a CRC error seen by all
        receivers. Only frames that would otherwise be acknowledged consume an injection."""
        if count < 1:
            raise ValueError("count must be >= 1")
        self._corrupt.append([sender, count])

    def force_bus_off(self, node: CanNode) -> None:
        """Put ``node`` into bus-off now (TEC = 256); recovery per its settings."""
        if node.error_state == BUS_OFF:
            return
        node.tec = BUS_OFF_LIMIT + 1
        node._fc_update(self.sched.now_ps)

    # --- measurements --------------------------------------------------------------------

    def load(self, t0_ps: int, t1_ps: int) -> float:
        """Fraction of ``[t0_ps, t1_ps)`` during which the bus was busy (frames and error
        frames, each including its intermission). The frame on the wire counts up to now."""
        if t1_ps <= t0_ps:
            raise ValueError("empty window")
        busy = 0
        i = bisect.bisect_right(self._record_ends, t0_ps)
        while i < len(self.records):
            rec = self.records[i]
            if rec.t_start_ps >= t1_ps:
                break
            busy += min(rec.t_end_ps, t1_ps) - max(rec.t_start_ps, t0_ps)
            i += 1
        cur = self._current
        if cur is not None:
            end = min(cur.t_end_ps, self.sched.now_ps, t1_ps)
            start = max(cur.t_start_ps, t0_ps)
            busy += max(0, end - start)
        return busy / (t1_ps - t0_ps)

    def write_trace(self, path: Any) -> None:
        """Write the successful frames with simulated timestamps (seconds since t = 0).

        ``.log``: :class:`can.CanutilsLogWriter` (candump -L); ``.asc``: :class:`can.ASCWriter`
        (its header dates are fixed to the epoch so the file is reproducible). Both formats
        store microseconds.
        """
        path_str = str(path)
        frames = [r.msg for r in self.records if r.kind == "frame"]
        if path_str.endswith(".log"):
            writer: Any = can.CanutilsLogWriter(path_str, channel=self.name)
            for msg in frames:
                writer.on_message_received(msg)
            writer.stop()
        elif path_str.endswith(".asc"):
            writer = can.ASCWriter(path_str, channel=1)
            # Anchor the relative ASC timestamps at simulated t = 0 (python-can would
            # otherwise use the first frame's timestamp as origin).
            epoch = "Thu Jan 01 00:00:00.000 1970"
            writer.file.write(f"Begin Triggerblock {epoch}\n")
            writer.header_written = True
            writer.started = writer.last_timestamp = 0.0
            writer.log_event("Start of measurement", 0.0)
            for msg in frames:
                asc_msg = copy.copy(msg)
                asc_msg.channel = None
                writer.on_message_received(asc_msg)
            writer.stop()
            with open(path_str, encoding="utf-8") as f:
                lines = f.readlines()
            lines = [f"date {epoch}\n" if ln.startswith("date ") else ln for ln in lines]
            with open(path_str, "w", encoding="utf-8") as f:
                f.writelines(lines)
        else:
            raise ValueError(f"unsupported trace format {path_str!r} (use .log or .asc)")

    # --- arbitration ---------------------------------------------------------------------

    def _schedule_round(self, t_ps: int) -> None:
        if self._round is not None and self._round.pending:
            if self._round.t_ps <= t_ps:
                return
            self._round.cancel()
        self._round = self.sched.call_at(t_ps, self._arbitrate)

    def _can_compete(self, node: CanNode) -> bool:
        return (node.bitrate_bps is not None and not node.listen_only
                and node.error_state != BUS_OFF)

    def _arbitrate(self) -> None:
        self._round = None
        if self._current is not None:
            return
        now = self.sched.now_ps
        # Let every other event of this instant run first, so that all requests made at the
        # same time compete in one round.
        if self.sched.next_event_ps() == now and self._deferrals < _MAX_ROUND_DEFERRALS:
            self._deferrals += 1
            self._round = self.sched.call_at(now, self._arbitrate)
            return
        self._deferrals = 0

        contenders: list[tuple[tuple[int, ...], CanNode, can.Message]] = []
        next_unsuspend: int | None = None
        for node in self._nodes:
            if not self._can_compete(node):
                continue
            if node._suspend_until_ps > now:
                t = node._suspend_until_ps
                next_unsuspend = t if next_unsuspend is None else min(next_unsuspend, t)
                continue
            msg = node.tx_candidate()
            if msg is not None:
                _check_message(msg)
                contenders.append((arbitration_bits(msg), node, msg))
        if not contenders:
            if next_unsuspend is not None:
                self._schedule_round(next_unsuspend)
            return

        best = min(c[0] for c in contenders)
        winners = [c for c in contenders if c[0] == best]
        losers = [c for c in contenders if c[0] != best]
        content = _content_key(winners[0][2])
        for _, _node, msg in winners[1:]:
            if _content_key(msg) != content:
                names = ", ".join(f"{n.name}: {m}" for _, n, m in winners)
                raise CanBusProtocolError(
                    f"{self.name}: nodes won arbitration with the same arbitration field "
                    f"(id 0x{msg.arbitration_id:X}) but different frames ({names}); "
                    "CANopen requires unique COB-IDs per transmitter")
        self._start_transfer(now, [c[1] for c in winners], [c[2] for c in winners])
        self.stats["arbitration_rounds"] += 1
        self.stats["arbitration_lost"] += len(losers)
        if len(winners) > 1:
            self.stats["merged_frames"] += 1
        for node in self._nodes:
            node._suspend_until_ps = 0
            node.on_bus_activity(now)
        for _, node, msg in losers:
            node.on_arbitration_lost(msg, now)

    def _take_corruption(self, senders: list[CanNode]) -> bool:
        names = {s.name for s in senders}
        for entry in self._corrupt:
            if entry[0] is None or entry[0] in names:
                entry[1] -= 1
                if entry[1] <= 0:
                    self._corrupt.remove(entry)
                return True
        return False

    def _start_transfer(self, now: int, senders: list[CanNode],
                        msgs: list[can.Message]) -> None:
        msg = msgs[0]
        clock = senders[0].clock
        n_stuffed = stuffed_length(msg)
        on_bus = [n for n in self._nodes if n not in senders and n.bitrate_bps is not None
                  and n.error_state != BUS_OFF]
        matching = [n for n in on_bus if self.bitrate_matches(n)]
        ackers = [n for n in matching if not n.listen_only]
        destroyers = [n for n in on_bus if not self.bitrate_matches(n) and not n.listen_only
                      and n.error_state == ERROR_ACTIVE]
        reason = ""
        detector = ""
        if not all(self.bitrate_matches(s) for s in senders):
            if any(not n.listen_only for n in on_bus):
                reason, err_bit = "bitrate", BITRATE_ERROR_BIT
                detector = senders[0].name
            else:
                reason, err_bit = "ack", n_stuffed + 1  # ACK slot
        elif destroyers:
            reason, err_bit, detector = "bitrate", BITRATE_ERROR_BIT, destroyers[0].name
        elif not ackers:
            reason, err_bit = "ack", n_stuffed + 1  # ACK slot
        elif self._take_corruption(senders):
            reason, err_bit = "crc", n_stuffed + 2  # ACK delimiter
        record_msg = copy.copy(msg)
        record_msg.timestamp = now / PS_PER_S
        record_msg.channel = self.name
        record_msg.is_rx = False
        if reason:
            n_bits = err_bit + 1 + ERROR_FRAME_BITS
            t_event = now + self.duration_ps(err_bit + 1, clock)
        else:
            n_bits = n_stuffed + TRAILER_BITS
            t_event = now + self.duration_ps(n_bits - 3, clock)
        t_end = now + self.duration_ps(n_bits, clock)
        self._current = _Transfer(senders, msgs, record_msg, now, t_event, t_end, n_bits,
                                  reason, detector, on_bus)
        if reason:
            self.sched.call_at(t_event, self._on_error)
        else:
            self.sched.call_at(t_event, self._on_eof)
        self.sched.call_at(t_end, self._on_idle)

    # --- frame completion ----------------------------------------------------------------

    def _still_on_bus(self, node: CanNode) -> bool:
        return node.bitrate_bps is not None and node.error_state != BUS_OFF

    def _count_mismatched_rx(self, cur: _Transfer) -> None:
        """Every mismatched, error-signalling receiver detects an error in each frame (+8)."""
        for node in cur.on_bus:
            if (self._still_on_bus(node) and not node.listen_only
                    and not self.bitrate_matches(node)):
                node.rec = min(REC_MAX, node.rec + 8)

    def _on_eof(self) -> None:
        cur = self._current
        assert cur is not None
        t = self.sched.now_ps
        receivers = [n for n in cur.on_bus if self._still_on_bus(n) and self.bitrate_matches(n)]
        for s in cur.senders:
            if s.error_state != BUS_OFF and s.tec > 0:
                s.tec -= 1
        for r in receivers:
            if r.listen_only:
                continue
            if r.rec > 127:
                r.rec = r.rec_after_passive_rx
            elif r.rec > 0:
                r.rec -= 1
        self._count_mismatched_rx(cur)
        for node in [*cur.senders, *cur.on_bus]:
            node._fc_update(t)
        cur.receivers = tuple(r.name for r in receivers)
        for s, m in zip(cur.senders, cur.msgs):
            s.on_tx_done(m, t)
        for r in receivers:
            rx_msg = copy.copy(cur.record_msg)
            rx_msg.is_rx = True
            r.on_rx(rx_msg, t)

    def _on_error(self) -> None:
        cur = self._current
        assert cur is not None
        t = self.sched.now_ps
        for s in cur.senders:
            if s.error_state == BUS_OFF:
                continue
            # CAN exception: an error-passive transmitter's ACK error (no dominant bit during
            # its passive error flag) does not change TEC.
            if cur.reason == "ack" and s.error_state == ERROR_PASSIVE:
                continue
            s.tec += 8
        for node in cur.on_bus:
            if (not self._still_on_bus(node) or node.listen_only
                    or not self.bitrate_matches(node)):
                continue
            node.rec = min(REC_MAX, node.rec + 1)
        self._count_mismatched_rx(cur)
        for node in [*cur.senders, *cur.on_bus]:
            node._fc_update(t)
        for s, m in zip(cur.senders, cur.msgs):
            s.on_tx_error(m, t, cur.reason)
        for node in self._nodes:
            if node.bitrate_bps is not None:
                node.on_bus_error(t, cur.reason)

    def _on_idle(self) -> None:
        cur = self._current
        assert cur is not None
        t = self.sched.now_ps
        self._current = None
        kind = "error" if cur.reason else "frame"
        record = BusRecord(kind, cur.record_msg, "+".join(s.name for s in cur.senders),
                           cur.t_start_ps, cur.t_end_ps, cur.n_bits, cur.reason,
                           cur.receivers, cur.detector)
        self.records.append(record)
        self._record_ends.append(record.t_end_ps)
        st = self.stats
        st["busy_ps"] += record.duration_ps
        if cur.reason:
            st["error_frames"] += 1
            st["errors_" + cur.reason] = st.get("errors_" + cur.reason, 0) + 1
            st["bits_error"] += cur.n_bits
        else:
            st["frames_ok"] += 1
            st["bits_ok"] += cur.n_bits
        for s in cur.senders:
            if s.error_state == ERROR_PASSIVE:
                s._suspend_until_ps = t + self.duration_ps(SUSPEND_TRANSMISSION_BITS, s.clock)
        for cb in list(self._listeners):
            cb(record)
        for node in self._nodes:
            node.on_bus_idle(t)
        self._schedule_round(t)
