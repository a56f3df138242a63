"""The worked example of ``docs/host_guide.md``, executed register by register.

Every write below uses the literal word address and value printed in the guide (no register
names, no driver helpers), so the guide cannot drift from the register map or the RTL: if a
value in the guide is wrong, the frames on the bus or the data in the drives differ and this
bench fails. The system is the usual one: master RTL + MCP2510 model + four reference drives.
"""

from __future__ import annotations

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave import NmtState
from tb.tblib.runner import run_cocotb
from tb.tblib.system_tb import SystemTB

SYSTEM = {"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000, "OSC_FREQ_HZ": 16_000_000,
          "CAN_BITRATE_BPS": 1_000_000, "MAX_NODES": 4, "RESET_WAIT_US": 20}


async def poll(tb: SystemTB, addr: int, mask: int, what: str, limit_us: int = 50_000) -> int:
    """Read ``addr`` every 10 us until a bit of ``mask`` is set; return the word."""
    for _ in range(limit_us // 10):
        word = await tb.host.read(addr)
        if word & mask:
            return word
        await Timer(10, "us")
    raise AssertionError(f"{what}: bit {mask:#x} of word {addr:#04x} not set in {limit_us} us")


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_guide_example(dut):
    """Purpose: the guide's steps 1-7 in order, with the guide's literal values.

    Verifies: ID reads "CO01"; STATUS.INIT_DONE; the configuration list of step 2 (node 3:
    heartbeat 10 ms) runs with 1 node ok; the expedited download of step 3 puts
    [2B 17 10 00 0A 00 00 00] on 603h and 1017h = 10 in node 3; the segmented upload of step 4
    returns node 3's device name and its length in SDO_CMD.XFER_SIZE; the abort of step 5 reads
    0602 0000h; the PDO cycle of step 6 sends 203h [0F 00 40 E2 01 00] after each SYNC, the
    drive's target position becomes 123456, and the feedback snapshot of 183h has a sequence
    number that grows by one per SYNC; the two uploads of step 7 run at once on channels 1
    and 0 (their requests interleave), SDO_SEL reads 02000300h when both are done and each
    channel's buffer holds its node's device name.
    """
    tb = SystemTB(dut)
    await tb.reset()
    host = tb.host
    # step 1: identify, wait for the controller, enable interrupts
    await Timer(1, "us")                 # the core leaves reset two clocks after rst_n_i
    assert await host.read(0x00) == 0x434F3031
    await poll(tb, 0x03, 1 << 4, "STATUS.INIT_DONE", 2_000)
    await host.write(0x05, 0x000000FF)
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    # step 2: configuration list, one entry (node 3, 1017h:00, 2 bytes, 10 ms) + end marker
    await host.write(0x7C, 0x00020300)   # ACFG_ENTRY: entry 0, node 3, size 2
    await host.write(0x7D, 0x00001017)   # ACFG_OBJ: 1017h sub 0
    await host.write(0x7E, 0x0000000A)   # ACFG_VALUE: 10 -> stores entry 0
    await host.write(0x7C, 0x00000001)   # ACFG_ENTRY: entry 1, node 0 = end
    await host.write(0x7E, 0x00000000)
    await host.write(0x78, 0x00000003)   # ACFG_CTRL: START | START_NODES
    word = await poll(tb, 0x79, 1 << 1, "ACFG_STATUS.DONE", 20_000)
    assert (word >> 8) & 0xFF == 1 and (word >> 16) & 0xFF == 0, hex(word)
    assert tb.slave(3).read(0x1017, 0) == 10
    await tb.wait_for(lambda: tb.slave(3).nmt_state == NmtState.OPERATIONAL, 2_000, 10, "start")
    # step 3: expedited download 1017h:00 = 10 to node 3 (again, by the host)
    n0 = len(tb.frames(0x603))
    await host.write(0x80, 0x0000000A)   # SDO_BUF word 0
    await host.write(0x70, 0x00001017)   # SDO_OBJ
    await host.write(0x71, 0x00000203)   # SDO_CMD: node 3, download, 2 bytes
    word = await poll(tb, 0x71, 1 << 1, "SDO_CMD.DONE")
    assert word == 0x00000202, hex(word)  # DONE, XFER_SIZE 2
    assert [bytes(r.msg.data) for r in tb.frames(0x603)[n0:]] == [bytes.fromhex("2B1710000A000000")]
    # step 4: segmented upload of 1008h:00 (device name) from node 3
    await host.write(0x70, 0x00001008)
    await host.write(0x71, 0x00100003)   # SDO_CMD: node 3, upload
    word = await poll(tb, 0x71, 1 << 1, "SDO_CMD.DONE")
    size = (word >> 8) & 0x7FF
    name = tb.slave(3).read_raw(0x1008, 0)
    assert word == (len(name) << 8) | 0x2 == 0x00004702, (hex(word), len(name))
    raw = b""
    for w in range(size // 4):           # whole words; the last, partial one is not needed here
        raw += (await host.read(0x80 + w)).to_bytes(4, "little")
    assert raw == name[:len(raw)]
    # step 5: an object that does not exist -> abort code in SDO_ABORT
    await host.write(0x70, 0x00002FFF)
    await host.write(0x71, 0x00100003)
    word = await poll(tb, 0x71, 1 << 1, "SDO_CMD.DONE")
    assert word & 0x800000FF == 0x06, hex(word)  # DONE + ERROR, ABORT_SENT = 0
    assert await host.read(0x72) == 0x06020000
    # step 6: one set-point TPDO and one feedback RPDO for node 3, SYNC every 1 ms
    await host.write(0x06, 0x00000301)   # NMT_CMD: start node 3 (already started: harmless)
    await host.write(0xC0, 0x00000000)   # PDO_SEL: TPDO 0
    await host.write(0xC4, 0x01068203)   # PDO_CFG: 203h, VALID, DLC 6, TT 1
    await host.write(0xC6, 0xE240000F)   # PDO_DATA_LO: controlword 000Fh, position bytes 0-1
    await host.write(0xC7, 0x00000001)   # PDO_DATA_HI: position bytes 2-3 (123456 = 0001E240h)
    await host.write(0xC8, 0x00000001)   # PDO_CMD: COMMIT
    await host.write(0xC0, 0x00000080)   # PDO_SEL: RPDO 0
    await host.write(0xC4, 0x01068183)   # PDO_CFG: 183h, VALID, DLC 6, TT 1
    await host.write(0x07, 1000)         # SYNC_PERIOD_US
    await host.write(0x02, 0x00000001)   # CTRL: SYNC_EN
    await Timer(5, "ms")
    seqs = []
    for _ in range(3):
        await host.write(0x04, 1 << 4)   # clear IRQ_STATUS.SYNC
        await poll(tb, 0x04, 1 << 4, "IRQ_STATUS.SYNC", 2_000)
        await Timer(300, "us")           # the drive answers right after the SYNC
        await host.write(0xC0, 0x00000180)   # PDO_SEL: RPDO 0 + ACK (snapshot)
        seqs.append(await host.read(0xC9) & 0xFFFF)
    await host.write(0x02, 0x00000000)
    assert seqs[1] == seqs[0] + 1 and seqs[2] == seqs[1] + 1, seqs
    assert tb.slave(3).read(0x607A, 0) == 123456
    sent = {bytes(r.msg.data) for r in tb.frames(0x203)}
    assert sent == {bytes.fromhex("0F0040E20100")}, sent
    # step 7: two uploads at once, node 2 on channel 1 and node 3 on channel 0
    await host.write(0x75, 0x00000001)   # SDO_SEL: channel 1
    await host.write(0x70, 0x00001008)   # SDO_OBJ: device name
    await host.write(0x71, 0x00100002)   # SDO_CMD: node 2, upload (channel 1)
    await host.write(0x75, 0x00000000)   # SDO_SEL: channel 0
    await host.write(0x71, 0x00100003)   # SDO_CMD: node 3, upload (channel 0)
    for _ in range(5_000):
        word = await host.read(0x75)
        if (word >> 8) & 0x3 == 0x3:
            break
        await Timer(10, "us")
    assert word == 0x02000300, hex(word)
    names = {}
    for chan, node in ((0, 3), (1, 2)):
        await host.write(0x75, chan)
        raw = b""
        for w in range(len(name) // 4):
            raw += (await host.read(0x80 + w)).to_bytes(4, "little")
        names[node] = raw
    for node in (2, 3):
        assert names[node] == tb.slave(node).read_raw(0x1008, 0)[:len(names[node])], node
    t2 = [r.t_start_ps for r in tb.frames(0x602)]
    t3 = [r.t_start_ps for r in tb.frames(0x603) if r.t_start_ps > t2[0]]
    assert any(t2[0] < t < t2[-1] for t in t3), "the two uploads did not interleave"
    tb.check_models_clean()
    # leave no SPI transfer in flight for the next test's fresh MCP2510 model
    while int(dut.spi_cs_n_o.value) != 1:
        await Timer(100, "ns")
    dut.rst_n_i.value = 0
    await Timer(5, "us")


@cocotb.test(timeout_time=50, timeout_unit="ms")
async def run_nmt_write_while_busy_refused(dut):
    """Purpose: an NMT_CMD write while the previous command is still pending is refused and
    reported, never overwrites it (nothing lost silently).

    Verifies: two back-to-back NMT_CMD writes (start node 3, then stop node 3) put only the
    first on the bus and set NMT_CMD.REFUSED; the next write after NMT_BUSY fell is accepted
    and clears REFUSED; the driver's nmt() waits for NMT_BUSY and is never refused.
    """
    tb = SystemTB(dut)
    await tb.reset()
    host = tb.host
    await tb.wait_master_ready()
    n0 = len(tb.frames(0x000))
    await host.write(0x06, 0x00000301)   # start node 3
    await host.write(0x06, 0x00000302)   # stop node 3, while the start is still pending
    assert await host.read(0x06) & (1 << 30), "REFUSED not set"
    await poll_clear(tb, 0x06, 1 << 31, "NMT_BUSY")
    await Timer(300, "us")
    assert [bytes(r.msg.data) for r in tb.frames(0x000)[n0:]] == [b"\x01\x03"]
    await host.write(0x06, 0x00000302)   # accepted now
    assert not await host.read(0x06) & (1 << 30), "REFUSED not cleared"
    for node in (1, 2, 4):
        await host.nmt(0x01, node)       # back to back through the driver: none refused
        assert not await host.read(0x06) & (1 << 30)
    await Timer(1, "ms")
    got = [bytes(r.msg.data) for r in tb.frames(0x000)[n0:]]
    assert got == [b"\x01\x03", b"\x02\x03", b"\x01\x01", b"\x01\x02", b"\x01\x04"], got
    tb.check_models_clean()
    await Timer(1, "ns")


async def poll_clear(tb: SystemTB, addr: int, mask: int, what: str, limit_us: int = 5000) -> None:
    for _ in range(limit_us // 10):
        if not await tb.host.read(addr) & mask:
            return
        await Timer(10, "us")
    raise AssertionError(f"{what} still set after {limit_us} us")


@pytest.mark.sim
def test_host_guide(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_host_guide",
               name=request.node.name, parameters=SYSTEM, stop_time_ms=500,
               ieee_asserts="disable")
