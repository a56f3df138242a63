"""Fault injection and checkers of the system fuzz bench (``tb/test_fuzz_system.py``).

The bench is the system of :mod:`tb.tblib.system_tb` (``canopen_master_top`` RTL, MCP2510
model, bit-exact CAN bus, CiA 301 reference slaves) running SYNC, PDOs, heartbeats and host
SDO transfers while this module disturbs it:

* :class:`FuzzNode`, a raw bus node, sends random frames (any 11-bit ID including the
  master's own COB-IDs, some 29-bit ones, DLC 0..15, RTR), bursts of back-to-back frames up to
  100 % bus load and babbling phases (one low-priority ID, back to back, for milliseconds);
* the bus gets CRC errors on random frames (:meth:`CanBus.corrupt_next_frame`), the master's
  controller is forced bus-off, the master and/or the MCP2510 are reset at a random SPI clock
  edge, and the host writes random values to read-only or unmapped addresses and
  out-of-range values to command registers.

The checkers are pure functions of what the run left (bus records, TX2RTS firing times, the
FSM log, register snapshots, the SDO log); each returns a list of violations (strings), empty
when the run is right. ``tb/test_fuzz_system.py::test_fuzz_checkers_can_fail`` feeds each one a
doctored log and sees it report.
"""

from __future__ import annotations

import math
import random
from bisect import bisect_left, bisect_right
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import can

from sim_models.can_bus import QueueNode, arbitration_bits, worst_case_bits
from tb.tblib.fsm_states import State

#: the frames the injector's IDs are drawn from, by weight: the master's own COB-IDs (SYNC,
#: its TPDOs and SDO requests), the COB-IDs it consumes (slave TPDOs, SDO responses, EMCY,
#: heartbeat), anything else, and 29-bit frames (dropped and counted by the master)
ID_CLASSES = ("sync", "master_tpdo", "sdo_req", "slave_tpdo", "sdo_resp", "emcy", "heartbeat",
              "nmt", "any", "extended")

#: SDO abort codes the client may send (docs/canopen_sdo_client.md, "Client aborts"); a
#: server abort carries the server's code, whatever it is
CLIENT_ABORT_CODES = frozenset({0x0504_0001, 0x0800_0000, 0x0503_0000, 0x0504_0005,
                                0x0607_0010, 0x0504_0000})


def longest_frame_bits() -> int:
    """Bits of the longest base data frame (8 bytes, worst-case stuffing, intermission)."""
    return worst_case_bits(8)


# ============================================================================ the raw node
class FuzzNode(QueueNode):
    """The injector's bus node: a :class:`QueueNode` that holds a frame back while another
    node offers a *different* frame with the same arbitration field.

    Two transmitters of one ID with different contents would both win arbitration and then
    collide bit by bit (bit errors on a real bus); the bus model does not model that and
    stops with ``CanBusProtocolError``. Holding back is the same outcome a real injector
    would see (its frame destroyed and retried after the other one), without the error frame.
    """

    def __init__(self, name: str, bitrate_bps: int) -> None:
        super().__init__(name, bitrate_bps)
        self.n_sent = 0
        self.held_back = 0

    def _others_candidates(self) -> Iterable[can.Message]:
        for node in self.bus.nodes if self.bus is not None else ():
            if node is self or node.bitrate_bps is None or node.error_state == "bus_off":
                continue
            msg = node.tx_candidate()
            if msg is not None:
                yield msg

    def tx_candidate(self) -> can.Message | None:
        if not self.queue:
            return None
        msg = self.queue[0]
        key = arbitration_bits(msg)
        for other in self._others_candidates():
            if arbitration_bits(other) == key and (
                    bytes(other.data) != bytes(msg.data) or other.dlc != msg.dlc):
                self.held_back += 1
                return None
        return msg

    def on_tx_done(self, msg: can.Message, t_ps: int) -> None:
        super().on_tx_done(msg, t_ps)
        self.n_sent += 1

    def on_bus_idle(self, t_ps: int) -> None:
        # a frame held back competes again at every idle point
        if self.queue and self.bus is not None:
            self.bus.request_tx()


@dataclass
class Topology:
    """What the master and the slaves of the run use, for the ID generator and the checks."""

    nodes: tuple[int, ...]
    rpdo_dlc: int  #: DLC the master expects on 180h + node (the slaves' TPDO1)
    tpdo_dlc: int  #: DLC the master sends on 200h + node
    absent_node: int = 0x7E  #: a node-ID no slave has (NMT / SDO frames for it are harmless)


def random_frame(rng: random.Random, topo: Topology) -> can.Message:
    """One random frame. NMT frames (ID 0) only address ``absent_node`` or carry an invalid
    command specifier and SDO requests (600h + n) only address absent nodes, so that the
    slaves' states stay what the scenario expects; every other class may hit anything."""
    # SYNCs and the master's TPDO COB-IDs make the slaves answer (TPDOs, EMCYs): rarer
    cls = rng.choices(ID_CLASSES, weights=(1, 2, 2, 12, 4, 2, 2, 2, 30, 3))[0]
    n = rng.choice(topo.nodes)
    ext = False
    if cls == "sync":
        cid = 0x080
    elif cls == "master_tpdo":
        cid = 0x200 + n
    elif cls == "sdo_req":
        cid = 0x600 + topo.absent_node
    elif cls == "slave_tpdo":
        cid = 0x180 + n
    elif cls == "sdo_resp":
        cid = 0x580 + n
    elif cls == "emcy":
        cid = 0x080 + n
    elif cls == "heartbeat":
        cid = 0x700 + topo.absent_node
    elif cls == "nmt":
        cid = 0x000
    elif cls == "extended":
        cid, ext = rng.getrandbits(29), True
    else:
        cid = rng.randrange(0x001, 0x800)
        # the master's and slaves' request IDs stay addressed to nobody (see above)
        if cid == 0 or 0x601 <= cid <= 0x67F or 0x701 <= cid <= 0x77F:
            cid = 0x600 + topo.absent_node
    rtr = rng.random() < 0.1 and cid != 0
    if cls == "slave_tpdo" and not rtr:
        # half of them valid PDOs, half with a DLC that disagrees with the mapping
        dlc = topo.rpdo_dlc if rng.random() < 0.5 else rng.choice(
            [d for d in range(16) if d != topo.rpdo_dlc])
    elif cls == "nmt":
        dlc = 2
    else:  # short frames mostly (more frames per bus time), sometimes DLC 9..15
        dlc = rng.randrange(9, 16) if rng.random() < 0.05 else min(rng.randrange(9),
                                                                   rng.randrange(9))
    n_data = 0 if rtr else min(dlc, 8)
    data = bytes(rng.getrandbits(8) for _ in range(n_data))
    if cls == "nmt":
        cs = rng.choice([0x01, 0x02, 0x80, 0x81, 0x82, 0x00, 0x55])
        data = bytes([cs, topo.absent_node if cs in (0x01, 0x02, 0x80, 0x81, 0x82) else n])
    return can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=rtr, dlc=dlc,
                       data=data)


def babble_frame(rng: random.Random) -> can.Message:
    """A babbling node's frame: one ID above the SYNC's (lower priority), 8 bytes."""
    return can.Message(arbitration_id=rng.randrange(0x081, 0x800) | 0x400,
                       is_extended_id=False, data=bytes(rng.getrandbits(8) for _ in range(8)))


# ============================================================================ checkers
@dataclass
class BusFrame:
    """What a checker needs of a :class:`sim_models.can_bus.BusRecord`."""

    kind: str
    can_id: int
    rtr: bool
    ext: bool
    dlc: int
    sender: str
    t_start: int
    t_end: int
    receivers: tuple[str, ...] = ()
    data: bytes = b""

    @classmethod
    def of(cls, r) -> BusFrame:
        m = r.msg
        return cls(r.kind, m.arbitration_id, bool(m.is_remote_frame), bool(m.is_extended_id),
                   m.dlc, r.sender, r.t_start_ps, r.t_end_ps, tuple(r.receivers),
                   bytes(m.data))


def _beats_sync(f: BusFrame) -> bool:
    """A frame that wins arbitration against the SYNC (080h data frame, DLC 0/1)."""
    if f.kind == "error":
        return True
    base = f.can_id >> 18 if f.ext else f.can_id
    return base < 0x080 or (base == 0x080 and not f.ext and not f.rtr)


def check_sync(fires: Sequence[int], frames: Sequence[BusFrame], master: str, period_ps: int,
               windows: Sequence[tuple[int, int]], bit_ps: int) -> tuple[list[str], dict]:
    """The SYNC producer in each window ``(t0, t1)`` of undisturbed operation (no reset,
    bus-off or SYNC reconfiguration inside).

    * every interval between two TX2RTS firings ``fires`` is the period exactly;
    * each firing puts exactly one SYNC (080h from ``master``) on the bus, before the next
      firing, and its start of frame is late only by what CAN arbitration explains: the frame
      on the wire at the firing (at most one longest frame), frames that beat the SYNC (lower
      IDs, error frames, the SYNC's own failed attempts) and an 8-bit suspend-transmission gap
      after each of the master's own frames when it is error passive; anything else (a
      lower-priority frame starting before the SYNC, an idle bus) is a violation.

    Returns (violations, figures: fired, max delay in ps and the max delay with no
    higher-priority traffic, which must stay within one longest frame).
    """
    errs: list[str] = []
    syncs = [f for f in frames if f.kind == "frame" and f.can_id == 0x080 and not f.ext
             and not f.rtr and master in f.sender.split("+")]
    starts = [f.t_start for f in frames]
    sync_starts = [f.t_start for f in syncs]
    longest = longest_frame_bits() * bit_ps
    fig = {"fired": 0, "max_delay_ps": 0, "max_delay_clean_ps": 0}
    for t0, t1 in windows:
        fw = [t for t in fires if t0 <= t < t1]
        fig["fired"] += len(fw)
        for a, b in zip(fw, fw[1:]):
            if b - a != period_ps:
                errs.append(f"SYNC fired at {a} and {b} ps: interval {b - a} != {period_ps}")
        for k, tf in enumerate(fw):
            t_next = fw[k + 1] if k + 1 < len(fw) else t1
            i = bisect_left(sync_starts, tf)
            mine = [s for s in sync_starts[i:] if s < t_next]
            if len(mine) != 1:
                errs.append(f"SYNC fired at {tf} ps: {len(mine)} SYNC frames before the next "
                            "firing")
                continue
            sof = mine[0]
            delay = sof - tf
            fig["max_delay_ps"] = max(fig["max_delay_ps"], delay)
            # the frame on the wire when it fired: one that started before the firing, or at
            # its very instant (the chip cannot join an arbitration whose start of frame
            # coincides with the TX2RTS edge; the bit-exact bus makes such ties common, since
            # the bit grid and the SYNC period are both whole microseconds)
            j = bisect_right(starts, tf)
            explained = 0
            if j > 0 and frames[j - 1].t_end > tf:
                explained += min(frames[j - 1].t_end, sof) - tf
                if master in frames[j - 1].sender.split("+"):
                    explained += 8 * bit_ps  # suspend transmission (error passive)
                if frames[j - 1].t_end - tf > longest:
                    errs.append(f"SYNC fired at {tf} ps behind a frame longer than the longest")
            clean = True
            prev = frames[j - 1] if j > 0 else None
            for f in frames[j:]:
                if f.t_start >= sof:
                    break
                # a frame right after one of the master's own (error) frames may start while
                # the error-passive master suspends transmission for 8 bits
                suspended = prev is not None and master in prev.sender.split("+") \
                    and f.t_start - prev.t_end <= 8 * bit_ps
                prev = f
                if not _beats_sync(f) and not suspended:
                    errs.append(f"SYNC fired at {tf} ps lost to 0x{f.can_id:03X} from "
                                f"{f.sender} starting at {f.t_start} ps")
                clean = False
                explained += min(f.t_end, sof) - f.t_start
                if master in f.sender.split("+"):
                    explained += 8 * bit_ps  # suspend transmission (error passive)
            if delay - explained > bit_ps:
                errs.append(f"SYNC fired at {tf} ps started {delay} ps later, "
                            f"{delay - explained} ps not explained by the bus")
            if clean:
                fig["max_delay_clean_ps"] = max(fig["max_delay_clean_ps"], delay)
                if delay > longest:
                    errs.append(f"SYNC fired at {tf} ps delayed {delay} ps > one longest "
                                f"frame ({longest} ps)")
    return errs, fig


def check_fsm_dwell(log: Sequence[tuple[int, State]], t_end: int, bound_ps: int,
                    holds: Sequence[tuple[int, int]] = ()) -> tuple[list[str], int]:
    """No FSM state except the idle hub St1 held longer than ``bound_ps`` (the watchdog
    WATCHDOG_US plus one microsecond tick). ``holds``: intervals in which the master is held
    in reset by the bench (St0 is legitimate there). Returns (violations, longest dwell in a
    non-hub state in ps)."""
    errs: list[str] = []
    longest = 0
    for k, (t, s) in enumerate(log):
        t_next = log[k + 1][0] if k + 1 < len(log) else t_end
        if s == State.S_HUB:
            continue
        dwell = t_next - t
        # time spent inside a bench-held reset does not count
        for h0, h1 in holds:
            dwell -= max(0, min(h1, t_next) - max(h0, t))
        longest = max(longest, dwell)
        if dwell > bound_ps:
            errs.append(f"FSM in {s.name} (St{int(s)}) for {dwell} ps from {t} ps "
                        f"(bound {bound_ps} ps)")
    return errs, longest


@dataclass
class PdoEpoch:
    """One counting window ``[t0, t1)``: the master's PDO counters cleared at t0 and read at
    t1 with the bus quiet at both ends (SYNC off, injector paused, frames drained)."""

    t0: int
    t1: int
    rpdo: dict[int, tuple[int, int]]  #: channel -> (COB-ID, DLC) of the master's RPDOs
    tpdo_cobs: tuple[int, ...]  #: COB-IDs of the master's valid TPDOs with RTR allowed
    counters: dict[str, int]  #: PDO_CNT_* at t1 (cleared at t0)
    seq0: dict[int, int]  #: PDO_SEQ.SEQ per RPDO channel at t0
    seq1: dict[int, int]
    len_err: dict[int, int]  #: PDO_ERR.LEN_ERR per channel at t1 (cleared at t0)
    rx_overflow: int = 0  #: CNT_RX_OVERFLOW increase


def expected_pdo_counts(ep: PdoEpoch, frames: Sequence[BusFrame], master: str) -> dict:
    """What the master must have counted in ``ep``: frames the master's controller received
    (``master`` in the receivers) with a start of frame in the window."""
    exp = {"rx": 0, "len_err": 0, "rtr": 0, "ch_rx": {}, "ch_len": {}}
    by_cob = {cob: (ch, dlc) for ch, (cob, dlc) in ep.rpdo.items()}
    for f in frames:
        if f.kind != "frame" or f.ext or not ep.t0 <= f.t_start < ep.t1 or \
                master not in f.receivers:
            continue
        if f.rtr:
            if f.can_id in ep.tpdo_cobs:
                exp["rtr"] += 1
            continue
        if f.can_id in by_cob:
            ch, dlc = by_cob[f.can_id]
            key = "rx" if f.dlc == dlc else "len_err"
            exp[key] += 1
            sub = exp["ch_rx" if key == "rx" else "ch_len"]
            sub[ch] = sub.get(ch, 0) + 1
    return exp


def check_pdo_epoch(ep: PdoEpoch, frames: Sequence[BusFrame], master: str
                    ) -> tuple[list[str], int]:
    """Every valid PDO on the bus counted exactly: PDO_CNT_RX, each channel's SEQ step,
    PDO_CNT_LEN_ERR and each channel's LEN_ERR, PDO_CNT_RTR, and no receive overflow.
    Returns (violations, PDOs lost = valid PDOs on the bus the master did not store)."""
    exp = expected_pdo_counts(ep, frames, master)
    errs: list[str] = []
    got = ep.counters
    for k in ("rx", "len_err", "rtr"):
        if got.get(k) != exp[k]:
            errs.append(f"[{ep.t0}, {ep.t1}) ps: PDO_CNT_{k.upper()} {got.get(k)} != "
                        f"{exp[k]} on the bus")
    for ch in ep.rpdo:
        steps = (ep.seq1[ch] - ep.seq0[ch]) & 0xFFFF
        if steps != exp["ch_rx"].get(ch, 0):
            errs.append(f"[{ep.t0}, {ep.t1}) ps: RPDO {ch} SEQ advanced {steps}, "
                        f"{exp['ch_rx'].get(ch, 0)} valid PDOs on the bus")
        if ep.len_err[ch] != exp["ch_len"].get(ch, 0):
            errs.append(f"[{ep.t0}, {ep.t1}) ps: RPDO {ch} LEN_ERR {ep.len_err[ch]} != "
                        f"{exp['ch_len'].get(ch, 0)}")
    if ep.rx_overflow:
        errs.append(f"[{ep.t0}, {ep.t1}) ps: {ep.rx_overflow} frames lost (RX overflow)")
    lost = max(0, exp["rx"] - got.get("rx", 0))
    return errs, lost


@dataclass
class SdoRecord:
    """One host SDO transfer: started at ``t0``; ``t1`` = when DONE was seen (None: never
    within the bench's patience ``bound_ps``)."""

    node: int
    index: int
    sub: int
    upload: bool
    size: int
    t0: int
    bound_ps: int  #: how long the bench polls before giving up
    t1: int | None = None
    refused: bool = False
    error: bool = False
    abort_code: int = 0
    abort_sent: bool = False


#: SDO client parameters of the default build (docs/canopen_sdo_client.md)
SDO_BUF_BYTES = 256
SDO_EMPTY_SEGS_MAX = 3


def sdo_max_requests(upload: bool, size: int) -> int:
    """The documented upper bound R on a transfer's request frames (abort frame excluded)."""
    if upload:
        return SDO_BUF_BYTES + SDO_EMPTY_SEGS_MAX + 2
    return 1 if 1 <= size <= 4 else 1 + max(1, math.ceil(size / 7))


def sdo_bound_ps(requests: int, timeout_ms: int) -> int:
    """The documented bound of a transfer with ``requests`` request frames: every transfer
    ends within (2R + 1) * (T + 1) ms (each request taken and answered within T + 1 ms each,
    an abort frame taken within T + 1 ms)."""
    return (2 * requests + 1) * (timeout_ms + 1) * 10**9


def sdo_patience_ps(upload: bool, size: int, timeout_ms: int) -> int:
    """How long the bench polls a transfer before calling it unbounded: 4 x the bound of a
    transfer with the requests a correct server needs plus the tolerated empty segments (a
    forged response may add segments; the documented worst case of an upload, 261 requests,
    would be 3.1 s at T = 5 ms)."""
    if upload:
        r = 1 + math.ceil(size / 7) + SDO_EMPTY_SEGS_MAX
    else:
        r = sdo_max_requests(False, size)
    return 4 * sdo_bound_ps(r, timeout_ms)


def check_sdo(log: Sequence[SdoRecord], frames: Sequence[BusFrame] = (), master: str = "",
              timeout_ms: int = 5) -> tuple[list[str], int]:
    """Every SDO transfer ended (success, refusal or a documented abort) within the documented
    bound (2R + 1) * (T + 1) ms, R = the request frames the master sent for it (counted on
    the bus, at most :func:`sdo_max_requests`). Returns (violations, transfers that never
    ended or ended late)."""
    errs: list[str] = []
    unbounded = 0
    for r in log:
        what = (f"SDO {'upload' if r.upload else 'download'} {r.index:04X}h:{r.sub} node "
                f"{r.node} at {r.t0} ps")
        if r.t1 is None:
            unbounded += 1
            errs.append(f"{what} never ended (polled {r.bound_ps} ps)")
            continue
        if r.refused:
            continue
        req = [f for f in frames if f.kind == "frame" and f.can_id == 0x600 + r.node
               and master in f.sender.split("+") and r.t0 <= f.t_start < r.t1
               and f.data[:1] != b"\x80"]
        # the transfer's requests start with its initiate (ccs 1 download / 2 upload, its
        # index and subindex); a request of the previous transfer still waiting in the
        # controller's TX buffer may go out after this one started
        mux = bytes([r.index & 0xFF, r.index >> 8, r.sub])
        first = next((k for k, f in enumerate(req) if f.data[:1] and f.data[0] >> 5 in (1, 2)
                      and f.data[1:4] == mux), 0)
        req = req[first:]
        n_req = max(1, len(req))
        bound = sdo_bound_ps(n_req, timeout_ms)
        if n_req > sdo_max_requests(r.upload, r.size) or r.t1 - r.t0 > bound:
            unbounded += 1
            errs.append(f"{what} took {r.t1 - r.t0} ps with {n_req} requests (bound "
                        f"{bound} ps, at most {sdo_max_requests(r.upload, r.size)} requests)")
            continue
        if r.error and r.abort_sent and r.abort_code not in CLIENT_ABORT_CODES:
            errs.append(f"{what}: client abort 0x{r.abort_code:08X} is not documented")
        if r.error and not r.abort_sent and r.abort_code == 0:
            errs.append(f"{what}: server abort without a code")
    return errs, unbounded


@dataclass
class ErrorSnapshot:
    """The master's view of its controller's error state against the controller itself,
    taken after a quiet interval longer than the documented polling bound."""

    t: int
    tec: int  #: CAN_STATUS.TEC
    rec: int
    eflg: int
    err_passive: bool  #: STATUS.ERR_PASSIVE
    bus_off: bool
    chip: tuple[tuple[int, int, str], ...]  #: the controller's (TEC, REC, state) values
    #: within the polling bound before ``t`` (model), the current one last


def check_error_state(snaps: Sequence[ErrorSnapshot]) -> list[str]:
    """CAN_STATUS TEC/REC and STATUS.ERR_PASSIVE/BUS_OFF show the controller as it was at
    some instant within the polling bound before the read (any of ``chip``)."""
    errs: list[str] = []
    for s in snaps:
        ok = [(min(tec, 255), rec) == (s.tec, s.rec) and s.err_passive == (st == "error_passive")
              and s.bus_off == (st == "bus_off") for tec, rec, st in s.chip]
        if not any(ok):
            tec, rec, st = s.chip[-1]
            errs.append(f"{s.t} ps: CAN_STATUS TEC/REC {s.tec}/{s.rec}, STATUS.ERR_PASSIVE "
                        f"{int(s.err_passive)} BUS_OFF {int(s.bus_off)}; controller "
                        f"{tec}/{rec} {st} (values within the polling bound: {s.chip})")
    return errs


def check_injected_errors(n_injected: int, frames: Sequence[BusFrame], t0: int, t1: int
                          ) -> list[str]:
    """Every CRC error the bench injected is an error frame on the bus, and there are no
    others (the bus is otherwise clean: no bit-rate mismatch, every frame acknowledged)."""
    n = sum(1 for f in frames if f.kind == "error" and t0 <= f.t_start < t1)
    return [] if n == n_injected else [f"[{t0}, {t1}) ps: {n} error frames on the bus, "
                                       f"{n_injected} injected"]


def check_master_tx_errors(cnt_tx_error: int, frames: Sequence[BusFrame], master: str,
                           t0: int, t1: int) -> list[str]:
    """CNT_TX_ERROR counts each of the master's frames destroyed by an error frame."""
    n = sum(1 for f in frames if f.kind == "error" and master in f.sender.split("+")
            and t0 <= f.t_start < t1)
    return [] if n == cnt_tx_error else [f"[{t0}, {t1}) ps: CNT_TX_ERROR {cnt_tx_error}, "
                                         f"{n} of the master's frames destroyed"]


def check_heartbeat_loss(hb_loss: int, frames: Sequence[BusFrame], master: str,
                         nodes: Sequence[int], consumer_ps: int, slack_ps: int, t0: int,
                         t1: int) -> list[str]:
    """CNT_HB_LOSS of the epoch ``[t0, t1)`` equals the consumer expiries the bus explains.

    From the heartbeats (700h + node, data frames) the master's controller received
    (``frames``: every bus frame up to ``t1``): a gap longer than ``consumer_ps`` + ``slack_ps``
    whose expiry (the earlier heartbeat + ``consumer_ps``) falls in the epoch is a loss that
    must be counted, a gap within ``slack_ps`` of ``consumer_ps`` (ms-tick granularity, the
    receive path) or an expiry of a heartbeat from before the epoch (a disruption may have
    restarted the consumer) may be counted. An injector that keeps the bus full with
    lower identifiers long enough starves 70xh heartbeats: that loss is legitimate."""
    sure = maybe = 0
    for n in nodes:
        rx = [f.t_end for f in frames if f.kind == "frame" and not f.ext and not f.rtr
              and f.can_id == 0x700 + n and master in f.receivers and f.t_end < t1]
        rx.sort()
        for k, t in enumerate(rx):
            if not t0 <= t + consumer_ps < t1:
                continue  # the consumer of this heartbeat expires outside the epoch
            gap = (rx[k + 1] if k + 1 < len(rx) else t1) - t
            if t < t0 and gap > consumer_ps - slack_ps:
                maybe += 1
            elif gap > consumer_ps + slack_ps:
                sure += 1
            elif gap > consumer_ps - slack_ps:
                maybe += 1
    if sure <= hb_loss <= sure + maybe:
        return []
    return [f"[{t0}, {t1}) ps: CNT_HB_LOSS {hb_loss}, the bus explains {sure} (up to "
            f"{sure + maybe})"]


def check_nothing_sent(frames: Sequence[BusFrame], master: str,
                       forbidden: Sequence[tuple[int, str, object]]) -> list[str]:
    """Refused host commands sent nothing: no frame of the master at or after each write's
    time ``t`` matches the predicate ``pred(frame)`` of that write."""
    errs = []
    for t, what, pred in forbidden:
        for f in frames:
            if f.kind == "frame" and master in f.sender.split("+") and f.t_start >= t \
                    and pred(f):
                errs.append(f"{t} ps: {what}: the master sent 0x{f.can_id:03X} "
                            f"DLC {f.dlc} {f.data.hex()} at {f.t_start} ps")
                break
    return errs


@dataclass
class FuzzReport:
    """Everything one seed's run found."""

    seed: int
    frames_injected: int = 0
    errors: dict[str, list[str]] = field(default_factory=dict)
    hangs: int = 0
    pdo_lost: int = 0
    sdo_unbounded: int = 0
    figures: dict[str, float] = field(default_factory=dict)

    def add(self, checker: str, errs: Iterable[str]) -> None:
        errs = list(errs)
        if errs:
            self.errors.setdefault(checker, []).extend(errs)

    def summary(self) -> str:
        lines = [f"seed {self.seed}: {self.frames_injected} frames injected, "
                 f"hangs {self.hangs}, PDOs lost {self.pdo_lost}, "
                 f"SDOs unbounded {self.sdo_unbounded}"]
        for k, v in sorted(self.figures.items()):
            lines.append(f"  {k} = {v}")
        for k, errs in self.errors.items():
            lines.append(f"  {k}: {len(errs)} violation(s), first: {errs[:3]}")
        return "\n".join(lines)
