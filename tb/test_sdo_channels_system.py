"""System bench of the SDO client channels (``canopen_sdo_channels`` inside the core).

The master (``canopen_master_top`` RTL, behavioural MCP2510, bit-exact bus) talks to the CiA 301
reference drives (PyPI ``canopen`` SDO servers) through several SDO channels at once: segmented
transfers to different nodes interleave on the bus, a second transfer to a node that already
has one running is refused, and transfers that abort in the same cycle are all counted.

Every transferred byte is checked inside the drive's object dictionary (downloads) or against
it (uploads), and the interleaving is read from the bus record.
"""

from __future__ import annotations

import os
import random
import struct

import can
import cocotb
import pytest
from cocotb.triggers import Combine, ReadOnly, RisingEdge, Timer

from sim_models.can_bus import QueueNode
from sim_models.canopen_slave import NmtState, make_message
from sim_models.sim_time import PS_PER_MS, PS_PER_US
from tb.tblib import regmap as R
from tb.tblib.host_driver import SdoAbort, SdoRefused
from tb.tblib.metrics import record
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.runner import param, run_cocotb
from tb.tblib.system_tb import SystemTB

SYSTEM = {"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000, "OSC_FREQ_HZ": 16_000_000,
          "CAN_BITRATE_BPS": 1_000_000, "MAX_NODES": 4, "RESET_WAIT_US": 20,
          "OMNI_ENABLE": "false"}
#: the drives' DOMAIN object (segmented transfers of any length)
DOMAIN = 0x2000
ABORT_TIMEOUT = 0x05040000
ABORT_GENERAL = 0x08000000


def interleaved(tb: SystemTB, a: int, b: int) -> bool:
    """A request of node ``b`` went out between two requests of node ``a`` (and vice versa)."""
    ta = [r.t_start_ps for r in tb.frames(0x600 + a)]
    tbb = [r.t_start_ps for r in tb.frames(0x600 + b)]
    return (any(ta[0] < t < ta[-1] for t in tbb) and any(tbb[0] < t < tbb[-1] for t in ta))


async def boot(tb: SystemTB) -> int:
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "slaves pre-operational")
    n = await tb.host.sdo_channels()
    assert n == param("N_SDO", 2), n
    tb.host.max_polls = 100_000
    return n


async def select_then_read(tb: SystemTB, chan: int, reg: str) -> int:
    """Write SDO_SEL.CHAN = ``chan`` and read ``reg`` in the very next cycle, pins driven here:
    the driver leaves an idle cycle between two accesses, this sequence does not. The read
    must see the new channel (the result RAM is read at the new SDO_SEL in time)."""
    dut, host = tb.dut, tb.host
    async with host._sdo_lock:
        await host.bus._acquire_lock()
        try:
            await RisingEdge(dut.clk_i)
            dut.avs_address_i.value = R.addr("SDO_SEL")
            dut.avs_writedata_i.value = R.make("SDO_SEL", CHAN=chan)
            dut.avs_byteenable_i.value = 0xF
            dut.avs_write_i.value = 1
            await RisingEdge(dut.clk_i)  # the write is taken
            dut.avs_write_i.value = 0
            dut.avs_address_i.value = R.addr(reg)
            dut.avs_read_i.value = 1
            await RisingEdge(dut.clk_i)  # the read is taken, the cycle after the write
            dut.avs_read_i.value = 0
            for _ in range(4):
                await RisingEdge(dut.clk_i)
                await ReadOnly()
                if dut.avs_readdatavalid_o.value == 1:
                    value = int(dut.avs_readdata_o.value)
                    break
            else:
                raise AssertionError("no readdatavalid within 4 cycles")
            await RisingEdge(dut.clk_i)
        finally:
            host.bus._release_lock()
            host._sdo_chan = None  # the driver's cached SDO_SEL is no longer known
    return value


@cocotb.test(timeout_time=400, timeout_unit="ms")
async def run_sdo_channels_interleave(dut):
    """Purpose: SDO transfers to different nodes run at the same time on different channels.

    Verifies: with every channel busy at once (channel c with drive c + 1), segmented 64-byte
    downloads land byte-exact in each drive's DOMAIN object and the uploads of the same objects
    return them; the frames of the transfers interleave on the bus (a request of one node
    between two requests of another); the concurrent run ends sooner than the sum of the same
    transfers run one after the other (measured, not assumed: it is the sum of the single
    transfer times that is compared) because it fills the bus gaps a single transfer leaves
    (bus load at least 10 points higher); each channel's done event sets its own SDO_SEL.DONE
    bit.
    """
    tb = SystemTB(dut)
    n = await boot(tb)
    host = tb.host
    rng = random.Random(7)
    nodes = [c + 1 for c in range(n)]
    payload = {node: bytes(rng.getrandbits(8) for _ in range(64)) for node in nodes}
    # one after the other, channel 0, as the reference time
    t0 = sim_time_ps()
    for node in nodes:
        await host.sdo_download(node, DOMAIN, 0, payload[node][::-1], chan=0)
    t_serial = sim_time_ps() - t0
    for node in nodes:
        assert tb.slave(node).read_raw(DOMAIN, 0)[:64] == payload[node][::-1]
    # all at once
    n_req_before = {node: len(tb.frames(0x600 + node)) for node in nodes}
    t0 = sim_time_ps()
    jobs = [cocotb.start_soon(host.sdo_download(node, DOMAIN, 0, payload[node], chan=c))
            for c, node in enumerate(nodes)]
    await Combine(*jobs)
    t_parallel = sim_time_ps() - t0
    for node in nodes:
        assert tb.slave(node).read_raw(DOMAIN, 0)[:64] == payload[node], node
        # initiate + 10 segments (64 = 9 x 7 + 1), nothing else
        assert len(tb.frames(0x600 + node)) - n_req_before[node] == 11, node
    load_serial = tb.bus.load(t0 - t_serial, t0)
    load_parallel = tb.bus.load(t0, t0 + t_parallel)
    if n > 1:
        for a, b in zip(nodes, nodes[1:]):
            assert interleaved(tb, a, b), (a, b)
        # one transfer leaves the bus idle while the master and the drive turn each segment
        # around (SPI, FSM); concurrent transfers fill those gaps: the bus is the limit
        assert load_parallel > load_serial + 0.1, (load_parallel, load_serial)
        assert t_parallel < t_serial * 0.9, (t_parallel, t_serial)
    done = R.get_field("SDO_SEL", "DONE", await host.read("SDO_SEL"))
    assert done == (1 << n) - 1, bin(done)
    jobs = [cocotb.start_soon(host.sdo_upload(node, DOMAIN, 0, chan=c))
            for c, node in enumerate(nodes)]
    await Combine(*jobs)
    for job, node in zip(jobs, nodes):
        assert job.result()[:64] == payload[node], node
    dut._log.info("%d channels: %d x 64-byte download %.1f us concurrently (bus load %.1f %%), "
                  "%.1f us one by one (%.1f %%)", n, n, t_parallel / PS_PER_US,
                  100 * load_parallel, t_serial / PS_PER_US, 100 * load_serial)
    if os.environ.get("BENCH") == "1":
        record(f"sdo_channels_{n}", {
            f"sdo_segmented_bytes_per_s_{n}ch": round(64 * n / (t_parallel / 1e12)),
            f"sdo_segmented_bytes_per_s_{n}ch_one_by_one": round(64 * n / (t_serial / 1e12)),
            f"sdo_bus_load_pct_{n}ch": round(100 * load_parallel, 1),
            f"sdo_bus_load_pct_{n}ch_one_by_one": round(100 * load_serial, 1)})
    tb.check_models_clean()
    await Timer(1, "ns")


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_sdo_same_node_refused(dut):
    """Purpose: one transfer per SDO server at a time; refused requests send nothing.

    Verifies: while channel 0 uploads node 1's DOMAIN object, a request to node 1 on channel 1
    is refused (SdoRefused, SDO_CMD.REFUSED of channel 1, no extra frame to 601h, channel 0's
    transfer unharmed); a request to node 2 on channel 1 at the same time is accepted; a
    request on a busy channel is refused (REFUSED and BUSY, no frame to its node) while the
    running transfer completes normally; the next accepted request clears REFUSED.
    """
    tb = SystemTB(dut)
    n = await boot(tb)
    if n < 2:
        dut._log.info("one SDO channel: nothing to refuse between channels")
        return
    host = tb.host
    data = bytes(range(100, 164))
    tb.slave(1).write(DOMAIN, 0, data)
    tb.slave(2).write(DOMAIN, 0, data[::-1])
    up0 = cocotb.start_soon(host.sdo_upload(1, DOMAIN, 0, chan=0))
    await tb.wait_for(lambda: len(tb.frames(0x601)) >= 1, 2_000, 5, "first request")
    n601 = len(tb.frames(0x601))
    try:
        await host.sdo_upload(1, 0x1008, 0, chan=1)
    except SdoRefused:
        pass
    else:
        raise AssertionError("a second transfer to node 1 was accepted")
    assert await host.sdo_command(1) & R.SDO_CMD_REFUSED
    up1 = cocotb.start_soon(host.sdo_upload(2, DOMAIN, 0, chan=1))
    assert (await up0)[:64] == data
    assert (await up1)[:64] == data[::-1]
    # channel 0's transfer: initiate + 10 segment requests; nothing from the refused one
    assert len(tb.frames(0x601)) - n601 == 10, len(tb.frames(0x601))
    # a busy channel refuses too: channel 1 runs node 3's upload (register by register, so
    # that no driver poll of the same channel sees the second write's REFUSED)
    async with host._sdo_lock:
        await host._sdo_select(1)
        await host.write("SDO_OBJ", R.make("SDO_OBJ", INDEX=0x1008, SUBINDEX=0))
        await host.write("SDO_CMD", R.make("SDO_CMD", NODE=3, UPLOAD=1))
    await tb.wait_for(lambda: len(tb.frames(0x603)) >= 1, 2_000, 5, "node 3 request")
    async with host._sdo_lock:
        await host.write("SDO_CMD", R.make("SDO_CMD", NODE=4, UPLOAD=1))
        await Timer(1, "us")
        word = await host.read("SDO_CMD")
    assert word & R.SDO_CMD_REFUSED and word & R.SDO_CMD_BUSY, hex(word)
    for _ in range(2_000):
        word = await host.sdo_command(1)
        if word & R.SDO_CMD_DONE:
            break
        await Timer(10, "us")
    name = tb.slave(3).read_raw(0x1008, 0)
    assert word & R.SDO_CMD_DONE and not word & R.SDO_CMD_ERROR, hex(word)
    assert R.get_field("SDO_CMD", "XFER_SIZE", word) == len(name), hex(word)
    assert word & R.SDO_CMD_REFUSED  # the refused write's flag stays until an accepted one
    assert not tb.frames(0x604), "the refused request was sent"
    assert await host.sdo_upload(3, 0x1008, 0, chan=1) == name
    assert not await host.sdo_command(1) & R.SDO_CMD_REFUSED  # cleared by the accepted one
    tb.check_models_clean()
    await Timer(1, "ns")


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_sdo_simultaneous_aborts_counted(dut):
    """Purpose: every channel times out at once; each transfer is reported and counted.

    Verifies: every channel uploads from an absent node at once (nodes 9..), with the requests
    written back to back so the timeouts expire together: each channel reports 0504 0000h sent
    by the master, the master sends exactly one abort frame per channel (they share TXB1 and
    leave one after another), and CNT_SDO_ABORT rises by the number of channels. Then channel 0
    ends with a success (4 bytes): an SDO_SEL write followed in the very next cycle by a read
    of SDO_ABORT or SDO_CMD shows the newly selected channel's code, size and abort-sent flag
    (the result RAM of canopen_sdo_channels is read at the new SDO_SEL in time).
    """
    tb = SystemTB(dut)
    n = await boot(tb)
    host = tb.host
    await host.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=3))
    await host.clear_counters()
    absent = [9 + c for c in range(n)]
    # all requests written back to back, so every timeout runs on the same millisecond ticks
    async with host._sdo_lock:
        for c, node in enumerate(absent):
            await host._sdo_select(c)
            await host.write("SDO_OBJ", R.make("SDO_OBJ", INDEX=0x1008, SUBINDEX=0))
            await host.write("SDO_CMD", R.make("SDO_CMD", NODE=node, UPLOAD=1))

    async def wait_abort(c: int) -> int:
        try:
            await host._sdo_wait(c)
        except SdoAbort as exc:
            assert exc.sent_by_client, exc
            return exc.code
        raise AssertionError(f"channel {c}: no abort")

    jobs = [cocotb.start_soon(wait_abort(c)) for c in range(n)]
    await Combine(*jobs)
    assert [j.result() for j in jobs] == [ABORT_TIMEOUT] * n
    await Timer(1, "ms")  # the last abort frames are still on their way
    for node in absent:
        aborts = [r for r in tb.frames(0x600 + node) if r.msg.data[0] == 0x80]
        assert len(aborts) == 1, node
    assert (await host.counters())["sdo_abort"] == n
    # channel 0 then ends with a success (4 bytes, code 0), the others keep their abort: a
    # read in the cycle right after an SDO_SEL write shows the newly selected channel's result
    await host.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=20))
    assert len(await host.sdo_upload(1, 0x1000, 0, chan=0)) == 4
    order = [c for _ in range(2) for c in range(n)] + [0, n - 1, 0]
    for c in order:
        code = await select_then_read(tb, c, "SDO_ABORT")
        cmd = await select_then_read(tb, c, "SDO_CMD")
        want = (0, 4, 0) if c == 0 else (ABORT_TIMEOUT, 0, 1)
        got = (code, R.get_field("SDO_CMD", "XFER_SIZE", cmd),
               R.get_field("SDO_CMD", "ABORT_SENT", cmd))
        assert got == want, f"channel {c}: (SDO_ABORT, XFER_SIZE, ABORT_SENT) {got}, not {want}"
    tb.check_models_clean()
    await Timer(1, "ns")


class EmptySegmentServer(QueueNode):
    """A misbehaving SDO server (node ``node``): it answers an initiate upload with
    "segmented, 7 bytes" and every upload segment request with an empty non-final segment
    (n = 7, c = 0, the request's toggle bit), for ever. Abort codes it receives go to
    ``aborts``."""

    def __init__(self, node: int, bitrate: int) -> None:
        super().__init__(f"stall{node}", bitrate)
        self.node = node
        self.segments = 0
        self.aborts: list[int] = []

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        super().on_rx(msg, t_ps)
        if msg.is_remote_frame or msg.arbitration_id != 0x600 + self.node:
            return
        cmd = msg.data[0]
        if cmd >> 5 == 2:
            self.send(make_message(0x580 + self.node, bytes([0x41]) + bytes(msg.data[1:4])
                                   + struct.pack("<L", 7)))
        elif cmd >> 5 == 3:
            self.segments += 1
            self.send(make_message(0x580 + self.node, bytes([(cmd & 0x10) | 0x0E]) + bytes(7)))
        elif cmd >> 5 == 4:
            self.aborts.append(struct.unpack_from("<L", bytes(msg.data), 4)[0])


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_sdo_liveness_and_rtr(dut):
    """Purpose: a misbehaving server cannot hold a channel; RTRs are not SDO responses.

    Verifies: an upload from a server that answers every segment request with an empty
    non-final segment ends with the master's abort 0800 0000h after 4 such segments (the
    client's EMPTY_SEGS_MAX = 3 tolerated), the abort frame is on the bus and reaches the
    server, CNT_SDO_ABORT counts it, and the same channel then completes an upload of node 1's
    1008h while a raw node sends two RTR frames on 581h during it: the transfer completes
    byte-exact and CNT_UNEXPECTED rises by exactly the two RTRs.
    """
    tb = SystemTB(dut)
    await boot(tb)
    host = tb.host
    stall = EmptySegmentServer(9, tb.bitrate)
    tb.bus.attach(stall)
    await host.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=5))
    await host.clear_counters()
    t0 = sim_time_ps()
    try:
        await host.sdo_upload(9, 0x2100, 0, chan=0)
    except SdoAbort as exc:
        assert exc.code == ABORT_GENERAL and exc.sent_by_client, exc
    else:
        raise AssertionError("the empty-segment server's upload did not abort")
    took = sim_time_ps() - t0
    await tb.wait_for(lambda: stall.aborts == [ABORT_GENERAL], 1_000, 5, "abort at the server")
    assert stall.segments == 4, stall.segments
    # documented bound: (2 x 5 requests + 1) x (5 ms + 1 ms)
    assert took < 66 * PS_PER_MS, took
    dut._log.info("empty-segment server: aborted after %.3f ms", took / PS_PER_MS)
    assert (await host.counters())["sdo_abort"] == 1

    # the channel takes the next transfer; two RTRs on 581h during it are ignored and counted
    unexp0 = (await host.counters())["unexpected"]
    n601 = len(tb.frames(0x601))
    rtr = can.Message(arbitration_id=0x581, is_extended_id=False, is_remote_frame=True, dlc=0)
    job = cocotb.start_soon(host.sdo_upload(1, 0x1008, 0, chan=0))
    for k in (1, 5):
        await tb.wait_for(lambda k=k: len(tb.frames(0x601)) >= n601 + k, 5_000, 2, "request")
        tb.raw.send(rtr)
    data = await job
    assert data == tb.slave(1).read_raw(0x1008, 0)
    assert len([r for r in tb.frames(0x581) if r.msg.is_remote_frame]) == 2
    assert (await host.counters())["unexpected"] - unexp0 == 2
    tb.check_models_clean()
    await Timer(1, "ns")


@pytest.mark.sim
@pytest.mark.parametrize("n_sdo", [2, 4])
def test_sdo_channels_system(request, n_sdo):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_sdo_channels_system",
               name=request.node.name, parameters={**SYSTEM, "N_SDO": n_sdo},
               stop_time_ms=1000, ieee_asserts="disable")


@pytest.mark.sim
@pytest.mark.bench
@pytest.mark.parametrize("n_sdo", [2, 4])
def test_bench_sdo_channels_system(request, n_sdo):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_sdo_channels_system",
               name=request.node.name, parameters={**SYSTEM, "N_SDO": n_sdo},
               stop_time_ms=1000, ieee_asserts="disable", extra_env={"BENCH": "1"},
               testcase="run_sdo_channels_interleave")
