"""Bench of ``canopen_pdo_engine``: CiA 301 PDOs between the engine and reference slaves.

The bench plays the master core around the engine: a SYNC producer pulses ``sync_i`` every
``sync_us`` (with ``sync_count_i`` = SYNC index mod 256), puts the SYNC frame on the 1 Mbit/s
bus model from its own node and holds ``window_open_i`` for ``window_us``; a taker plays the
FSM's St8/St11 (``tx_req_o`` / ``tx_ack_i``), only taking a frame when the master's CAN node
has room (``tx_depth``, like the MCP2510's PDO buffer) and sends it through a ``QueueNode``;
frames with PDO identifiers (180h..57Fh) received by that node are handed to the engine like
St5 does (``rx_valid_i`` .. ``rx_done_o``). Three :class:`CanopenSlave` drives (nodes 1..3,
operational: TPDO1 = 6041h + 6064h on every SYNC, RPDO1 = 6040h + 607Ah) sit on the bus, plus
a ``requester`` node that injects RTRs and stray frames. The host side is the register driver
:class:`tb.tblib.host_driver.CanopenMasterHost` on the engine's register port (what
``canopen_host_regs`` passes through for C0h..FFh); ``tick_us_i`` is tied high (1 MHz clock).

Checkers, all written from the documented behaviour, not from the RTL:

* every received frame gets ``rx_done_o`` within max(N_TPDO + 8, N_RPDO + 2) cycles (the
  engine compares the frame with one channel per cycle); ``rx_reply_o``
  comes with ``tx_req_o`` = 1 and never with ``rx_unexpected_o``;
* a frame on ``tx_req_o`` never changes and is never withdrawn before ``tx_ack_i``;
* ``ev_*_o`` strobes are counted cycle by cycle and compared with the expected events and the
  engine's PDO_CNT_* registers;
* reference models (functions below) give the frames each synchronous TPDO must send after
  each SYNC, the missed cycles of each synchronous RPDO, and the frame a slave's object
  dictionary must hold at each SYNC.
"""

from __future__ import annotations

import bisect
import collections
import random
import struct
from collections.abc import Callable
from dataclasses import dataclass

import can
import cocotb
import pytest
from cocotb.triggers import ClockCycles, Event, FallingEdge, Lock, ReadOnly, RisingEdge, Timer

from sim_models.can_bus import CanBus, QueueNode
from sim_models.canopen_slave import CanopenSlave, NmtState, make_message
from sim_models.sim_time import PS_PER_US, Scheduler
from tb.tblib import regmap as R
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.frame_handover import hand_over_frame
from tb.tblib.host_driver import PDO_COUNTER_NAMES, CanopenMasterHost
from tb.tblib.model_clock import ModelClock, sim_time_ps
from tb.tblib.runner import param, run_cocotb

CLK_HZ = 1_000_000  # one cycle per microsecond: tick_us_i is tied high
CLK_PS = 10**12 // CLK_HZ
BITRATE = 1_000_000
NODES = (1, 2, 3)
SYNC_US = 1000
WINDOW_US = 800
PDO_IDS = range(0x180, 0x580)  # TPDO1..RPDO4 function codes: what St4 hands to St5
COB_SYNC = 0x080


# ============================================================================ payloads
def drive_payload(cw: int, pos: int) -> bytes:
    """RPDO1 of the reference drive: controlword 6040h (U16) + target position 607Ah (I32)."""
    return struct.pack("<Hi", cw & 0xFFFF, pos)


def pattern(n: int) -> bytes:
    """6 bytes whose two halves (PDO_DATA_LO / HI) both carry n: a torn frame is visible."""
    n16 = n & 0xFFFF
    return struct.pack("<HHH", n16, n16, n16)


def pattern_of(data: bytes) -> int:
    a, b, c = struct.unpack("<HHH", data)
    assert a == b == c, f"torn PDO: {data.hex(' ')}"
    return a


# ============================================================================ reference models
def sync_index(t_ps: int, sync_edges: list[int]) -> int:
    """Index of the last SYNC edge at or before t_ps (-1: before the first)."""
    return bisect.bisect_right(sync_edges, t_ps) - 1


def expected_sync_frames(sync_edges: list[int], commits: list[tuple[int, bytes]], tt: int,
                         first_sync: int = 0) -> dict[int, bytes]:
    """Frames a synchronous TPDO must send: {SYNC index: payload}.

    ``commits``: (edge, data) of every COMMIT of the channel, none at a SYNC edge. A commit
    becomes the data at the first SYNC after it; TT 1..240 send at every TT-th SYNC counted from
    ``first_sync`` (the first SYNC after the configuration); TT 0 sends after a SYNC if a commit
    happened since the previous SYNC.
    """
    out: dict[int, bytes] = {}
    data = bytes(6)
    ci = 0
    count = 0
    for i, ts in enumerate(sync_edges):
        if i < first_sync:
            continue
        fresh = False
        while ci < len(commits) and commits[ci][0] < ts:
            data = commits[ci][1]
            ci += 1
            fresh = True
        if tt == 0:
            if fresh:
                out[i] = data
        else:
            count += 1
            if count == tt:
                count = 0
                out[i] = data
    return out


def expected_missed(sync_edges: list[int], store_edges: list[int], tt: int) -> int:
    """Missed cycles of a synchronous RPDO (TT 1..240): the monitor is armed by the first PDO
    stored and checks, every TT SYNCs counted from the SYNC before that PDO, that a PDO was
    stored in the interval. At the same edge a SYNC is checked before the PDO counts."""
    events = sorted([(t, 0) for t in sync_edges] + [(t, 1) for t in store_edges])
    armed = got = False
    count = missed = 0
    for _t, kind in events:
        if kind == 1:
            got = True
            if not armed:
                armed, count = True, 0
        elif armed:
            count += 1
            if count >= tt:
                missed += 0 if got else 1
                got, count = False, 0
    return missed


# ============================================================================ bench
@dataclass
class TxRecord:
    t_ps: int  #: edge that sampled tx_ack_i
    msg: can.Message
    t_req_ps: int  #: first falling edge with the frame on tx_req_o
    sync: int = 0  #: tx_sync_o when the frame was taken (a synchronous TPDO)


@dataclass
class RxRecord:
    t_ps: int  #: edge that sampled rx_valid_i
    msg: can.Message
    latency: int
    reply: int
    unexpected: int


class PdoPortBus:
    """The engine's register port seen as the host bus: word addresses of the map (C0h..FFh),
    one write per cycle, read data one cycle after the address (as canopen_host_regs passes
    them through). A write with byte enables other than 1111 is dropped, as there."""

    def __init__(self, dut) -> None:
        self.dut = dut
        self.lock = Lock()
        #: (edge, window offset, value) of every write
        self.writes: list[tuple[int, int, int]] = []
        dut.reg_we_i.value = 0
        dut.reg_addr_i.value = 0
        dut.reg_wdata_i.value = 0

    @staticmethod
    def _offset(address: int) -> int:
        off = address - R.REG_PDO_WIN
        assert 0 <= off < R.PDO_WIN_WORDS, f"address {address:#x} outside PDO_WIN"
        return off

    async def write(self, address: int, value: int, byteenable: int | None = None) -> None:
        off = self._offset(address)
        if byteenable not in (None, 0xF):
            return
        dut = self.dut
        async with self.lock:
            await FallingEdge(dut.clk_i)
            dut.reg_addr_i.value = off
            dut.reg_wdata_i.value = value
            dut.reg_we_i.value = 1
            await RisingEdge(dut.clk_i)
            dut.reg_we_i.value = 0
            self.writes.append((sim_time_ps(), off, value))

    async def read(self, address: int) -> int:
        off = self._offset(address)
        dut = self.dut
        async with self.lock:
            await FallingEdge(dut.clk_i)
            dut.reg_addr_i.value = off
            await RisingEdge(dut.clk_i)  # read data registered at this edge
            await ReadOnly()
            return int(dut.reg_rdata_o.value)


class BenchMaster(QueueNode):
    """The master's CAN controller: sends what the FSM takes, passes received frames on."""

    def __init__(self, name: str, bitrate: int, on_frame: Callable[[can.Message], None]):
        super().__init__(name, bitrate)
        self._on_frame = on_frame

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        super().on_rx(msg, t_ps)
        self._on_frame(msg)


class TB:
    """DUT + bench core (SYNC producer, tx taker, rx feeder) + bus + slaves 1..3 + host."""

    def __init__(self, dut, *, sync_us: int = SYNC_US, window_us: int = WINDOW_US) -> None:
        self.dut = dut
        self.n_tpdo = param("N_TPDO")
        self.n_rpdo = param("N_RPDO")
        self.rx_bound = max(self.n_tpdo + 8, self.n_rpdo + 2)
        start_clock(dut.clk_i, CLK_HZ)
        self.sched = Scheduler()
        self.sched.run_until(sim_time_ps())
        self.clock = ModelClock(self.sched)
        self.bus = CanBus(self.sched, BITRATE)
        self.master = BenchMaster("master", BITRATE, self._from_bus)
        self.syncer = QueueNode("syncer", BITRATE)
        self.requester = QueueNode("requester", BITRATE)
        for node in (self.master, self.syncer, self.requester):
            self.bus.attach(node)
        self.slaves = {n: CanopenSlave(self.sched, n, bitrate_bps=BITRATE,
                                       boot_time_ps=20 * PS_PER_US) for n in NODES}
        #: per node: (t, 6040h, 607Ah) when the slave processed each SYNC
        self.od_log: dict[int, list[tuple[int, int, int]]] = {n: [] for n in NODES}
        for n, slave in self.slaves.items():
            self.bus.attach(slave)
            slave.sync_listeners.append(
                lambda s, t, _c, n=n: self.od_log[n].append((t, s.read(0x6040),
                                                             s.read(0x607A))))
        self.host = CanopenMasterHost(dut, dut.clk_i, bus=PdoPortBus(dut))
        self.port: PdoPortBus = self.host.bus
        # SYNC producer
        self.sync_us = sync_us
        self.window_us = window_us
        self.sync_enabled = False
        self._sync_go = Event()
        self.sync_edges: list[int] = []  #: edges that sampled sync_i = 1
        # tx taker
        self.take_tx = True
        self.tx_depth = 1
        self.ack_delay: Callable[[], int] = lambda: 0
        self.tx_log: list[TxRecord] = []
        # rx feeder
        self.rx_queue: collections.deque[can.Message] = collections.deque()
        self._rx_event = Event()
        self.rx_log: list[RxRecord] = []
        # strobe counts: name -> edges where the strobe was high
        self.strobes: dict[str, list[int]] = {n: [] for n in ("ev_rx_o", "ev_len_err_o",
                                                              "ev_missed_o", "ev_late_o")}
        for sig in (dut.sync_i, dut.sync_count_i, dut.window_open_i, dut.rx_valid_i,
                    dut.rx_id_i, dut.rx_rtr_i, dut.rx_dlc_i, dut.rx_data_i, dut.tx_ack_i,
                    dut.tx_cancelled_i):
            sig.value = 0
        dut.tick_us_i.value = 1
        cocotb.start_soon(self._sync_producer())
        cocotb.start_soon(self._tx_taker())
        cocotb.start_soon(self._rx_feeder())
        for name in self.strobes:
            cocotb.start_soon(self._strobe_counter(name))

    # ------------------------------------------------------------------ bench core
    async def _sync_producer(self) -> None:
        dut = self.dut
        while True:
            if not self.sync_enabled:
                self._sync_go.clear()
                await self._sync_go.wait()
            await FallingEdge(dut.clk_i)
            dut.sync_count_i.value = len(self.sync_edges) & 0xFF
            dut.sync_i.value = 1
            self.clock.sync()
            self.syncer.send(make_message(COB_SYNC, b""))
            self.sync_edges.append(sim_time_ps() + CLK_PS // 2)
            await Timer(CLK_PS, "ps")
            dut.sync_i.value = 0
            rest = self.sync_us * PS_PER_US - CLK_PS
            if self.window_us:
                dut.window_open_i.value = 1
                await Timer(self.window_us * PS_PER_US - CLK_PS, "ps")
                dut.window_open_i.value = 0
                rest -= self.window_us * PS_PER_US - CLK_PS
            await Timer(rest, "ps")

    def _tx_frame(self) -> tuple[int, int, int, int]:
        d = self.dut
        return (int(d.tx_id_o.value), int(d.tx_rtr_o.value), int(d.tx_dlc_o.value),
                int(d.tx_data_o.value))

    async def _tx_taker(self) -> None:
        """FSM St8 -> St11: take the frame when the PDO TX buffer is free, then send it."""
        dut = self.dut
        while True:
            if dut.tx_req_o.value != 1:
                await RisingEdge(dut.tx_req_o)
            await FallingEdge(dut.clk_i)
            t_req = sim_time_ps()
            frame = self._tx_frame()
            delay = self.ack_delay()
            if delay:
                await ClockCycles(dut.clk_i, delay, rising=False)
            while True:
                self.clock.sync()
                if self.take_tx and len(self.master.queue) < self.tx_depth:
                    break
                await FallingEdge(dut.clk_i)
            assert dut.tx_req_o.value == 1, "tx_req_o withdrawn before tx_ack_i"
            assert self._tx_frame() == frame, "frame changed while tx_req_o = 1"
            sync = int(dut.tx_sync_o.value)
            dut.tx_ack_i.value = 1
            await RisingEdge(dut.clk_i)
            dut.tx_ack_i.value = 0
            fid, rtr, dlc, data = frame
            if rtr:
                msg = make_message(fid, b"", remote=True, dlc=dlc)
            else:
                msg = make_message(fid, data.to_bytes(8, "little")[:min(dlc, 8)])
            self.tx_log.append(TxRecord(sim_time_ps(), msg, t_req, sync))
            self.clock.sync()
            self.master.send(msg)
            await ReadOnly()

    def _from_bus(self, msg: can.Message) -> None:
        if not msg.is_extended_id and msg.arbitration_id in PDO_IDS:
            self.rx_queue.append(msg)
            self._rx_event.set()

    async def _rx_feeder(self) -> None:
        """FSM St5: one frame at a time, the next only after rx_done_o."""
        dut = self.dut
        while True:
            while not self.rx_queue:
                self._rx_event.clear()
                await self._rx_event.wait()
            msg = self.rx_queue.popleft()
            await FallingEdge(dut.clk_i)
            t0, latency = await hand_over_frame(dut, msg, self.rx_bound)
            rec = RxRecord(t0, msg, latency, int(dut.rx_reply_o.value),
                           int(dut.rx_unexpected_o.value))
            if rec.reply:
                assert dut.tx_req_o.value == 1, "rx_reply_o without tx_req_o"
                assert not rec.unexpected, "rx_reply_o with rx_unexpected_o"
            self.rx_log.append(rec)

    async def _strobe_counter(self, name: str) -> None:
        sig = getattr(self.dut, name)
        clk = self.dut.clk_i
        while True:
            await RisingEdge(sig)
            self.strobes[name].append(sim_time_ps())
            while True:  # back-to-back strobes are separate events
                await RisingEdge(clk)
                await ReadOnly()
                if sig.value != 1:
                    break
                self.strobes[name].append(sim_time_ps())

    # ------------------------------------------------------------------ control
    async def start(self, slave_tpdos: bool = True) -> None:
        """Reset the DUT, boot the slaves and start them (operational)."""
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        await self.wait_for(lambda: all(s.nmt_state is NmtState.PRE_OPERATIONAL
                                        for s in self.slaves.values()), 2000)
        if not slave_tpdos:
            for s in self.slaves.values():
                s.write(0x1800, 1, 0x80000000 | (0x180 + s.node_id))
        self.clock.sync()
        self.syncer.send(make_message(0x000, bytes([0x01, 0x00])))
        await self.wait_for(lambda: all(s.nmt_state is NmtState.OPERATIONAL
                                        for s in self.slaves.values()), 2000)

    async def wait_for(self, cond: Callable[[], bool], timeout_us: float,
                       step_us: float = 5) -> None:
        t_end = sim_time_ps() + int(timeout_us * PS_PER_US)
        while not cond():
            assert sim_time_ps() < t_end, f"condition not met within {timeout_us} us"
            await Timer(step_us, "us")

    def sync_start(self) -> None:
        self.sync_enabled = True
        self._sync_go.set()

    def sync_stop(self) -> None:
        self.sync_enabled = False

    async def wait_syncs(self, n: int) -> None:
        """Wait until n more SYNCs were strobed (the SYNC producer must run)."""
        target = len(self.sync_edges) + n
        await self.wait_for(lambda: len(self.sync_edges) >= target,
                            (n + 1) * self.sync_us + 100, step_us=1)

    async def at_phase(self, us: int) -> None:
        """Wait until ``us`` microseconds after the next SYNC."""
        await self.wait_syncs(1)
        t = self.sync_edges[-1] + us * PS_PER_US - sim_time_ps()
        if t > 0:
            await Timer(t, "ps")

    def allow_tx(self, on: bool) -> None:
        self.take_tx = on

    def frames(self, cob: int, *, remote: bool = False,
               sender: str | None = None) -> list[tuple[int, bytes]]:
        """(SOF time, payload) of the frames with identifier ``cob`` on the bus."""
        return [(r.t_start_ps, bytes(r.msg.data)) for r in self.bus.records
                if r.kind == "frame" and r.msg.arbitration_id == cob
                and r.msg.is_remote_frame == remote and (sender is None or r.sender == sender)]

    def sent(self, cob: int) -> list[TxRecord]:
        return [r for r in self.tx_log if r.msg.arbitration_id == cob]

    def stores(self, cob: int, dlc: int) -> list[int]:
        """Edges where the engine stored a PDO of ``cob`` (fed data frames with that DLC)."""
        return [r.t_ps + CLK_PS for r in self.rx_log
                if r.msg.arbitration_id == cob and not r.msg.is_remote_frame
                and r.msg.dlc == dlc]

    async def counters(self) -> dict[str, int]:
        return await self.host.pdo_counters()

    def commit_edge(self) -> int:
        """Edge of the last register write (the COMMIT of a tpdo_write)."""
        return self.port.writes[-1][0]


def match_latency(k: int) -> tuple[int, int]:
    """rx_valid_i -> rx_done_o of a frame decided at the k-th channel of its kind (the match
    compares one channel per cycle): 2 + k, one more when the engine was executing another
    item in the cycle of rx_valid_i. An unexpected frame is decided at the last channel."""
    return (2 + k, 3 + k)


def check_rx_clean(tb: TB) -> None:
    for rec in tb.rx_log:
        assert rec.latency <= tb.rx_bound


# ============================================================================ tests
@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_sync_tpdos_reach_slaves(dut):
    """Purpose: synchronous TPDOs (every SYNC, every 3rd SYNC, acyclic) reach the slaves.

    Verifies: with a new set-point committed at a random point of each SYNC period, TPDO 0
    (TT 1, slave 1's RPDO1) sends exactly one frame after every SYNC, TPDO 1 (TT 3, slave 2)
    after every 3rd SYNC counted from its configuration, TPDO 2 (TT 0, slave 3) after each
    SYNC that follows a commit; every frame carries the last data committed before its SYNC
    (reference model); each slave's 6040h/607Ah at SYNC k + 1 equal the frame sent after SYNC
    k; every frame leaves inside the synchronous window; nothing is late.
    """
    tb = TB(dut)
    await tb.start()
    host = tb.host
    cfg = {0: (0x201, 1, 1), 1: (0x202, 3, 2), 2: (0x203, 0, 3)}  # ch: cob, tt, node
    for ch, (cob, tt, _n) in cfg.items():
        await host.tpdo_config(ch, cob, 6, tt)
    commits: dict[int, list[tuple[int, bytes]]] = {ch: [] for ch in cfg}
    rng = random.Random(11)
    tb.sync_start()
    n_cycles = 24
    for k in range(n_cycles):
        await tb.at_phase(rng.randint(100, 850))
        for ch in cfg:
            if ch == 2 and k % 2:
                continue
            data = drive_payload(0x000F, (ch + 1) * 100_000 + k)
            await host.tpdo_write(ch, data)
            commits[ch].append((tb.commit_edge(), data))
    await tb.wait_syncs(2)
    tb.sync_stop()
    await Timer(1, "ms")
    edges = tb.sync_edges
    for ch, (cob, tt, node) in cfg.items():
        want = expected_sync_frames(edges, commits[ch], tt)
        got: dict[int, bytes] = {}
        for rec in tb.sent(cob):
            i = sync_index(rec.t_ps, edges)
            assert i not in got, f"TPDO {ch}: two frames after SYNC {i}"
            assert rec.t_ps - edges[i] < tb.window_us * PS_PER_US, "frame after the window"
            got[i] = bytes(rec.msg.data)
        assert got == want, f"TPDO {ch} (TT {tt}): frames {got} expected {want}"
        # the slave's object dictionary at each SYNC holds the last frame before it
        log = tb.od_log[node]
        assert len(log) == len(edges), (len(log), len(edges))
        last = drive_payload(0, 0)
        for i in range(len(edges)):
            cw, pos = log[i][1], log[i][2]
            assert drive_payload(cw, pos) == last, \
                f"node {node} at SYNC {i}: OD {cw:#x}/{pos}, expected {last.hex(' ')}"
            if i in want:
                last = want[i]
    assert len(tb.sent(0x201)) == len(edges)
    assert len(tb.sent(0x202)) == len(edges) // 3
    cnt = await tb.counters()
    assert cnt["late"] == 0 and tb.strobes["ev_late_o"] == []
    assert cnt["tx"] == len(tb.tx_log)
    check_rx_clean(tb)


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_no_torn_update(dut):
    """Purpose: commits while the engine sends never tear a set-point.

    Verifies: the host commits a new 6-byte pattern (both register halves carry the same
    number) every 3..40 us to a TT 1 TPDO and, with a trigger, to a TT 255 TPDO, while the
    taker holds each frame on tx_req_o for a random 0..40 cycles and the bus is busy: every
    frame sent and every value applied in the slaves is untorn; each TT 1 frame carries the
    last commit before its SYNC (or the one at the SYNC edge itself); the TT 255 frames carry
    increasing commits and the last one is the final commit; frames on tx_req_o never change
    (taker checker).
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    rng = random.Random(5)
    tb.ack_delay = lambda: rng.randint(0, 40)
    await host.tpdo_config(0, 0x201, 6, 1)
    await host.tpdo_config(1, 0x202, 6, 255)
    commits: dict[int, list[tuple[int, bytes]]] = {0: [], 1: []}
    tb.sync_start()
    await tb.wait_syncs(1)
    n = 1
    t_end = sim_time_ps() + 12 * tb.sync_us * PS_PER_US
    while sim_time_ps() < t_end:
        ch = n % 2
        await host.tpdo_write(ch, pattern(n), trigger=ch == 1)
        commits[ch].append((tb.commit_edge(), pattern(n)))
        n += 1
        await Timer(rng.randint(3, 40), "us")
    await tb.wait_syncs(2)
    tb.sync_stop()
    await Timer(2, "ms")
    edges = tb.sync_edges
    # TT 1: the frame after SYNC i carries the last commit before it, or the one at its edge
    for rec in tb.sent(0x201):
        i = sync_index(rec.t_ps, edges)
        value = pattern_of(bytes(rec.msg.data))
        before = [0] + [pattern_of(d) for t, d in commits[0] if t < edges[i]]  # 0: no data
        at_edge = [pattern_of(d) for t, d in commits[0] if t == edges[i]]
        assert value in before[-1:] + at_edge, \
            f"SYNC {i}: frame {value}, last commit before {before[-1:]}, at edge {at_edge}"
    # TT 255: untorn, increasing, the last frame is the last commit
    values = [pattern_of(bytes(r.msg.data)) for r in tb.sent(0x202)]
    assert len(values) > 20, values
    assert values == sorted(values) and values[-1] == pattern_of(commits[1][-1][1])
    assert set(values) <= {pattern_of(d) for _, d in commits[1]}
    for node in (1, 2):
        for _t, _pdo, payload in tb.slaves[node].rpdo_applied:
            pattern_of(payload[:6])
    assert len(tb.slaves[2].rpdo_applied) == len(values)


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_event_tpdo_trigger_and_inhibit(dut):
    """Purpose: event-driven TPDOs (TT 254/255) go on the host's trigger, inhibit permitting.

    Verifies: no frame without a trigger (SYNCs running, a commit alone does nothing); a
    trigger sends exactly one frame with the committed data, commit + trigger one with the
    new data; with an inhibit time of 5 x 100 us, a trigger right after a frame (and two more
    commits + triggers inside the inhibit time) gives exactly one more frame, with the last
    data, taken between 500 and 600 us (+ scan) after the first one, PDO_CMD.INHIBITED shown
    meanwhile; the slave applied every frame.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 254)
    tb.sync_start()
    await tb.wait_syncs(3)
    assert tb.sent(0x201) == []
    await host.tpdo_write(0, drive_payload(6, 111))
    await Timer(2, "ms")
    assert tb.sent(0x201) == []
    st = await host.tpdo_status(0)
    assert st["data"][:6] == drive_payload(6, 111) and not st["due"] and not st["pending"]
    await host.tpdo_trigger(0)
    await tb.wait_for(lambda: len(tb.sent(0x201)) == 1, 500, step_us=1)
    assert bytes(tb.sent(0x201)[0].msg.data) == drive_payload(6, 111)
    await host.tpdo_write(0, drive_payload(7, 222), trigger=True)
    await tb.wait_for(lambda: len(tb.sent(0x201)) == 2, 500, step_us=1)
    assert bytes(tb.sent(0x201)[1].msg.data) == drive_payload(7, 222)
    tb.sync_stop()
    # inhibit time 500 us
    await host.tpdo_config(0, 0x201, 6, 255, inhibit_100us=5)
    await host.tpdo_trigger(0)
    await tb.wait_for(lambda: len(tb.sent(0x201)) == 3, 500, step_us=1)
    t_a = tb.sent(0x201)[2].t_ps
    await host.tpdo_write(0, drive_payload(0xF, 333), trigger=True)
    st = await host.tpdo_status(0)
    assert st["inhibited"] and st["due"], st
    await Timer(100, "us")
    await host.tpdo_write(0, drive_payload(0xF, 444), trigger=True)
    await Timer(1500, "us")
    sent = tb.sent(0x201)
    assert len(sent) == 4, [bytes(r.msg.data).hex() for r in sent]
    gap = sent[3].t_ps - t_a
    assert 500 * PS_PER_US < gap <= (600 + tb.rx_bound) * PS_PER_US, f"gap {gap} ps"
    assert bytes(sent[3].msg.data) == drive_payload(0xF, 444)
    st = await host.tpdo_status(0)
    assert not st["inhibited"] and not st["due"] and st["seq"] == 4
    await Timer(200, "us")
    applied = [p[:6] for _t, _n, p in tb.slaves[1].rpdo_applied]
    assert applied == [drive_payload(6, 111), drive_payload(7, 222), drive_payload(7, 222),
                       drive_payload(0xF, 444)]
    assert tb.slaves[1].read(0x607A) == 444


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rtr_on_master_tpdo(dut):
    """Purpose: remote requests for the master's TPDOs (FSM T11 path).

    Verifies: an RTR for a TT 253 TPDO is answered by rx_done_o with rx_reply_o and tx_req_o
    = 1 (5 cycles from rx_valid_i with an idle transmitter, 6 when the engine was busy), and
    the reply carries the data
    committed last (applied by the slave); TT 252 answers with the data sampled at the last
    SYNC, not with a commit made after it; an RTR for a TPDO without RTR allowed, for an RPDO
    COB-ID and for a COB-ID of no channel is unexpected and sends nothing; an RTR while the
    inhibit time of a TT 254 TPDO runs is done without reply and the frame follows when the
    inhibit time ends; PDO_CNT_RTR counts the accepted RTRs.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 253)
    await host.tpdo_config(1, 0x202, 6, 252)
    await host.tpdo_config(2, 0x203, 6, 1, rtr_allowed=False)
    await host.tpdo_config(3, 0x204, 6, 254, rtr_allowed=True, inhibit_100us=10)
    await host.rpdo_config(0, 0x181, 6, 255)

    async def rtr(cob: int) -> RxRecord:
        n = len(tb.rx_log)
        tb.clock.sync()
        tb.requester.send(make_message(cob, b"", remote=True, dlc=6))
        await tb.wait_for(lambda: len(tb.rx_log) > n, 1000, step_us=1)
        return tb.rx_log[n]

    await host.tpdo_write(0, drive_payload(6, 1234))
    rec = await rtr(0x201)
    assert rec.reply == 1 and rec.unexpected == 0 and rec.latency in (5, 6), rec
    await Timer(300, "us")
    assert [bytes(r.msg.data) for r in tb.sent(0x201)] == [drive_payload(6, 1234)]
    assert tb.slaves[1].read(0x607A) == 1234
    # TT 252: sampled at the SYNC
    await host.tpdo_write(1, drive_payload(1, 1))
    tb.sync_start()
    await tb.wait_syncs(1)
    tb.sync_stop()
    await host.tpdo_write(1, drive_payload(2, 2))
    assert (await host.tpdo_status(1))["pending"]
    rec = await rtr(0x202)
    assert rec.reply == 1
    await Timer(300, "us")
    assert [bytes(r.msg.data) for r in tb.sent(0x202)] == [drive_payload(1, 1)]
    tb.sync_start()
    await tb.wait_syncs(1)
    tb.sync_stop()
    assert tb.sent(0x202)[1:] == [], "TT 252 sends on RTR only"
    await rtr(0x202)
    await Timer(300, "us")
    assert [bytes(r.msg.data) for r in tb.sent(0x202)] == [drive_payload(1, 1),
                                                          drive_payload(2, 2)]
    # not answered
    n_tx = len(tb.tx_log)
    for cob in (0x203, 0x181, 0x185):
        rec = await rtr(cob)
        # remote frames are compared with the TPDOs only: decided at the last one
        assert rec.unexpected == 1 and rec.reply == 0, (hex(cob), rec)
        assert rec.latency in match_latency(tb.n_tpdo - 1), (hex(cob), rec)
    await Timer(300, "us")
    assert len(tb.tx_log) == n_tx
    # inhibited: no reply now, the frame comes when the inhibit time (1 ms) ends
    await host.tpdo_write(3, drive_payload(3, 3), trigger=True)
    await tb.wait_for(lambda: len(tb.sent(0x204)) == 1, 500, step_us=1)
    t_a = tb.sent(0x204)[0].t_ps
    rec = await rtr(0x204)
    assert rec.reply == 0 and rec.unexpected == 0 and rec.latency in match_latency(3), rec
    await tb.wait_for(lambda: len(tb.sent(0x204)) == 2, 1500, step_us=1)
    assert 1000 * PS_PER_US < tb.sent(0x204)[1].t_ps - t_a <= 1100 * PS_PER_US
    cnt = await tb.counters()
    assert cnt["rtr"] == 4 and cnt["unexpected"] == 3, cnt
    check_rx_clean(tb)


@cocotb.test(timeout_time=400, timeout_unit="ms")
async def run_rpdo_reception_200_syncs(dut):
    """Purpose: RPDO reception from three slaves over 200 SYNC cycles.

    Verifies: each slave's TPDO1 (a new position every SYNC) is stored with rx_done_o 2 + k
    cycles after rx_valid_i (RPDO k; one more when the engine was busy); every 10th cycle the
    host's snapshot of each channel equals the slave's last frame on the bus, with SEQ =
    frames so far, SYNC_COUNT = sync_count_i of the SYNC before it, NEW set (acknowledged by
    the previous read); after 200 SYNCs: SEQ = 200 on each channel, 600 ev_rx_o strobes =
    PDO_CNT_RX, no length error, no missed cycle, nothing unexpected.
    """
    tb = TB(dut)
    for n, slave in tb.slaves.items():
        slave.sync_listeners.append(lambda s, _t, _c, n=n: s.write(0x6064, 0,
                                                                     n * 100_000 + len(s.sync_log)))
    await tb.start()
    host = tb.host
    for ch, n in enumerate(NODES):
        await host.rpdo_config(ch, 0x180 + n, 6, 1)
    tb.sync_start()
    n_syncs = 200
    for k in range(n_syncs):
        await tb.wait_syncs(1)
        if k % 10 == 9:
            await Timer(tb.window_us, "us")
            for ch, n in enumerate(NODES):
                snap = await host.rpdo_read(ch)
                frames = tb.frames(0x180 + n, sender=f"slave{n}")
                assert snap["data"] == frames[-1][1], (k, ch, snap, frames[-1])
                assert snap["seq"] == len(frames) == k + 1, (k, ch, snap["seq"], len(frames))
                assert snap["sync_count"] == k & 0xFF and snap["new"], (k, snap)
                assert snap["len_err"] == 0 and snap["missed"] == 0
    await tb.wait_syncs(1)
    tb.sync_stop()
    await Timer(1, "ms")
    for ch, n in enumerate(NODES):
        snap = await host.rpdo_read(ch)
        assert snap["seq"] == len(tb.frames(0x180 + n)) == n_syncs + 1
    cnt = await tb.counters()
    total = 3 * (n_syncs + 1)
    assert cnt["rx"] == total == len(tb.strobes["ev_rx_o"]), (cnt, len(tb.strobes["ev_rx_o"]))
    assert cnt["len_err"] == cnt["missed"] == cnt["unexpected"] == 0, cnt
    for r in tb.rx_log:
        assert r.latency in match_latency(r.msg.arbitration_id - 0x181), r
    assert not any(r.reply for r in tb.rx_log)


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_length_mismatch(dut):
    """Purpose: PDOs whose DLC differs from the configured one are counted, not stored.

    Verifies: an RPDO expecting 8 bytes from a slave sending 6 counts every frame in LEN_ERR,
    stores nothing (SEQ 0, NEW 0, data 0) and never arms the missed-cycle monitor; three 4-byte
    frames injected on a correctly configured channel are counted and leave the stored data
    (the last good frame) and SEQ untouched; ev_len_err_o strobes = PDO_CNT_LEN_ERR = all
    mismatches; PDO_RX_NEW shows only the good channel.
    """
    tb = TB(dut)
    await tb.start()
    host = tb.host
    await host.rpdo_config(0, 0x181, 6, 1)
    await host.rpdo_config(1, 0x182, 8, 1)
    tb.sync_start()
    for k in range(10):
        await tb.at_phase(700)
        if k in (3, 5, 6):
            tb.clock.sync()
            tb.slaves[1].send_raw(make_message(0x181, b"\xde\xad\xbe\xef"))
    await tb.wait_syncs(1)
    tb.sync_stop()
    await Timer(1, "ms")
    good = tb.frames(0x181, sender="slave1")
    good6 = [d for _, d in good if len(d) == 6]
    assert len(good) - len(good6) == 3
    assert await host.rpdo_new() == 0b01
    s0 = await host.rpdo_read(0)
    assert s0["data"] == good6[-1] and s0["seq"] == len(good6) and s0["len_err"] == 3, s0
    s1 = await host.rpdo_read(1)
    n2 = len(tb.frames(0x182, sender="slave2"))
    assert s1 == {"data": bytes(8), "seq": 0, "sync_count": 0, "new": False,
                  "poll_due": False, "len_err": n2, "missed": 0}, s1
    cnt = await tb.counters()
    assert cnt["len_err"] == n2 + 3 == len(tb.strobes["ev_len_err_o"]), cnt
    assert cnt["missed"] == 0


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_missed_cycles(dut):
    """Purpose: synchronous RPDOs missing for their cycle are counted.

    Verifies: TT 1 RPDOs of slaves 1 and 2 and a TT 2 RPDO of slave 3 (its TPDO1 set to every
    2nd SYNC) run 10 SYNCs clean; slaves 2 and 3 are powered off for 12 SYNCs, then slave 2
    comes back (boot-up, NMT start) for 8 more: each channel's MISSED equals the reference
    model's count (0 for slave 1, one per SYNC without the PDO for slave 2, one per two SYNCs
    for slave 3, none after slave 2 is back); ev_missed_o strobes = PDO_CNT_MISSED = the sum.
    """
    tb = TB(dut)
    await tb.start()
    host = tb.host
    tb.slaves[3].write(0x1800, 2, 2)
    specs = {0: (1, 1), 1: (2, 1), 2: (3, 2)}  # ch: node, tt
    for ch, (node, tt) in specs.items():
        await host.rpdo_config(ch, 0x180 + node, 6, tt)
    tb.sync_start()
    await tb.wait_syncs(10)
    await Timer(500, "us")
    tb.clock.sync()
    tb.slaves[2].power_off()
    tb.slaves[3].power_off()
    await tb.wait_syncs(12)
    await Timer(300, "us")
    tb.clock.sync()
    tb.slaves[2].power_on()
    await tb.wait_for(lambda: tb.slaves[2].nmt_state is NmtState.PRE_OPERATIONAL, 500)
    tb.clock.sync()
    tb.syncer.send(make_message(0x000, bytes([0x01, 2])))
    await tb.wait_syncs(8)
    tb.sync_stop()
    await Timer(1, "ms")
    total = 0
    for ch, (node, tt) in specs.items():
        want = expected_missed(tb.sync_edges, tb.stores(0x180 + node, 6), tt)
        snap = await host.rpdo_read(ch)
        assert snap["missed"] == want, (ch, snap["missed"], want)
        total += want
    assert total > 15
    cnt = await tb.counters()
    assert cnt["missed"] == total == len(tb.strobes["ev_missed_o"]), cnt


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rtr_poll(dut):
    """Purpose: RPDOs polled with an RTR after every SYNC (slave TPDO type 253).

    Verifies: with slave 3's TPDO1 set to RTR-only, an RPDO with RTR poll sends exactly one
    remote frame 183h (DLC 6) after each SYNC and before the next, the slave answers each and
    the engine stores the answers: SEQ = number of SYNCs, data = the slave's last answer
    (its position changes every SYNC), nothing missed; without the poll the slave stays
    silent.
    """
    tb = TB(dut)
    slave = tb.slaves[3]
    slave.sync_listeners.append(lambda s, _t, _c: s.write(0x6064, 0, 7000 + len(s.sync_log)))
    await tb.start()
    host = tb.host
    slave.write(0x1800, 2, 253)
    await host.rpdo_config(0, 0x183, 6, 1, rtr_poll=True)
    tb.sync_start()
    n = 20
    await tb.wait_syncs(n)
    await Timer(tb.window_us, "us")
    tb.sync_stop()
    await Timer(1, "ms")
    polls = tb.frames(0x183, remote=True, sender="master")
    answers = tb.frames(0x183, sender="slave3")
    edges = tb.sync_edges
    assert len(edges) == n and len(polls) == n and len(answers) == n, \
        (len(edges), len(polls), len(answers))
    assert [sync_index(t, edges) for t, _ in polls] == list(range(n))
    assert all(r.msg.dlc == 6 for r in tb.sent(0x183))
    snap = await host.rpdo_read(0)
    assert snap["seq"] == n and snap["data"] == answers[-1][1] and snap["missed"] == 0
    # 6064h is written when the slave processes each SYNC, before the poll that follows it
    assert struct.unpack("<Hi", snap["data"])[1] == 7000 + n
    await host.rpdo_config(0, 0x183, 6, 255, rtr_poll=False)
    tb.sync_start()
    await tb.wait_syncs(3)
    tb.sync_stop()
    await Timer(1, "ms")
    assert len(tb.frames(0x183, sender="slave3")) == n


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_unexpected_cob_ids(dut):
    """Purpose: frames for no channel are flagged and change nothing.

    Verifies: a data frame 185h (no channel), a data frame on the master's own TPDO COB-ID
    201h, an RTR on an RPDO COB-ID 181h and an RTR for a TPDO without RTR allowed each give
    rx_done_o with rx_unexpected_o once the last channel of its kind was compared
    (``match_latency``); no frame is sent, nothing is
    stored (PDO_RX_NEW = 0, SEQ 0), PDO_CNT_UNEXPECTED = 4; an invalid RPDO channel with a
    matching COB-ID does not take a frame either.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 1, rtr_allowed=False)
    await host.rpdo_config(0, 0x181, 6, 255)
    await host.rpdo_config(1, 0x186, 6, 255, valid=False)
    stray = [make_message(0x185, b"\x01\x02"), make_message(0x201, bytes(6)),
             make_message(0x181, b"", remote=True, dlc=6),
             make_message(0x201, b"", remote=True, dlc=6), make_message(0x186, bytes(6))]
    for msg in stray:
        tb.clock.sync()
        tb.requester.send(msg)
    await tb.wait_for(lambda: len(tb.rx_log) == len(stray), 2000)
    assert [(r.unexpected, r.reply) for r in tb.rx_log] == [(1, 0)] * len(stray)
    for r in tb.rx_log:
        last = (tb.n_tpdo if r.msg.is_remote_frame else tb.n_rpdo) - 1
        assert r.latency in match_latency(last), r
    assert tb.tx_log == []
    assert await host.rpdo_new() == 0
    assert (await host.rpdo_read(0))["seq"] == 0
    cnt = await tb.counters()
    assert cnt["unexpected"] == len(stray) and cnt["rx"] == 0, cnt


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_queue_late_and_no_loss(dut):
    """Purpose: several due PDOs are queued, none lost; late synchronous frames are dropped.

    Verifies: 3 TT 1 TPDOs + 2 RPDO polls give exactly 5 frames per SYNC; with the taker
    stalled over 3 windows the engine never withdraws the frame it presents (the first item
    the round-robin scan started after the first SYNC), drops every synchronous TPDO not
    started by each window end (3 per window, minus the presented one: ev_late_o strobes,
    PDO_CNT_LATE, per-channel LATE), keeps the RTR polls and a TT 255 trigger made during the
    stall (sent after it); afterwards every SYNC again gives exactly 5 frames; with no window
    (window_open_i low) the TPDOs still due at the next SYNC are counted late, per channel
    counted from 0 after PDO_CTRL.CLR_COUNTERS.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    for ch in range(3):
        await host.tpdo_config(ch, 0x201 + ch, 6, 1)
    await host.tpdo_config(3, 0x284, 2, 255)
    for ch in range(2):
        await host.rpdo_config(ch, 0x181 + ch, 6, 255, rtr_poll=True)
    tb.sync_start()
    await tb.wait_syncs(1)

    def per_sync(first: int, last: int) -> list[int]:
        counts = collections.Counter(sync_index(r.t_ps, tb.sync_edges) for r in tb.tx_log)
        return [counts[i] for i in range(first, last)]

    await tb.wait_syncs(4)
    assert per_sync(1, 4) == [5, 5, 5]
    # stall over three windows
    await tb.at_phase(tb.window_us + 20)
    tb.allow_tx(False)
    stall_sync = len(tb.sync_edges)
    await tb.wait_syncs(1)
    await Timer(100, "us")
    await host.tpdo_write(3, b"\x55\xaa", trigger=True)
    await tb.wait_syncs(2)
    await Timer(tb.window_us + 20, "us")
    tb.allow_tx(True)
    await Timer(400, "us")
    # the polls kept over the stall are presented before the SYNC that follows the release
    release_sync = tb.sync_edges[stall_sync + 3]
    after = [r for r in tb.tx_log if r.t_ps > tb.sync_edges[stall_sync + 2]]
    stuck = after[0].msg.arbitration_id
    assert stuck in (0x201, 0x202, 0x203, 0x181, 0x182), hex(stuck)
    late = 3 * 3 - (stuck in (0x201, 0x202, 0x203))
    cnt = await tb.counters()
    assert cnt["late"] == late == len(tb.strobes["ev_late_o"]), (cnt, tb.strobes["ev_late_o"])
    assert 0x284 in {r.msg.arbitration_id for r in after}, "event TPDO lost"
    assert {r.msg.arbitration_id for r in after
            if r.msg.is_remote_frame and r.t_req_ps < release_sync} == {0x181, 0x182}
    lates = []
    for ch in range(3):
        lates.append((await host.tpdo_status(ch))["late"])
    want = [3 - (0x201 + ch == stuck) for ch in range(3)]
    assert lates == want, (lates, want, hex(stuck))
    first = len(tb.sync_edges)
    await tb.wait_syncs(3)
    assert per_sync(first, first + 2) == [5, 5]
    # no window: late when still due at the next SYNC
    await host.pdo_clear_counters()
    assert (await tb.counters())["late"] == 0
    # CLR_COUNTERS also clears every channel's LATE (counted from 0 again below)
    assert [(await host.tpdo_status(ch))["late"] for ch in range(3)] == [0, 0, 0]
    tb.window_us = 0
    await tb.at_phase(900)
    n_tx = len(tb.tx_log)
    tb.allow_tx(False)
    await tb.wait_syncs(2)
    await Timer(100, "us")
    tb.allow_tx(True)
    await Timer(600, "us")
    stuck = tb.tx_log[n_tx].msg.arbitration_id
    assert (await tb.counters())["late"] == 3 - (stuck in (0x201, 0x202, 0x203))
    lates = [(await host.tpdo_status(ch))["late"] for ch in range(3)]
    assert lates == [1 - (0x201 + ch == stuck) for ch in range(3)], (lates, hex(stuck))
    tb.sync_stop()


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_host_window_registers(dut):
    """Purpose: the register window: selection, staging, snapshots, flags, counters.

    Verifies: PDO_INFO = (4, 4); reset values 0; PDO_CFG / PDO_INHIBIT read back per channel
    and kind, a channel that does not exist reads 0 and ignores writes; the staging register
    shows the latest committed data of the selected TPDO (also while the commit is pending)
    and keeps the other half when only PDO_DATA_LO is rewritten; an RPDO snapshot does not
    change when a new PDO arrives until the channel is selected again; PDO_SEL.ACK and
    PDO_RX_NEW clear NEW; PDO_TX_PENDING/DUE bitmaps; PDO_CTRL.CLR_COUNTERS; a partial write
    is ignored.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    assert await host.pdo_info() == (tb.n_tpdo, tb.n_rpdo)
    for name in R.PDO_REGISTERS:
        if name in ("PDO_INFO",):
            continue
        for rpdo in (0, 1):
            await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo, CH=1))
            assert await host.read(name) == (R.make("PDO_SEL", RPDO=rpdo, CH=1)
                                             if name == "PDO_SEL" else 0), name
    for rpdo in (0, 1):
        for ch in range(tb.n_tpdo):
            await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo, CH=ch))
            cfg = R.make("PDO_CFG", COB_ID=0x300 + 16 * rpdo + ch, VALID=0, DLC=ch + 1,
                         TT=ch + 2, RTR=rpdo)
            await host.write("PDO_CFG", cfg)
            await host.write("PDO_INHIBIT", 100 * ch + rpdo + 1)
    for rpdo in (0, 1):
        for ch in range(tb.n_tpdo):
            await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo, CH=ch))
            cfg = await host.read_fields("PDO_CFG")
            assert cfg == {"COB_ID": 0x300 + 16 * rpdo + ch, "RTR": rpdo, "VALID": 0,
                           "DLC": ch + 1, "TT": ch + 2}, cfg
            assert await host.read("PDO_INHIBIT") == (0 if rpdo else 100 * ch + 1)
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=tb.n_tpdo))
    await host.write("PDO_CFG", 0xFFFFFFFF)
    assert await host.read("PDO_CFG") == 0
    # staging: latest committed data, pending commit, half rewrite
    await host.tpdo_config(0, 0x201, 8, 1)
    await host.tpdo_write(0, bytes(range(1, 9)))
    assert await host.read("PDO_TX_PENDING") == 1
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=1))
    await host.write("PDO_DATA_LO", 0xDEADBEEF)
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))
    assert (await host.read("PDO_DATA_HI"), await host.read("PDO_DATA_LO")) == (0x08070605,
                                                                               0x04030201)
    await host.write("PDO_DATA_LO", 0x11223344)
    await host.write("PDO_CMD", R.PDO_CMD_COMMIT)
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=1))
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))
    assert (await host.read("PDO_DATA_HI"), await host.read("PDO_DATA_LO")) == (0x08070605,
                                                                               0x11223344)
    tb.sync_start()
    await tb.wait_syncs(1)
    tb.sync_stop()
    await Timer(500, "us")
    assert await host.read("PDO_TX_PENDING") == 0 and await host.read("PDO_TX_DUE") == 0
    assert [bytes(r.msg.data) for r in tb.sent(0x201)] == [bytes.fromhex("4433221105060708")]
    # RPDO snapshot held until the next selection; NEW acknowledge
    await host.rpdo_config(2, 0x181, 6, 255)
    await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=1, CH=2))
    tb.clock.sync()
    tb.requester.send(make_message(0x181, drive_payload(1, 10)))
    await tb.wait_for(lambda: len(tb.rx_log) == 1, 500)
    assert await host.read("PDO_DATA_LO") == 0 and await host.read("PDO_RX_NEW") == 0b100
    snap = await host.rpdo_read(2, ack=False)
    assert snap["data"] == drive_payload(1, 10) and snap["new"] and snap["seq"] == 1
    tb.clock.sync()
    tb.requester.send(make_message(0x181, drive_payload(2, 20)))
    await tb.wait_for(lambda: len(tb.rx_log) == 2, 500)
    assert await host.read("PDO_DATA_LO") == int.from_bytes(drive_payload(1, 10)[:4], "little")
    snap = await host.rpdo_read(2, ack=True)
    assert snap["data"] == drive_payload(2, 20) and snap["new"] and snap["seq"] == 2
    assert (await host.rpdo_read(2))["new"] is False
    tb.clock.sync()
    tb.requester.send(make_message(0x181, drive_payload(3, 30)))
    await tb.wait_for(lambda: len(tb.rx_log) == 3, 500)
    assert await host.rpdo_new() == 0b100
    await host.rpdo_ack(0b011)
    assert await host.rpdo_new() == 0b100
    await host.rpdo_ack(0b100)
    assert await host.rpdo_new() == 0
    cnt = await tb.counters()
    assert cnt["rx"] == 3 and cnt["tx"] == 1
    await host.pdo_clear_counters()
    assert set((await tb.counters()).values()) == {0}
    assert set(PDO_COUNTER_NAMES) == {n[len("PDO_CNT_"):] for n in R.PDO_REGISTERS
                                      if n.startswith("PDO_CNT_")}


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_host_input_refused(dut):
    """Purpose: out-of-range host values in the PDO window are refused with a defined reaction.

    Verifies: PDO_SEL naming a channel that does not exist (TPDO N_TPDO and 31, RPDO 31), right
    after a valid TPDO was selected, neither stops the simulation (bound check) nor touches a
    channel: PDO_SEL.REFUSED = 1, the window reads 0 and ignores PDO_CFG / PDO_DATA / PDO_CMD
    (nothing sent); PDO_CFG with DLC 9..15 or TT 241..251 (TPDO and RPDO) is refused
    (REFUSED = 1, the channel's configuration unchanged) and a triggered TPDO still goes out
    with its old DLC; the next accepted PDO_SEL / PDO_CFG write clears REFUSED; the driver's
    tpdo_config of a channel that does not exist leaves PDO_SEL.REFUSED set.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 2, 255)
    await host.tpdo_write(0, b"\x11\x22", commit=True)
    good = await host.read("PDO_CFG")
    for rpdo, ch in ((0, tb.n_tpdo), (0, 31), (1, 31), (1, tb.n_rpdo)):
        await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))             # a valid TPDO first
        await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo, CH=ch))
        sel = await host.read("PDO_SEL")
        assert sel & R.PDO_SEL_REFUSED, f"PDO_SEL RPDO={rpdo} CH={ch} not refused: {sel:#x}"
        await host.write("PDO_CFG", 0xFFFFFFFF)
        await host.write("PDO_DATA_LO", 0xDEADBEEF)
        await host.write("PDO_CMD", R.PDO_CMD_COMMIT | R.PDO_CMD_TRIGGER)
        for name in ("PDO_CFG", "PDO_DATA_LO", "PDO_DATA_HI", "PDO_CMD", "PDO_SEQ"):
            assert await host.read(name) == 0, f"{name} with no channel selected"
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))
    assert not await host.read("PDO_SEL") & R.PDO_SEL_REFUSED
    assert await host.read("PDO_CFG") == good
    bad_cfgs = [R.make("PDO_CFG", COB_ID=0x202, VALID=1, DLC=dlc, TT=255) for dlc in (9, 15)]
    bad_cfgs += [R.make("PDO_CFG", COB_ID=0x202, VALID=1, DLC=2, TT=tt) for tt in (241, 251)]
    for rpdo in (0, 1):
        await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo, CH=0))
        before = await host.read("PDO_CFG")
        for cfg in bad_cfgs:
            await host.write("PDO_CFG", cfg)
            assert await host.read("PDO_SEL") & R.PDO_SEL_REFUSED, f"{cfg:#x} not refused"
            assert await host.read("PDO_CFG") == before, f"{cfg:#x} changed the channel"
    await host.tpdo_trigger(0)
    await tb.wait_for(lambda: len(tb.sent(0x201)) == 1, 500, step_us=1)
    await Timer(200, "us")
    assert [bytes(r.msg.data) for r in tb.sent(0x201)] == [b"\x11\x22"]
    assert tb.sent(0x202) == []
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))
    await host.write("PDO_CFG", good)
    assert not await host.read("PDO_SEL") & R.PDO_SEL_REFUSED
    await host.tpdo_config(tb.n_tpdo, 0x203, 2, 255)
    assert await host.pdo_refused()


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_pdo_right_after_sync(dut):
    """Purpose: a PDO stored in the cycles between a SYNC and that SYNC's visit of the channel
    belongs to the new SYNC period, not to the one the visit closes.

    Verifies: a TT 1 RPDO fed (directly on the rx port, the slaves' TPDOs off) per SYNC period
    either nothing, a PDO 500 us after the SYNC, or a PDO sampled 1..2 cycles after the SYNC
    (stored at most 4 cycles after it, before the housekeeping sweep reaches the RPDO: it
    visits the N_TPDO TPDOs first, 2 cycles each, and a receive match goes first); MISSED
    equals the reference model (a store at or after a SYNC edge counts for the period that
    SYNC opens), and ev_missed_o strobes = PDO_CNT_MISSED. A PDO counted for the closing
    period instead gives a different MISSED (the pattern has early PDOs followed by an empty
    period).
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.rpdo_config(0, 0x181, 6, 1)
    msg = make_message(0x181, drive_payload(0x0F, 1))

    def inject() -> None:
        tb.rx_queue.append(msg)
        tb._rx_event.set()

    tb.sync_start()
    # per SYNC period: M = PDO at 500 us, E = PDO right after the SYNC, - = none
    for sym in "ME-EE--ME-M-EE--EM":
        if sym == "M":
            await tb.at_phase(500)
            inject()
        else:
            await tb.wait_syncs(1)
            if sym == "E":
                inject()
    await tb.wait_syncs(2)
    tb.sync_stop()
    await Timer(1, "ms")
    stores = tb.stores(0x181, 6)
    assert len(stores) == 11, stores
    early = [t - tb.sync_edges[sync_index(t, tb.sync_edges)] for t in stores]
    early = [d for d in early if d <= 4 * CLK_PS]
    assert len(early) == 7, early
    want = expected_missed(tb.sync_edges, stores, 1)
    assert want >= 7, want
    snap = await host.rpdo_read(0)
    assert snap["missed"] == want and snap["seq"] == 11, snap
    cnt = await tb.counters()
    assert cnt["missed"] == want == len(tb.strobes["ev_missed_o"]), cnt


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_tpdo_cancelled_counted_late(dut):
    """Purpose: a synchronous TPDO the core withdrew from its TX buffer because the next SYNC
    fired before it started (tx_cancelled_i after its tx_ack_i) is counted late, like one
    dropped at the window end; other frames are not.

    Verifies: tx_sync_o is 1 with the frames of TT 0 and TT 1 channels and 0 with a TT 255
    frame and an RPDO poll; a tx_cancelled_i strobe after a TT 1 frame gives one ev_late_o
    strobe, PDO_CNT_LATE + 1 and LATE + 1 of that channel only; after a TT 0 frame the same
    for its channel; after the TT 255 frame and after an RPDO poll it counts nothing.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 1)
    await host.tpdo_config(1, 0x202, 6, 0)
    await host.tpdo_config(2, 0x284, 2, 255)
    await host.rpdo_config(0, 0x181, 6, 255, rtr_poll=True)
    tb.sync_start()
    await tb.wait_syncs(2)
    tb.sync_stop()
    await Timer(300, "us")
    kinds = {r.msg.arbitration_id: r.sync for r in tb.tx_log}
    assert kinds == {0x201: 1, 0x181: 0}, kinds

    async def cancel_after(cob: int) -> int:
        """Strobe tx_cancelled_i right after the next frame ``cob`` was taken (the next frame
        is taken only once this one left the bench's CAN node, 100 us later); returns its
        tx_sync_o."""
        n = len(tb.tx_log)
        await tb.wait_for(lambda: any(r.msg.arbitration_id == cob for r in tb.tx_log[n:]),
                          2000, 1)
        assert tb.tx_log[-1].msg.arbitration_id == cob, hex(tb.tx_log[-1].msg.arbitration_id)
        await FallingEdge(dut.clk_i)
        dut.tx_cancelled_i.value = 1
        await FallingEdge(dut.clk_i)
        dut.tx_cancelled_i.value = 0
        await Timer(20, "us")  # the channel's sweep visit counts it
        return tb.tx_log[-1].sync

    async def lates() -> list[int]:
        return [(await host.tpdo_status(ch))["late"] for ch in range(3)]

    async def one_sync(*cobs: int) -> list[int]:
        tasks = [cocotb.start_soon(cancel_after(c)) for c in cobs]
        tb.sync_start()
        await tb.wait_syncs(1)
        tb.sync_stop()
        return [await t for t in tasks]

    base = len(tb.strobes["ev_late_o"])
    # TT 255: taken on a trigger, not synchronous: nothing counted
    t = cocotb.start_soon(cancel_after(0x284))
    await host.tpdo_write(2, b"\x01\x02", trigger=True)
    assert await t == 0
    assert await lates() == [0, 0, 0] and len(tb.strobes["ev_late_o"]) == base
    # TT 1 counted, the RPDO poll not
    assert await one_sync(0x201, 0x181) == [1, 0]
    assert await lates() == [1, 0, 0]
    assert len(tb.strobes["ev_late_o"]) == base + 1
    # TT 0 (marked by a commit, sent after the next SYNC)
    await host.tpdo_write(1, b"\x11" * 6)
    assert await one_sync(0x202) == [1]
    await Timer(300, "us")
    assert await lates() == [1, 1, 0]
    cnt = await tb.counters()
    assert cnt["late"] == 2 == len(tb.strobes["ev_late_o"]) - base, cnt


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_selected_channel_follows_engine(dut):
    """Purpose: the window of a channel that stays selected follows the engine's writes of
    that channel, and a counter cleared by CLR_COUNTERS counts from 1 at its first event.

    Verifies: with TPDO 0 (TT 1) selected once, PDO_SEQ read after each of three SYNCs equals
    the frames taken so far, without a new selection. With the inhibit tick held off
    (tick_us_i = 0: no sweep visit between the clear and the event), CLR_COUNTERS between a
    frame's tx_ack_i and its tx_cancelled_i, then the late count: PDO_LATE = 1 and
    PDO_CNT_LATE = 1. With RPDO 1 selected, CLR_COUNTERS, then one frame of the wrong DLC:
    PDO_ERR.LEN_ERR = 1, after a second one 2, without a new selection. With RPDO 2 (TT 1)
    selected and missing after one PDO, CLR_COUNTERS, one SYNC: MISSED = 1.
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 1)
    await host.tpdo_write(0, b"\x5a" * 6)
    await host.write("PDO_SEL", R.make("PDO_SEL", CH=0))
    tb.sync_start()
    for n in range(1, 4):
        await tb.wait_syncs(1)
        await Timer(300, "us")
        seq = (await host.read_fields("PDO_SEQ"))["SEQ"]
        assert seq == len(tb.sent(0x201)) == n, (seq, n)
    tb.sync_stop()
    await Timer(1500, "us")
    dut.tick_us_i.value = 0
    # the next frame of TPDO 0: taken (its SEQ write), counters cleared, then withdrawn
    n_tx = len(tb.tx_log)
    tb.sync_start()
    await tb.wait_syncs(1)
    tb.sync_stop()
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx, 200, 1)
    await host.pdo_clear_counters()
    assert await host.read("PDO_LATE") == 0
    await FallingEdge(dut.clk_i)
    dut.tx_cancelled_i.value = 1
    await FallingEdge(dut.clk_i)
    dut.tx_cancelled_i.value = 0
    await Timer(20, "us")
    assert await host.read("PDO_LATE") == 1
    assert await host.read("PDO_CNT_LATE") == 1
    await Timer(1500, "us")
    # RPDO 1 selected: LEN_ERR counts from 1 after the clear
    await host.rpdo_config(1, 0x182, 8, 255)
    await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=1, CH=1))
    await host.pdo_clear_counters()
    for n in (1, 2):
        tb.clock.sync()
        tb.requester.send(make_message(0x182, bytes(4)))
        await tb.wait_for(lambda n=n: len(tb.rx_log) == n, 500, 1)
        await Timer(20, "us")
        err = await host.read_fields("PDO_ERR")
        assert err["LEN_ERR"] == n and err["MISSED"] == 0, err
    # RPDO 2 (TT 1) selected: armed by one PDO, then missed at every SYNC; MISSED counts from
    # 1 after the clear (the SYNC visit is the first write after it)
    await host.rpdo_config(2, 0x183, 8, 1)
    await host.write("PDO_SEL", R.make("PDO_SEL", RPDO=1, CH=2))
    tb.clock.sync()
    tb.requester.send(make_message(0x183, bytes(8)))
    await tb.wait_for(lambda: len(tb.rx_log) == 3, 500, 1)
    tb.sync_start()
    await tb.wait_syncs(3)
    tb.sync_stop()
    await Timer(1500, "us")
    assert (await host.read_fields("PDO_ERR"))["MISSED"] >= 1
    await host.pdo_clear_counters()
    assert (await host.read_fields("PDO_ERR"))["MISSED"] == 0
    tb.sync_start()
    await tb.wait_syncs(1)
    tb.sync_stop()
    await Timer(50, "us")
    err = await host.read_fields("PDO_ERR")
    assert err == {"LEN_ERR": 0, "MISSED": 1}, err


@cocotb.test(timeout_time=50, timeout_unit="ms", expect_fail=True)
async def run_od_checker_can_fail(dut):
    """Purpose: prove the slave OD / frame checker fails on a wrong expectation.

    Verifies: a TT 1 TPDO whose commits are recorded with one value off by one makes the
    comparison with the reference model fail (expect_fail).
    """
    tb = TB(dut)
    await tb.start(slave_tpdos=False)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 1)
    commits = []
    tb.sync_start()
    for k in range(3):
        await tb.at_phase(300)
        await host.tpdo_write(0, drive_payload(1, k))
        commits.append((tb.commit_edge(), drive_payload(1, k + (k == 1))))
    await tb.wait_syncs(1)
    tb.sync_stop()
    await Timer(1, "ms")
    want = expected_sync_frames(tb.sync_edges, commits, 1)
    got = {sync_index(r.t_ps, tb.sync_edges): bytes(r.msg.data) for r in tb.sent(0x201)}
    assert got == want


@cocotb.test(timeout_time=50, timeout_unit="ms", expect_fail=True)
async def run_missed_model_can_fail(dut):
    """Purpose: prove the missed-cycle check fails when the expectation is wrong.

    Verifies: slave 1 powered off for 3 SYNCs; comparing MISSED with the reference count + 1
    fails (expect_fail).
    """
    tb = TB(dut)
    await tb.start()
    await tb.host.rpdo_config(0, 0x181, 6, 1)
    tb.sync_start()
    await tb.wait_syncs(3)
    await Timer(500, "us")
    tb.clock.sync()
    tb.slaves[1].power_off()
    await tb.wait_syncs(3)
    tb.sync_stop()
    await Timer(1, "ms")
    want = expected_missed(tb.sync_edges, tb.stores(0x181, 6), 1)
    assert (await tb.host.rpdo_read(0))["missed"] == want + 1


# ============================================================================ pytest entry
@pytest.mark.sim
def test_canopen_pdo_engine(request):
    run_cocotb(toplevel="canopen_pdo_engine", module="tb.test_canopen_pdo_engine",
               name=request.node.name, parameters={"N_TPDO": 4, "N_RPDO": 4})
