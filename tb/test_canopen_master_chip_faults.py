"""System bench of the master's reactions to faults of its MCP2510 (issue 13, items 1 and 4).

``canopen_master_top`` with the strict MCP2510 model (any data-sheet rule broken fails the
test, e.g. a TXnRTS request of a buffer whose SIDH/SIDL/DLC were not written since the chip's
reset), the bit-exact CAN bus and two reference slaves. Faults come from the bus model:
CRC errors on the master's own frames (``corrupt_next_frame``) and bus-off
(``force_bus_off``, with and without the chip's automatic recovery), plus host re-inits and a
failing initialisation attempt. Checks:

* re-initialisation (CTRL.REINIT, INIT retry, bus-off the chip does not recover from) while
  SYNC runs: no violation, no frame with ID 000h from the master, SYNC resumes with ID 080h and
  the right DLC/counter, CAN_STATUS is 0 from the RESET instruction on;
* the host's view of the error state (CAN_STATUS TEC/REC/EFLG, STATUS.ERR_PASSIVE and
  STATUS.BUS_OFF) is never older than ``BOUND_US`` (the documented bound: the controller's
  error poll interval of 500 us plus 200 us of SPI work that may be ahead of it).
"""

from __future__ import annotations

import can
import cocotb
import pytest
from cocotb.triggers import RisingEdge, Timer, ValueChange

from sim_models.can_bus import BUS_OFF_RECOVERY_BITS
from sim_models.canopen_slave import NmtState
from sim_models.mcp2510 import regs as MR
from sim_models.sim_time import PS_PER_US
from tb.tblib import regmap as R
from tb.tblib.fsm_states import State
from tb.tblib.host_driver import SdoAbort
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.pdo_cycle import SYSTEM
from tb.tblib.runner import run_cocotb
from tb.tblib.system_tb import SystemTB

CHIP = "master_mcp2510"
#: documented bound of the host's error state behind the chip (ERR_POLL_US + 200 us)
BOUND_US = 700
#: bus-off longer than 128 frames of 160 bits -> re-initialisation (1 Mbit/s)
BUSOFF_REINIT_US = 20_480
EFLG_STATE = 0x3F


class ErrorView:
    """Samples the chip's TEC/REC/EFLG every 2 us and what the host reads (STATUS, CAN_STATUS)
    every ``host_step_us``; ``staleness_us()`` is the largest age of a value the host read
    (how long before the read the chip last held it; 0 if it still holds it)."""

    def __init__(self, tb: SystemTB, host_step_us: float = 25) -> None:
        self.tb = tb
        self.chip_log: list[tuple[int, tuple[int, ...]]] = []
        self.host_log: list[tuple[int, tuple[int, ...]]] = []
        self.running = True
        cocotb.start_soon(self._chip())
        cocotb.start_soon(self._host(host_step_us))

    def chip_value(self) -> tuple[int, ...]:
        c = self.tb.chip
        eflg = c.peek(MR.EFLG) & EFLG_STATE
        return (c.peek(MR.TEC), c.peek(MR.REC), eflg, int(bool(eflg & MR.EFLG_TXBO)),
                int(bool(eflg & (MR.EFLG_TXEP | MR.EFLG_RXEP))))

    async def host_value(self) -> tuple[int, ...]:
        st = await self.tb.host.read("STATUS")
        cs = await self.tb.host.read("CAN_STATUS")
        return (cs & 0xFF, cs >> 8 & 0xFF, cs >> 16 & EFLG_STATE,
                int(bool(st & R.STATUS_BUS_OFF)), int(bool(st & R.STATUS_ERR_PASSIVE)))

    async def _chip(self) -> None:
        while self.running:
            self.chip_log.append((sim_time_ps(), self.chip_value()))
            await Timer(2, "us")

    async def _host(self, step_us: float) -> None:
        while self.running:
            v = await self.host_value()
            self.host_log.append((sim_time_ps(), v))  # the end of the reads: the worst case
            await Timer(step_us, "us")

    def saw(self, field: int, pred) -> bool:
        return any(pred(v[field]) for _, v in self.host_log)

    def staleness_us(self) -> float:
        worst = 0
        last_seen: list[dict[int, int]] = [{} for _ in range(5)]
        chip = iter(self.chip_log)
        pending = next(chip, None)
        for t, h in self.host_log:
            while pending is not None and pending[0] <= t:
                for k, v in enumerate(pending[1]):
                    last_seen[k][v] = pending[0]
                pending = next(chip, None)
            for k, v in enumerate(h):
                assert v in last_seen[k], f"host read {h} at {t} ps: never held by the chip"
                worst = max(worst, t - last_seen[k][v])
        return worst / PS_PER_US


class SyncPinCounter:
    """Counts the TX2RTS# pulses (falling edges of mcp_txrts_n_o bit 2)."""

    def __init__(self, dut) -> None:
        self.sig = dut.mcp_txrts_n_o
        self.pulses = 0
        cocotb.start_soon(self._run())

    async def _run(self) -> None:
        prev = 1
        while True:
            await ValueChange(self.sig)
            v = self.sig.value
            now = int(v) >> 2 & 1 if v.is_resolvable else 1
            if prev == 1 and now == 0:
                self.pulses += 1
            prev = now


async def check_every_sync_fired(tb: SystemTB, pins: SyncPinCounter) -> None:
    """Stop SYNC; every SYNC the master counted (SYNC_COUNT) was a TX2RTS# pulse, i.e. none
    was started while TXB2 was unloaded (the controller would have dropped it)."""
    await tb.host.sync_config(period_us=0, enable=False)
    await Timer(20, "us")
    count = await tb.host.read("SYNC_COUNT")
    assert count == pins.pulses, f"SYNC_COUNT {count}, TX2RTS pulses {pins.pulses}"


async def boot(tb: SystemTB) -> None:
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "slaves pre-operational")
    for s in tb.slaves:
        s.write(0x1017, 0, 2)  # heartbeats every 2 ms: receive traffic during the faults


def resets(tb: SystemTB) -> list[int]:
    """Start times of the RESET instructions the chip received."""
    return [t.t_start_ps for t in tb.pins.slave.transactions if t.mosi[:1] == b"\xc0"]


def check_syncs(tb: SystemTB, t_from: int, n_min: int, overflow: int) -> None:
    """At least ``n_min`` SYNC frames after ``t_from``, each ID 080h with the right DLC."""
    syncs = [r for r in tb.frames(0x080) if r.t_start_ps >= t_from]
    assert len(syncs) >= n_min, f"{len(syncs)} SYNCs after {t_from} ps"
    for r in syncs:
        assert r.sender == CHIP and not r.msg.is_remote_frame
        if overflow >= 2:
            assert r.msg.dlc == 1 and 1 <= r.msg.data[0] <= overflow, r.msg
        else:
            assert r.msg.dlc == 0, r.msg


def check_clean(tb: SystemTB) -> None:
    own_000 = [r for r in tb.frames(0x000) if r.sender == CHIP]
    assert own_000 == [], f"the master sent ID 000h frames: {own_000}"
    tb.check_models_clean()


async def wait_syncs(tb: SystemTB, t_from: int, n: int) -> None:
    await tb.wait_for(lambda: len([r for r in tb.frames(0x080) if r.t_start_ps >= t_from]) >= n,
                      20_000, 20, f"{n} SYNCs")


# ============================================================================== tests
@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_reinit_while_sync_runs(dut):
    """Purpose: CTRL.REINIT while SYNC runs never fires an unloaded TXB2, and clears CAN_STATUS.

    Verifies: three re-inits at different phases of a 400 us SYNC period (counter 1..4), each
    after CRC errors made TEC > 0: CAN_STATUS reads TEC/REC/EFLG = 0 as soon as the RESET
    instruction is on the SPI bus, the strict chip model sees no TXnRTS request of an unwritten
    buffer, the master sends no ID 000h frame, and SYNC resumes with ID 080h, DLC 1 and a
    counter byte in 1..4; every SYNC the master counted was a TX2RTS# pulse (none was asked for
    while TXB2 was unloaded).
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    pins = SyncPinCounter(dut)
    await boot(tb)
    await tb.host.sync_config(period_us=400, overflow=4)
    await wait_syncs(tb, 0, 5)
    for k in range(3):
        tb.bus.corrupt_next_frame(sender=CHIP, count=2)
        await tb.wait_for(lambda: tb.chip.tec >= 16, 5_000, 5, "CRC errors")
        await Timer(BOUND_US, "us")
        assert (await tb.host.read("CAN_STATUS")) & 0xFF > 0, "TEC of the CRC errors not shown"
        await Timer(50 + 137 * k, "us")
        n_rst = len(resets(tb))
        await tb.host.reinit()
        await tb.wait_for(lambda n=n_rst: len(resets(tb)) > n, 2_000, 1, "RESET instruction")
        assert await tb.host.read("CAN_STATUS") == 0, "CAN_STATUS not cleared by the RESET"
        t_init = sim_time_ps()
        await tb.wait_master_ready()
        await wait_syncs(tb, t_init, 4)
        check_syncs(tb, t_init, 4, 4)
    await check_every_sync_fired(tb, pins)
    check_clean(tb)
    await Timer(1, "ns")


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_init_retry_while_sync_runs(dut):
    """Purpose: an initialisation attempt that fails (chip stays in configuration mode) and is
    retried from RESET while SYNC runs never fires an unloaded TXB2.

    Verifies: after CTRL.REINIT the first mode request is ignored by the chip, the controller
    polls MODE_POLL_MAX times, sends RESET again and succeeds; no violation of the strict chip
    model, no ID 000h frame from the master, SYNC resumes (ID 080h, DLC 0), SYNC_COUNT equals
    the TX2RTS# pulses.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    pins = SyncPinCounter(dut)
    await boot(tb)
    await tb.host.sync_config(period_us=300)
    await wait_syncs(tb, 0, 3)
    ignore = {"n": 0}
    original = tb.chip._request_mode

    def request_mode(reqop, t):
        if ignore["n"] > 0:
            ignore["n"] -= 1
            return []
        return original(reqop, t)

    tb.chip._request_mode = request_mode
    ignore["n"] = 1
    n_rst = len(resets(tb))
    await tb.host.reinit()
    await tb.wait_for(lambda: len(resets(tb)) >= n_rst + 2, 5_000, 5, "retry from RESET")
    t_retry = sim_time_ps()
    await tb.wait_master_ready()
    assert len(resets(tb)) == n_rst + 2 and ignore["n"] == 0
    await wait_syncs(tb, t_retry, 5)
    check_syncs(tb, t_retry, 5, 0)
    await check_every_sync_fired(tb, pins)
    check_clean(tb)
    await Timer(1, "ns")


@cocotb.test(timeout_time=300, timeout_unit="ms")
async def run_error_passive_and_active_followed(dut):
    """Purpose: STATUS and CAN_STATUS follow the chip's error state within the bound.

    Verifies: 28 CRC errors on the master's SYNCs make the chip error-passive (TEC >= 128); the
    host reads STATUS.ERR_PASSIVE = 1 and the chip's TEC; each later successful SYNC lowers TEC
    by 1 (no error interrupt) until the chip is error-active and below the warning limit again,
    and the host reads ERR_PASSIVE = 0 and the new TEC. Every value the host read (TEC, REC,
    EFLG, ERR_PASSIVE, BUS_OFF), sampled every 25 us, was held by the chip at most BOUND_US
    before.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot(tb)
    await tb.host.sync_config(period_us=100)
    await wait_syncs(tb, 0, 3)
    view = ErrorView(tb)
    await Timer(10, "us")  # a first sample of the chip before the fault
    tb.bus.corrupt_next_frame(sender=CHIP, count=28)
    await tb.wait_for(lambda: tb.chip.error_state == "error_passive", 10_000, 5, "passive")
    await tb.wait_for(lambda: tb.chip.tec < 96, 40_000, 50, "TEC below the warning limit")
    await Timer(2 * BOUND_US, "us")
    view.running = False
    await Timer(50, "us")
    assert view.saw(4, lambda v: v == 1), "STATUS.ERR_PASSIVE never 1"
    assert view.saw(0, lambda v: v >= 200), "CAN_STATUS.TEC never showed the passive TEC"
    last = view.host_log[-1][1]
    assert last[4] == 0 and last[0] < 96, f"still passive or warning: {last}"
    lag = view.staleness_us()
    dut._log.info(f"error state: host view at most {lag:.0f} us old (bound {BOUND_US} us)")
    assert lag <= BOUND_US, f"host error state {lag:.0f} us old"
    check_clean(tb)
    await Timer(1, "ns")


@cocotb.test(timeout_time=300, timeout_unit="ms")
async def run_bus_off_shown_and_recovered(dut):
    """Purpose: bus-off shows in STATUS.BUS_OFF; the chip's own recovery is waited for, a chip
    that does not recover is re-initialised after the bound, and SYNC resumes both ways.

    Verifies: (1) bus-off with the chip's automatic recovery (1408 bit times): the host reads
    STATUS.BUS_OFF = 1 during it and 0 after it, within BOUND_US; the master sends no RESET;
    SYNC resumes (ID 080h, DLC 1, counter 1..4). (2) bus-off without recovery: BUS_OFF = 1
    until the master re-initialises the chip, 20 480 us (128 frames of 160 bits) after the
    bus-off plus at most BOUND_US; CAN_STATUS and BUS_OFF are 0 after the RESET; SYNC resumes;
    no violation of the strict chip model, no ID 000h frame from the master, SYNC_COUNT equals
    the TX2RTS# pulses.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    pins = SyncPinCounter(dut)
    await boot(tb)
    await tb.host.sync_config(period_us=500, overflow=4)
    await wait_syncs(tb, 0, 3)
    view = ErrorView(tb)
    await Timer(10, "us")  # a first sample of the chip before the fault
    # (1) automatic recovery
    n_rst = len(resets(tb))
    t_off = sim_time_ps()
    tb.bus.force_bus_off(tb.chip)
    rec_us = BUS_OFF_RECOVERY_BITS  # 1 bit = 1 us at 1 Mbit/s
    await Timer(rec_us + BOUND_US, "us")
    assert tb.chip.error_state == "error_active"
    assert len(resets(tb)) == n_rst, "bus-off with recovery must not re-initialise the chip"
    on = [t for t, v in view.host_log if v[3] == 1]
    assert on, "STATUS.BUS_OFF never 1 during the bus-off"
    assert on[0] - t_off <= BOUND_US * PS_PER_US
    assert view.host_log[-1][1][3] == 0, "STATUS.BUS_OFF still 1 after the recovery"
    await wait_syncs(tb, t_off + rec_us * PS_PER_US, 3)
    check_syncs(tb, t_off, 3, 4)
    # (2) no recovery: the master re-initialises the chip after the bound
    tb.chip.auto_bus_off_recovery = False
    t_off = sim_time_ps()
    tb.bus.force_bus_off(tb.chip)
    await tb.wait_for(lambda: len(resets(tb)) > n_rst, BUSOFF_REINIT_US + 2 * BOUND_US, 10,
                      "re-initialisation after a bus-off without recovery")
    t_rst = resets(tb)[n_rst]
    tb.chip.auto_bus_off_recovery = True
    delay_us = (t_rst - t_off) / PS_PER_US
    dut._log.info(f"bus-off without recovery: RESET {delay_us:.1f} us after the bus-off")
    assert BUSOFF_REINIT_US <= delay_us <= BUSOFF_REINIT_US + BOUND_US, delay_us
    assert all(v[3] == 1 for t, v in view.host_log if t_off + BOUND_US * PS_PER_US < t < t_rst)
    assert await tb.host.read("CAN_STATUS") == 0
    assert not await tb.host.read("STATUS") & R.STATUS_BUS_OFF
    await tb.wait_master_ready()
    t_init = sim_time_ps()
    await wait_syncs(tb, t_init, 4)
    check_syncs(tb, t_init, 4, 4)
    view.running = False
    await Timer(50, "us")
    lag = view.staleness_us()
    dut._log.info(f"bus-off: host view at most {lag:.0f} us old (bound {BOUND_US} us)")
    assert lag <= BOUND_US, f"host error state {lag:.0f} us old"
    await check_every_sync_fired(tb, pins)
    check_clean(tb)
    await Timer(1, "ns")


# ======================================================= busy bus: receive while TX waits
#: flood frame: DLC 0 (the shortest frame, 47 us at 1 Mbit/s: the fastest arrival rate), an id
#: that is no CANopen service of the master (counted as unexpected, St4 -> St1, G3) and that
#: wins arbitration against the master's SDO/NMT (6xxh) or, below 080h, also its SYNC
FLOOD_ID_SDO, FLOOD_ID_SYNC = 0x110, 0x050
#: a received frame waits at most one RX read per FIFO slot before St12 hands its frame over
#: (4 frames of 47 us); far below the length of the floods (3 ms)
ST12_BOUND_US = 250


async def boot_quiet(tb: SystemTB) -> None:
    """Reset and boot-up, no heartbeats: during the floods only they and the master send."""
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "slaves pre-operational")


def flood(n: int, can_id: int) -> list[can.Message]:
    return [can.Message(arbitration_id=can_id, is_extended_id=False, dlc=0) for _ in range(n)]


def st12_dwell_us(tb: SystemTB, t_from: int) -> float:
    """Longest stay in St12 since ``t_from``."""
    log = [(t, s) for t, s in tb.fsm.log if t >= t_from] + [(sim_time_ps(), None)]
    worst = max((t1 - t0 for (t0, s), (t1, _) in zip(log, log[1:]) if s == State.S_CAN_TX),
                default=0)
    return worst / PS_PER_US


async def check_flood_received(tb: SystemTB, t_from: int, cnt0: dict[str, int]) -> None:
    """Every frame the chip received since ``t_from`` (the bus idle before) reached the host's
    counters, no overflow, St12 never held longer than ST12_BOUND_US."""
    cnt = await tb.host.counters()
    # the bus is idle before the flood; the models' SOF may lie a little before the time the
    # bench queued the frame, so the window starts 500 us early
    t_win = t_from - 500 * PS_PER_US
    others = [r for r in tb.frames() if r.t_start_ps >= t_win and CHIP in r.receivers]
    dwell = st12_dwell_us(tb, t_from)
    tb.dut._log.info(f"busy bus: {len(others)} frames of other nodes, RX_FRAMES "
                     f"+{cnt['rx_frames'] - cnt0['rx_frames']}, RX_OVERFLOW "
                     f"+{cnt['rx_overflow'] - cnt0['rx_overflow']}, longest St12 {dwell:.1f} us")
    assert cnt["rx_overflow"] == cnt0["rx_overflow"], "frames lost in the MCP2510 (RX overflow)"
    assert cnt["rx_frames"] - cnt0["rx_frames"] == len(others), "received frames missing"
    assert dwell <= ST12_BOUND_US, f"St12 held {dwell:.1f} us (bound {ST12_BOUND_US} us)"


async def sdo_upload_outcome(tb: SystemTB, node: int, timeout_ms: int, chan: int = 0):
    """The transfer's exception (None on success) and the time its DONE was seen."""
    try:
        await tb.host.sdo_upload(node, 0x1000, 0, timeout_ms=timeout_ms, chan=chan)
    except Exception as e:  # noqa: BLE001 - the outcome is checked by the caller
        return e, sim_time_ps()
    return None, sim_time_ps()


async def wait_request_in_txb1(tb: SystemTB) -> None:
    """Until the chip shows TXB1 (the SDO request's buffer) requested."""
    await tb.wait_for(lambda: tb.chip.peek(MR.TXB1CTRL) & MR.TXBNCTRL_TXREQ, 1_000, 2,
                      "SDO request in TXB1")


async def forge_while_request_waits(tb: SystemTB, n_flood: int, data: bytes):
    """A flood of ``n_flood`` 0-byte frames (id 110h) keeps channel 0's upload request to node 2
    in TXB1; a forged response 582h with ``data`` goes out third in the flood. Returns the
    transfer's outcome (sdo_upload_outcome) 1 ms after the flood."""
    tb.raw.send(*flood(n_flood, FLOOD_ID_SDO))
    xfer = cocotb.start_soon(sdo_upload_outcome(tb, 2, 100))
    await wait_request_in_txb1(tb)
    forged = can.Message(arbitration_id=0x582, is_extended_id=False, data=data)
    tb.raw.queue.insert(2, forged)
    await tb.wait_for(lambda: not tb.raw.queue, 10_000, 20, "flood sent")
    await Timer(1_000, "us")
    return await xfer


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rx_kept_while_sdo_reply_waits(dut):
    """Purpose: the master keeps receiving while an SDO reply waits for TXB1 (fuzz finding 2).

    Verifies: T13/T11/T15/T28 only with the reply's TX buffer free, else T25 and the reply from
    St1 (T21) later. A flood of 0-byte frames (id 110h, they win every arbitration against the
    master's 602h) keeps the SDO upload request in TXB1; a forged response (scs 7) makes the
    client abort, whose frame needs TXB1 as well. The FSM must not wait in St12 for TXB1 (it
    would, for the rest of the 3 ms flood, and the chip's receive buffers would overflow): no
    RX overflow, every frame of the flood counted in CNT_RX_FRAMES, St12 at most
    ST12_BOUND_US; the transfer ends with abort 0504 0001h sent by the client. Fuzz finding 3:
    the upload request still waiting in TXB1 when the client aborted is cancelled (BIT MODIFY
    TXB1CTRL.TXREQ = 0) before the abort is loaded: the only frame 602h on the bus is the abort,
    sent within 200 us after the flood.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    cnt0 = await tb.host.counters()
    t0 = sim_time_ps()
    exc, _ = await forge_while_request_waits(tb, 64, bytes([0xE0, 0, 0x10, 0, 0, 0, 0, 0]))
    assert isinstance(exc, SdoAbort), f"the transfer ended with {exc!r}"
    assert exc.code == 0x05040001 and exc.sent_by_client, exc
    # fuzz finding 3: the request of the ended transfer was cancelled in TXB1, only the abort
    # frame of node 2's transfer reaches the bus, and it goes right after the flood
    sdo = [r for r in tb.frames(0x602) if r.t_start_ps >= t0]
    assert [r.msg.data[0] for r in sdo] == [0x80], f"frames 602h after the abort: {sdo}"
    flood_end = max(r.t_end_ps for r in tb.frames(FLOOD_ID_SDO))
    assert sdo[0].t_start_ps - flood_end < 200 * PS_PER_US, "abort frame not sent promptly"
    await check_flood_received(tb, t0, cnt0)
    check_clean(tb)
    await Timer(1, "ns")


#: DONE of a transfer ended by a server abort while its request waits in TXB1, after the end of
#: the abort frame: St6, the cancel (BIT MODIFY TXB1CTRL, READ STATUS one longest frame of 192
#: bits later, 192 us at 1 Mbit/s), the withdraw acknowledge and the driver's DONE poll
SRV_ABORT_DONE_US = 500


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_sdo_request_withdrawn_after_server_abort(dut):
    """Purpose: a transfer ended by a server abort leaves no request behind (fuzz finding 3).

    Verifies: the upload request 40h to node 2 waits in TXB1 under a flood of 0-byte frames
    (id 110h wins every arbitration); a forged server abort 582h (multiplexer 1000h:0, code
    0602 0000h) ends the transfer. canopen_sdo_channels asks the core to withdraw the request;
    the core cancels TXB1 and only then is DONE set: no frame 602h at all reaches the bus (the
    request was cancelled, a server abort needs no client frame), DONE within
    SRV_ABORT_DONE_US after the abort frame, result 0602 0000h not sent by the client,
    CNT_SDO_ABORT + 1, nothing of the flood lost.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    cnt0 = await tb.host.counters()
    t0 = sim_time_ps()
    exc, t_done = await forge_while_request_waits(
        tb, 96, bytes([0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x02, 0x06]))
    assert isinstance(exc, SdoAbort), f"the transfer ended with {exc!r}"
    assert exc.code == 0x06020000 and not exc.sent_by_client, exc
    sdo = [r for r in tb.frames(0x602) if r.t_start_ps >= t0]
    assert not sdo, f"a request of the ended transfer went on the bus: {sdo}"
    rsp = [r for r in tb.frames(0x582) if r.t_start_ps >= t0]
    assert [r.msg.data[0] for r in rsp] == [0x80], f"frames 582h: {rsp}"
    done_us = (t_done - rsp[0].t_end_ps) / PS_PER_US
    dut._log.info("DONE %.1f us after the server abort's end", done_us)
    assert 0 < done_us <= SRV_ABORT_DONE_US, f"DONE {done_us:.1f} us after the server abort"
    cnt = await tb.host.counters()
    assert cnt["sdo_abort"] - cnt0["sdo_abort"] == 1, (cnt0, cnt)
    await check_flood_received(tb, t0, cnt0)
    check_clean(tb)
    await Timer(1, "ns")


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_sdo_request_withdrawn_after_timeout(dut):
    """Purpose: a transfer ended by its timeout leaves no request behind (fuzz finding 3).

    Verifies: channel 0 uploads from node 2 (timeout 2 ms); its request waits in TXB1 under a
    flood of 0-byte frames (id 110h, 7.5 ms). Channel 1 then uploads from node 1 (timeout
    50 ms): its request is presented to the FSM and waits for TXB1 too, so channel 0's abort
    frame (0504 0000h, decided at the timeout) is not presented and times out as well. Before
    the fix the transfer then ended (DONE) with its request still in TXB1, which went on the
    bus after the flood. Now the abort decision withdraws the request (TXB1 cancelled), and
    DONE comes at the abort frame's own timeout: no frame 602h after DONE (none at all here),
    DONE within 2 x (timeout + 1) ms of the start + 1 ms, result 0504 0000h sent by the client,
    CNT_SDO_ABORT + 1; channel 1's transfer succeeds after the flood.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    # channel 1 waits for the whole flood: the driver's DONE poll budget must cover it
    tb.host.max_polls = 100_000
    cnt0 = await tb.host.counters()
    t0 = sim_time_ps()
    tb.raw.send(*flood(160, FLOOD_ID_SDO))
    xfer0 = cocotb.start_soon(sdo_upload_outcome(tb, 2, 2, chan=0))
    await wait_request_in_txb1(tb)
    t_start = sim_time_ps()
    xfer1 = cocotb.start_soon(sdo_upload_outcome(tb, 1, 50, chan=1))
    exc0, t_done0 = await xfer0
    assert tb.raw.queue, "the flood ended before channel 0's transfer"
    assert isinstance(exc0, SdoAbort), f"channel 0 ended with {exc0!r}"
    assert exc0.code == 0x05040000 and exc0.sent_by_client, exc0
    done_ms = (t_done0 - t_start) / PS_PER_US / 1000
    dut._log.info("channel 0 DONE %.3f ms after its request was in TXB1", done_ms)
    assert done_ms <= 2 * (2 + 1) + 1, f"DONE {done_ms:.3f} ms after the start"
    await tb.wait_for(lambda: not tb.raw.queue, 20_000, 20, "flood sent")
    exc1, _ = await xfer1
    assert exc1 is None, f"channel 1 ended with {exc1!r}"
    await Timer(1_000, "us")
    late = [r for r in tb.frames(0x602) if r.t_start_ps >= t_done0]
    assert not late, f"a frame of channel 0's ended transfer went on the bus after DONE: {late}"
    # the request was cancelled in TXB1 and the abort frame never taken: no frame 602h at all
    sdo = [r for r in tb.frames(0x602) if r.t_start_ps >= t0]
    assert not sdo, f"frames 602h of channel 0's transfer: {sdo}"
    cnt = await tb.host.counters()
    assert cnt["sdo_abort"] - cnt0["sdo_abort"] == 1, (cnt0, cnt)
    check_clean(tb)
    await Timer(1, "ns")


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rx_kept_while_sync_waits(dut):
    """Purpose: the master keeps receiving while the SYNC it fired waits for the bus.

    Verifies: St2 (T3) is not entered in the cycle after the TX2RTS fire, before the controller
    shows TXB2 pending (else St12 would wait for TXB2 until the SYNC is on the bus). A flood of
    0-byte frames with id 050h (they win every arbitration against SYNC 080h) runs over three
    SYNC periods of 1 ms: no RX overflow, every frame counted, St12 at most ST12_BOUND_US, and
    the SYNCs go out after the flood.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    await tb.host.sync_config(period_us=1_000)
    await wait_syncs(tb, 0, 2)
    cnt0 = await tb.host.counters()
    t0 = sim_time_ps()
    tb.raw.send(*flood(64, FLOOD_ID_SYNC))
    await tb.wait_for(lambda: not tb.raw.queue, 10_000, 20, "flood sent")
    t1 = sim_time_ps()
    await wait_syncs(tb, t1, 2)
    await check_flood_received(tb, t0, cnt0)
    check_clean(tb)
    await Timer(1, "ns")



#: flood id that beats the master's TPDOs (201h, 282h) and loses to its SYNC (080h)
FLOOD_ID_PDO = 0x100


async def flood_over_two_fires(tb: SystemTB) -> tuple[int, int, int]:
    """A 0-byte flood of id 100h from 200 us before a SYNC fire (1 ms period) to about 1.7 ms
    after it: the SYNCs win, the master's PDOs wait. Returns the SOF times of the first three
    SYNC frames from the flood's start on."""
    t_s = tb.sync_sof_times()[-1]
    await Timer(t_s + 800 * PS_PER_US - sim_time_ps(), "ps")
    t_f = sim_time_ps()
    tb.raw.send(*flood(40, FLOOD_ID_PDO))
    await tb.wait_for(lambda: not tb.raw.queue, 10_000, 20, "flood sent")
    await wait_syncs(tb, t_f, 3)
    s1, s2, s3 = [t for t in tb.sync_sof_times() if t > t_f][:3]
    return s1, s2, s3


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_sync_tpdo_withdrawn_when_sync_fires(dut):
    """Purpose: a synchronous TPDO still waiting in TXB0 when the next SYNC fires would go out
    after that SYNC, in the next cycle (slaves would apply it one cycle late): the master
    cancels it and counts it late; an event TPDO is never withdrawn.

    Verifies: TT 1 TPDO 201h, SYNC every 1 ms; a flood of 100h frames (beats 201h, loses to
    080h) over two SYNC fires keeps the first cycle's TPDO in TXB0 at the second fire: no 201h
    frame between the first and the second SYNC, exactly one (the second cycle's) between the
    second and the third, PDO_CNT_LATE = 1 and the channel's LATE = 1 (without the cancel both
    frames follow the second SYNC and nothing is counted). Then an event TPDO (TT 255, 282h)
    triggered in the same kind of flood is in TXB0 at a fire and is sent once, after the
    flood; LATE stays 1; SYNC frames follow their fires (no model violation).
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    host = tb.host
    await host.tpdo_config(0, 0x201, 6, 1)
    await host.tpdo_config(1, 0x282, 2, 255)
    await host.sync_config(period_us=1_000)
    await wait_syncs(tb, 0, 3)
    assert (await host.pdo_counters())["late"] == 0
    s1, s2, s3 = await flood_over_two_fires(tb)

    def n_201(t_a: int, t_b: int) -> int:
        return sum(1 for r in tb.frames(0x201) if t_a < r.t_start_ps < t_b)

    got = (n_201(s1, s2), n_201(s2, s3))
    dut._log.info("TPDO 201h frames after SYNC 1 / SYNC 2 of the flood: %s", got)
    assert got == (0, 1), got
    assert (await host.pdo_counters())["late"] == 1
    assert (await host.tpdo_status(0))["late"] == 1
    # an event TPDO waiting in TXB0 at a fire is not withdrawn
    await host.tpdo_config(0, 0x201, 6, 1, valid=False)
    await wait_syncs(tb, sim_time_ps(), 1)
    n_282 = len(tb.frames(0x282))
    t_s = tb.sync_sof_times()[-1]
    await Timer(t_s + 900 * PS_PER_US - sim_time_ps(), "ps")
    tb.raw.send(*flood(40, FLOOD_ID_PDO))
    await Timer(20, "us")
    await host.tpdo_write(1, b"\x5a\xa5", trigger=True)
    await tb.wait_for(lambda: not tb.raw.queue, 10_000, 20, "flood sent")
    await tb.wait_for(lambda: len(tb.frames(0x282)) > n_282, 5_000, 20, "event TPDO")
    await wait_syncs(tb, sim_time_ps(), 2)
    ev = tb.frames(0x282)[n_282:]
    assert len(ev) == 1 and bytes(ev[0].msg.data) == b"\x5a\xa5", ev
    fires_before = [t for t in tb.sync_sof_times() if t_s < t < ev[0].t_start_ps]
    assert len(fires_before) >= 1, "the event TPDO was not in TXB0 at a SYNC"
    assert (await host.pdo_counters())["late"] == 1
    assert (await host.tpdo_status(1))["late"] == 0
    check_clean(tb)
    await Timer(1, "ns")


#: documented bound from a RESET# pulse the master did not cause to its RESET instruction (error
#: poll interval 500 us + SPI work ahead of the poll, docs/mcp2510_ctrl.md "Chip lost")
CHIP_LOST_BOUND_US = 700


async def reset_chip_and_await_recovery(tb: SystemTB, what: str) -> float:
    """Pulse the chip's RESET pin now, wait for the master's RESET instruction and assert it
    came within CHIP_LOST_BOUND_US, then wait until the master is ready again. Returns the
    latency from the pulse to the RESET instruction in us."""
    n_rst = len(resets(tb))
    t_glitch = sim_time_ps()
    tb.chip.reset_pin(t_glitch)
    await tb.wait_for(lambda: len(resets(tb)) > n_rst, 2 * CHIP_LOST_BOUND_US, 1,
                      "RESET instruction after the chip reset")
    lat_us = (resets(tb)[n_rst] - t_glitch) / PS_PER_US
    tb.dut._log.info("chip reset %s: RESET instruction %.1f us after the pulse", what, lat_us)
    assert lat_us <= CHIP_LOST_BOUND_US, f"detected after {lat_us:.1f} us"
    await tb.wait_master_ready()
    return lat_us


def check_chip_resets_clean(tb: SystemTB) -> None:
    """After RESET-pin pulses: no ID 000h frame from the master, no chip violation except the
    accesses the chip ignored around the pulse and during its start-up, no SPI pin violation."""
    own_000 = [r for r in tb.frames(0x000) if r.sender == CHIP]
    assert own_000 == [], f"the master sent ID 000h frames: {own_000}"
    other = [v for v in tb.chip.violations if "RESET pin" not in v
             and "oscillator start-up time" not in v]
    assert other == [], other
    assert tb.pins.slave.violations == [], tb.pins.slave.violations


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_chip_reset_detected_and_reinitialised(dut):
    """Purpose: a reset of the MCP2510 through its RESET pin that the master did not cause
    (glitch, brown-out) is detected by the error poll, reported and recovered from.

    Verifies: RESET pin pulses at an SCK rising edge at three phases of a 400 us SYNC period
    (heartbeats of two slaves on the bus): the master's RESET instruction follows within
    CHIP_LOST_BOUND_US, CNT_CAN_ERROR counts each loss, IRQ_STATUS.CAN_ERROR and INIT are set,
    SYNC comes back (ID 080h, DLC 0) and its TX2RTS# pulses are exactly one period apart again,
    the master sends no ID 000h frame, and the chip model sees no violation except the SPI
    accesses the chip ignored during its own start-up time right after the pulse (the master
    cannot know of the reset before its next poll).
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    tb.chip.strict = False
    pins = SyncPinCounter(dut)
    fires: list[int] = []

    async def fire_log() -> None:
        prev = 1
        while True:
            await ValueChange(dut.mcp_txrts_n_o)
            v = dut.mcp_txrts_n_o.value
            now = int(v) >> 2 & 1 if v.is_resolvable else 1
            if prev == 1 and now == 0:
                fires.append(sim_time_ps())
            prev = now

    cocotb.start_soon(fire_log())
    await boot(tb)
    period = 400
    await tb.host.sync_config(period_us=period)
    await wait_syncs(tb, 0, 3)
    ctrl = await tb.host.read("CTRL")  # keep SYNC_EN
    await tb.host.write("CTRL", ctrl | R.CTRL_CLR_COUNTERS)
    for k in range(3):
        await tb.host.write("IRQ_STATUS", 0xFF)
        await Timer(97 + 131 * k, "us")
        for _ in range(1 + 37 * k):
            await RisingEdge(dut.spi_sck_o)
        await reset_chip_and_await_recovery(tb, str(k))
        t_init = sim_time_ps()
        await wait_syncs(tb, t_init, 4)
        check_syncs(tb, t_init, 4, 0)
        after = [t for t in fires if t >= t_init][1:]  # the first may be a late fire
        steps = {b - a for a, b in zip(after, after[1:])}
        assert steps == {period * PS_PER_US}, f"SYNC fire intervals after re-init: {steps}"
        irq = await tb.host.read("IRQ_STATUS")
        assert irq & R.IRQ_STATUS_CAN_ERROR and irq & R.IRQ_STATUS_INIT, hex(irq)
        assert await tb.host.read("CNT_CAN_ERROR") == k + 1
    await check_every_sync_fired(tb, pins)
    check_chip_resets_clean(tb)
    await Timer(1, "ns")


async def wait_int_read_address(dut) -> None:
    """Return at the SCK rising edge of the first address bit of the master's next INT read: a
    READ (03h) that starts while INT# is low (read from the pins; RX buffers are signalled on
    RXnBF#, so a READ started under INT# is the CANINTF/EFLG read)."""
    while True:
        await ValueChange(dut.spi_cs_n_o)
        if int(dut.spi_cs_n_o.value) != 0 or int(dut.mcp_int_n_i.value) != 0:
            continue
        instr = 0
        for _ in range(8):
            await RisingEdge(dut.spi_sck_o)
            instr = (instr << 1) | int(dut.spi_mosi_o.value)
        if instr == 0x03:
            await RisingEdge(dut.spi_sck_o)
            if int(dut.spi_cs_n_o.value) == 0:
                return


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_chip_reset_during_int_read(dut):
    """Purpose: a RESET-pin pulse of the MCP2510 while the master sends the address byte of its
    INT read (READ of CANINTF/EFLG at 2Ch): the chip abandons the access and releases SO, which
    the board pulls up, so both bytes read FFh (fuzz seed 1002: with SO floating the unknown bits
    became the mask of the following BIT MODIFY of CANINTF, an undefined byte on MOSI).

    Verifies, for two pulses: MOSI never carries an unknown level (the pin bridge fails the test
    on one), the master's RESET instruction follows within CHIP_LOST_BOUND_US, CNT_CAN_ERROR
    grows by 1 or 2 per loss (the loss, plus the ERRIF of the FFh INT read the reset cut short),
    SYNC resumes (ID 080h, DLC 0), no ID 000h frame from the master, and no
    chip violation except the accesses the chip ignored during its own start-up.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    tb.chip.strict = False
    await boot(tb)
    await tb.host.sync_config(period_us=400)
    await wait_syncs(tb, 0, 3)
    ctrl = await tb.host.read("CTRL")  # keep SYNC_EN
    await tb.host.write("CTRL", ctrl | R.CTRL_CLR_COUNTERS)
    cnt = 0
    for k in range(2):
        await wait_int_read_address(dut)
        await reset_chip_and_await_recovery(tb, f"{k} in an INT read")
        t_init = sim_time_ps()
        await wait_syncs(tb, t_init, 3)
        check_syncs(tb, t_init, 3, 0)
        now = await tb.host.read("CNT_CAN_ERROR")
        assert now - cnt in (1, 2), f"CNT_CAN_ERROR {cnt} -> {now} for chip reset {k}"
        cnt = now
    check_chip_resets_clean(tb)
    await Timer(1, "ns")


async def wait_txb_load_address(dut) -> int:
    """Return at the SCK rising edge of the last address bit of the master's next WRITE that
    loads TXB0 or TXB1 (address 30h/31h/40h/41h: a frame to send, RTS follows); returns the
    buffer number."""
    while True:
        await ValueChange(dut.spi_cs_n_o)
        if int(dut.spi_cs_n_o.value) != 0:
            continue
        word = 0
        for _ in range(16):
            await RisingEdge(dut.spi_sck_o)
            word = (word << 1) | int(dut.spi_mosi_o.value)
        if word >> 8 == 0x02 and word & 0xFF in (0x30, 0x31, 0x40, 0x41):
            return ((word & 0xFF) >> 4) - 3


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_chip_reset_between_tx_load_and_rts(dut):
    """Purpose: a RESET-pin pulse of the MCP2510 while the master loads a transmit buffer
    (fuzz seed 1000): the chip drops the rest of the WRITE, is ready again before the WRITE
    ends, and the master's RTS requests a buffer not written since the reset. In configuration
    mode the chip does not transmit; the master's re-initialisation starts with the RESET
    instruction, which clears the request, so the undefined buffer never reaches the bus.

    Verifies, for two pulses (SDO requests of channel 0, TXB1): the RTS reached the chip after
    its start-up time with the request pending in configuration mode (the scenario happened);
    the master's RESET instruction follows within CHIP_LOST_BOUND_US and the request is gone
    after it; the chip model (it checks a request made in configuration mode when the chip
    enters a mode that transmits) sees no violation but the accesses ignored around the
    pulse; the master sends no frame but SYNC 080h and SDO requests 601h/602h (no undefined
    contents); the SDO transfer ends (success, or abort/timeout); SYNC resumes.
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    tb.chip.strict = False
    await boot(tb)
    await tb.host.sync_config(period_us=400)
    await wait_syncs(tb, 0, 3)
    t0 = sim_time_ps()
    for k in range(2):
        n_rst = len(resets(tb))
        up = cocotb.start_soon(sdo_upload_outcome(tb, 1 + k, 20))
        n = await wait_txb_load_address(dut)
        t_glitch = sim_time_ps()
        tb.chip.reset_pin(t_glitch)
        ctrl = MR.TXB0CTRL + 0x10 * n
        await tb.wait_for(lambda c=ctrl, n0=n_rst: tb.chip.peek(c) & MR.TXBNCTRL_TXREQ or
                          len(resets(tb)) > n0, 100, 0.2, "the RTS after the load")
        assert tb.chip.peek(ctrl) & MR.TXBNCTRL_TXREQ, "the RTS did not reach the chip"
        assert tb.chip.opmode == MR.OPMODE_CONFIG
        assert sim_time_ps() - t_glitch >= tb.chip.ost_ps
        await tb.wait_for(lambda n0=n_rst: len(resets(tb)) > n0, 2 * CHIP_LOST_BOUND_US, 1,
                          "RESET instruction after the chip reset")
        lat_us = (resets(tb)[n_rst] - t_glitch) / PS_PER_US
        dut._log.info("chip reset %d in the load of TXB%d: RESET instruction %.1f us after "
                      "the pulse", k, n, lat_us)
        assert lat_us <= CHIP_LOST_BOUND_US, f"detected after {lat_us:.1f} us"
        assert not tb.chip.peek(ctrl) & MR.TXBNCTRL_TXREQ
        await tb.wait_master_ready()
        t_init = sim_time_ps()
        await wait_syncs(tb, t_init, 3)
        check_syncs(tb, t_init, 3, 0)
        await up
        err, _ = up.result()
        dut._log.info("SDO upload %d: %s", k, err or "done")
    own = {r.msg.arbitration_id for r in tb.frames() if r.sender == CHIP and r.t_start_ps > t0}
    assert own <= {0x080, 0x601, 0x602}, f"unexpected frames of the master: {sorted(own)}"
    check_chip_resets_clean(tb)
    await Timer(1, "ns")


class _RecordHook(list):
    """The bus's record list, calling ``hook(record)`` when a record is appended (at the end of
    the record's intermission, before the next arbitration)."""

    def __init__(self, items, hook) -> None:
        super().__init__(items)
        self.hook = hook

    def append(self, rec) -> None:
        super().append(rec)
        self.hook(rec)


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_tx_error_counted_once(dut):
    """Purpose: CNT_TX_ERROR counts each destroyed frame of the master exactly once, also when
    frames of other nodes get error frames while the master's frame waits for its retry.

    Verifies: two rounds on a quiet bus (the master sends only SYNCs, 1 ms period): the master's
    SYNC is destroyed by CRC errors (round 1: once, round 2: three times in a row), and right
    after its (last) error frame a raw node queues two frames with ID 010h (they win against
    the retry) whose next 3 attempts are destroyed too (MERRF for other nodes' errors while
    TXB2 waits with TXERR set). CNT_TX_ERROR equals the error frames of the master's own frames
    on the bus after each round (1, then 4).
    """
    tb = SystemTB(dut, node_ids=(1, 2))
    await boot_quiet(tb)
    await tb.host.sync_config(period_us=1000)
    await wait_syncs(tb, 0, 2)
    ctrl = await tb.host.read("CTRL")  # keep SYNC_EN
    await tb.host.write("CTRL", ctrl | R.CTRL_CLR_COUNTERS)
    t0 = sim_time_ps()
    state = {"left": 0, "raw": 0}

    def hook(rec) -> None:
        if rec.kind == "error" and rec.sender == CHIP and state["left"] > 0:
            state["left"] -= 1
            if state["left"] == 0:
                tb.raw.send(*[can.Message(arbitration_id=0x010, is_extended_id=False, dlc=2,
                                          data=b"\x01\x02") for _ in range(state["raw"])])
                tb.bus.corrupt_next_frame(sender="raw", count=3)

    tb.bus.records = _RecordHook(tb.bus.records, hook)
    for k, (own, raw) in enumerate(((1, 2), (3, 2))):
        state["left"], state["raw"] = own, raw
        tb.bus.corrupt_next_frame(sender=CHIP, count=own)
        await tb.wait_for(lambda: state["left"] == 0 and not tb.raw.queue, 10_000, 10,
                          "the round's frames")
        t_round = sim_time_ps()
        await wait_syncs(tb, t_round, 2)
        await Timer(BOUND_US, "us")
        recs = [r for r in tb.bus.records if r.t_start_ps >= t0]
        own_err = sum(1 for r in recs if r.kind == "error" and r.sender == CHIP)
        raw_err = sum(1 for r in recs if r.kind == "error" and r.sender == "raw")
        cnt = await tb.host.read("CNT_TX_ERROR")
        dut._log.info("round %d: master frames destroyed %d, raw frames destroyed %d, "
                      "CNT_TX_ERROR %d", k, own_err, raw_err, cnt)
        assert raw_err == 3 * (k + 1), raw_err
        assert own_err == (1, 4)[k], own_err
        assert cnt == own_err, f"CNT_TX_ERROR {cnt}, master frames destroyed {own_err}"
    check_clean(tb)
    await Timer(1, "ns")

# ============================================================================ pytest entry
@pytest.mark.sim
def test_canopen_master_chip_faults(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_canopen_master_chip_faults",
               name=request.node.name, parameters=SYSTEM, stop_time_ms=3000,
               ieee_asserts="disable")
