"""Bench of ``canopen_autoconfig``: the configure-then-start walk of the SDO table.

The bench plays the SDO client (answers each download after a few cycles, with a server abort
for the entries a test marks) and the NMT path (takes start requests when ready). It checks the
exact order of downloads and NMT starts against a Python model of the rule: entries of one node
in table order, a node started only after all its entries succeeded, a failing node's remaining
entries skipped and reported with node, entry and abort code.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly, RisingEdge, Timer

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import param, run_cocotb

#: failures the block logs per run (ACFG_FAIL_SEL.INDEX range)
LOG_DEPTH = 16


@dataclass(frozen=True)
class Entry:
    node: int
    index: int
    sub: int
    size: int
    value: int


def expected(table: list[Entry], fail: dict[int, int], start_nodes: bool):
    """(downloads, nmt starts, ok count, fail count, failures in order) by the documented
    rule; a failure is (node, entry, abort code)."""
    downloads, nmt, ok, nfail, fails = [], [], 0, 0, []
    i, depth = 0, param("CFG_DEPTH")
    while i < depth and i < len(table) and table[i].node != 0:
        node, failed = table[i].node, False
        while i < depth and i < len(table) and table[i].node == node:
            if not failed:
                downloads.append(table[i])
                if i in fail:
                    failed = True
                    nfail += 1
                    fails.append((node, i, fail[i]))
            i += 1
        if not failed:
            ok += 1
            if start_nodes:
                nmt.append(node)
    return downloads, nmt, ok, nfail, fails


class TB:
    def __init__(self, dut) -> None:
        self.dut = dut
        start_clock(dut.clk_i, 10_000_000)
        for sig in (dut.tbl_we_i, dut.tbl_addr_i, dut.tbl_node_i, dut.tbl_index_i, dut.tbl_sub_i,
                    dut.tbl_size_i, dut.tbl_value_i, dut.start_i, dut.start_nodes_i,
                    dut.sdo_done_i, dut.sdo_error_i, dut.sdo_abort_i, dut.log_sel_i):
            sig.value = 0
        dut.nmt_ready_i.value = 1
        self.downloads: list[Entry] = []
        self.nmt: list[int] = []
        self.fail: dict[int, int] = {}  # download number -> abort code
        self.table: list[Entry] = []

    async def write_table(self, table: list[Entry]) -> None:
        dut = self.dut
        self.table = table
        for addr, e in enumerate(table):
            await FallingEdge(dut.clk_i)
            dut.tbl_addr_i.value = addr
            dut.tbl_node_i.value = e.node
            dut.tbl_index_i.value = e.index
            dut.tbl_sub_i.value = e.sub
            dut.tbl_size_i.value = e.size
            dut.tbl_value_i.value = e.value
            dut.tbl_we_i.value = 1
        await FallingEdge(dut.clk_i)
        dut.tbl_we_i.value = 0

    async def sdo_client(self, rng: random.Random) -> None:
        """Answer every request: done after 3..20 cycles, error for marked table entries."""
        dut = self.dut
        buf = None
        while True:
            await RisingEdge(dut.clk_i)
            await ReadOnly()
            if dut.sdo_buf_we_o.value == 1:
                buf = int(dut.sdo_buf_wdata_o.value)
            if dut.sdo_req_o.value != 1:
                continue
            e = Entry(int(dut.sdo_node_o.value), int(dut.sdo_index_o.value),
                      int(dut.sdo_sub_o.value), int(dut.sdo_size_o.value), buf)
            self.downloads.append(e)
            row = self.table.index(e)
            await Timer(1, "ps")
            for _ in range(rng.randint(3, 20)):
                await RisingEdge(dut.clk_i)
            await FallingEdge(dut.clk_i)
            dut.sdo_done_i.value = 1
            dut.sdo_error_i.value = int(row in self.fail)
            dut.sdo_abort_i.value = self.fail.get(row, 0)
            await FallingEdge(dut.clk_i)
            dut.sdo_done_i.value = 0
            dut.sdo_error_i.value = 0

    async def nmt_path(self) -> None:
        dut = self.dut
        while True:
            await RisingEdge(dut.clk_i)
            await ReadOnly()
            if dut.nmt_req_o.value == 1:
                self.nmt.append(int(dut.nmt_node_o.value))

    async def run(self, start_nodes: bool) -> int:
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.start_nodes_i.value = int(start_nodes)
        dut.start_i.value = 1
        await FallingEdge(dut.clk_i)
        dut.start_i.value = 0
        n = 0
        while True:
            await RisingEdge(dut.clk_i)
            n += 1
            assert n < 100_000, "the table walk did not finish"
            if dut.done_o.value == 1:
                await FallingEdge(dut.clk_i)
                return n

    async def check(self, start_nodes: bool) -> None:
        dl, nmt, ok, nfail, fails = expected(self.table, self.fail, start_nodes)
        assert self.downloads == dl, f"downloads {self.downloads} != {dl}"
        assert self.nmt == nmt, f"NMT starts {self.nmt} != {nmt}"
        dut = self.dut
        assert int(dut.nodes_ok_o.value) == ok and int(dut.nodes_fail_o.value) == nfail
        # the failure log: the first 16 failures in order, zeros beyond the run's failures
        logged = fails[:LOG_DEPTH]
        for k in range(min(len(logged) + 1, LOG_DEPTH)):
            await FallingEdge(dut.clk_i)
            dut.log_sel_i.value = k
            await RisingEdge(dut.clk_i)  # registered read: valid after this edge
            await ReadOnly()
            got = (int(dut.fail_node_o.value), int(dut.fail_entry_o.value),
                   int(dut.fail_abort_o.value))
            want = logged[k] if k < len(logged) else (0, 0, 0)
            assert got == want, f"failure {k}: {got} != {want}"
        await FallingEdge(dut.clk_i)
        dut.log_sel_i.value = 0
        assert dut.busy_o.value == 0


def network_table(rng: random.Random, nodes: list[int]) -> list[Entry]:
    table = []
    for node in nodes:
        for k in range(rng.randint(1, 5)):
            size = rng.randint(1, 4)
            table.append(Entry(node, 0x1400 + 0x100 * (k % 4) + k, rng.randint(0, 8), size,
                               rng.getrandbits(8 * size)))
    return table + [Entry(0, 0, 0, 0, 0)]


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_configure_and_start(dut):
    """Purpose: every entry downloaded in order; each node started after its entries.

    Verifies: download order and values, NMT start after each node's last entry, NODES_OK,
    done strobe, nothing after the node-0 terminator; also with start_nodes_i = 0 (no NMT).
    """
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    rng = random.Random(1)
    cocotb.start_soon(tb.sdo_client(rng))
    cocotb.start_soon(tb.nmt_path())
    await tb.write_table(network_table(rng, [1, 2, 3, 4]) + [Entry(9, 0x1017, 0, 2, 5)])
    await tb.run(start_nodes=True)
    await tb.check(start_nodes=True)
    tb.downloads.clear()
    tb.nmt.clear()
    await tb.run(start_nodes=False)
    await tb.check(start_nodes=False)
    await Timer(1, "ns")


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_entry_held_while_downloading(dut):
    """Purpose: the entry being run does not change when the host rewrites its table row.

    Verifies: for every download, the table row being run is overwritten (another node, index,
    sub-index, size and value) right after sdo_req_o; sdo_node/index/sub/size and the buffer
    word stay the requested entry until sdo_done_i (the table RAM's output register holds the
    entry; it is not read again before the next fetch), and the run downloads the original
    entries in order.
    """
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    table = network_table(random.Random(7), [5, 6])
    await tb.write_table(table)
    fields = (dut.sdo_node_o, dut.sdo_index_o, dut.sdo_sub_o, dut.sdo_size_o,
              dut.sdo_buf_wdata_o)

    async def client() -> None:
        row = 0
        while True:
            await RisingEdge(dut.clk_i)
            await ReadOnly()
            if dut.sdo_req_o.value != 1:
                continue
            held = [int(f.value) for f in fields]
            tb.downloads.append(Entry(*held[:4], held[4]))
            await FallingEdge(dut.clk_i)
            dut.tbl_addr_i.value = row
            dut.tbl_node_i.value = 0x7F
            dut.tbl_index_i.value = 0xFFFF
            dut.tbl_sub_i.value = 0xFF
            dut.tbl_size_i.value = 7
            dut.tbl_value_i.value = 0xFFFFFFFF
            dut.tbl_we_i.value = 1
            await FallingEdge(dut.clk_i)
            dut.tbl_we_i.value = 0
            for _ in range(5):
                await RisingEdge(dut.clk_i)
                await ReadOnly()
                assert [int(f.value) for f in fields] == held, f"entry {row} changed"
            await FallingEdge(dut.clk_i)
            dut.sdo_done_i.value = 1
            await FallingEdge(dut.clk_i)
            dut.sdo_done_i.value = 0
            row += 1

    cocotb.start_soon(client())
    cocotb.start_soon(tb.nmt_path())
    await tb.run(start_nodes=True)
    tb.table = table
    await tb.check(start_nodes=True)


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_failing_entry_stops_its_node(dut):
    """Purpose: a failing entry stops that node only.

    Verifies: the rest of node 2's entries are skipped, node 2 is not started, the failure is
    logged with node, entry number and the abort code (log index 0); nodes 1 and 3 are
    configured and started; a second failure (node 4) is counted and logged at index 1, the
    first one kept at index 0.
    """
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    rng = random.Random(2)
    cocotb.start_soon(tb.sdo_client(rng))
    cocotb.start_soon(tb.nmt_path())
    table = network_table(rng, [1, 2, 3, 4])
    first_of = {n: next(i for i, e in enumerate(table) if e.node == n) for n in (2, 4)}
    tb.fail = {first_of[2]: 0x06020000, first_of[4]: 0x06010002}
    await tb.write_table(table)
    await tb.run(start_nodes=True)
    await tb.check(start_nodes=True)
    assert 2 not in tb.nmt and 4 not in tb.nmt
    await Timer(1, "ns")


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_table_edges(dut):
    """Purpose: empty table, a table filling every entry, and NMT back-pressure.

    Verifies: an empty table ends at once with 0 nodes; a table without terminator stops at
    CFG_DEPTH; a start request waits while nmt_ready_i = 0 and is issued once when it returns.
    """
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    rng = random.Random(3)
    cocotb.start_soon(tb.sdo_client(rng))
    cocotb.start_soon(tb.nmt_path())
    await tb.write_table([Entry(0, 0, 0, 0, 0)])
    await tb.run(start_nodes=True)
    await tb.check(start_nodes=True)
    assert tb.downloads == [] and int(dut.nodes_ok_o.value) == 0
    depth = param("CFG_DEPTH")
    full = [Entry(1 + i // 3, 0x2000 + i, 0, 4, rng.getrandbits(32)) for i in range(depth)]
    await tb.write_table(full)
    dut.nmt_ready_i.value = 0

    async def release():
        await Timer(200, "us")
        await FallingEdge(dut.clk_i)
        dut.nmt_ready_i.value = 1

    cocotb.start_soon(release())
    await tb.run(start_nodes=True)
    await tb.check(start_nodes=True)
    await Timer(1, "ns")


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_failure_log_depth(dut):
    """Purpose: the failure log holds the first 16 failures of a run, one per failing node.

    Verifies: 18 nodes whose only entry fails with a code of its own: NODES_FAIL = 18, log
    indices 0..15 = nodes 1..16 with their entry numbers and codes in order; a second run with
    only node 5 failing shows it at index 0 and zeros at index 1 (no stale entry of the first
    run).
    """
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    rng = random.Random(5)
    cocotb.start_soon(tb.sdo_client(rng))
    cocotb.start_soon(tb.nmt_path())
    table = [Entry(n, 0x1017, 0, 2, n) for n in range(1, 19)] + [Entry(0, 0, 0, 0, 0)]
    tb.fail = {i: 0x0601_0000 + i for i in range(18)}
    await tb.write_table(table)
    await tb.run(start_nodes=True)
    assert int(dut.nodes_fail_o.value) == 18
    await tb.check(start_nodes=True)
    tb.downloads.clear()
    tb.nmt.clear()
    tb.fail = {4: 0x0602_0000}
    await tb.run(start_nodes=True)
    await tb.check(start_nodes=True)
    await Timer(1, "ns")


@cocotb.test(timeout_time=20, timeout_unit="ms", expect_fail=True)
async def run_checker_can_fail(dut):
    """Purpose: prove the comparison fails: the model is told node 1 must not be started."""
    tb = TB(dut)
    await reset_active_low(dut.clk_i, dut.rst_n_i)
    rng = random.Random(4)
    cocotb.start_soon(tb.sdo_client(rng))
    cocotb.start_soon(tb.nmt_path())
    await tb.write_table(network_table(rng, [1]))
    await tb.run(start_nodes=True)
    assert tb.nmt == [], "deliberately wrong expectation"


@pytest.mark.sim
def test_canopen_autoconfig(request):
    run_cocotb(toplevel="canopen_autoconfig", module="tb.test_canopen_autoconfig",
               name=request.node.name, parameters={"CFG_DEPTH": 24})
