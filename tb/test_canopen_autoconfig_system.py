"""System bench of the automatic configuration (``canopen_autoconfig`` inside the core).

The host fills the configuration list through the ACFG_* registers, starts it, and the master
configures each drive by expedited SDO downloads (PDO communication and mapping parameters,
heartbeat producer time) and then starts it with NMT, the thesis' boot sequence. The slaves
are the CiA 301 reference drives (PyPI ``canopen`` object dictionary and SDO server), so every
value is checked inside the slave that received it, and the order of events on the bus is
checked from the bus record.
"""

from __future__ import annotations

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave import NmtState
from tb.tblib import regmap as R
from tb.tblib.drive_config import drive_entries
from tb.tblib.host_driver import SdoRefused
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.runner import run_cocotb
from tb.tblib.system_tb import SystemTB

SYSTEM = {"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000, "OSC_FREQ_HZ": 16_000_000,
          "CAN_BITRATE_BPS": 1_000_000, "MAX_NODES": 4, "RESET_WAIT_US": 20}

ABORT_NO_OBJECT = 0x06020000
ABORT_READ_ONLY = 0x06010002
ABORT_TIMEOUT = 0x05040000


async def finish(tb: SystemTB) -> None:
    """Check the models, then hold the core in reset so that no SPI transfer is in flight when
    the next test powers up a fresh MCP2510 model."""
    tb.check_models_clean()
    while int(tb.dut.spi_cs_n_o.value) != 1:
        await Timer(100, "ns")
    tb.dut.rst_n_i.value = 0
    await Timer(5, "us")


async def boot(tb: SystemTB) -> None:
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "slaves pre-operational")
    # the drives' defaults differ from what the list writes, so a value found later was
    # written by the master
    for s in tb.slaves:
        s.write(0x1600, 0, 0)
        s.write(0x1A00, 0, 0)
        s.write(0x1800, 2, 0xFF)


def sdo_requests(tb: SystemTB, node: int) -> list[bytes]:
    return [bytes(r.msg.data) for r in tb.frames(0x600 + node)]


def nmt_frames(tb: SystemTB) -> list[tuple[int, bytes]]:
    return [(r.t_start_ps, bytes(r.msg.data)) for r in tb.frames(0x000)]


@cocotb.test(timeout_time=300, timeout_unit="ms")
async def run_config_list_success(dut):
    """Purpose: the configuration list configures four drives by SDO and then starts each.

    Verifies: 56 entries + end marker written through ACFG_*; every value is in the drive's
    object dictionary afterwards (RPDO1 and TPDO1 re-mapped, TPDO1 type 1, 1017h); one SDO
    request per entry and in table order; each drive's NMT start comes after its last SDO
    response and before the next drive's first request; ACFG_STATUS 4 ok / 0 failed, DONE, the
    CONFIG interrupt flag set and SDO_SEL.DONE only for channel 1 (the list's transfers are
    not the host's);
    while the list runs channel 0's SDO_CMD.BUSY reads 1 and a host SDO request on channel 0 is
    refused (SDO_CMD.REFUSED, no frame), while a host upload on channel 1 (node 3's device
    name, segmented) runs at the same time and succeeds, its frames interleaved on the bus
    with the list's; afterwards the host's own SDO on channel 0 works again.
    """
    tb = SystemTB(dut)
    await boot(tb)
    host = tb.host
    entries = [e for s in tb.slaves for e in drive_entries(s.node_id)]
    assert await host.acfg_load(entries) == len(entries) + 1
    await host.irq_clear(0xFF)
    await host.acfg_start(start_nodes=True)
    await Timer(50, "us")
    assert (await host.acfg_status())["busy"]
    assert await host.sdo_command(0) & R.SDO_CMD_BUSY, "SDO_CMD.BUSY while the list runs"
    try:
        await host.sdo_upload(4, 0x1008, 0, chan=0)  # channel 0 is the list's: refused
    except SdoRefused:
        pass
    else:
        raise AssertionError("a host request on channel 0 was accepted while the list ran")
    assert await host.sdo_command(0) & R.SDO_CMD_REFUSED
    name = await host.sdo_upload(3, 0x1008, 0, chan=1)  # in parallel with the list
    assert name == tb.slave(3).read_raw(0x1008, 0), name
    t_name_done = sim_time_ps()
    assert (await host.acfg_status())["busy"], "the list ended before the parallel upload"
    t_end_us = 200_000
    while True:
        st = await host.acfg_status()
        if st["done"] and not st["busy"]:
            break
        await Timer(100, "us")
        t_end_us -= 100
        assert t_end_us > 0, st
    assert st["nodes_ok"] == 4 and st["nodes_fail"] == 0, st
    irq = await host.irq_status()
    assert irq & R.IRQ_STATUS_CONFIG and irq & R.IRQ_STATUS_SDO_DONE, hex(irq)
    # SDO_DONE is channel 1's (the host upload); the list's transfers on channel 0 set nothing
    assert R.get_field("SDO_SEL", "DONE", await host.read("SDO_SEL")) == 0b10
    await tb.wait_for(tb.all_operational, 2_000, 10, "operational")
    await Timer(200, "us")  # the bus records a frame after its intermission
    for s in tb.slaves:
        n = s.node_id
        assert s.read(0x1400, 1) == 0x200 + n
        assert s.read(0x1600, 0) == 2
        assert s.read(0x1600, 1) == 0x6040_0010 and s.read(0x1600, 2) == 0x607A_0020
        assert s.read(0x1A00, 0) == 2 and s.read(0x1800, 1) == 0x180 + n
        assert s.read(0x1A00, 1) == 0x6041_0010 and s.read(0x1A00, 2) == 0x6064_0020
        assert s.read(0x1800, 2) == 1 and s.read(0x1017, 0) == 10
        # the list's requests: initiate download (ccs 001); node 3 also had the host upload
        reqs = [r for r in sdo_requests(tb, n) if r[0] & 0xE0 == 0x20]
        assert len(reqs) == len(drive_entries(n)), (n, reqs)
        for req, (_, index, sub, size, value) in zip(reqs, drive_entries(n)):
            assert req[0] == 0x23 | ((4 - size) << 2), req.hex()  # expedited, size indicated
            assert int.from_bytes(req[1:3], "little") == index and req[3] == sub
            assert req[4:4 + size] == value.to_bytes(4, "little")[:size]
    # bus order: SDOs of node n, its NMT start, then node n+1
    starts = {d[1]: t for t, d in nmt_frames(tb) if d[0] == 0x01}
    assert sorted(starts) == [1, 2, 3, 4], nmt_frames(tb)
    for s in tb.slaves:
        n = s.node_id
        last_resp = tb.frames(0x580 + n)[-1].t_end_ps
        assert starts[n] > last_resp
        if n < 4:
            first_dl = next(r for r in tb.frames(0x600 + n + 1) if r.msg.data[0] & 0xE0 == 0x20)
            assert starts[n] < first_dl.t_start_ps
    assert all(r[0] != 0x40 for r in sdo_requests(tb, 4)), "the refused host upload was sent"
    # channel 1's upload of node 3 interleaved with the list's downloads to node 1/2
    up = [r for r in tb.frames(0x603) if r.msg.data[0] in (0x40, 0x60, 0x70)]
    assert up and up[-1].t_end_ps < t_name_done, up
    lst = [r.t_start_ps for r in tb.frames(0x601) + tb.frames(0x602)]
    assert any(up[0].t_start_ps < t < up[-1].t_start_ps for t in lst), "no interleaving"
    t0 = tb.frames(0x601)[0].t_start_ps
    t1 = max(starts.values())
    dut._log.info("configuration list: %d entries + 4 NMT starts in %.1f us (%.1f us/entry)",
                  len(entries), (t1 - t0) / 1e6, (t1 - t0) / 1e6 / len(entries))
    assert await host.sdo_upload(4, 0x1017, 0) == (10).to_bytes(2, "little")
    await finish(tb)


@cocotb.test(timeout_time=300, timeout_unit="ms")
async def run_config_list_failures(dut):
    """Purpose: a failing entry stops that node, is reported with its abort code, the list goes
    on with the next node.

    Verifies: node 2's third entry writes an object that does not exist (0602 0000h), node 3's
    second a read-only one (0601 0002h), node 9 is not on the bus (SDO timeout 0504 0000h sent
    by the master); nodes 1 and 4 succeed. ACFG_STATUS: 2 ok, 3 failed; ACFG_FAIL/ACFG_ABORT
    hold the first failure (node 2, its entry number, 0602 0000h) and, through ACFG_FAIL_SEL,
    the second and third (node 3 0601 0002h, node 9 0504 0000h); the entries after a failing
    one are not sent; only nodes 1 and 4 get an NMT start and become operational, 2 and 3 stay
    pre-operational; CNT_SDO_ABORT counts the three failures.
    """
    tb = SystemTB(dut)
    await boot(tb)
    host = tb.host
    await host.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=20))
    await host.clear_counters()
    n1, n2, n3, n4 = drive_entries(1), drive_entries(2), drive_entries(3), drive_entries(4)
    n2 = n2[:2] + [(2, 0x2FFF, 0, 4, 1)] + n2[2:]  # entry 2 of node 2
    n3 = n3[:1] + [(3, 0x1000, 0, 4, 0)] + n3[1:]
    n9 = [(9, 0x1017, 0, 2, 10)]
    entries = n1 + n2 + n3 + n9 + n4
    await host.acfg_load(entries)
    st = await host.acfg_run(start_nodes=True, timeout_us=300_000)
    assert st["nodes_ok"] == 2 and st["nodes_fail"] == 3, st
    assert st["fail_node"] == 2 and st["fail_entry"] == len(n1) + 2, st
    assert st["fail_abort"] == ABORT_NO_OBJECT, hex(st["fail_abort"])
    assert await host.acfg_failures() == [
        (2, len(n1) + 2, ABORT_NO_OBJECT), (3, len(n1) + len(n2) + 1, ABORT_READ_ONLY),
        (9, len(n1) + len(n2) + len(n3), ABORT_TIMEOUT)]
    assert await host.acfg_failure(3) == (0, 0, 0)
    assert len(sdo_requests(tb, 2)) == 3 and len(sdo_requests(tb, 3)) == 2
    assert [r[0] for r in sdo_requests(tb, 9)] == [0x2B, 0x80]  # the request, the master's abort
    aborts = {n: bytes(r.msg.data) for n in (2, 3) for r in tb.frames(0x580 + n)
              if r.msg.data[0] == 0x80}
    assert int.from_bytes(aborts[2][4:], "little") == ABORT_NO_OBJECT
    assert int.from_bytes(aborts[3][4:], "little") == ABORT_READ_ONLY
    master_abort = [bytes(r.msg.data) for r in tb.frames(0x609) if r.msg.data[0] == 0x80]
    assert [int.from_bytes(a[4:], "little") for a in master_abort] == [ABORT_TIMEOUT]
    await Timer(2, "ms")  # DONE comes with the last NMT request, before its frame
    assert sorted(d[1] for _, d in nmt_frames(tb) if d[0] == 0x01) == [1, 4]
    states = {s.node_id: s.nmt_state for s in tb.slaves}
    assert states == {1: NmtState.OPERATIONAL, 2: NmtState.PRE_OPERATIONAL,
                      3: NmtState.PRE_OPERATIONAL, 4: NmtState.OPERATIONAL}, states
    assert tb.slave(2).read(0x1600, 0) == 0, "entries after the failure were applied"
    assert (await host.counters())["sdo_abort"] == 3
    # without START_NODES the list configures but starts nobody
    n_nmt = len(nmt_frames(tb))
    await host.acfg_load(n1)
    st = await host.acfg_run(start_nodes=False, timeout_us=100_000)
    assert st["nodes_ok"] == 1 and st["nodes_fail"] == 0 and len(nmt_frames(tb)) == n_nmt
    await finish(tb)


@pytest.mark.sim
def test_canopen_autoconfig_system(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_canopen_autoconfig_system",
               name=request.node.name, parameters=SYSTEM, stop_time_ms=1000,
               ieee_asserts="disable")
