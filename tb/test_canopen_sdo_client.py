"""Bench of the SDO client of ``canopen_sdo_channels``: CiA 301 SDO transfers against the
reference slave.

The SDO client is the shared engine of ``canopen_sdo_channels`` (one sequencer, each channel's
state in a RAM word; docs/canopen_sdo_channels.md). This bench drives the entity's host port on
channel 0 through :class:`ChannelsView` (the former ``canopen_sdo_client`` port names mapped to
the entity's ``host_*`` ports, ``done_o`` = channel 0's bit of ``chan_done_o``), and, in the
multi-channel tests, the other channels with their own slaves.

The bench plays the master FSM: it takes the DUT's request frames (``tx_req_o`` /
``tx_ack_i``) and sends them through a Python CAN node (``QueueNode``) on the timing-accurate
bus model at 1 Mbit/s, where :class:`sim_models.canopen_slave.CanopenSlave` (node 5) answers
with the ``canopen`` library's SDO server; the slave's responses (580h..5FFh) are handed back
to the DUT with ``rx_valid_i``. A "direct" mode skips the bus and answers in the cycle after
``tx_ack_i`` (worst case for the DUT's internal timing).

Checkers, all independent of the RTL:

* every frame the DUT sends is compared byte for byte with the frames CiA 301 prescribes for
  the transfer (``expected_download`` / ``expected_upload`` / ``abort_frame`` below);
* downloaded data is compared with the slave's object dictionary, uploaded data with the
  buffer read back through the host port (bytes beyond the transfer must stay untouched);
* every received frame must be answered by ``rx_done_o`` within ``RX_LATENCY_MAX`` cycles (the
  engine's documented bound), ``rx_reply_o`` must come with ``tx_req_o``, and a frame flagged
  ``rx_unexpected_o`` must not change ``state_o`` (the selected channel's state);
* ``error_o`` at ``done_o``, the abort code, ``abort_sent_o`` and ``size_o`` one cycle later
  (registered outputs of the result RAM); abort frames are also looked
  for on the bus, and the server's record of the abort it received is checked.
"""

from __future__ import annotations

import collections
import random
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import cocotb
import pytest
from cocotb.triggers import Event, FallingEdge, First, ReadOnly, RisingEdge, Timer

from sim_models.can_bus import CanBus, QueueNode
from sim_models.canopen_slave import CanopenSlave, NmtState, make_message
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler
from tb.tblib.bench_nodes import ForwardingNode
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.frame_handover import hand_over_frame
from tb.tblib.model_clock import ModelClock, sim_time_ps
from tb.tblib.runner import param, run_cocotb

CLK_HZ = 10_000_000
CLK_PS = 10**12 // CLK_HZ
BITRATE = 1_000_000
NODE = 5
DOMAIN = 0x2000  # DOMAIN, rw: any length is legal
#: rx_done_o at most this many edges after the one sampling rx_valid_i: the engine's bound
#: (docs/canopen_sdo_channels.md, "Engine schedule"): the item in progress (<= 9 more cycles),
#: one tx-ack item (6) and the frame's own item (<= 10), + 1 for the counting convention
RX_LATENCY_MAX = 26
#: measured with the zero-latency server (exact; see run_zero_latency_server)
ZL_RX_MIN = 12
ZL_RX_MAX = 16

# CiA 301 abort codes (Table 22), written here independently of the RTL package
ABORT_TOGGLE = 0x0503_0000
ABORT_TIMEOUT = 0x0504_0000
ABORT_CS = 0x0504_0001
ABORT_OUT_OF_MEM = 0x0504_0005
ABORT_READ_WO = 0x0601_0001
ABORT_WRITE_RO = 0x0601_0002
ABORT_NOT_IN_OD = 0x0602_0000
ABORT_LENGTH = 0x0607_0010
ABORT_NO_SUB = 0x0609_0011
ABORT_NO_DATA = 0x0800_0024  # the library's answer to an upload of an empty object
ABORT_NO_VALUE = 0x060A_0023  # the library's answer for a DOMAIN never written
ABORT_GENERAL = 0x0800_0000


# ============================================================================ reference frames
def _mux(index: int, sub: int) -> bytes:
    return struct.pack("<HB", index, sub)


def expected_download(index: int, sub: int, data: bytes) -> list[bytes]:
    """Frames a CiA 301 client sends for a download (the bench's own encoder)."""
    n = len(data)
    if 1 <= n <= 4:  # expedited, size indicated: ccs=1, n=4-size, e=1, s=1
        return [bytes([0x20 | (4 - n) << 2 | 0x03]) + _mux(index, sub) + data.ljust(4, b"\0")]
    frames = [bytes([0x21]) + _mux(index, sub) + struct.pack("<L", n)]  # e=0, s=1, size
    chunks = [data[i:i + 7] for i in range(0, n, 7)] or [b""]  # size 0: one empty segment
    for k, chunk in enumerate(chunks):
        last = int(k == len(chunks) - 1)
        frames.append(bytes([(k & 1) << 4 | (7 - len(chunk)) << 1 | last]) + chunk.ljust(7, b"\0"))
    return frames


def expected_upload(index: int, sub: int, n_segments: int) -> list[bytes]:
    frames = [bytes([0x40]) + _mux(index, sub) + bytes(4)]
    frames += [bytes([0x60 | (k & 1) << 4]) + bytes(7) for k in range(n_segments)]
    return frames


def n_upload_segments(size: int) -> int:
    return 0 if size <= 4 else -(-size // 7)


def abort_frame(index: int, sub: int, code: int) -> bytes:
    return bytes([0x80]) + _mux(index, sub) + struct.pack("<L", code)


def with_byte0(msg: can.Message, fn: Callable[[int], int]) -> can.Message:
    data = bytearray(msg.data)
    data[0] = fn(data[0])
    return make_message(msg.arbitration_id, bytes(data))


# ============================================================================ bench
class ChannelsView:
    """``canopen_sdo_channels`` seen through the former ``canopen_sdo_client`` port names."""

    _MAP = {"req_valid_i": "host_req_i", "req_upload_i": "host_upload_i",
            "req_node_i": "host_node_i", "req_index_i": "host_index_i",
            "req_subindex_i": "host_sub_i", "req_size_i": "host_size_i",
            "cob_req_i": "host_cob_req_i", "cob_resp_i": "host_cob_rsp_i"}

    def __init__(self, dut) -> None:
        self._dut = dut

    def __getattr__(self, name: str):
        return getattr(self._dut, self._MAP.get(name, name))


@dataclass
class Result:
    """What the host sees at done_o, plus the frames the DUT sent for the transfer."""

    error: int
    code: int
    sent: int
    size: int
    busy_at_done: int
    frames: list[bytes]
    ids: list[int]
    t_req_ps: int
    t_done_ps: int
    tx_times: list[int] = field(default_factory=list)
    n_bus0: int = 0  #: frames the bench's master node had sent on the bus before the request


@dataclass
class RxRecord:
    t_ps: int
    msg: can.Message
    latency: int
    reply: int
    unexpected: int
    state_before: int
    state_after: int


class TB:
    """DUT + bench FSM (tx taker, rx feeder, ms tick) + CAN bus + reference slave node 5."""

    def __init__(self, dut, *, direct: bool = False, ack_node: bool = False) -> None:
        self.raw = dut
        self.dut = ChannelsView(dut)
        dut = self.dut
        self.n_sdo = param("N_SDO")
        self.buf_bytes = param("BUF_BYTES")
        self.timeout_def_ms = param("TIMEOUT_DEF_MS")
        self.empty_segs_max = param("EMPTY_SEGS_MAX")
        self.direct = direct
        start_clock(dut.clk_i, CLK_HZ)
        self.sched = Scheduler()
        self.sched.run_until(sim_time_ps())
        self.clock = ModelClock(self.sched)
        self.bus = CanBus(self.sched, BITRATE)
        self.master = ForwardingNode("master", BITRATE, self._from_bus)
        self.bus.attach(self.master)
        self.slave = CanopenSlave(self.sched, NODE, bitrate_bps=BITRATE,
                                  boot_time_ps=20 * PS_PER_US)
        if not direct:
            self.bus.attach(self.slave)
        if ack_node:  # a passive node that acknowledges frames when the slave is off
            self.bus.attach(QueueNode("acker", BITRATE))
        # bench FSM state
        self.take_tx = True
        self._take_event = Event()
        self.tx_log: list[tuple[int, can.Message]] = []
        self.rx_queue: collections.deque[tuple[can.Message, bool]] = collections.deque()
        self._rx_event = Event()
        self.rx_log: list[RxRecord] = []
        self.max_rx_latency = RX_LATENCY_MAX
        #: applied to every frame from the server before the DUT sees it (None = drop it)
        self.mangle: Callable[[can.Message], can.Message | None] | None = None
        self.done_count = 0
        self.done_base = 0
        self.chan_done: list[list[int]] = [[] for _ in range(4)]
        self._done_event = Event()
        self.t_req_edge = 0
        for sig in (dut.tick_ms_i, dut.req_valid_i, dut.req_upload_i, dut.req_node_i,
                    dut.req_index_i, dut.req_subindex_i, dut.req_size_i, dut.cob_req_i,
                    dut.cob_resp_i, dut.timeout_ms_i, dut.buf_addr_i, dut.buf_we_i,
                    dut.buf_wdata_i, dut.tx_ack_i, dut.rx_valid_i, dut.rx_id_i, dut.rx_rtr_i,
                    dut.rx_dlc_i, dut.rx_data_i, dut.host_chan_i, dut.own_i, dut.own_req_i,
                    dut.own_node_i, dut.own_index_i, dut.own_sub_i, dut.own_size_i,
                    dut.own_buf_we_i, dut.own_buf_data_i):
            sig.value = 0
        dut.enable_i.value = 1
        # no TX buffer here (a taken frame is on the bus): the withdraw of an ended transfer's
        # request is acknowledged at once, as the core does when TXB1 holds no such request
        dut.wdr_ack_i.value = 1
        cocotb.start_soon(self._ticker())
        cocotb.start_soon(self._tx_taker())
        cocotb.start_soon(self._rx_feeder())
        cocotb.start_soon(self._done_counter())

    # ------------------------------------------------------------------ bench FSM
    async def _ticker(self) -> None:
        """tick_ms_i: one clock cycle high every 1 ms (aligned to falling edges)."""
        await FallingEdge(self.dut.clk_i)
        while True:
            self.dut.tick_ms_i.value = 1
            await Timer(CLK_PS, "ps")
            self.dut.tick_ms_i.value = 0
            await Timer(PS_PER_MS - CLK_PS, "ps")

    async def _tx_taker(self) -> None:
        """Take every frame the DUT requests (tx_ack_i at the first falling edge) and send it."""
        dut = self.dut
        while True:
            if dut.tx_req_o.value != 1:
                await RisingEdge(dut.tx_req_o)
            await FallingEdge(dut.clk_i)
            while not self.take_tx:
                self._take_event.clear()
                await self._take_event.wait()
                await FallingEdge(dut.clk_i)
            if dut.tx_req_o.value != 1:
                continue  # withdrawn
            assert int(dut.tx_dlc_o.value) == 8, "SDO frames have DLC 8"
            msg = make_message(int(dut.tx_id_o.value),
                               int(dut.tx_data_o.value).to_bytes(8, "little"))
            dut.tx_ack_i.value = 1
            await RisingEdge(dut.clk_i)
            dut.tx_ack_i.value = 0
            self.tx_log.append((sim_time_ps(), msg))
            self._deliver(msg)
            await ReadOnly()

    def _deliver(self, msg: can.Message) -> None:
        if not self.direct:
            self.clock.sync()
            self.master.send(msg)
            return
        # direct: the server answers at once, without the bus
        now = self.clock.sync()
        self.slave.on_rx(msg, now)
        for m in self.slave.tx_queue:
            self.slave.on_tx_done(m, now)
            self._from_bus(m)

    def _from_bus(self, msg: can.Message) -> None:
        # the FSM only hands SDO responses (580h..5FFh) to the client
        if not msg.is_remote_frame and 0x580 <= msg.arbitration_id <= 0x5FF:
            self.rx_queue.append((msg, True))
            self._rx_event.set()

    def inject(self, msg: can.Message) -> None:
        """Hand a frame to the DUT next (not mangled), e.g. a stray frame during a transfer."""
        self.rx_queue.appendleft((msg, False))
        self._rx_event.set()

    async def _rx_feeder(self) -> None:
        dut = self.dut
        while True:
            while not self.rx_queue:
                self._rx_event.clear()
                await self._rx_event.wait()
            msg, may_mangle = self.rx_queue.popleft()
            if may_mangle and self.mangle is not None:
                msg = self.mangle(msg)
                if msg is None:
                    continue
            await FallingEdge(dut.clk_i)
            state_before = int(dut.state_o.value)
            _, latency = await hand_over_frame(dut, msg, self.max_rx_latency)
            rec = RxRecord(sim_time_ps(), msg, latency, int(dut.rx_reply_o.value),
                           int(dut.rx_unexpected_o.value), state_before,
                           int(dut.state_o.value))
            self.rx_log.append(rec)
            if rec.reply:
                assert dut.tx_req_o.value == 1, "rx_reply_o without tx_req_o"
                assert not rec.unexpected, "rx_reply_o together with rx_unexpected_o"
            if rec.unexpected:
                assert rec.state_after == rec.state_before, \
                    f"unexpected frame changed state {rec.state_before} -> {rec.state_after}"

    async def _done_counter(self) -> None:
        """done_o of channel 0: its bit of chan_done_o (a 1-cycle strobe); every channel's
        done strobes are also recorded with their times (``chan_done``)."""
        sig = self.raw.chan_done_o
        while True:
            await sig.value_change
            if not sig.value.is_resolvable:
                continue
            bits = int(sig.value)
            for c in range(4):
                if bits >> c & 1:
                    self.chan_done[c].append(sim_time_ps())
            if bits & 1:
                self.done_count += 1
                self._done_event.set()

    # ------------------------------------------------------------------ host side
    async def start(self, operational: bool = False) -> None:
        """Reset the DUT and wait for the slave's boot-up (and NMT start if asked)."""
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        await self.wait_for(lambda: self.slave.nmt_state is NmtState.PRE_OPERATIONAL, 1000)
        if operational:
            self.clock.sync()
            self.master.send(make_message(0x000, bytes([0x01, NODE])))
            await self.wait_for(lambda: self.slave.nmt_state is NmtState.OPERATIONAL, 1000)

    async def wait_for(self, cond: Callable[[], bool], timeout_us: float,
                       step_us: float = 5) -> None:
        t_end = sim_time_ps() + int(timeout_us * PS_PER_US)
        while not cond():
            assert sim_time_ps() < t_end, f"condition not met within {timeout_us} us"
            await Timer(step_us, "us")

    def allow_tx(self, on: bool) -> None:
        self.take_tx = on
        if on:
            self._take_event.set()

    async def write_buf(self, data: bytes, offset_words: int = 0, chan: int = 0) -> None:
        dut = self.dut
        if chan:
            await FallingEdge(dut.clk_i)
            dut.host_chan_i.value = chan
        data = data + bytes(-len(data) % 4)
        for w in range(len(data) // 4):
            await FallingEdge(dut.clk_i)
            dut.buf_addr_i.value = offset_words + w
            dut.buf_wdata_i.value = int.from_bytes(data[4 * w:4 * w + 4], "little")
            dut.buf_we_i.value = 1
        await FallingEdge(dut.clk_i)
        dut.buf_we_i.value = 0
        if chan:
            dut.host_chan_i.value = 0

    async def read_buf(self, n: int, chan: int = 0) -> bytes:
        dut = self.dut
        if chan:
            await FallingEdge(dut.clk_i)
            dut.host_chan_i.value = chan
        out = bytearray()
        for w in range(-(-n // 4)):
            await FallingEdge(dut.clk_i)
            dut.buf_addr_i.value = w
            await RisingEdge(dut.clk_i)  # address sampled, word registered at this edge
            await ReadOnly()
            out += int(dut.buf_rdata_o.value).to_bytes(4, "little")
        if chan:
            await FallingEdge(dut.clk_i)
            dut.host_chan_i.value = 0
        return bytes(out[:n])

    async def start_all(self, reqs: list[dict]) -> None:
        """One request per channel (reqs[c] for channel c) in consecutive clock cycles."""
        dut = self.raw
        for c, r in enumerate(reqs):
            await FallingEdge(dut.clk_i)
            dut.host_chan_i.value = c
            dut.host_upload_i.value = int(r["upload"])
            dut.host_node_i.value = r["node"]
            dut.host_index_i.value = r["index"]
            dut.host_sub_i.value = 0
            dut.host_size_i.value = r.get("size", 0)
            dut.host_cob_req_i.value = 0
            dut.host_cob_rsp_i.value = 0
            dut.timeout_ms_i.value = r.get("timeout_ms", 20)
            dut.host_req_i.value = 1
        await FallingEdge(dut.clk_i)
        dut.host_req_i.value = 0
        dut.host_chan_i.value = 0

    async def results(self) -> list[tuple[int, int, int, int]]:
        """(error, abort code, abort sent, size) of every channel, read through host_chan_i."""
        dut = self.raw
        out = []
        for c in range(self.n_sdo):
            await FallingEdge(dut.clk_i)
            dut.host_chan_i.value = c
            await ReadOnly()
            error = int(dut.error_o.value)
            await RisingEdge(dut.clk_i)  # the result RAM's outputs: +1 cycle after host_chan_i
            await ReadOnly()
            out.append((error, int(dut.abort_code_o.value),
                        int(dut.abort_sent_o.value), int(dut.size_o.value)))
        await FallingEdge(dut.clk_i)
        dut.host_chan_i.value = 0
        return out

    async def wait_all_idle(self, limit_ms: float) -> None:
        dut = self.raw
        t_end = sim_time_ps() + int(limit_ms * PS_PER_MS)
        await Timer(1, "us")
        while int(dut.chan_busy_o.value) != 0:
            assert sim_time_ps() < t_end, f"channels still busy after {limit_ms} ms"
            await Timer(10, "us")

    async def request(self, *, upload: bool, index: int, sub: int = 0, size: int = 0,
                      node: int = NODE, timeout_ms: int = 20, cob_req: int = 0,
                      cob_resp: int = 0) -> None:
        """One req_valid_i pulse with the request inputs."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.req_upload_i.value = int(upload)
        dut.req_node_i.value = node
        dut.req_index_i.value = index
        dut.req_subindex_i.value = sub
        dut.req_size_i.value = size
        dut.cob_req_i.value = cob_req
        dut.cob_resp_i.value = cob_resp
        dut.timeout_ms_i.value = timeout_ms
        self.done_base = self.done_count
        dut.req_valid_i.value = 1
        await RisingEdge(dut.clk_i)
        dut.req_valid_i.value = 0
        self.t_req_edge = sim_time_ps()  # the edge that sampled req_valid_i

    async def wait_done(self, n_tx0: int, t_req: int, limit_ms: float = 100,
                        n_bus0: int = 0) -> Result:
        dut = self.dut
        t_end = sim_time_ps() + int(limit_ms * PS_PER_MS)
        while self.done_count <= self.done_base:
            assert sim_time_ps() < t_end, f"transfer did not end within {limit_ms} ms"
            self._done_event.clear()
            await First(self._done_event.wait(), Timer(t_end - sim_time_ps(), "ps"))
        await ReadOnly()
        t_done = sim_time_ps()
        error, busy = int(dut.error_o.value), int(dut.busy_o.value)
        await RisingEdge(dut.clk_i)  # abort code, abort sent, size: one cycle after done_o
        await ReadOnly()
        log = self.tx_log[n_tx0:]
        return Result(error=error, code=int(dut.abort_code_o.value),
                      sent=int(dut.abort_sent_o.value), size=int(dut.size_o.value),
                      busy_at_done=busy,
                      frames=[bytes(m.data) for _, m in log],
                      ids=[m.arbitration_id for _, m in log], t_req_ps=t_req,
                      t_done_ps=t_done, tx_times=[t for t, _ in log], n_bus0=n_bus0)

    async def transfer(self, *, limit_ms: float = 100, **req) -> Result:
        dut = self.dut
        await FallingEdge(dut.clk_i)
        assert dut.busy_o.value == 0, "request while busy"
        n_tx0 = len(self.tx_log)
        n_bus0 = len(self.bus_frames_from_master())
        t_req = sim_time_ps()
        await self.request(**req)
        return await self.wait_done(n_tx0, t_req, limit_ms, n_bus0)

    async def download(self, index: int, sub: int, data: bytes, **kw) -> Result:
        await self.write_buf(data)
        return await self.transfer(upload=False, index=index, sub=sub, size=len(data), **kw)

    async def upload(self, index: int, sub: int = 0, **kw) -> Result:
        return await self.transfer(upload=True, index=index, sub=sub, **kw)

    def bus_frames_from_master(self) -> list[bytes]:
        return [bytes(r.msg.data) for r in self.bus.records
                if r.kind == "frame" and r.sender == "master"]

    async def wait_bus_frame(self, res: Result, payload: bytes, timeout_us: float = 1000) -> None:
        """Wait until ``payload`` was sent on the bus after the request of ``res``."""
        await self.wait_for(lambda: payload in self.bus_frames_from_master()[res.n_bus0:],
                            timeout_us)


# ============================================================================ checkers
def check_ok(res: Result, size: int) -> None:
    assert res.error == 0, f"transfer aborted: code {res.code:08X}, sent by client={res.sent}"
    assert res.code == 0 and res.sent == 0
    assert res.size == size, f"size_o = {res.size}, expected {size}"
    assert res.busy_at_done == 0, "busy_o still 1 at done_o"


def check_abort(res: Result, code: int, *, sent: bool, size: int | None = None,
                abort_frames: int | None = None) -> None:
    """``abort_frames``: abort frames the client must have sent (default: 1 if ``sent``)."""
    assert res.error == 1, "transfer should have ended in an abort"
    assert res.code == code, f"abort code {res.code:08X}, expected {code:08X}"
    assert res.sent == int(sent), f"abort_sent_o = {res.sent}, expected {int(sent)}"
    if size is not None:
        assert res.size == size, f"size_o = {res.size}, expected {size}"
    client_aborts = [f for f in res.frames if f[0] == 0x80]
    n_abort = int(sent) if abort_frames is None else abort_frames
    assert len(client_aborts) == n_abort, f"client abort frames: {client_aborts}"
    assert res.busy_at_done == 0


def check_frames(res: Result, expected: list[bytes], cob: int = 0x600 + NODE) -> None:
    assert res.frames == expected, (
        "frames sent:\n  " + "\n  ".join(f.hex(" ") for f in res.frames)
        + "\nexpected:\n  " + "\n  ".join(f.hex(" ") for f in expected))
    assert all(i == cob for i in res.ids), [hex(i) for i in res.ids]


def check_data(got: bytes, expected: bytes, what: str = "data") -> None:
    assert got == expected, f"{what}: got {got.hex(' ')}, expected {expected.hex(' ')}"


# ============================================================================ tests
@cocotb.test(timeout_time=400, timeout_unit="ms")
async def run_every_size_download_upload(dut):
    """Purpose: expedited and segmented download and upload of every size 0..64 bytes.

    Verifies: for each size the DUT's frames equal the CiA 301 sequence (expedited initiate for
    1..4 bytes, else initiate with the size then segments with alternating toggle, n and c;
    size 0 = one empty last segment); the slave's 2000h holds exactly the downloaded bytes; the
    upload writes exactly those bytes to the buffer (the bytes behind stay untouched) with
    size_o = size; an empty object's upload ends with the server's abort 0800 0024h.
    """
    tb = TB(dut)
    await tb.start()
    rng = random.Random(1)
    fill = bytes([0xA5]) * tb.buf_bytes
    for size in range(65):
        data = bytes(rng.getrandbits(8) for _ in range(size))
        res = await tb.download(DOMAIN, 0, data)
        check_ok(res, size)
        check_frames(res, expected_download(DOMAIN, 0, data))
        check_data(tb.slave.read_raw(DOMAIN), data, f"slave 2000h after download of {size}")
        await tb.write_buf(fill)
        res = await tb.upload(DOMAIN)
        if size == 0:
            check_abort(res, ABORT_NO_DATA, sent=False, size=0)
            continue
        check_ok(res, size)
        check_frames(res, expected_upload(DOMAIN, 0, n_upload_segments(size)))
        back = await tb.read_buf(min(size + 8, tb.buf_bytes))
        check_data(back[:size], data, f"upload of {size}")
        check_data(back[size:], fill[:len(back) - size], "bytes behind the upload")
    assert max(r.latency for r in tb.rx_log) <= RX_LATENCY_MAX
    assert not any(r.unexpected for r in tb.rx_log)


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_full_buffer_and_typed_objects(dut):
    """Purpose: a BUF_BYTES transfer each way and the slave's typed objects, in operational.

    Verifies: download then upload of BUF_BYTES random bytes round-trips through 2000h (slave
    OD compared too); uploads of 1008h (71-character string, segmented), 1000h (U32),
    1001h (U8, n = 3), 1018h sub 1/4 equal the slave's values; a U16 written to 6040h by an
    expedited download reads back from the OD and by upload.
    """
    tb = TB(dut)
    await tb.start(operational=True)
    rng = random.Random(2)
    n = tb.buf_bytes
    data = bytes(rng.getrandbits(8) for _ in range(n))
    res = await tb.download(DOMAIN, 0, data)
    check_ok(res, n)
    check_frames(res, expected_download(DOMAIN, 0, data))
    check_data(tb.slave.read_raw(DOMAIN), data, "slave 2000h")
    await tb.write_buf(bytes(n))
    res = await tb.upload(DOMAIN)
    check_ok(res, n)
    check_data(await tb.read_buf(n), data, "upload of BUF_BYTES")
    for index, sub in ((0x1008, 0), (0x1000, 0), (0x1001, 0), (0x1018, 1), (0x1018, 4)):
        raw = tb.slave.read_raw(index, sub)
        res = await tb.upload(index, sub)
        check_ok(res, len(raw))
        check_frames(res, expected_upload(index, sub, n_upload_segments(len(raw))))
        check_data(await tb.read_buf(len(raw)), raw, f"{index:04X}:{sub}")
    res = await tb.download(0x6040, 0, struct.pack("<H", 0x0006))
    check_ok(res, 2)
    assert tb.slave.read(0x6040) == 0x0006
    res = await tb.upload(0x6040)
    check_ok(res, 2)
    check_data(await tb.read_buf(2), b"\x06\x00", "6040h")
    assert tb.slave.nmt_state is NmtState.OPERATIONAL


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_server_aborts(dut):
    """Purpose: aborts sent by the server end the transfer with the server's code.

    Verifies: upload of 2000h never written (060A 0023h), missing object 3000h on expedited
    and segmented download and on upload (0602 0000h), missing subindex (0609 0011h), write
    to read-only 2001h expedited and segmented (0601 0002h), read of write-only 2002h
    (0601 0001h), wrong length on a U32 expedited (0607 0010h) and segmented (0607 0010h
    after the last segment, size_o = the 7 bytes the server had confirmed): error_o = 1,
    abort_sent_o = 0, no abort frame from the client.
    """
    tb = TB(dut)
    await tb.start()
    check_abort(await tb.upload(DOMAIN), ABORT_NO_VALUE, sent=False, size=0)
    res = await tb.download(0x3000, 0, b"\x01\x02\x03\x04")
    check_abort(res, ABORT_NOT_IN_OD, sent=False, size=0)
    check_frames(res, expected_download(0x3000, 0, b"\x01\x02\x03\x04"))
    res = await tb.download(0x3000, 0, bytes(10))
    check_abort(res, ABORT_NOT_IN_OD, sent=False, size=0)
    check_frames(res, expected_download(0x3000, 0, bytes(10))[:1])
    check_abort(await tb.upload(0x3000), ABORT_NOT_IN_OD, sent=False, size=0)
    check_abort(await tb.upload(0x1018, 9), ABORT_NO_SUB, sent=False, size=0)
    check_abort(await tb.download(0x2001, 0, b"\x00\x00\x00\x00"), ABORT_WRITE_RO, sent=False)
    check_abort(await tb.download(0x2001, 0, bytes(8)), ABORT_WRITE_RO, sent=False)
    check_abort(await tb.upload(0x2002), ABORT_READ_WO, sent=False, size=0)
    check_abort(await tb.download(0x607A, 0, b"\x01\x02"), ABORT_LENGTH, sent=False, size=0)
    res = await tb.download(0x607A, 0, bytes(range(8)))
    check_abort(res, ABORT_LENGTH, sent=False, size=7)
    check_frames(res, expected_download(0x607A, 0, bytes(range(8))))
    assert tb.slave.read(0x607A) == 0, "the refused value must not be stored"


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_client_length_and_memory_aborts(dut):
    """Purpose: the client's own size checks on uploads, and the local size check.

    Verifies: an indicated size above BUF_BYTES is aborted 0504 0005h before any segment; with
    the size hidden (s = 0) the client aborts 0504 0005h at the segment that would overflow
    the buffer; an indicated size larger than the data (c = 1 too early) and smaller than the
    data are aborted 0607 0010h: each abort frame has the exact CiA 301 content on the bus and
    the server received the code; a download of more than BUF_BYTES is refused without any
    frame (error_o, 0504 0005h).
    """
    tb = TB(dut)
    await tb.start()
    nb = tb.buf_bytes
    big = bytes(random.Random(3).getrandbits(8) for _ in range(nb + 44))
    tb.clock.sync()
    tb.slave.write(DOMAIN, 0, big)
    res = await tb.upload(DOMAIN)
    check_abort(res, ABORT_OUT_OF_MEM, sent=True, size=0)
    check_frames(res, expected_upload(DOMAIN, 0, 0) + [abort_frame(DOMAIN, 0, ABORT_OUT_OF_MEM)])
    await tb.wait_bus_frame(res, abort_frame(DOMAIN, 0, ABORT_OUT_OF_MEM))
    assert tb.slave.node.sdo.last_received_error == ABORT_OUT_OF_MEM

    def hide_size(msg: can.Message) -> can.Message:  # initiate upload response: s = 0
        if msg.data[0] & 0xE0 == 0x40:
            data = bytearray(msg.data)
            data[0] &= ~0x01
            data[4:8] = bytes(4)
            return make_message(msg.arbitration_id, bytes(data))
        return msg

    tb.mangle = hide_size
    res = await tb.upload(DOMAIN)
    n_ok = nb // 7 * 7  # whole segments that still fit
    check_abort(res, ABORT_OUT_OF_MEM, sent=True, size=n_ok)
    check_frames(res, expected_upload(DOMAIN, 0, nb // 7 + 1)
                 + [abort_frame(DOMAIN, 0, ABORT_OUT_OF_MEM)])
    check_data(await tb.read_buf(n_ok), big[:n_ok], "bytes before the overflow")

    name = tb.slave.read_raw(0x1008)  # 71 bytes, 11 segments
    for delta in (+3, -6):
        def fake_size(msg: can.Message, delta=delta) -> can.Message:
            if msg.data[0] & 0xE0 == 0x40:
                data = bytearray(msg.data)
                struct.pack_into("<L", data, 4, len(name) + delta)
                return make_message(msg.arbitration_id, bytes(data))
            return msg

        tb.mangle = fake_size
        res = await tb.upload(0x1008)
        segs = 11 if delta > 0 else 10  # too small: detected when the total passes it
        # the rejected segment is not written: 10 segments (70 bytes) resp. 9 (63 bytes)
        check_abort(res, ABORT_LENGTH, sent=True, size=70 if delta > 0 else 63)
        check_frames(res, expected_upload(0x1008, 0, segs)
                     + [abort_frame(0x1008, 0, ABORT_LENGTH)])
        await tb.wait_bus_frame(res, abort_frame(0x1008, 0, ABORT_LENGTH))
        assert tb.slave.node.sdo.last_received_error == ABORT_LENGTH
        tb.slave.node.sdo.last_received_error = 0
    tb.mangle = None

    n_bus = len(tb.bus_frames_from_master())
    res = await tb.transfer(upload=False, index=DOMAIN, size=nb + 1)
    check_abort(res, ABORT_OUT_OF_MEM, sent=True, size=0, abort_frames=0)
    assert res.frames == [], "a refused request sends no frame"
    assert res.t_done_ps - res.t_req_ps <= 3 * CLK_PS
    await Timer(300, "us")
    assert len(tb.bus_frames_from_master()) == n_bus


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_timeouts(dut):
    """Purpose: no response (slave powered off) and no frame taken never hang the client.

    Verifies: an upload to a powered-off slave ends with the client's abort 0504 0000h, whose
    frame is on the bus and is requested between timeout_ms_i and timeout_ms_i + 1 ms after
    the request was taken; a segmented download whose server disappears after two segments
    ends the same way after the third segment; when the FSM never takes the request the
    transfer ends after the timeout with 0504 0000h, tx_req_o withdrawn and no frame sent;
    timeout_ms_i = 0 is bounded too: it uses TIMEOUT_DEF_MS (abort 0504 0000h on the bus
    between TIMEOUT_DEF_MS and TIMEOUT_DEF_MS + 1 ms after the request was taken).
    """
    tb = TB(dut, ack_node=True)
    await tb.start()
    tb.clock.sync()
    tb.slave.power_off()
    res = await tb.upload(0x1000, timeout_ms=3)
    check_abort(res, ABORT_TIMEOUT, sent=True, size=0)
    check_frames(res, expected_upload(0x1000, 0, 0) + [abort_frame(0x1000, 0, ABORT_TIMEOUT)])
    waited = res.tx_times[1] - res.tx_times[0]
    assert 3 * PS_PER_MS < waited <= 4 * PS_PER_MS + 10 * CLK_PS, f"waited {waited} ps"
    await tb.wait_bus_frame(res, abort_frame(0x1000, 0, ABORT_TIMEOUT))

    # server disappears during a segmented download
    tb.clock.sync()
    tb.slave.power_on()
    await tb.wait_for(lambda: tb.slave.nmt_state is NmtState.PRE_OPERATIONAL, 1000)
    seen = []

    def power_off_after_two(msg: can.Message) -> can.Message:
        seen.append(msg)
        if len(seen) == 3:  # initiate response + 2 segment responses
            tb.clock.sync()
            tb.slave.power_off()
        return msg

    tb.mangle = power_off_after_two
    data = bytes(range(40))
    res = await tb.download(DOMAIN, 0, data, timeout_ms=2)
    check_abort(res, ABORT_TIMEOUT, sent=True, size=14)
    check_frames(res, expected_download(DOMAIN, 0, data)[:4]
                 + [abort_frame(DOMAIN, 0, ABORT_TIMEOUT)])
    await tb.wait_bus_frame(res, abort_frame(DOMAIN, 0, ABORT_TIMEOUT))
    tb.mangle = None

    # the FSM never takes the request
    tb.allow_tx(False)
    n_bus = len(tb.bus_frames_from_master())
    res = await tb.upload(0x1000, timeout_ms=2)
    check_abort(res, ABORT_TIMEOUT, sent=True, size=0, abort_frames=0)
    assert res.frames == []
    assert 2 * PS_PER_MS < res.t_done_ps - res.t_req_ps <= 3 * PS_PER_MS + 10 * CLK_PS
    await RisingEdge(dut.clk_i)
    await ReadOnly()
    assert dut.tx_req_o.value == 0, "request not withdrawn"
    tb.allow_tx(True)
    await Timer(200, "us")
    assert len(tb.bus_frames_from_master()) == n_bus

    # timeout 0: the default timeout TIMEOUT_DEF_MS bounds the wait
    tdef = tb.timeout_def_ms
    res = await tb.upload(0x1000, timeout_ms=0, limit_ms=tdef + 5)
    check_abort(res, ABORT_TIMEOUT, sent=True, size=0)
    check_frames(res, expected_upload(0x1000, 0, 0) + [abort_frame(0x1000, 0, ABORT_TIMEOUT)])
    waited = res.tx_times[1] - res.tx_times[0]
    assert tdef * PS_PER_MS < waited <= (tdef + 1) * PS_PER_MS + 10 * CLK_PS, \
        f"timeout 0 waited {waited} ps, TIMEOUT_DEF_MS = {tdef}"
    await tb.wait_bus_frame(res, abort_frame(0x1000, 0, ABORT_TIMEOUT))
    dut._log.info(f"timeout_ms_i = 0: abort after {waited / PS_PER_MS:.3f} ms "
                  f"(TIMEOUT_DEF_MS = {tdef})")


class StallingServer(QueueNode):
    """A misbehaving SDO server (node ``node``, bench-only) for the liveness checks.

    It answers an initiate upload with "segmented, size ``size``" and every upload segment
    request with the next entry of ``script``: ``(data, last)`` gives a segment with those
    bytes and c = ``last``; once the script is used up it answers with empty non-final
    segments (n = 7, c = 0) for ever, always with the request's toggle bit. Abort frames it
    receives are recorded in ``aborts``.
    """

    def __init__(self, node: int, size: int, script: list[tuple[bytes, bool]]) -> None:
        super().__init__(f"stall{node}", BITRATE)
        self.node = node
        self.size = size
        self.script = list(script)
        self.segments = 0  #: segment responses sent
        self.aborts: list[int] = []

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        super().on_rx(msg, t_ps)
        if msg.is_remote_frame or msg.arbitration_id != 0x600 + self.node or msg.dlc != 8:
            return
        cmd = msg.data[0]
        if cmd >> 5 == 2:  # initiate upload: segmented, size indicated
            self.send(make_message(0x580 + self.node, bytes([0x41]) + bytes(msg.data[1:4])
                                   + struct.pack("<L", self.size)))
        elif cmd >> 5 == 3:  # upload segment
            data, last = self.script.pop(0) if self.script else (b"", False)
            self.segments += 1
            byte0 = (cmd & 0x10) | (7 - len(data)) << 1 | int(last)
            self.send(make_message(0x580 + self.node, bytes([byte0]) + data.ljust(7, b"\0")))
        elif cmd >> 5 == 4:
            self.aborts.append(struct.unpack_from("<L", bytes(msg.data), 4)[0])


def transfer_bound_ms(requests: int, timeout_ms: int) -> int:
    """The documented bound of a transfer with ``requests`` request frames (docs, Bounds):
    each request waits at most T + 1 ms to be taken and T + 1 ms for its response, the
    closing abort frame at most T + 1 ms to be taken."""
    return (2 * requests + 1) * (timeout_ms + 1)


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_empty_segment_server(dut):
    """Purpose: a server that keeps an upload alive with empty segments cannot hold the client.

    Verifies: against a server answering every upload segment request of a 7-byte object with
    an empty non-final segment (n = 7, c = 0), the client accepts EMPTY_SEGS_MAX such segments
    and aborts at the next one with 0800 0000h: exact frame sequence, the abort frame on the
    bus and received by the server, size_o = 0, the transfer ends within the documented bound;
    the client then accepts and completes a new transfer (1008h from node 5). EMPTY_SEGS_MAX
    empty segments followed by the data are accepted (the 7 bytes land in the buffer); the
    limit counts every empty segment of the transfer, not only consecutive ones.
    """
    tb = TB(dut)
    await tb.start()
    emax = tb.empty_segs_max
    value = bytes(range(0x41, 0x48))  # 7 bytes
    stall = StallingServer(9, len(value), [])
    tb.bus.attach(stall)

    res = await tb.upload(0x2100, node=9, timeout_ms=5)
    check_abort(res, ABORT_GENERAL, sent=True, size=0)
    check_frames(res, expected_upload(0x2100, 0, emax + 1)
                 + [abort_frame(0x2100, 0, ABORT_GENERAL)], cob=0x609)
    assert stall.segments == emax + 1
    await tb.wait_bus_frame(res, abort_frame(0x2100, 0, ABORT_GENERAL))
    await tb.wait_for(lambda: stall.aborts == [ABORT_GENERAL], 200)
    took = res.t_done_ps - res.t_req_ps
    assert took <= transfer_bound_ms(emax + 2, 5) * PS_PER_MS, f"took {took} ps"
    dut._log.info(f"empty-segment server: abort 0800 0000h after {emax + 1} empty segments, "
                  f"{took / PS_PER_MS:.3f} ms after the request")

    # the channel takes the next transfer
    name = tb.slave.read_raw(0x1008)
    res = await tb.upload(0x1008)
    check_ok(res, len(name))
    check_data(await tb.read_buf(len(name)), name, "1008h after the aborted upload")

    # EMPTY_SEGS_MAX empty segments, then the data: accepted
    stall.script = [(b"", False)] * emax + [(value, True)]
    stall.segments = 0
    await tb.write_buf(bytes(8))
    res = await tb.upload(0x2100, node=9, timeout_ms=5)
    check_ok(res, len(value))
    check_frames(res, expected_upload(0x2100, 0, emax + 1), cob=0x609)
    check_data(await tb.read_buf(8), value + b"\0", "upload after empty segments")

    # empty segments spread over the transfer: the (EMPTY_SEGS_MAX + 1)-th one aborts
    two = bytes(range(0x61, 0x6F))  # 14 bytes
    stall.size = len(two)
    stall.script = [(b"", False), (two[:7], False)] + [(b"", False)] * emax + [(two[7:], True)]
    stall.aborts.clear()
    res = await tb.upload(0x2100, node=9, timeout_ms=5)
    check_abort(res, ABORT_GENERAL, sent=True, size=7)
    check_frames(res, expected_upload(0x2100, 0, emax + 2)
                 + [abort_frame(0x2100, 0, ABORT_GENERAL)], cob=0x609)
    await tb.wait_for(lambda: stall.aborts == [ABORT_GENERAL], 200)


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rtr_on_response_cob(dut):
    """Purpose: a remote frame with the transfer's response COB-ID is not a response.

    Verifies: during a segmented upload of 1008h from node 5, an RTR on 585h with DLC 0 while
    the initiate response is awaited and an RTR on 585h with DLC 8 while a segment response
    is awaited (its all-zero data would read as a valid segment t = 0, n = 0, c = 0) are each
    answered rx_done_o with rx_unexpected_o, no reply, no state change (the checker of every
    frame); the transfer completes with all 71 bytes and no abort frame is sent; an RTR while
    idle is unexpected too.
    """
    tb = TB(dut)
    await tb.start()

    def rtr(dlc: int) -> can.Message:
        return can.Message(arbitration_id=0x580 + NODE, is_extended_id=False,
                           is_remote_frame=True, dlc=dlc)

    name = tb.slave.read_raw(0x1008)
    n_rx = len(tb.rx_log)
    n_tx0 = len(tb.tx_log)
    t_req = sim_time_ps()
    await tb.request(upload=True, index=0x1008)
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx0, 100, step_us=1)
    tb.inject(rtr(0))  # initiate upload response awaited
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx0 + 1, 1000, step_us=1)
    await FallingEdge(dut.clk_i)
    assert int(dut.state_o.value) == 9, "not in S_UL_SEG_WAIT for the first segment"
    tb.inject(rtr(8))  # first segment response (t = 0) awaited
    res = await tb.wait_done(n_tx0, t_req)
    check_ok(res, len(name))
    check_frames(res, expected_upload(0x1008, 0, n_upload_segments(len(name))))
    check_data(await tb.read_buf(len(name)), name, "1008h with RTRs in between")
    remote = [r for r in tb.rx_log[n_rx:] if r.msg.is_remote_frame]
    assert len(remote) == 2, remote
    assert all(r.unexpected == 1 and r.reply == 0 for r in remote)
    assert [r.state_before for r in remote] == [7, 9]  # S_UL_INIT_WAIT, S_UL_SEG_WAIT
    assert sum(r.unexpected for r in tb.rx_log[n_rx:]) == 2

    tb.inject(rtr(8))  # idle
    await tb.wait_for(lambda: len(tb.rx_log) > n_rx + len(res.frames) + 2, 100, step_us=1)
    last = tb.rx_log[-1]
    assert last.msg.is_remote_frame and last.unexpected == 1 and last.state_after == 0


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_toggle_errors(dut):
    """Purpose: a response with the wrong toggle bit is answered by abort 0503 0000h.

    Verifies: upload of 1008h with the 2nd segment response's toggle bit corrupted, and a
    download with the 1st segment response's toggle corrupted: the client sends the abort
    frame (exact content checked on the bus), the server records 0503 0000h, size_o counts
    only the accepted segments and the slave's 2000h keeps its old content.
    """
    tb = TB(dut)
    await tb.start()
    count = {"seg": 0}

    def flip_nth_segment(n: int, scs: int):
        def mangle(msg: can.Message) -> can.Message:
            if msg.data[0] & 0xE0 == scs:
                count["seg"] += 1
                if count["seg"] == n:
                    return with_byte0(msg, lambda b: b ^ 0x10)
            return msg
        return mangle

    tb.mangle = flip_nth_segment(2, 0x00)
    res = await tb.upload(0x1008)
    check_abort(res, ABORT_TOGGLE, sent=True, size=7)
    check_frames(res, expected_upload(0x1008, 0, 2) + [abort_frame(0x1008, 0, ABORT_TOGGLE)])
    await tb.wait_bus_frame(res, abort_frame(0x1008, 0, ABORT_TOGGLE))
    assert tb.slave.node.sdo.last_received_error == ABORT_TOGGLE
    check_data(await tb.read_buf(7), tb.slave.read_raw(0x1008)[:7], "first segment")

    old = bytes(range(9))
    tb.mangle = None
    check_ok(await tb.download(DOMAIN, 0, old), 9)
    tb.slave.node.sdo.last_received_error = 0
    count["seg"] = 0
    tb.mangle = flip_nth_segment(1, 0x20)
    data = bytes(range(100, 120))
    res = await tb.download(DOMAIN, 0, data)
    check_abort(res, ABORT_TOGGLE, sent=True, size=0)
    check_frames(res, expected_download(DOMAIN, 0, data)[:2]
                 + [abort_frame(DOMAIN, 0, ABORT_TOGGLE)])
    await tb.wait_bus_frame(res, abort_frame(DOMAIN, 0, ABORT_TOGGLE))
    assert tb.slave.node.sdo.last_received_error == ABORT_TOGGLE
    check_data(tb.slave.read_raw(DOMAIN), old, "2000h after the aborted download")


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_protocol_errors(dut):
    """Purpose: responses that do not fit the transfer, and legal response variants.

    Verifies: a subindex mismatch in the initiate upload response gives abort 0800 0000h; a
    wrong command specifier (scs 2 answering an initiate download) and a DLC of 4 in a segment
    response give 0504 0001h; an expedited response without size (s = 0) delivers 4 bytes; a
    segmented upload without size indication (s = 0) delivers all 71 bytes of 1008h; an abort
    frame for another multiplexer during a transfer is flagged unexpected and ignored.
    """
    tb = TB(dut)
    await tb.start()

    def on_cs(cs: int, fn: Callable[[can.Message], can.Message]):
        def mangle(msg: can.Message) -> can.Message:
            return fn(msg) if msg.data[0] & 0xE0 == cs else msg
        return mangle

    def set_byte(k: int, v: int) -> Callable[[can.Message], can.Message]:
        def fn(msg: can.Message) -> can.Message:
            data = bytearray(msg.data)
            data[k] = v
            return make_message(msg.arbitration_id, bytes(data))
        return fn

    tb.mangle = on_cs(0x40, set_byte(3, 0x07))  # initiate upload response for sub 7
    res = await tb.upload(0x1000)
    check_abort(res, ABORT_GENERAL, sent=True, size=0)
    check_frames(res, expected_upload(0x1000, 0, 0) + [abort_frame(0x1000, 0, ABORT_GENERAL)])

    tb.mangle = on_cs(0x60, lambda m: with_byte0(m, lambda b: 0x40 | b & 0x1F))
    res = await tb.download(DOMAIN, 0, bytes(12))
    check_abort(res, ABORT_CS, sent=True, size=0)
    check_frames(res, expected_download(DOMAIN, 0, bytes(12))[:1]
                 + [abort_frame(DOMAIN, 0, ABORT_CS)])

    tb.mangle = on_cs(0x00, lambda m: make_message(m.arbitration_id, bytes(m.data[:4])))
    res = await tb.upload(0x1008)
    check_abort(res, ABORT_CS, sent=True, size=0)
    check_frames(res, expected_upload(0x1008, 0, 1) + [abort_frame(0x1008, 0, ABORT_CS)])
    reply = [r for r in tb.rx_log if r.msg.dlc == 4]
    assert reply and reply[-1].reply == 1 and reply[-1].unexpected == 0

    tb.mangle = on_cs(0x40, lambda m: with_byte0(m, lambda b: b & ~0x0D))  # e=1, s=0, n=0
    await tb.write_buf(bytes([0xEE]) * 8)
    res = await tb.upload(0x1001)
    check_ok(res, 4)
    check_data(await tb.read_buf(8), b"\x00\x00\x00\x00" + bytes([0xEE]) * 4, "s = 0 upload")

    tb.mangle = on_cs(0x40, lambda m: with_byte0(m, lambda b: b & ~0x01))  # s = 0
    res = await tb.upload(0x1008)
    name = tb.slave.read_raw(0x1008)
    check_ok(res, len(name))
    check_data(await tb.read_buf(len(name)), name, "1008h without size")

    tb.mangle = None
    stray = make_message(0x580 + NODE, abort_frame(0x1234, 5, ABORT_GENERAL))
    n_rx = len(tb.rx_log)
    n_tx0 = len(tb.tx_log)
    t_req = sim_time_ps()
    await tb.request(upload=True, index=0x1000)
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx0, 100, step_us=1)
    tb.inject(stray)
    res = await tb.wait_done(n_tx0, t_req)
    check_ok(res, 4)
    first = tb.rx_log[n_rx]
    assert first.msg.data == stray.data and first.unexpected == 1 and first.reply == 0


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_unexpected_frames(dut):
    """Purpose: frames that are not for the active transfer, busy requests, COB-ID override.

    Verifies: while idle, a response-like frame from node 5, a frame from node 6 and a DLC-4
    frame give rx_done_o with rx_unexpected_o, no reply, no state change, no transfer; during
    a transfer (waiting for a response) a frame from node 6 is flagged unexpected and the
    transfer completes normally; a req_valid_i pulse while busy is ignored (one done_o, only
    the first request's frames); a host buffer write while busy is ignored (the download's
    later segments still carry the original bytes); explicit cob_req_i / cob_resp_i override
    the node-ID.
    """
    tb = TB(dut)
    await tb.start()
    stray = [make_message(0x585, bytes([0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0])),
             make_message(0x586, bytes([0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4])),
             make_message(0x585, bytes([0x60, 0x00, 0x20, 0x00]))]
    for msg in stray:
        tb.inject(msg)
    await tb.wait_for(lambda: len(tb.rx_log) == 3, 50, step_us=1)
    for rec in tb.rx_log:
        assert rec.unexpected == 1 and rec.reply == 0 and rec.state_after == 0
    assert dut.busy_o.value == 0 and dut.tx_req_o.value == 0 and tb.done_count == 0

    n_tx0 = len(tb.tx_log)
    t_req = sim_time_ps()
    await tb.request(upload=True, index=0x1008)
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx0, 100, step_us=1)
    tb.inject(make_message(0x586, bytes([0x00] * 8)))
    await tb.request(upload=False, index=DOMAIN, size=8)  # busy: ignored
    res = await tb.wait_done(n_tx0, t_req)
    name = tb.slave.read_raw(0x1008)
    check_ok(res, len(name))
    check_frames(res, expected_upload(0x1008, 0, n_upload_segments(len(name))))
    check_data(await tb.read_buf(len(name)), name, "1008h")
    assert sum(r.unexpected for r in tb.rx_log) == 4
    await Timer(300, "us")
    assert tb.done_count == 1 and dut.busy_o.value == 0

    data = bytes(range(30, 60))
    await tb.write_buf(data)
    n_tx0 = len(tb.tx_log)
    t_req = sim_time_ps()
    await tb.request(upload=False, index=DOMAIN, size=len(data))
    await tb.wait_for(lambda: len(tb.tx_log) > n_tx0, 100, step_us=1)
    await tb.write_buf(b"\xde\xad\xbe\xef" * 3, offset_words=4)  # busy: ignored
    res = await tb.wait_done(n_tx0, t_req)
    check_ok(res, len(data))
    check_frames(res, expected_download(DOMAIN, 0, data))
    check_data(tb.slave.read_raw(DOMAIN), data, "2000h")

    res = await tb.upload(0x1000, node=0x11, cob_req=0x605, cob_resp=0x585)
    check_ok(res, 4)
    check_data(await tb.read_buf(4), struct.pack("<L", tb.slave.read(0x1000)), "1000h")


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_zero_latency_server(dut):
    """Purpose: responses arriving in the cycle after tx_ack_i (no bus, no FSM delay).

    Verifies: segmented download and upload of 64 bytes and an upload of 1008h still work
    when the response follows the request immediately (the engine's ack item and buffer
    units still busy), with rx_done_o within RX_LATENCY_MAX cycles of rx_valid_i (the measured
    worst case is exactly ZL_RX_MAX, the best ZL_RX_MIN); tx_req_o rises 10 clock edges
    (download: engine item with the buffer read) resp. 7 edges (upload) after the edge that
    samples req_valid_i (the bench takes the frame at the following edge).
    """
    tb = TB(dut, direct=True)
    await tb.start()
    data = bytes(random.Random(9).getrandbits(8) for _ in range(64))
    res = await tb.download(DOMAIN, 0, data)
    d_dl = (res.tx_times[0] - tb.t_req_edge) // CLK_PS
    check_ok(res, 64)
    check_frames(res, expected_download(DOMAIN, 0, data))
    check_data(tb.slave.read_raw(DOMAIN), data, "2000h")
    await tb.write_buf(bytes(64))
    res = await tb.upload(DOMAIN)
    d_ul = (res.tx_times[0] - tb.t_req_edge) // CLK_PS
    check_ok(res, 64)
    check_data(await tb.read_buf(64), data, "upload")
    res = await tb.upload(0x1008)
    check_ok(res, 71)
    lat = [r.latency for r in tb.rx_log]
    assert (d_dl, d_ul) == (10 + 1, 7 + 1), f"request -> frame taken: {d_dl}, {d_ul} edges"
    assert (min(lat), max(lat)) == (ZL_RX_MIN, ZL_RX_MAX), f"rx latencies {sorted(set(lat))}"


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_all_channels_at_once(dut):
    """Purpose: every channel of the shared engine runs a transfer at the same time.

    Verifies: with one slave per channel (nodes 5, 6, ...), N_SDO segmented downloads of
    different data started in consecutive clock cycles all complete: each slave's 2000h holds
    its channel's bytes, each channel sent exactly the CiA 301 frame sequence on its own
    request COB-ID, the requests of the channels interleave on the bus, each channel's done
    strobe came once; then N_SDO uploads started together return each channel's bytes in its
    own buffer region (channel c's buffer shows node 5 + c's data).
    """
    tb = TB(dut)
    n = tb.n_sdo
    slaves = [tb.slave] + [CanopenSlave(tb.sched, NODE + c, bitrate_bps=BITRATE,
                                        boot_time_ps=20 * PS_PER_US) for c in range(1, n)]
    for sl in slaves[1:]:
        tb.bus.attach(sl)
    await tb.start()
    await tb.wait_for(lambda: all(sl.nmt_state is NmtState.PRE_OPERATIONAL for sl in slaves),
                      1000)
    datas = [bytes((17 * c + k) & 0xFF for k in range(40 + 3 * c)) for c in range(n)]
    for c in range(n):
        await tb.write_buf(datas[c], chan=c)
    n_tx0 = len(tb.tx_log)
    await tb.start_all([{"upload": False, "node": NODE + c, "index": DOMAIN,
                         "size": len(datas[c])} for c in range(n)])
    await tb.wait_all_idle(100)
    for c, (err, code, sent, size) in enumerate(await tb.results()):
        assert (err, code, sent, size) == (0, 0, 0, len(datas[c])), f"channel {c}: {code:08X}"
        check_data(slaves[c].read_raw(DOMAIN), datas[c], f"node {NODE + c} 2000h")
        frames = [bytes(m.data) for _, m in tb.tx_log[n_tx0:]
                  if m.arbitration_id == 0x600 + NODE + c]
        assert frames == expected_download(DOMAIN, 0, datas[c]), f"channel {c} frames"
        assert len(tb.chan_done[c]) == 1, f"channel {c}: {len(tb.chan_done[c])} done strobes"
    ids = [m.arbitration_id for _, m in tb.tx_log[n_tx0:]]
    switches = sum(a != b for a, b in zip(ids, ids[1:]))
    assert switches > 2 * n, f"requests did not interleave: {[hex(i) for i in ids]}"

    for c in range(n):  # clear the buffers so that the upload must fill them
        await tb.write_buf(bytes(len(datas[c])), chan=c)
    await tb.start_all([{"upload": True, "node": NODE + c, "index": DOMAIN} for c in range(n)])
    await tb.wait_all_idle(100)
    for c, (err, code, sent, size) in enumerate(await tb.results()):
        assert (err, code, sent, size) == (0, 0, 0, len(datas[c])), f"channel {c}: {code:08X}"
        check_data(await tb.read_buf(len(datas[c]), chan=c), datas[c], f"channel {c} upload")


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_all_channels_same_tick(dut):
    """Purpose: work for every channel in the same cycle: one ms tick expires all timers.

    Verifies: with the bench taking no frame, N_SDO uploads started in consecutive cycles just
    after a ms tick (timeout 3 ms) all end at the same tick with 0504 0000h sent by the master
    and no frame: every channel's done strobe comes between the 4th tick after the start and
    N_SDO work items (8 cycles each) later, the order of the channels; no channel ends before.
    """
    tb = TB(dut)
    n = tb.n_sdo
    await tb.start()
    tb.allow_tx(False)
    await RisingEdge(dut.tick_ms_i)
    await FallingEdge(dut.tick_ms_i)
    t0 = sim_time_ps()
    await tb.start_all([{"upload": True, "node": 0x30 + c, "index": 0x1000, "timeout_ms": 3}
                        for c in range(n)])
    await tb.wait_all_idle(10)
    tb.allow_tx(True)
    t_tick = t0 - CLK_PS + 4 * PS_PER_MS  # the 4th tick after the one before the starts
    for c, (err, code, sent, _size) in enumerate(await tb.results()):
        assert (err, code, sent) == (1, ABORT_TIMEOUT, 1), f"channel {c}: {code:08X}"
        assert len(tb.chan_done[c]) == 1
        dt = (tb.chan_done[c][0] - t_tick) // CLK_PS
        assert 0 < dt <= 8 * n, f"channel {c} ended {dt} cycles after the expiring tick"
    order = sorted(range(n), key=lambda c: tb.chan_done[c][0])
    assert order == list(range(n)), f"sweep order {order}"


@cocotb.test(timeout_time=20, timeout_unit="ms", expect_fail=True)
async def run_data_checker_can_fail(dut):
    """Purpose: prove the data checker fails on a wrong expected value.

    Verifies: a correct upload of 1000h compared with 0x00020193 (the real value is
    0x00020192) makes check_data fail (expect_fail).
    """
    tb = TB(dut)
    await tb.start()
    res = await tb.upload(0x1000)
    check_ok(res, 4)
    check_data(await tb.read_buf(4), struct.pack("<L", 0x00020193), "1000h")


@cocotb.test(timeout_time=20, timeout_unit="ms", expect_fail=True)
async def run_frame_checker_can_fail(dut):
    """Purpose: prove the frame checker fails on a wrong expected sequence.

    Verifies: a correct 10-byte download compared with a sequence whose first segment has
    toggle 1 makes check_frames fail (expect_fail).
    """
    tb = TB(dut)
    await tb.start()
    data = bytes(range(10))
    res = await tb.download(DOMAIN, 0, data)
    check_ok(res, 10)
    wrong = expected_download(DOMAIN, 0, data)
    wrong[1] = bytes([wrong[1][0] ^ 0x10]) + wrong[1][1:]
    check_frames(res, wrong)


# ============================================================================ pytest entry
@pytest.mark.sim
@pytest.mark.parametrize("n_sdo", [2, 4])
def test_canopen_sdo_client(request, n_sdo):
    run_cocotb(toplevel="canopen_sdo_channels", module="tb.test_canopen_sdo_client",
               name=request.node.name,
               # a short default timeout keeps the timeout_ms_i = 0 case fast
               parameters={"N_SDO": n_sdo, "BUF_BYTES": 256, "TIMEOUT_DEF_MS": 12,
                           "EMPTY_SEGS_MAX": 3})
