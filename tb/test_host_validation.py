"""Host input validation and the REFUSED rule, on the full system (issue 13, items 5 and 6).

The master RTL with its MCP2510 model, a CAN bus and one reference slave (node 3), driven only
through the Avalon-MM driver. Every out-of-range host value must be refused with its REFUSED
bit, nothing sent and nothing changed; every register must read a defined value after reset;
a change of SYNC_OVERFLOW must reach the next SYNC; REFUSED describes the last write only and
the driver reads it right after its own write, never while polling.
"""

from __future__ import annotations

import can
import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave import NmtState
from tb.tblib import regmap as R
from tb.tblib.host_driver import NMT_START, NmtRefused, Refused, SdoRefused
from tb.tblib.pdo_cycle import SYSTEM
from tb.tblib.runner import param, run_cocotb
from tb.tblib.system_tb import SystemTB

NODE = 3  # the reference slave


def readable(info: R.RegInfo) -> bool:
    return any(f.access in ("RO", "RW", "W1C") for f in info.fields.values())


async def read_raw(tb: SystemTB, addr: int):
    """One read as the LogicArray on avs_readdata_o (U/X/Z visible)."""
    value = await tb.host.bus.read(addr)
    await Timer(1, "ns")
    return value


async def check_all_defined(tb: SystemTB, when: str, reset_values: bool = True) -> int:
    """Read every readable register (node slots < MAX_NODES, the PDO window as TPDO 0 and as
    RPDO 0, the Omni-ID bank) and assert that no bit is U/X/Z and (``reset_values``) that every
    field with a documented reset value has it; returns the number of reads."""
    max_nodes = param("MAX_NODES")
    bad: list[str] = []
    n = 0

    async def check(name: str, info: R.RegInfo, addr: int, fields_reset: bool) -> None:
        nonlocal n
        v = await read_raw(tb, addr)
        n += 1
        if not v.is_resolvable:
            bad.append(f"{name} @{addr:02X}h reads {v} ({when})")
            return
        word = int(v)
        if not (fields_reset and reset_values):
            return
        for fname, f in info.fields.items():
            if f.access in ("RO", "RW", "W1C") and f.reset is not None:
                got = R.get_field(name, fname, word)
                if got != f.reset:
                    bad.append(f"{name}.{fname} = {got:#x}, documented reset {f.reset:#x} "
                               f"({when})")

    for name, info in R.REGISTERS.items():
        if not readable(info):
            continue
        for slot in (range(max_nodes) if info.stride else [None]):
            await check(name, info, R.addr(name, slot), True)
    for rpdo in (0, 1):
        await tb.host.write("PDO_SEL", R.make("PDO_SEL", RPDO=rpdo))
        for name, info in R.PDO_REGISTERS.items():
            if readable(info):
                await check(name, info, info.addr, name != "PDO_SEL" or rpdo == 0)
    await tb.host.write("PDO_SEL", 0)
    await tb.host.write("CTRL", R.CTRL_OMNI)
    for name, info in R.OMNI_REGISTERS.items():
        if readable(info):
            await check(name, info, info.addr, True)
    await tb.host.write("CTRL", 0)
    assert not bad, "registers not defined / not at their reset value:\n" + "\n".join(bad)
    return n


# ============================================================================== tests
@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_reset_values_defined(dut):
    """Purpose: every register reads a defined value after reset (issue 13.5).

    Verifies: right after reset (before the CAN controller is initialised) and again once the
    master runs, every readable register of the map (all node slots, the PDO window for a TPDO
    and an RPDO, the Omni-ID bank) has no U/X/Z bit, and right after reset every field with a
    documented reset value reads it; in particular EMCY_NODE / EMCY_DATA_LO / EMCY_DATA_HI /
    EMCY_TIME_MS read 0 before the first EMCY. An EMCY frame then shows in them and they read
    0 again once it is popped.
    """
    tb = SystemTB(dut, node_ids=(NODE,))
    await tb.reset()
    await Timer(1, "us")
    n = await check_all_defined(tb, "after reset")
    await tb.wait_master_ready()
    await check_all_defined(tb, "master running", reset_values=False)
    dut._log.info("%d registers read defined after reset", n)
    tb.raw.send(can.Message(arbitration_id=0x080 + 5, is_extended_id=False,
                            data=bytes.fromhex("1032110000000000")))
    await tb.wait_for(lambda: len(tb.frames(0x085)) == 1, 1_000, 10, "EMCY on the bus")
    await Timer(50, "us")
    assert R.get_field("EMCY_STATUS", "COUNT", await tb.host.read("EMCY_STATUS")) == 1
    assert await tb.host.read("EMCY_NODE") == 5
    assert await tb.host.read("EMCY_DATA_LO") == 0x00113210
    emcy = await tb.host.emcy_pop()
    assert emcy is not None and emcy["node"] == 5 and emcy["error_code"] == 0x3210
    for name in ("EMCY_NODE", "EMCY_DATA_LO", "EMCY_DATA_HI", "EMCY_TIME_MS"):
        assert await tb.host.read(name) == 0, f"{name} after the FIFO emptied"
    tb.check_models_clean()


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_nmt_cmd_refused(dut):
    """Purpose: NMT_CMD with a command specifier CiA 301 does not define, or a node-ID above
    127, is refused (issue 13.5).

    Verifies: CS 00h, 03h, 7Fh, 83h, FFh (node 3) and start with NODE 128 / 255 each set
    NMT_CMD.REFUSED in the first read after the write (NmtRefused from the driver) and put no
    frame on COB-ID 000h (the slave stays pre-operational); the next valid command clears
    REFUSED and starts node 3 with exactly one frame [01 03].
    """
    tb = SystemTB(dut, node_ids=(NODE,))
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: tb.slave(NODE).nmt_state == NmtState.PRE_OPERATIONAL, 5_000, 50,
                      "boot-up")
    for cs, node in ((0x00, NODE), (0x03, NODE), (0x7F, NODE), (0x83, NODE), (0xFF, NODE),
                     (NMT_START, 128), (NMT_START, 255)):
        with pytest.raises(NmtRefused):
            await tb.host.nmt(cs, node)
    await Timer(300, "us")
    assert tb.frames(0x000) == [], [bytes(r.msg.data).hex() for r in tb.frames(0x000)]
    assert tb.slave(NODE).nmt_state == NmtState.PRE_OPERATIONAL
    await tb.host.nmt(NMT_START, NODE)
    assert not await tb.host.read("NMT_CMD") & R.NMT_CMD_REFUSED
    await tb.wait_for(lambda: tb.slave(NODE).nmt_state == NmtState.OPERATIONAL, 1_000, 10,
                      "node started")
    await Timer(20, "us")
    assert [bytes(r.msg.data) for r in tb.frames(0x000)] == [bytes([NMT_START, NODE])]
    tb.check_models_clean()


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_sdo_node_refused_and_refused_lifetime(dut):
    """Purpose: SDO_CMD to node 0 or a node above 127 is refused; REFUSED describes the last
    write only and the driver follows that rule (issue 13.5 and 13.6).

    Verifies: uploads to nodes 0, 128, 255 raise SdoRefused at once (REFUSED in the first read
    after the write) and put no SDO request (600h..67Fh) on the bus; an upload written with the
    old layout (upload flag in bit 7: 83h = node 131) is refused, not sent as node 3. While a
    segmented upload of 1008h runs on channel 0, a second SDO_CMD on that channel is refused
    (REFUSED = 1, BUSY = 1, DONE = 0 in its first read) and the first transfer still completes:
    its waiter returns the device name (it must not take the other write's REFUSED for its
    own); after it ended, a refused write (node 0) leaves DONE = 1; the next accepted transfer
    clears REFUSED.
    """
    tb = SystemTB(dut, node_ids=(NODE,))
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: tb.slave(NODE).nmt_state == NmtState.PRE_OPERATIONAL, 5_000, 50,
                      "boot-up")
    host = tb.host
    for node in (0, 128, 255):
        with pytest.raises(SdoRefused):
            await host.sdo_upload(node, 0x1000, 0)
    await host.write("SDO_CMD", 0x83)  # v1 layout "upload node 3": NODE = 131 now
    assert await host.read("SDO_CMD") & R.SDO_CMD_REFUSED
    await Timer(300, "us")
    sdo_req = [r for r in tb.frames() if 0x600 <= r.msg.arbitration_id <= 0x67F]
    assert sdo_req == [], [hex(r.msg.arbitration_id) for r in sdo_req]
    # a transfer running while someone else's write on its channel is refused
    name = bytes(tb.slave(NODE).read_raw(0x1008, 0))
    first = cocotb.start_soon(host.sdo_upload(NODE, 0x1008, 0))
    await tb.wait_for(lambda: any(r.msg.arbitration_id == 0x580 + NODE for r in tb.frames()),
                      2_000, 5, "first response")
    await host.write("SDO_CMD", R.make("SDO_CMD", NODE=NODE, UPLOAD=1))
    word = await host.read("SDO_CMD")
    assert word & R.SDO_CMD_REFUSED and word & R.SDO_CMD_BUSY and not word & R.SDO_CMD_DONE, \
        f"second write on a busy channel: {word:#010x}"
    got = await first
    assert got == name, got
    word = await host.read("SDO_CMD")
    assert word & R.SDO_CMD_DONE, f"{word:#010x}"
    await host.write("SDO_CMD", R.make("SDO_CMD", NODE=0, UPLOAD=1))
    word = await host.read("SDO_CMD")
    assert word & R.SDO_CMD_REFUSED and word & R.SDO_CMD_DONE, \
        f"a refused write changed DONE: {word:#010x}"
    assert await host.sdo_upload(NODE, 0x1008, 0) == name
    assert not await host.read("SDO_CMD") & R.SDO_CMD_REFUSED
    tb.check_models_clean()


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_sync_overflow_change(dut):
    """Purpose: a SYNC_OVERFLOW change reaches the next SYNC; reserved values and changes while
    SYNC runs are refused (issue 13.5, CiA 301 1019h).

    Verifies: SYNC 1 ms with overflow 4: counter bytes 1, 2, 3, 4, 1, ...; while it runs a
    write of 8 is refused (REFUSED, value kept, the counter runs on 1..4; the driver raises
    Refused) and 1 / 241 are refused; stopped (SYNC_EN = 0), overflow 0: the first SYNC after
    the restart has DLC 0 (not the frame preloaded with the old setting); stopped again,
    overflow 8: the first SYNC after the restart carries 1 (the counter restarts at 1), then 2,
    3; stopped, the same value written again: the counter goes on where it was.
    """
    tb = SystemTB(dut, node_ids=(NODE,))
    await tb.reset()
    await tb.wait_master_ready()
    host = tb.host

    def sync_data(since: int) -> list[bytes]:
        return [bytes(r.msg.data) for r in tb.frames(0x080)[since:]]

    async def run_syncs(n: int) -> list[bytes]:
        n0 = len(tb.frames(0x080))
        await host.write("CTRL", R.CTRL_SYNC_EN)
        await tb.wait_for(lambda: len(tb.frames(0x080)) >= n0 + n, (n + 2) * 1000, 50,
                          f"{n} SYNCs")
        await host.write("CTRL", 0)
        await Timer(1500, "us")  # a SYNC already started goes out
        return sync_data(n0)

    await host.sync_config(1000, overflow=4, enable=False)
    got = await run_syncs(6)
    assert got[:6] == [bytes([c]) for c in (1, 2, 3, 4, 1, 2)], got
    # refused while running, and reserved values
    n0 = len(tb.frames(0x080))
    await host.write("CTRL", R.CTRL_SYNC_EN)
    await Timer(1200, "us")
    with pytest.raises(Refused):
        await host.sync_config(1000, overflow=8)
    for bad in (1, 241):
        await host.write("SYNC_OVERFLOW", bad)
        word = await host.read("SYNC_OVERFLOW")
        assert word & R.SYNC_OVERFLOW_REFUSED and word & 0xFF == 4, f"{bad}: {word:#x}"
    await Timer(3000, "us")
    await host.write("CTRL", 0)
    await Timer(1500, "us")
    seq = [d[0] for d in sync_data(n0)]
    assert all(1 <= c <= 4 for c in seq) and len(seq) >= 4, seq
    assert all(b == a % 4 + 1 for a, b in zip(seq, seq[1:], strict=False)), seq
    # stopped: overflow 0 -> the next SYNC has no counter byte
    await host.write("SYNC_OVERFLOW", 0)
    assert not await host.read("SYNC_OVERFLOW") & R.SYNC_OVERFLOW_REFUSED
    got = await run_syncs(2)
    assert got[:2] == [b"", b""], got
    # stopped: overflow 8 -> the counter restarts at 1
    await host.write("SYNC_OVERFLOW", 8)
    got = await run_syncs(3)
    assert got[:3] == [b"\x01", b"\x02", b"\x03"], got
    last = got[-1][0]
    # the same value again: no change, the counter goes on
    await host.write("SYNC_OVERFLOW", 8)
    got = await run_syncs(1)
    assert got[0] == bytes([last % 8 + 1]), (last, got)
    tb.check_models_clean()


# ============================================================================ pytest entry
@pytest.mark.sim
def test_host_validation(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_host_validation",
               name=request.node.name, parameters=SYSTEM, stop_time_ms=1000,
               ieee_asserts="disable")
