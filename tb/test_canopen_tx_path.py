"""Bench of ``canopen_tx_path``: generation sources, Transmit_Data, TX buffer plan, withdrawals.

The bench plays the FSM (one generation state, St11, St12 until the controller loaded the
buffer) and the controller's TX interface. Expected values are the documented plan
(docs/canopen_tx_path.md), written here as a table, not read from the RTL: TXB2 / TXP 3 /
started by TX2RTS for the SYNC source, TXB1 / TXP 2 for NMT and SDO, TXB0 / TXP 1 for PDOs;
the host NMT command's admission rules; the SDO withdrawal (cancel of TXB1 once, acknowledge
when nothing of the transfer is left) and the cancel of a synchronous TPDO at the next SYNC.
"""

from __future__ import annotations

import cocotb
import pytest
from cocotb.triggers import FallingEdge, ReadOnly

from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.runner import run_cocotb
from tb.tblib.strobe_ports import StrobePorts

CLK_HZ = 20_000_000
STATES = ("in_sync_gen_i", "in_nmt_gen_i", "in_sdo_gen_i", "in_pdo_gen_i", "in_encap_i",
          "in_tx_i")
STROBES = ("nmt_req_i", "acfg_nmt_req_i", "sdo_wdr_req_i", "sync_fire_i", "ctl_tx_ready_i",
           "ctl_tx_loaded_i")
#: the buffer plan: source -> (buffer, priority, send after load)
PLAN = {"sync": (2, 3, 0), "nmt": (1, 2, 1), "mon": (1, 2, 1), "sdo": (1, 2, 1),
        "pdo": (0, 1, 1)}


def data_bytes(data: bytes) -> int:
    """Frame payload as the 64-bit port value (byte k at bits 8k+7..8k)."""
    return int.from_bytes(data.ljust(8, b"\0"), "little")


SAMPLED = ("ctl_tx_valid_o", "nmt_refused_o", "sdo_wdr_ack_o", "nmt_gen_req_o")


class TB:
    def __init__(self, dut) -> None:
        self.dut = dut
        self.ports = StrobePorts(dut, dut.clk_i, STATES + STROBES)
        self.acks = {"mon": 0, "sdo": 0, "pdo": 0}
        self.cancels = [0, 0, 0]
        self.s: dict[str, int] = {}  # outputs sampled in the last clock() cycle

    async def start(self) -> None:
        dut = self.dut
        start_clock(dut.clk_i, CLK_HZ)
        self.ports.zero(*STATES, *STROBES, "omni_en_i", "mon_tx_req_i", "mon_tx_rtr_i",
                        "sdo_tx_req_i", "sdo_tx_abort_i", "pdo_tx_req_i", "pdo_tx_rtr_i",
                        "pdo_tx_sync_i", "nmt_cs_i", "nmt_node_i", "acfg_nmt_node_i",
                        "sync_overflow_i", "sync_counter_i", "cyc_id_i", "cyc_dlc_i",
                        "cyc_data_i", "mon_tx_id_i", "mon_tx_dlc_i", "mon_tx_data_i",
                        "sdo_tx_id_i", "sdo_tx_dlc_i", "sdo_tx_data_i", "sdo_wdr_id_i",
                        "pdo_tx_id_i", "pdo_tx_dlc_i", "pdo_tx_data_i", "ctl_tx_pending_i")
        dut.ctl_init_done_i.value = 1
        await reset_active_low(dut.clk_i, dut.rst_n_i)
        await FallingEdge(dut.clk_i)

    def out(self, name: str) -> int:
        """An output as of the last falling edge: registered outputs only (the inputs of the
        cycle before are still applied there; combinational outputs: ``self.s``)."""
        return self.ports.out(name)

    async def clock(self, **inputs: int) -> None:
        """Apply ``inputs`` for one clock (strobes and states back to 0 after it); the outputs
        of that cycle (before its edge) are kept in ``self.s``, acks and cancels counted."""
        self.ports.apply(**inputs)
        await ReadOnly()
        self.s = {name: self.out(name) for name in SAMPLED}
        for src in self.acks:
            self.acks[src] += self.out(f"{src}_tx_ack_o")
        cancel = self.out("ctl_tx_cancel_o")
        for k in range(3):
            self.cancels[k] += (cancel >> k) & 1
        await FallingEdge(self.dut.clk_i)
        self.ports.release(inputs)

    async def idle(self, n: int, **inputs: int) -> None:
        """``inputs`` for one clock, then ``n`` clocks with nothing active (cancels counted)."""
        await self.clock(**inputs)
        for _ in range(n):
            await self.clock()

    async def generate(self, state: str) -> None:
        """One generation state, St11, then St12 until the controller took and loaded it."""
        await self.clock(**{state: 1})
        await self.clock(in_encap_i=1)
        assert self.s["ctl_tx_valid_o"] == 0
        await self.clock(in_tx_i=1)
        assert self.s["ctl_tx_valid_o"] == 1, "St12 requests the controller"
        await self.clock(in_tx_i=1, ctl_tx_ready_i=1)
        await self.clock(in_tx_i=1)
        assert self.s["ctl_tx_valid_o"] == 0, "the request drops once taken"
        await self.clock(in_tx_i=1, ctl_tx_loaded_i=1)

    def frame(self) -> tuple[int, int, int, int, int, int, int]:
        return (self.out("ctl_tx_buf_o"), self.out("ctl_tx_txp_o"), self.out("ctl_tx_send_o"),
                self.out("ctl_tx_id_o"), self.out("ctl_tx_rtr_o"), self.out("ctl_tx_dlc_o"),
                self.out("ctl_tx_data_o"))


async def check_plan(dut, plan: dict[str, tuple[int, int, int]]) -> None:
    tb = TB(dut)
    await tb.start()
    # SYNC without counter, with counter (1019h >= 2), the Omni-ID cycle frame
    await tb.generate("in_sync_gen_i")
    assert tb.frame() == (*plan["sync"], 0x080, 0, 0, 0)
    dut.sync_overflow_i.value = 5
    dut.sync_counter_i.value = 0x42
    await tb.generate("in_sync_gen_i")
    assert tb.frame() == (*plan["sync"], 0x080, 0, 1, 0x42)
    dut.omni_en_i.value = 1
    dut.cyc_id_i.value = 0x102
    dut.cyc_dlc_i.value = 3
    dut.cyc_data_i.value = data_bytes(b"\x11\x22\x33")
    await tb.generate("in_sync_gen_i")
    assert tb.frame() == (*plan["sync"], 0x102, 0, 3, data_bytes(b"\x11\x22\x33"))
    dut.omni_en_i.value = 0
    # host NMT: start node 5
    await tb.clock(nmt_req_i=1, nmt_cs_i=1, nmt_node_i=5)
    assert tb.out("nmt_pending_o") == 1 and tb.out("nmt_gen_req_o") == 1
    await tb.generate("in_nmt_gen_i")
    assert tb.frame() == (*plan["nmt"], 0x000, 0, 2, data_bytes(b"\x01\x05"))
    assert tb.out("nmt_pending_o") == 0
    # the configuration list's NMT start of node 9
    await tb.clock(acfg_nmt_req_i=1, acfg_nmt_node_i=9)
    assert tb.out("acfg_nmt_pending_o") == 1
    await tb.generate("in_nmt_gen_i")
    assert tb.frame() == (*plan["nmt"], 0x000, 0, 2, data_bytes(b"\x01\x09"))
    assert tb.out("acfg_nmt_pending_o") == 0
    # node monitor: a guarding RTR
    dut.mon_tx_req_i.value = 1
    dut.mon_tx_id_i.value = 0x705
    dut.mon_tx_rtr_i.value = 1
    dut.mon_tx_dlc_i.value = 1
    await tb.generate("in_nmt_gen_i")
    assert tb.frame() == (*plan["mon"], 0x705, 1, 1, 0)
    assert tb.acks["mon"] == 1
    dut.mon_tx_req_i.value = 0
    # SDO request and a PDO
    dut.sdo_tx_req_i.value = 1
    dut.sdo_tx_id_i.value = 0x605
    dut.sdo_tx_dlc_i.value = 8
    dut.sdo_tx_data_i.value = data_bytes(b"\x40\x00\x10\x00")
    await tb.generate("in_sdo_gen_i")
    assert tb.frame() == (*plan["sdo"], 0x605, 0, 8, data_bytes(b"\x40\x00\x10\x00"))
    assert tb.acks["sdo"] == 1
    dut.pdo_tx_req_i.value = 1
    dut.pdo_tx_id_i.value = 0x205
    dut.pdo_tx_dlc_i.value = 2
    dut.pdo_tx_data_i.value = data_bytes(b"\xAB\xCD")
    await tb.generate("in_pdo_gen_i")
    assert tb.frame() == (*plan["pdo"], 0x205, 0, 2, data_bytes(b"\xAB\xCD"))
    assert tb.acks["pdo"] == 1


@cocotb.test(timeout_time=1, timeout_unit="ms")
async def run_buffer_plan(dut):
    """Every source's frame goes to its buffer with its priority; each source acked once."""
    await check_plan(dut, PLAN)


@cocotb.test(timeout_time=1, timeout_unit="ms", expect_fail=True)
async def run_buffer_plan_checker_can_fail(dut):
    """The same check with PDOs planned on TXB1 must fail (the checker is live)."""
    await check_plan(dut, {**PLAN, "pdo": (1, 1, 1)})


@cocotb.test(timeout_time=1, timeout_unit="ms")
async def run_nmt_admission(dut):
    """NMT_CMD: bad CS, node > 127, Omni-ID mode, or one waiting: refused, never overwritten."""
    tb = TB(dut)
    await tb.start()
    for cs, node, omni in ((0x03, 1, 0), (0x01, 128, 0), (0x01, 1, 1)):
        await tb.clock(nmt_req_i=1, nmt_cs_i=cs, nmt_node_i=node, omni_en_i=omni)
        assert tb.s["nmt_refused_o"] == 1, f"cs {cs:#x} node {node} omni {omni}"
        assert tb.out("nmt_pending_o") == 0
        await tb.clock()
        assert tb.s["nmt_refused_o"] == 1, "REFUSED stays until the next accepted command"
    dut.omni_en_i.value = 0
    for cs in (0x01, 0x02, 0x80, 0x81, 0x82):
        await tb.clock(nmt_req_i=1, nmt_cs_i=cs, nmt_node_i=0)
        assert tb.s["nmt_refused_o"] == 0
        assert tb.out("nmt_pending_o") == 1
        await tb.clock()
        assert tb.s["nmt_refused_o"] == 0, "an accepted command clears REFUSED"
        # a second command while one waits is refused and does not overwrite the first
        await tb.clock(nmt_req_i=1, nmt_cs_i=0x02, nmt_node_i=7)
        assert tb.s["nmt_refused_o"] == 1
        await tb.generate("in_nmt_gen_i")
        assert tb.out("ctl_tx_data_o") == data_bytes(bytes([cs, 0]))
    # generation requests only with the buffer free
    await tb.clock(nmt_req_i=1, nmt_cs_i=0x01, nmt_node_i=3)
    await tb.clock(ctl_tx_pending_i=0b010)
    assert tb.s["nmt_gen_req_o"] == 0
    await tb.clock(ctl_tx_pending_i=0)
    assert tb.s["nmt_gen_req_o"] == 1


@cocotb.test(timeout_time=1, timeout_unit="ms")
async def run_sdo_withdraw(dut):
    """An ended transfer's request in TXB1 is cancelled once; the ack waits until TXB1 is free."""
    tb = TB(dut)
    await tb.start()
    dut.sdo_tx_req_i.value = 1
    dut.sdo_tx_id_i.value = 0x605
    dut.sdo_tx_dlc_i.value = 8
    await tb.generate("in_sdo_gen_i")
    dut.sdo_tx_req_i.value = 0
    dut.ctl_tx_pending_i.value = 0b010
    # another transfer's withdrawal: nothing of it in TXB1, acknowledged at once
    await tb.clock(sdo_wdr_req_i=1, sdo_wdr_id_i=0x606)
    assert tb.s["sdo_wdr_ack_o"] == 1
    for _ in range(6):
        await tb.clock(sdo_wdr_req_i=1, sdo_wdr_id_i=0x605)
        assert tb.s["sdo_wdr_ack_o"] == 0, "its request still waits in TXB1"
    assert tb.cancels == [0, 1, 0], f"one cancel of TXB1, got {tb.cancels}"
    await tb.clock(sdo_wdr_req_i=1, ctl_tx_pending_i=0)
    assert tb.s["sdo_wdr_ack_o"] == 1
    # an abort frame in TXB1 is not a request: never cancelled
    dut.sdo_tx_req_i.value = 1
    dut.sdo_tx_abort_i.value = 1
    await tb.generate("in_sdo_gen_i")
    await tb.clock(sdo_wdr_req_i=1, ctl_tx_pending_i=0b010)
    assert tb.s["sdo_wdr_ack_o"] == 1
    await tb.idle(5)
    assert tb.cancels == [0, 1, 0]


@cocotb.test(timeout_time=1, timeout_unit="ms")
async def run_sync_tpdo_cancel(dut):
    """A synchronous TPDO still in TXB0 at the next SYNC is cancelled once and reported."""
    tb = TB(dut)
    await tb.start()
    dut.pdo_tx_req_i.value = 1
    dut.pdo_tx_sync_i.value = 1
    dut.pdo_tx_id_i.value = 0x185
    await tb.generate("in_pdo_gen_i")
    dut.pdo_tx_req_i.value = 0
    await tb.idle(5, sync_fire_i=1, ctl_tx_pending_i=0b001)
    assert tb.cancels == [1, 0, 0], f"one cancel of TXB0, got {tb.cancels}"
    assert tb.out("pdo_cancel_sent_o") == 1
    await tb.clock(ctl_tx_pending_i=0)
    assert tb.out("pdo_cancel_sent_o") == 0, "TXB0 free: the outcome is known"
    # an event-driven TPDO is never cancelled by a SYNC
    dut.pdo_tx_req_i.value = 1
    dut.pdo_tx_sync_i.value = 0
    await tb.generate("in_pdo_gen_i")
    await tb.idle(5, sync_fire_i=1, ctl_tx_pending_i=0b001)
    assert tb.cancels == [1, 0, 0]


@pytest.mark.sim
def test_canopen_tx_path(request):
    run_cocotb(toplevel="canopen_tx_path", module="tb.test_canopen_tx_path",
               name=request.node.name, stop_time_ms=10)
