"""The C HAL (``sw/canopen_master.{c,h}``) against the RTL.

The HAL is compiled with the host C compiler into a shared library (``build/c_hal``, warnings
as errors) and called through :mod:`ctypes` from cocotb: each HAL call runs in a bridged thread
and each of its ``rd``/``wr`` callbacks is one Avalon-MM transaction on the system bench
(``canopen_master_top`` + MCP2510 model + CAN bus + CiA 301 reference drives), see
``tb/tblib/c_hal.py``. Three scenarios in one simulation (CANopen-only build, as the long PDO
benches):

* ``run_guide_through_c``: the worked example of ``docs/host_guide.md`` (steps 1-7) done with
  the HAL; the HAL's register writes are compared with the guide's literal words, the results
  with the drives' object dictionaries and the frames on the bus;
* ``run_demo_through_c``: the demo's configuration (``tb/test_demo.py``): configuration list of
  four CiA 402 drives (56 SDO downloads) and NMT start, device names by segmented upload, the
  PDO cycle (SYNC 2 ms with counter, driven by the core's interrupt and ``cm_irq_handler``),
  node status, an EMCY popped by the interrupt handler, a drive losing power;
* ``run_fault_detected``: the HAL built against a register header with one wrong field shift
  (``SDO_CMD.XFER_SIZE``) fails the guide's upload check.

Plus, without a simulator: the HAL and the header compile with ``-std=c99 -Wall -Wextra
-Werror -pedantic`` (and ``-Wconversion -Wshadow``), include nothing beyond stdint/stddef/string
and use no allocation; the header is an output of ``scripts/regmap.py`` covered by ``--check``.
"""

from __future__ import annotations

import ctypes as C
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave import NmtState
from sim_models.sim_time import PS_PER_US
from tb.tblib import c_hal
from tb.tblib import regmap as R
from tb.tblib.c_hal import CHal, CmAcfgEntry, CmAcfgResult, CmNodeStatus, CmRpdo, CmSdoResult
from tb.tblib.drive_config import drive_entries
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.pdo_cycle import SYSTEM_CANOPEN_ONLY
from tb.tblib.runner import ROOT, run_cocotb
from tb.tblib.system_tb import SystemTB

X = CHal.CTX
LIB_ENV, FAULT_LIB_ENV = "C_HAL_LIB", "C_HAL_FAULT_LIB"
#: the doctored field of the fault test: SDO_CMD.XFER_SIZE read one bit too high
FAULT = (r"^(#define CM_SDO_CMD_XFER_SIZE_SHIFT\s+)8u", r"\g<1>9u")
IRQ_BIT = {name: f.lo for name, f in R.REGISTERS["IRQ_STATUS"].fields.items()}


def _hal(tb: SystemTB, env: str = LIB_ENV) -> CHal:
    return CHal(Path(os.environ[env]), tb.host, poll_us=10)


async def isr_until(tb: SystemTB, hal: CHal, bit: str, limit_us: int) -> tuple[int, int]:
    """Interrupt-driven: whenever irq_o is 1, run cm_irq_handler; return (time in ps, pending
    bits of the call) of the first call that handled IRQ_STATUS bit ``bit``."""
    t_end = sim_time_ps() + limit_us * PS_PER_US
    spurious = 0
    while sim_time_ps() < t_end:
        if int(tb.dut.irq_o.value) == 1:
            t = sim_time_ps()
            pending = await hal.call("cm_irq_handler", X)
            if pending >> IRQ_BIT[bit] & 1:
                return t, pending
            # irq_o falls a few cycles after the W1C write of the handler: a look right after
            # it may still see 1 (a spurious interrupt, as on a CPU); never twice in a row
            spurious = 0 if pending else spurious + 1
            assert spurious < 2, "irq_o = 1 but the handler finds no pending enabled bit"
        await Timer(5, "us")
    raise AssertionError(f"IRQ_STATUS.{bit} not handled within {limit_us} us")


async def upload(hal: CHal, chan: int, node: int, index: int, sub: int = 0
                 ) -> tuple[int, bytes, CmSdoResult]:
    buf = (C.c_uint8 * 256)()
    n = C.c_size_t(0)
    res = CmSdoResult()
    st = await hal.call("cm_sdo_upload", X, chan, node, index, sub, buf, 256, C.byref(n),
                        C.byref(res))
    return st, bytes(buf[:n.value]), res


async def end_of_test(tb: SystemTB, hal: CHal) -> None:
    """Check that only SDO_BUF words beyond a transfer read undefined bits, then leave no SPI
    transfer in flight for the next test's fresh MCP2510 model."""
    assert all(R.REG_SDO_BUF <= a < R.REG_SDO_BUF + R.SDO_BUF_WORDS
               for a, _ in hal.undefined_reads), hal.undefined_reads
    while int(tb.dut.spi_cs_n_o.value) != 1:
        await Timer(100, "ns")
    tb.dut.rst_n_i.value = 0
    await Timer(5, "us")


async def guide_steps_1_to_5(tb: SystemTB, hal: CHal) -> None:
    """Steps 1-5 of the host guide through the HAL (shared with the fault test)."""
    # step 1: identify (ID "CO01", VERSION), wait for INIT_DONE, all interrupts enabled
    await Timer(1, "us")
    assert await hal.call("cm_init", X, 0xFF) == c_hal.CM_OK
    assert ("r", 0x00, 0x434F3031) in hal.log
    assert hal.ctx.version == R.VERSION_RESET and hal.ctx.n_sdo == 2
    assert hal.writes()[-1] == (0x05, 0x000000FF)
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    # step 2: configuration list, node 3 1017h:00 = 10 ms, then START | START_NODES
    mark = len(hal.log)
    entries = (CmAcfgEntry * 1)(CmAcfgEntry(3, 0x1017, 0, 2, 10))
    assert await hal.call("cm_acfg_load", X, entries, 1, 0) == c_hal.CM_OK
    res = CmAcfgResult()
    assert await hal.call("cm_acfg_run", X, 1, C.byref(res)) == c_hal.CM_OK
    assert hal.writes(mark) == [(0x7C, 0x00020300), (0x7D, 0x00001017), (0x7E, 0x0000000A),
                                (0x7C, 0x00000001), (0x7E, 0x00000000), (0x78, 0x00000003)]
    assert (res.nodes_ok, res.nodes_fail) == (1, 0)
    assert tb.slave(3).read(0x1017, 0) == 10
    await tb.wait_for(lambda: tb.slave(3).nmt_state == NmtState.OPERATIONAL, 2_000, 10, "start")
    # step 3: expedited download 1017h:00 = 10 (2 bytes) to node 3
    mark, n0 = len(hal.log), len(tb.frames(0x603))
    data = c_hal.u8_buf(b"\x0a\x00")
    res = CmSdoResult()
    assert await hal.call("cm_sdo_download", X, 0, 3, 0x1017, 0, data, 2,
                          C.byref(res)) == c_hal.CM_OK
    assert hal.writes(mark) == [(0x75, 0), (0x80, 0x0000000A), (0x70, 0x00001017),
                                (0x71, 0x00000203)]
    assert [v for k, a, v in hal.log[mark:] if k == "r" and a == 0x71][-1] == 0x00000202
    assert [bytes(r.msg.data) for r in tb.frames(0x603)[n0:]] == [bytes.fromhex("2B1710000A000000")]
    # step 4: segmented upload of 1008h:00 (device name, 71 bytes) from node 3
    mark = len(hal.log)
    st, name, res = await upload(hal, 0, 3, 0x1008)
    assert st == c_hal.CM_OK, st
    assert hal.writes(mark) == [(0x70, 0x00001008), (0x71, 0x00100003)]
    expected = tb.slave(3).read_raw(0x1008, 0)
    assert res.size == len(expected) == 71, (res.size, len(expected))
    assert name == expected, (name, expected)
    assert [a for k, a, _ in hal.log[mark:] if k == "r" and a >= 0x80] == list(range(0x80, 0x92))
    # step 5: an object that does not exist: abort 0602 0000h from the drive
    mark = len(hal.log)
    st, _, res = await upload(hal, 0, 3, 0x2FFF)
    assert st == c_hal.CM_ERR_ABORT, st
    assert (res.abort_code, res.abort_sent) == (0x06020000, 0), (hex(res.abort_code),
                                                                 res.abort_sent)
    assert hal.writes(mark) == [(0x70, 0x00002FFF), (0x71, 0x00100003)]


@cocotb.test(timeout_time=150, timeout_unit="ms")
async def run_guide_through_c(dut):
    """Purpose: docs/host_guide.md steps 1-7 through the C HAL.

    Verifies: every HAL write of steps 2-6 equals the guide's literal address/value (plus the
    HAL's own SDO_SEL / PDO_INHIBIT / SYNC_OVERFLOW / SYNC_WINDOW writes); ID, version and
    SDO channel count read by cm_init; node 3 configured and started by the list; the download
    frame on 603h; the uploaded device name equals node 3's 1008h; abort 06020000h from the
    drive; the PDO cycle driven by irq_o + cm_irq_handler: each RPDO snapshot equals the last
    183h frame before it and its SEQ grows by one per SYNC, each 203h frame carries the
    set-point committed before its SYNC, the drive's 607Ah ends at the last one; step 7: two
    uploads at once on channels 1 and 0, a third request to node 2 (busy on channel 1) is
    refused by the core (CM_ERR_REFUSED, no frame), both names right.
    """
    tb = SystemTB(dut)
    await tb.reset()
    hal = _hal(tb)
    await guide_steps_1_to_5(tb, hal)
    # step 6: set-point TPDO 0 -> 203h, feedback RPDO 0 <- 183h, SYNC 1 ms
    mark = len(hal.log)
    assert await hal.call("cm_nmt", X, 0x01, 3) == c_hal.CM_OK
    assert await hal.call("cm_tpdo_config", X, 0, 0x203, 6, 1, 0, 0) == c_hal.CM_OK
    sp = c_hal.u8_buf(bytes.fromhex("0F0040E20100"))   # controlword 000Fh, 123456
    assert await hal.call("cm_tpdo_set", X, 0, sp, 6, 1, 0) == c_hal.CM_OK
    commits = [(sim_time_ps(), 123456)]  # (time the commit call returned, target position)
    assert await hal.call("cm_rpdo_config", X, 0, 0x183, 6, 1, 0) == c_hal.CM_OK
    assert await hal.call("cm_sync_config", X, 1000, 0, 0, 1) == c_hal.CM_OK
    assert hal.writes(mark) == [
        (0x06, 0x00000301),
        (0xC0, 0x000), (0xC5, 0), (0xC4, 0x01068203),
        (0xC0, 0x000), (0xC6, 0xE240000F), (0xC7, 0x00000001), (0xC8, 0x00000001),
        (0xC0, 0x080), (0xC4, 0x01068183),
        (0x07, 1000), (0x08, 0), (0x09, 0), (0x02, 0x00000001)]
    seqs = []
    for k in range(4):
        await isr_until(tb, hal, "SYNC", 2_000)
        await Timer(300, "us")            # the drive answers right after the SYNC
        snap = CmRpdo()
        t_snap = sim_time_ps()
        assert await hal.call("cm_rpdo_get", X, 0, 1, C.byref(snap)) == c_hal.CM_OK
        last = [r for r in tb.frames(0x183) if r.t_end_ps < t_snap][-1]
        assert bytes(snap.data[:snap.dlc]) == bytes(last.msg.data) and snap.dlc == 6
        seqs.append(snap.seq)
        target = 123456 + 1000 * (k + 1)
        data = c_hal.u8_buf((0x000F).to_bytes(2, "little") + target.to_bytes(4, "little"))
        assert await hal.call("cm_tpdo_set", X, 0, data, 6, 1, 0) == c_hal.CM_OK
        commits.append((sim_time_ps(), target))
    await Timer(2_500, "us")              # two more SYNCs: the last set-point is applied
    assert await hal.call("cm_sync_config", X, 1000, 0, 0, 0) == c_hal.CM_OK
    assert seqs == list(range(seqs[0], seqs[0] + 4)), seqs
    syncs = tb.sync_sof_times()
    for r in tb.frames(0x203):
        t_sync = max(t for t in syncs if t < r.t_start_ps)
        want = [v for t, v in commits if t < t_sync][-1]
        assert bytes(r.msg.data) == (0x000F).to_bytes(2, "little") + want.to_bytes(4, "little")
    assert tb.slave(3).read(0x607A, 0) == commits[-1][1]
    # step 7: node 2 on channel 1 and node 3 on channel 0 at once; node 2 again is refused
    n602 = len(tb.frames(0x602))
    assert await hal.call("cm_sdo_start_upload", X, 1, 2, 0x1008, 0) == c_hal.CM_OK
    assert await hal.call("cm_sdo_start_upload", X, 0, 2, 0x1008, 0) == c_hal.CM_ERR_REFUSED
    assert await hal.call("cm_sdo_start_upload", X, 0, 3, 0x1008, 0) == c_hal.CM_OK
    done = {}
    for _ in range(2_000):
        for chan in (0, 1):
            if chan not in done:
                res = CmSdoResult()
                st = await hal.call("cm_sdo_poll", X, chan, C.byref(res))
                if st != c_hal.CM_PENDING:
                    done[chan] = (st, res.size)
        if len(done) == 2:
            break
        await Timer(20, "us")
    assert done == {0: (c_hal.CM_OK, 71), 1: (c_hal.CM_OK, 71)}, done
    for chan, node in ((0, 3), (1, 2)):
        buf = (C.c_uint8 * 71)()
        assert await hal.call("cm_sdo_read_buf", X, chan, buf, 71) == c_hal.CM_OK
        assert bytes(buf) == tb.slave(node).read_raw(0x1008, 0), node
    initiates = [r for r in tb.frames(0x602)[n602:] if r.msg.data[0] == 0x40]
    assert len(initiates) == 1, "the refused request put a frame on the bus"
    t2 = [r.t_start_ps for r in tb.frames(0x602)[n602:]]
    assert any(t2[0] < r.t_start_ps < t2[-1] for r in tb.frames(0x603)), "no interleaving"
    tb.dut._log.info("C HAL guide: %d register accesses, %d idle polls", len(hal.log), hal.polls)
    tb.check_models_clean()
    await end_of_test(tb, hal)


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_demo_through_c(dut):
    """Purpose: the demo's configuration (tb/test_demo.py) through the C HAL.

    Verifies: the configuration list of the four drives (tb/tblib/drive_config.py, 56 entries,
    heartbeat 2 ms here) loaded by cm_acfg_load and run by cm_acfg_run: 4 ok / 0 failed, the
    values in each drive's object dictionary, all operational, the CONFIG interrupt
    dispatched; the four device names by segmented upload; the PDO cycle (SYNC 2 ms, counter
    16) driven by irq_o + cm_irq_handler: set-points in the drives, every feedback snapshot
    equal to the drive's last TPDO and its SYNC_COUNT equal to the counter of the SYNC before
    it; node status operational / alive for all four; an EMCY of drive 2 delivered by the
    handler's on_emcy with the frame's bytes; drive 3 losing power: NODE interrupt, only slot
    2 LOST, within the consumer time + one heartbeat period.
    """
    tb = SystemTB(dut, ppm=(-100, -50, 50, 100))
    await tb.reset()
    hal = _hal(tb)
    hal.dispatch([IRQ_BIT["NODE"], IRQ_BIT["SYNC"], IRQ_BIT["CONFIG"]], emcy=True)
    irqs = sum(1 << IRQ_BIT[n] for n in ("NODE", "EMCY", "SYNC", "CONFIG"))
    await Timer(1, "us")
    assert await hal.call("cm_init", X, irqs) == c_hal.CM_OK
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    rows = [e for s in tb.slaves for e in drive_entries(s.node_id, hb_ms=2)]
    entries = (CmAcfgEntry * len(rows))(*(CmAcfgEntry(*e) for e in rows))
    assert await hal.call("cm_acfg_load", X, entries, len(rows), 0) == c_hal.CM_OK
    res = CmAcfgResult()
    assert await hal.call("cm_acfg_run", X, 1, C.byref(res)) == c_hal.CM_OK
    assert (res.nodes_ok, res.nodes_fail) == (4, 0)
    for s in tb.slaves:
        assert s.read(0x1017, 0) == 2, f"node {s.node_id} 1017h not set by the list"
        assert s.read(0x1A00, 1) == 0x6041_0010 and s.read(0x1600, 2) == 0x607A_0020
    await tb.wait_for(tb.all_operational, 2_000, 10, "operational")
    await isr_until(tb, hal, "CONFIG", 100)
    assert 1 << IRQ_BIT["CONFIG"] in hal.irq_calls
    for slot, s in enumerate(tb.slaves):
        assert await hal.call("cm_node_config", X, slot, s.node_id, 1, 6, 0, 0) == c_hal.CM_OK
    # device names, alternating the two SDO channels
    for i, s in enumerate(tb.slaves):
        st, name, _ = await upload(hal, i % 2, s.node_id, 0x1008)
        assert st == c_hal.CM_OK and name == s.read_raw(0x1008, 0), (st, name)
    # PDO cycle: set-point to RPDO1 of each drive, feedback from its TPDO1, every SYNC
    for ch, s in enumerate(tb.slaves):
        assert await hal.call("cm_tpdo_config", X, ch, 0x200 + s.node_id, 6, 1, 0, 0) == 0
        sp = (0x000F).to_bytes(2, "little") + (10_000 * s.node_id).to_bytes(4, "little")
        assert await hal.call("cm_tpdo_set", X, ch, c_hal.u8_buf(sp), 6, 1, 0) == 0
        assert await hal.call("cm_rpdo_config", X, ch, 0x180 + s.node_id, 6, 1, 0) == 0
    assert await hal.call("cm_sync_config", X, 2000, 16, 0, 1) == c_hal.CM_OK
    seqs: list[list[int]] = [[] for _ in tb.slaves]
    for _ in range(4):
        await isr_until(tb, hal, "SYNC", 3_000)
        await Timer(1_000, "us")          # 4 set-points + 4 feedback frames: < 0.9 ms
        t_snap = sim_time_ps()
        syncs = tb.frames(0x080)
        for ch, s in enumerate(tb.slaves):
            snap = CmRpdo()
            assert await hal.call("cm_rpdo_get", X, ch, 1, C.byref(snap)) == c_hal.CM_OK
            last = [r for r in tb.frames(0x180 + s.node_id) if r.t_end_ps < t_snap][-1]
            before = [r for r in syncs if r.t_end_ps <= last.t_start_ps]
            assert before, (ch, last.t_start_ps, [r.t_start_ps for r in syncs])
            sync = before[-1]
            assert bytes(snap.data[:6]) == bytes(last.msg.data), (ch, bytes(snap.data))
            assert snap.sync_count == sync.msg.data[0], (snap.sync_count, bytes(sync.msg.data))
            assert snap.len_err == 0 and snap.missed == 0
            seqs[ch].append(snap.seq)
    for s in tb.slaves:
        assert s.read(0x607A, 0) == 10_000 * s.node_id, f"node {s.node_id} set-point"
    assert all(q == list(range(q[0], q[0] + 4)) for q in seqs), seqs
    for slot in range(4):
        ns = CmNodeStatus()
        assert await hal.call("cm_node_status", X, slot, C.byref(ns)) == c_hal.CM_OK
        assert (ns.nmt_state, ns.alive, ns.lost) == (0x05, 1, 0), (slot, ns.nmt_state)
    # EMCY from drive 2, popped by the interrupt handler
    assert tb.slave(2).emcy(0x2310, 0x03, b"\x01\x02\x03\x04\x05")
    await isr_until(tb, hal, "EMCY", 1_000)
    frame = tb.frames(0x082)[-1]
    assert hal.emcys == [{"node": 2, "data": bytes(frame.msg.data), "error_code": 0x2310,
                          "error_register": 0x03, "lost": 0,
                          "time_ms": hal.emcys[0]["time_ms"]}], hal.emcys
    emcy = c_hal.CmEmcy()
    assert await hal.call("cm_emcy_pop", X, C.byref(emcy)) == c_hal.CM_ERR_EMPTY
    # drive 3 loses power: the master reports it
    tb.slave(3).power_off()
    t_off = sim_time_ps()
    t_lost, _ = await isr_until(tb, hal, "NODE", 20_000)
    lost = []
    for slot in range(4):
        ns = CmNodeStatus()
        assert await hal.call("cm_node_status", X, slot, C.byref(ns)) == c_hal.CM_OK
        lost.append(ns.lost)
    assert lost == [0, 0, 1, 0], lost
    assert t_lost - t_off <= (6 + 2) * 1000 * PS_PER_US, (t_lost - t_off) / PS_PER_US
    assert 1 << IRQ_BIT["NODE"] in hal.irq_calls
    assert await hal.call("cm_sync_config", X, 0, 0, 0, 0) == c_hal.CM_OK
    tb.dut._log.info("C HAL demo: node 3 lost %.1f us after power-off, %d accesses, %d polls",
                     (t_lost - t_off) / PS_PER_US, len(hal.log), hal.polls)
    tb.check_models_clean()
    await end_of_test(tb, hal)


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_fault_detected(dut):
    """Purpose: the bench catches a wrong HAL.

    Verifies: the HAL built against a register header whose SDO_CMD.XFER_SIZE shift is 9
    instead of 8 fails the guide's checks (the upload returns 35 bytes instead of node 3's 71).
    """
    tb = SystemTB(dut)
    await tb.reset()
    hal = _hal(tb, FAULT_LIB_ENV)
    with pytest.raises(AssertionError) as err:
        await guide_steps_1_to_5(tb, hal)
    tb.dut._log.info("wrong HAL detected: %s", str(err.value).splitlines()[0])
    assert "(35, 71)" in str(err.value), err.value
    await end_of_test(tb, hal)


@pytest.mark.sim
def test_c_hal(request):
    lib = c_hal.build(c_hal.BUILD / "libcanopen_master.so")
    fault = c_hal.build_with_header_change(c_hal.BUILD / "libcanopen_master_fault.so", *FAULT)
    run_cocotb(toplevel="canopen_master_top", module="tb.test_c_hal", name=request.node.name,
               parameters=SYSTEM_CANOPEN_ONLY, stop_time_ms=1000, ieee_asserts="disable",
               extra_env={LIB_ENV: str(lib), FAULT_LIB_ENV: str(fault)})


# ------------------------------------------------------------------------------ no simulator
STRICT = ("-Wconversion", "-Wshadow", "-Wstrict-prototypes", "-Wmissing-prototypes")


@pytest.mark.parametrize("std", ["c99", "c11"])
def test_c_hal_compiles_warnings_as_errors(tmp_path, std):
    """The HAL and the register header compile with -Wall -Wextra -Werror -pedantic (and the
    stricter -Wconversion -Wshadow ...), the header alone too; a warning does fail the build
    (a doctored copy with an unused variable)."""
    cc = c_hal.compiler()
    flags = [f"-std={std}", *c_hal.CFLAGS[1:], *STRICT, f"-I{c_hal.SW / 'include'}",
             f"-I{c_hal.SW}"]
    src = c_hal.SOURCES[0]
    res = subprocess.run([cc, *flags, "-c", str(src), "-o", str(tmp_path / "hal.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    only_header = tmp_path / "regs.c"
    only_header.write_text('#include "canopen_master_regs.h"\n#include "canopen_master.h"\n'
                           "unsigned f(unsigned w);\nunsigned f(unsigned w)\n{\n"
                           "    return CM_GET(CM_SDO_CMD_XFER_SIZE, w) + CM_PUT(CM_NMT_CMD_NODE,"
                           " 3) + CM_REG_NODE_STATUS_SLOT(2) + CM_REG_SDO_BUF_W_BYTE(1);\n}\n")
    res = subprocess.run([cc, *flags, "-c", str(only_header), "-o", str(tmp_path / "r.o")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    bad = tmp_path / "bad.c"
    bad.write_text(src.read_text().replace("size_t cm_ctx_size(void)\n{",
                                           "size_t cm_ctx_size(void)\n{\n    int unused;", 1))
    res = subprocess.run([cc, *flags, "-c", str(bad), "-o", str(tmp_path / "bad.o")],
                         capture_output=True, text=True)
    assert res.returncode != 0 and "unused" in res.stderr


def test_c_hal_uses_no_libc_beyond_stdint_stddef_string():
    """Portable to a bare Nios II / HPS: only stdint.h, stddef.h, string.h, no allocation."""
    for path in (*c_hal.SOURCES, *c_hal.HEADERS):
        text = path.read_text()
        system = set(re.findall(r'#include\s*<([^>]+)>', text))
        assert system <= {"stdint.h", "stddef.h", "string.h"}, (path.name, system)
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf)\s*\(", text), path.name


def _load_generator():
    spec = importlib.util.spec_from_file_location("regmap_gen_c", ROOT / "scripts" / "regmap.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_c_header_generated_and_checked(tmp_path, monkeypatch):
    """sw/include/canopen_master_regs.h is an output of scripts/regmap.py: it equals the
    generator's text, and --check reports a stale copy of it."""
    gen = _load_generator()
    header = ROOT / "sw" / "include" / "canopen_master_regs.h"
    assert gen.OUTPUTS.get(header) is gen.gen_c
    assert header.read_text() == gen.gen_c()
    text = gen.gen_c()
    assert f"#define CM_REG_SDO_CMD                        0x{R.REG_SDO_CMD:02X}u" in text
    assert f"0x{4 * R.REG_SDO_CMD:03X}u" in text
    copy = tmp_path / "canopen_master_regs.h"
    copy.write_text(text)
    monkeypatch.setattr(gen, "OUTPUTS", {copy: gen.gen_c})
    monkeypatch.setattr(gen, "ROOT", tmp_path)
    assert gen.main(["--check"]) == 0
    copy.write_text(text.replace("CM_SDO_CMD_XFER_SIZE_SHIFT            8u",
                                 "CM_SDO_CMD_XFER_SIZE_SHIFT            9u"))
    assert gen.main(["--check"]) == 1


# ------------------------------------------------------------------------------ HAL logic on a
# register fake (no simulator): the paths the RTL runs do not reach (bad ID/version, bounds,
# refusals, argument checks), with exact access counts
class FakeCore:
    """Read values as a dict (writes are logged, not stored); ``reads[addr]`` (a list)
    overrides successive reads of ``addr``."""

    def __init__(self, lib: C.CDLL, regs: dict[int, int], max_polls: int = 50) -> None:
        self.regs = {0x00: R.ID_RESET, 0x01: R.VERSION_RESET, **regs}
        self.reads: dict[int, list[int]] = {}
        self.log: list[tuple] = []
        self.idles = 0
        self.irqs: list[int] = []
        self.lib = lib
        self.ctx = c_hal.CmCtx()
        self._cbs = (c_hal.WR_FN(self._wr), c_hal.RD_FN(self._rd), c_hal.IDLE_FN(self._idle),
                     c_hal.IRQ_FN(lambda _c, m: self.irqs.append(m)))
        lib.cm_setup(C.byref(self.ctx), self._cbs[0], self._cbs[1], self._cbs[2], None)
        self.ctx.max_polls = max_polls

    def _wr(self, _c, a: int, v: int) -> None:
        self.log.append(("w", a, v))  # reads keep showing regs (status, not the write)

    def _rd(self, _c, a: int) -> int:
        self.log.append(("r", a))
        queue = self.reads.get(a)
        return queue.pop(0) if queue else self.regs.get(a, 0)

    def _idle(self, _c) -> None:
        self.idles += 1

    def __call__(self, name: str, *args):
        return getattr(self.lib, name)(C.byref(self.ctx), *args)

    def count(self, kind: str, addr: int) -> int:
        return sum(1 for e in self.log if e[0] == kind and e[1] == addr)


@pytest.fixture(scope="module")
def hal_lib(tmp_path_factory):
    return c_hal.load(c_hal.build(tmp_path_factory.mktemp("c_hal") / "libcm_unit.so"))


def test_c_hal_identify_and_init_bounds(hal_lib):
    """Wrong ID / version are reported without further access; INIT_DONE never coming ends
    after exactly max_polls reads (CM_ERR_INIT when INIT_FAIL is shown, else CM_ERR_TIMEOUT)."""
    f = FakeCore(hal_lib, {0x00: 0x12345678})
    assert f("cm_identify") == c_hal.CM_ERR_ID and f.log == [("r", 0x00)]
    major, minor = R.VERSION_RESET >> 16, R.VERSION_RESET & 0xFFFF
    for ver, want in (((major + 1) << 16 | minor, c_hal.CM_ERR_VERSION),
                      (major << 16 | (minor + 1), c_hal.CM_OK)):
        assert FakeCore(hal_lib, {0x01: ver})("cm_identify") == want, hex(ver)
    if minor:
        assert FakeCore(hal_lib, {0x01: major << 16 | (minor - 1)})("cm_identify") \
            == c_hal.CM_ERR_VERSION
    f = FakeCore(hal_lib, {R.REG_SDO_SEL: 2 << 24, R.REG_PDO_INFO: 8 << 8 | 8})
    assert f("cm_init", 0xFF) == c_hal.CM_ERR_TIMEOUT
    assert (f.count("r", R.REG_STATUS), f.idles, f.count("w", R.REG_IRQ_ENABLE)) == (50, 50, 0)
    assert (f.ctx.n_sdo, f.ctx.n_tpdo, f.ctx.n_rpdo) == (2, 8, 8)
    f = FakeCore(hal_lib, {R.REG_STATUS: R.STATUS_INIT_FAIL})
    assert f("cm_init", 0xFF) == c_hal.CM_ERR_INIT
    f = FakeCore(hal_lib, {R.REG_STATUS: R.STATUS_INIT_DONE})
    assert f("cm_init", 0x84) == c_hal.CM_OK and f.log[-1] == ("w", R.REG_IRQ_ENABLE, 0x84)


def test_c_hal_refused_only_right_after_the_command_write(hal_lib):
    """REFUSED in the first read after the command write -> CM_ERR_REFUSED, no poll; REFUSED
    seen later while polling DONE is not the HAL's (another writer): ignored. NMT waits for
    NMT_BUSY at most max_polls reads and then writes nothing."""
    f = FakeCore(hal_lib, {R.REG_SDO_SEL: 2 << 24})
    f("cm_identify")
    f.reads[R.REG_SDO_CMD] = [R.SDO_CMD_REFUSED]
    assert f("cm_sdo_start_upload", 1, 5, 0x1008, 0) == c_hal.CM_ERR_REFUSED
    assert f.count("r", R.REG_SDO_CMD) == 1
    f.reads[R.REG_SDO_CMD] = [0, R.SDO_CMD_REFUSED | R.SDO_CMD_BUSY,
                              R.SDO_CMD_REFUSED | R.SDO_CMD_DONE | 4 << 8]
    res = CmSdoResult()
    data = c_hal.u8_buf(b"\x01\x02\x03\x04")
    assert f("cm_sdo_download", 1, 5, 0x2000, 1, data, 4, C.byref(res)) == c_hal.CM_OK
    assert res.size == 4
    f.log.clear()
    f.reads[R.REG_NMT_CMD] = [R.NMT_CMD_NMT_BUSY] * 100
    assert f("cm_nmt", 0x01, 3) == c_hal.CM_ERR_TIMEOUT
    assert f.count("r", R.REG_NMT_CMD) == 50 and f.count("w", R.REG_NMT_CMD) == 0
    f.reads[R.REG_NMT_CMD] = [0, R.NMT_CMD_REFUSED]
    assert f("cm_nmt", 0x01, 3) == c_hal.CM_ERR_REFUSED
    f.reads[R.REG_ACFG_STATUS] = [R.ACFG_STATUS_REFUSED]
    assert f("cm_acfg_start", 1) == c_hal.CM_ERR_REFUSED


def test_c_hal_sdo_bounds_and_sizes(hal_lib):
    """A transfer whose DONE never comes ends after max_polls polls (CM_ERR_TIMEOUT); an upload
    larger than the buffer copies what fits (CM_ERR_SIZE, only those words read); an abort
    returns the code and who sent it."""
    f = FakeCore(hal_lib, {R.REG_SDO_SEL: 2 << 24})
    f("cm_identify")
    assert f("cm_sdo_start_upload", 0, 3, 0x1008, 0) == c_hal.CM_OK
    f.log.clear()
    res = CmSdoResult()
    buf = (C.c_uint8 * 10)()
    n = C.c_size_t(0)
    f.regs[R.REG_SDO_CMD] = R.SDO_CMD_BUSY
    assert f("cm_sdo_upload", 0, 3, 0x1008, 0, buf, 10, C.byref(n), C.byref(res)) \
        == c_hal.CM_ERR_TIMEOUT
    assert f.count("r", R.REG_SDO_CMD) == 1 + 50
    f.regs[R.REG_SDO_CMD] = R.SDO_CMD_DONE | 100 << 8
    for w in range(25):
        f.regs[R.REG_SDO_BUF + w] = int.from_bytes(bytes(range(4 * w, 4 * w + 4)), "little")
    f.log.clear()
    assert f("cm_sdo_upload", 0, 3, 0x1008, 0, buf, 10, C.byref(n), C.byref(res)) \
        == c_hal.CM_ERR_SIZE
    assert (res.size, n.value, bytes(buf)) == (100, 10, bytes(range(10)))
    assert sorted({e[1] for e in f.log if e[0] == "r" and e[1] >= R.REG_SDO_BUF}) \
        == [R.REG_SDO_BUF, R.REG_SDO_BUF + 1, R.REG_SDO_BUF + 2]
    f.regs[R.REG_SDO_CMD] = R.SDO_CMD_DONE | R.SDO_CMD_ERROR | R.SDO_CMD_ABORT_SENT
    f.regs[R.REG_SDO_ABORT] = 0x05040000
    assert f("cm_sdo_upload", 0, 3, 0x1008, 0, buf, 10, C.byref(n), C.byref(res)) \
        == c_hal.CM_ERR_ABORT
    assert (res.abort_code, res.abort_sent) == (0x05040000, 1)


def test_c_hal_rejects_bad_arguments_without_access(hal_lib):
    """Out-of-range arguments return CM_ERR_ARG and touch no register."""
    f = FakeCore(hal_lib, {R.REG_SDO_SEL: 2 << 24, R.REG_PDO_INFO: 8 << 8 | 8})
    f("cm_identify")
    f.log.clear()
    data = c_hal.u8_buf(bytes(300))
    bad_entry = (CmAcfgEntry * 1)(CmAcfgEntry(3, 0x1017, 0, 5, 10))
    calls = [("cm_sdo_start_download", 0, 3, 0x1017, 0, data, 0),
             ("cm_sdo_start_download", 0, 3, 0x1017, 0, data, 257),
             ("cm_sdo_start_download", 0, 0, 0x1017, 0, data, 2),
             ("cm_sdo_start_upload", 2, 3, 0x1008, 0),       # channel 2 of 2
             ("cm_nmt", 0x03, 1), ("cm_nmt", 0x01, 128),
             ("cm_tpdo_config", 0, 0x203, 9, 1, 0, 0),
             ("cm_tpdo_config", 0, 0x203, 6, 245, 0, 0),
             ("cm_tpdo_config", 8, 0x203, 6, 1, 0, 0),       # channel 8 of 8
             ("cm_rpdo_config", 0, 0x800, 6, 1, 0),
             ("cm_sync_config", 1000, 1, 0, 1),
             ("cm_acfg_load", bad_entry, 1, 0),
             ("cm_node_config", 16, 3, 1, 10, 0, 0), ("cm_node_config", 0, 3, 3, 10, 0, 0)]
    for name, *args in calls:
        assert f(name, *args) == c_hal.CM_ERR_ARG, (name, args)
    assert f.log == []


def test_c_hal_irq_handler_and_emcy(hal_lib):
    """The handler clears exactly the pending enabled bits (W1C) before dispatching them;
    nothing pending: one read of each register, no write; an empty FIFO pops nothing."""
    f = FakeCore(hal_lib, {R.REG_IRQ_STATUS: 0x15, R.REG_IRQ_ENABLE: 0x11})
    f.ctx.on_irq[4] = f._cbs[3]
    f.ctx.on_irq[2] = f._cbs[3]
    assert f("cm_irq_handler") == 0x11
    assert [e for e in f.log if e[0] == "w"] == [("w", R.REG_IRQ_STATUS, 0x11)]
    assert f.irqs == [0x10]
    f = FakeCore(hal_lib, {R.REG_IRQ_STATUS: 0x04, R.REG_IRQ_ENABLE: 0x10})
    assert f("cm_irq_handler") == 0 and len(f.log) == 2
    emcy = c_hal.CmEmcy()
    assert f("cm_emcy_pop", C.byref(emcy)) == c_hal.CM_ERR_EMPTY
    assert [e for e in f.log if e[0] == "w"] == []
