"""PDO exchange bench (issue 6): drives on a SYNC cycle, checked PDO by PDO.

The system of ``tb/tblib/system_tb.py`` (``canopen_master_top`` RTL, behavioural MCP2510, bit-exact
CAN bus, CiA 301 reference drives) runs a cyclic set-point / feedback exchange the way a motion
controller does it:

* the master configures every drive by SDO (its own SDO client, driven by the host): RPDO1 =
  target position 607Ah + target velocity 60FFh (8 bytes, synchronous), TPDO1 = position actual
  6064h + velocity actual 606Ch (8 bytes, every SYNC), each PDO invalidated (COB-ID bit 31),
  re-mapped and validated as CiA 301 requires; then the controlword 6040h enables the drive;
* every cycle the host (Avalon driver, paced by the SYNC interrupt) commits new set-points that
  encode the cycle and the axis and reads every feedback PDO from the RPDO channels;
* the drive applies set-point k at SYNC k+1 and its CiA 402 model copies the targets into the
  actual values, so the feedback of cycle c carries the set-point of cycle c-2: cycle-dependent
  and exactly predictable.

Set-point k is the one the master sends after SYNC k (the host committed it in cycle k-1). The
checker (:func:`check_run`) compares, for every cycle and axis, what is on the bus, what each
drive received and applied (its ``rx_log``/``sync_log``/``rpdo_applied``) and what the host
read (data, SEQ + 1 per cycle, SYNC counter), and returns every discrepancy. The PDO engine's
counters and the frames per COB-ID are compared with the cycle count exactly.

``run_bench_pdo_axes`` (``make bench``) measures how many axes fit a 1 ms cycle at 1 Mbit/s
with payloads chosen for maximum bit stuffing and compares with the bus-only bound.
"""

from __future__ import annotations

import math
import os
import random
import time
from bisect import bisect_left
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import can
import cocotb
import pytest
from cocotb.triggers import RisingEdge, Timer

from sim_models.can_bus import frame_length_bits, worst_case_bits
from sim_models.canopen_slave import NmtState
from sim_models.canopen_slave.cia402 import DriveState
from sim_models.sim_time import PS_PER_MS, PS_PER_US
from tb.tblib.metrics import record
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.runner import run_cocotb
from tb.tblib.system_tb import SystemTB

#: the demo's system parameters (tb/test_demo.py): 20 MHz core clock, 5 MHz SPI, 1 Mbit/s
SYSTEM = {"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000, "OSC_FREQ_HZ": 16_000_000,
          "CAN_BITRATE_BPS": 1_000_000, "MAX_NODES": 4, "RESET_WAIT_US": 20}
#: the long runs use the CANopen-only build (OMNI_ENABLE = false): the same CANopen RTL without
#: the Omni-ID engine, which GHDL would otherwise evaluate every clock (2.7 x the wall time);
#: the default build is covered by test_pdo_cycle_rtr_and_missing and the other system benches
SYSTEM_CANOPEN_ONLY = {**SYSTEM, "OMNI_ENABLE": "false"}
N_CYCLES = 1000
#: SYNC with a counter byte (1019h): the counter is what PDO_SEQ.SYNC_COUNT stores
SYNC_OVERFLOW = 240
PDO_BYTES = 8
#: PDO_SEQ.SYNC_COUNT of a PDO received after the SYNC with counter byte c is c (this bench
#: found it was c + 1: the core passed the counter of the *next* SYNC; fixed in the core, and
#: run_rpdo_sync_count pins it). The checker compares against the preceding SYNC's counter.
RPDO_SYNC_COUNT_SKEW = 0
NMT_START = 0x01
CW_SHUTDOWN, CW_ENABLE_OPERATION = 0x0006, 0x000F


def map_entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


def cycle_bits(n_axes: int, counter: bool = True, extra_bits: int = 0) -> int:
    """Bus bits of one SYNC cycle under worst-case stuffing (3-bit intermission included):
    the SYNC (1 data byte with a counter, else 0) and per axis one 8-byte set-point and one
    8-byte feedback PDO."""
    return (worst_case_bits(1 if counter else 0) + n_axes * 2 * worst_case_bits(PDO_BYTES)
            + extra_bits)


def bits_to_us(bits: int, bitrate: int) -> int:
    return math.ceil(bits * 1_000_000 / bitrate)


def counter_of(k: int) -> int:
    """SYNC counter byte of the k-th SYNC since reset (1-based), SYNC_OVERFLOW throughout."""
    return (k - 1) % SYNC_OVERFLOW + 1


def sp_default(axis: int, k: int) -> bytes:
    """Set-point of cycle k for axis (0-based): target position = axis << 24 | k, target
    velocity = 4000_0000h | k << 4 | axis."""
    pos = axis << 24 | k
    vel = 0x4000_0000 | k << 4 | axis
    return pos.to_bytes(4, "little") + vel.to_bytes(4, "little")


# ============================================================================ host side
async def configure_drive(tb: SystemTB, node: int, *, tpdo_tt: int = 1) -> None:
    """Configure one drive by SDO from the master, the CiA 301 way (invalidate, map, validate),
    then enable it (CiA 402 controlword: shutdown, enable operation)."""
    h = tb.host
    rpdo, tpdo = 0x200 + node, 0x180 + node

    async def u32(index: int, sub: int, v: int) -> None:
        await h.sdo_download(node, index, sub, v.to_bytes(4, "little"))

    async def u8(index: int, sub: int, v: int) -> None:
        await h.sdo_download(node, index, sub, bytes([v]))

    await u32(0x1400, 1, 0x8000_0000 | rpdo)
    await u8(0x1600, 0, 0)
    await u32(0x1600, 1, map_entry(0x607A, 0, 32))
    await u32(0x1600, 2, map_entry(0x60FF, 0, 32))
    await u8(0x1600, 0, 2)
    await u8(0x1400, 2, 1)  # synchronous: applied at the next SYNC
    await u32(0x1400, 1, rpdo)
    await u32(0x1800, 1, 0x8000_0000 | tpdo)
    await u8(0x1A00, 0, 0)
    await u32(0x1A00, 1, map_entry(0x6064, 0, 32))
    await u32(0x1A00, 2, map_entry(0x606C, 0, 32))
    await u8(0x1A00, 0, 2)
    await u8(0x1800, 2, tpdo_tt)
    await u32(0x1800, 1, tpdo)
    for cw in (CW_SHUTDOWN, CW_ENABLE_OPERATION):
        await h.sdo_download(node, 0x6040, 0, cw.to_bytes(2, "little"))


async def boot_and_configure(tb: SystemTB, *, tpdo_tt: dict[int, int] | None = None,
                             start: Sequence[int] | None = None) -> None:
    """Reset, wait for the boot-ups, configure every drive by SDO, NMT-start ``start`` (all by
    default) and check inside the drives that it worked."""
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    await Timer(300, "us")
    for s in tb.slaves:
        await configure_drive(tb, s.node_id, tpdo_tt=(tpdo_tt or {}).get(s.node_id, 1))
    for s in tb.slaves:
        assert s.read(0x1600, 0) == 2 and s.read(0x1600, 2) == map_entry(0x60FF, 0, 32)
        assert s.read(0x1A00, 0) == 2 and s.read(0x1A00, 2) == map_entry(0x606C, 0, 32)
        assert s.read(0x1400, 1) == 0x200 + s.node_id and s.read(0x1400, 2) == 1
        assert s.read(0x1800, 1) == 0x180 + s.node_id
        assert s.drive_state == DriveState.OPERATION_ENABLED, (s.node_id, s.drive_state)
    nodes = [s.node_id for s in tb.slaves] if start is None else list(start)
    await nmt_start(tb, nodes)


async def nmt_start(tb: SystemTB, nodes: Sequence[int]) -> None:
    """NMT start: one command for all slaves, else one per node (NMT_CMD holds one command:
    wait until the previous one left)."""
    for node in [0] if sorted(nodes) == sorted(s.node_id for s in tb.slaves) else nodes:
        while await tb.host.nmt_busy():
            await Timer(10, "us")
        await tb.host.nmt(NMT_START, node)
    await tb.wait_for(lambda: all(tb.slave(n).nmt_state == NmtState.OPERATIONAL
                                  for n in nodes), 2_000, 10, "operational")


@dataclass
class Axis:
    """One axis of the cycle: drive ``node`` on master TPDO ``ch`` (set-point) and master RPDO
    ``ch`` (feedback). ``mode``: "sync" (drive TPDO type 1) or "rtr" (drive TPDO type 253,
    polled by the master's RPDO channel after every SYNC)."""

    node: int
    ch: int
    mode: str = "sync"


@dataclass
class HostRead:
    cycle: int
    node: int
    new: bool
    seq: int
    sync_count: int
    data: bytes


@dataclass
class Run:
    """Everything one run of cycles leaves for the checker."""

    axes: list[Axis]
    n_cycles: int
    sp: Callable[[int, int], bytes]
    t0_ps: int  #: just before the first SYNC
    period_us: int = 0
    t_end_ps: int = 0
    first_sync: int = 0  #: SYNC_COUNT before the run
    init_fb: dict[int, tuple[bytes, bytes]] = field(default_factory=dict)
    host: list[HostRead] = field(default_factory=list)
    sync_counts: list[int] = field(default_factory=list)
    wall_s: float = 0.0


def drive_values(tb: SystemTB, node: int) -> tuple[bytes, bytes]:
    """Inside the drive before a run: (actual 6064h+606Ch, what SYNC 1 will copy into them).
    The latter is the targets 607Ah+60FFh, or the synchronous RPDO1 the drive received after
    the previous run's last SYNC (it is applied at the next SYNC, before the copy)."""
    s = tb.slave(node)
    pending = s._rpdo[0].pending  # model state: (payload, t_rx) or None
    return (s.read_raw(0x6064, 0) + s.read_raw(0x606C, 0),
            pending[0] if pending is not None
            else s.read_raw(0x607A, 0) + s.read_raw(0x60FF, 0))


async def configure_master_pdos(tb: SystemTB, axes: Sequence[Axis]) -> None:
    for a in axes:
        await tb.host.tpdo_config(a.ch, 0x200 + a.node, PDO_BYTES, 1)
        if a.mode == "rtr":
            await tb.host.rpdo_config(a.ch, 0x180 + a.node, PDO_BYTES, 253, rtr_poll=True)
        else:
            await tb.host.rpdo_config(a.ch, 0x180 + a.node, PDO_BYTES, 1)


async def wait_sync_irq(tb: SystemTB) -> None:
    if int(tb.dut.irq_o.value) != 1:
        await RisingEdge(tb.dut.irq_o)


async def run_cycles(tb: SystemTB, axes: Sequence[Axis], n_cycles: int, period_us: int,
                     sp: Callable[[int, int], bytes] = sp_default, *,
                     first_read_us: float | None = None, deadline_us: float | None = None,
                     stop_on_error: bool = False) -> Run:
    """Run ``n_cycles`` SYNC cycles; SYNC is off before and after.

    Per cycle the host, woken by the SYNC interrupt, clears it, reads SYNC_COUNT, commits the
    next set-points (they go out after the next SYNC), waits until every feedback channel shows
    NEW (or until ``deadline_us`` after the SYNC) and reads the snapshot of every channel.
    ``stop_on_error``: stop at the first cycle with a missing feedback, a late TPDO or a missed
    RPDO cycle (the throughput bench).
    """
    h = tb.host
    mask = sum(1 << a.ch for a in axes)
    bitrate = tb.bitrate
    if first_read_us is None:  # the SYNC and one minimum-length PDO per feedback channel
        first_read_us = bits_to_us(worst_case_bits(1) + len(axes) * 111, bitrate)
    if deadline_us is None:
        deadline_us = period_us - 60
    run = Run(list(axes), n_cycles, sp, sim_time_ps(), period_us)
    run.init_fb = {a.node: drive_values(tb, a.node) for a in axes}
    run.first_sync = await h.read("SYNC_COUNT")
    for a in axes:
        await h.tpdo_write(a.ch, sp(a.ch, 1))
    await h.rpdo_ack(0xFFFF_FFFF)
    await h.irq_clear("SYNC")
    await h.irq_enable("SYNC")
    wall0 = time.monotonic()
    await h.sync_config(period_us, overflow=SYNC_OVERFLOW)
    for c in range(1, n_cycles + 1):
        await wait_sync_irq(tb)
        t_sync = sim_time_ps()
        await h.irq_clear("SYNC")
        count = await h.read("SYNC_COUNT")
        run.sync_counts.append(count - run.first_sync)
        if c == n_cycles:
            await h.sync_config(period_us=0, enable=False)
        else:
            for a in axes:
                await h.tpdo_write(a.ch, sp(a.ch, c + 1))
        t_first = t_sync + int(first_read_us * PS_PER_US)
        t_dead = t_sync + int(deadline_us * PS_PER_US)
        if sim_time_ps() < t_first:
            await Timer(t_first - sim_time_ps(), "ps")
        while (await h.rpdo_new()) & mask != mask and sim_time_ps() < t_dead:
            await Timer(10, "us")
        bad = False
        for a in axes:
            r = await h.rpdo_read(a.ch)
            run.host.append(HostRead(c, a.node, r["new"], r["seq"], r["sync_count"], r["data"]))
            bad |= not r["new"]
        if stop_on_error and c < n_cycles:
            late = await h.read("PDO_CNT_LATE")
            missed = await h.read("PDO_CNT_MISSED")
            if bad or late or missed or (c > 1 and not bus_cycle_complete(tb, axes)):
                run.n_cycles = c
                await h.sync_config(period_us=0, enable=False)
                break
    run.wall_s = time.monotonic() - wall0
    await h.irq_enable(0)
    await Timer(period_us, "us")  # the last cycle's frames
    run.t_end_ps = sim_time_ps()
    return run


def bus_cycle_complete(tb: SystemTB, axes: Sequence[Axis]) -> bool:
    """The bench's early stop (the bus model's view): the cycle before the last SYNC had
    exactly one set-point and one feedback frame per axis."""
    want = Counter({0x200 + a.node: 1 for a in axes} | {0x180 + a.node: 1 for a in axes})
    got: Counter = Counter()
    syncs = 0
    for r in reversed(tb.bus.records):
        if r.kind != "frame":
            continue
        cid = r.msg.arbitration_id
        if cid == 0x080:
            syncs += 1
            if syncs == 2:
                break
        elif syncs == 1 and not r.msg.is_remote_frame:
            got[cid] += 1
    return syncs == 2 and got == want


# ============================================================================ checker
def expected_feedback(run: Run, axis: Axis, c: int) -> bytes:
    """Feedback of cycle c. A synchronous TPDO is sampled at SYNC c before the set-point
    received in cycle c-1 is applied, so it carries the set-point of cycle c-2; an RTR-polled
    one is sampled when the poll arrives, after SYNC c applied set-point c-1. Before any
    set-point: the actual values before the run (c = 1, synchronous), then what SYNC 1 copied
    (c = 2 synchronous, c = 1 polled; see :func:`drive_values`)."""
    lag = 2 if axis.mode == "sync" else 1
    k = c - lag
    if k >= 1:
        return run.sp(axis.ch, k)
    actual0, target0 = run.init_fb[axis.node]
    return actual0 if axis.mode == "sync" and c == 1 else target0


def check_run(tb: SystemTB, run: Run) -> list[tuple[str, int, int, str]]:
    """Every discrepancy of the run as (where, cycle, node, what); [] when all is right.

    where = "bus": per cycle [SYNC k, SYNC k+1) exactly one set-point frame 200h+node with
    set-point k and one feedback data frame 180h+node with the expected feedback;
    "drive": drive received set-point k between its SYNC k and SYNC k+1 and applied it at
    SYNC k+1 (k < N; the last one has no next SYNC);
    "host": per cycle a NEW snapshot with the expected data, SEQ = previous SEQ + 1 and the
    SYNC counter of SYNC k.
    """
    errs: list[tuple[str, int, int, str]] = []
    n = run.n_cycles
    frames = [r for r in tb.bus.records
              if r.kind == "frame" and run.t0_ps <= r.t_start_ps < run.t_end_ps]
    syncs = [r for r in frames if r.msg.arbitration_id == 0x080]
    if len(syncs) != n:
        errs.append(("bus", 0, 0, f"{len(syncs)} SYNC frames, expected {n}"))
        return errs
    for k, r in enumerate(syncs, 1):
        if bytes(r.msg.data) != bytes([counter_of(run.first_sync + k)]):
            errs.append(("bus", k, 0, f"SYNC counter {bytes(r.msg.data).hex()}"))
    if run.sync_counts != list(range(1, n + 1)):
        errs.append(("host", 0, 0, "the host missed a SYNC interrupt"))
    bounds = [r.t_start_ps for r in syncs] + [run.t_end_ps]
    for a in run.axes:
        for cob, what, exp in ((0x200 + a.node, "set-point", lambda k, a=a: run.sp(a.ch, k)),
                               (0x180 + a.node, "feedback",
                                lambda k, a=a: expected_feedback(run, a, k))):
            per: dict[int, list[bytes]] = {}
            for r in frames:
                if r.msg.arbitration_id == cob and not r.msg.is_remote_frame:
                    k = bisect_left(bounds, r.t_start_ps + 1)
                    per.setdefault(k, []).append(bytes(r.msg.data))
            for k in range(0, n + 1):
                got = per.get(k, [])
                if k == 0:
                    if got:
                        errs.append(("bus", 0, a.node, f"{what} frames before the first SYNC"))
                    continue
                if len(got) != 1:
                    errs.append(("bus", k, a.node, f"{what} frames {len(got)}"))
                elif got[0] != exp(k):
                    errs.append(("bus", k, a.node, f"{what} {got[0].hex()} != {exp(k).hex()}"))
        # inside the drive
        s = tb.slave(a.node)
        st = [t for t, _ in s.sync_log if run.t0_ps <= t < run.t_end_ps]
        if len(st) != n:
            errs.append(("drive", 0, a.node, f"{len(st)} SYNCs consumed, expected {n}"))
            continue
        st.append(run.t_end_ps)
        rx = [(t, bytes(m.data)) for t, m in s.rx_log if run.t0_ps <= t < run.t_end_ps
              and m.arbitration_id == 0x200 + a.node and not m.is_remote_frame]
        rx_by_k: dict[int, list[bytes]] = {}
        for t, d in rx:
            rx_by_k.setdefault(bisect_left(st, t), []).append(d)
        applied = {t: p for t, pdo, p in s.rpdo_applied
                   if pdo == 1 and run.t0_ps <= t < run.t_end_ps}
        for k in range(1, n + 1):
            got = rx_by_k.get(k, [])
            if got != [run.sp(a.ch, k)]:
                errs.append(("drive", k, a.node, f"received {[g.hex() for g in got]}"))
            if k < n and applied.get(st[k]) != run.sp(a.ch, k):
                errs.append(("drive", k, a.node, "set-point not applied at SYNC k+1"))
        # the host
        prev_seq = None
        for hr in (x for x in run.host if x.node == a.node):
            if not hr.new:
                errs.append(("host", hr.cycle, a.node, "no new feedback"))
                continue
            if prev_seq is not None and hr.seq != (prev_seq + 1) & 0xFFFF:
                errs.append(("host", hr.cycle, a.node, f"SEQ {hr.seq} after {prev_seq}"))
            prev_seq = hr.seq
            if hr.sync_count != counter_of(run.first_sync + hr.cycle + RPDO_SYNC_COUNT_SKEW):
                errs.append(("host", hr.cycle, a.node, f"SYNC counter {hr.sync_count}"))
            if hr.data != expected_feedback(run, a, hr.cycle):
                errs.append(("host", hr.cycle, a.node, f"data {hr.data.hex()}"))
    return errs


def cycle_stats(tb: SystemTB, run: Run) -> dict[str, float]:
    """Bus figures of the run: load, busy time after each SYNC, the master's set-point gaps."""
    frames = [r for r in tb.bus.records
              if r.kind == "frame" and run.t0_ps <= r.t_start_ps < run.t_end_ps]
    syncs = [r.t_start_ps for r in frames if r.msg.arbitration_id == 0x080]
    busy_end, busy_wc, gaps = [], [], []
    for k, t in enumerate(syncs):
        t_next = syncs[k + 1] if k + 1 < len(syncs) else run.t_end_ps
        cyc = [r for r in frames if t <= r.t_start_ps < t_next]
        busy_end.append(max(r.t_end_ps for r in cyc) - t)
        # the same cycle with every frame at its worst-case stuffed length: each extra bit
        # delays everything after it by one bit time (the master's gaps do not depend on it)
        extra = sum(worst_case_bits(0 if r.msg.is_remote_frame else min(r.msg.dlc, 8))
                    - r.n_bits for r in cyc)
        busy_wc.append(busy_end[-1] + tb.bus.duration_ps(extra))
        for p, q in zip(cyc, cyc[1:]):
            if all(0x200 < r.msg.arbitration_id < 0x280 for r in (p, q)):
                gaps.append(q.t_start_ps - p.t_end_ps)  # bus idle between two set-points
    # SYNC start of frame behind its grid (first SYNC + (k - 1) x period): the SYNC is fired
    # on time by the TX2RTS pin but waits while a frame of the previous cycle is on the bus
    grid = run.period_us * PS_PER_US
    delay = [t - (syncs[0] + k * grid) for k, t in enumerate(syncs)]
    return {
        "bus_load_pct": round(100 * tb.bus.load(syncs[0], syncs[-1]), 2),
        "sync_delay_us_max": max(delay) / PS_PER_US,
        "cycles_with_sync_delay": sum(1 for d in delay if d > 0),
        "setpoint_gap_us_mean": round(sum(gaps) / len(gaps) / PS_PER_US, 3) if gaps else 0.0,
        "busy_after_sync_us_max": max(busy_end[:-1]) / PS_PER_US,
        "busy_after_sync_us_mean": round(sum(busy_end[:-1]) / (len(busy_end) - 1) / PS_PER_US,
                                         3),
        "busy_after_sync_us_wc_max": max(busy_wc[:-1]) / PS_PER_US,
        "setpoint_gap_us_max": max(gaps) / PS_PER_US if gaps else 0.0,
        "frame_bits_max": max(r.n_bits for r in frames),
        "frame_bits_min_pdo": min(r.n_bits for r in frames if r.msg.dlc == 8),
    }


def frames_per_cob(tb: SystemTB, run: Run) -> Counter:
    return Counter((r.msg.arbitration_id, r.msg.is_remote_frame) for r in tb.bus.records
                   if r.kind == "frame" and run.t0_ps <= r.t_start_ps < run.t_end_ps)


# ============================================================================ tests
@cocotb.test(timeout_time=3000, timeout_unit="ms")
async def run_pdo_exchange_1000_cycles(dut):
    """Purpose: 4 drives, one 8-byte set-point and one 8-byte feedback PDO each per SYNC, for
    1000 cycles at the shortest SYNC period the bus allows under worst-case stuffing.

    Verifies (exactly, every cycle and axis): set-point k is on the bus in cycle k, received by
    its drive in cycle k and applied at SYNC k+1; the drive's feedback (set-point k-2) is on the
    bus in cycle k and read by the host with SEQ + 1 and SYNC counter k; PDO engine counters
    tx = rx = 4 x 1000, late = missed = len_err = unexpected = rtr = 0; frames per COB-ID =
    1000; no error frame, no master counter error.
    """
    tb = SystemTB(dut, with_raw_node=False)
    axes = [Axis(s.node_id, ch) for ch, s in enumerate(tb.slaves)]
    bits = cycle_bits(len(axes))
    period = bits_to_us(bits, tb.bitrate)
    dut._log.info(f"cycle: SYNC {worst_case_bits(1)} + {len(axes)} x 2 x "
                  f"{worst_case_bits(PDO_BYTES)} bits (worst-case stuffing) = {bits} bits -> "
                  f"SYNC period {period} us")
    await boot_and_configure(tb)
    await configure_master_pdos(tb, axes)
    await tb.host.pdo_clear_counters()
    c0 = await tb.host.counters()
    run = await run_cycles(tb, axes, N_CYCLES, period)
    errs = check_run(tb, run)
    cnt = await tb.host.pdo_counters()
    c1 = await tb.host.counters()
    per_cob = frames_per_cob(tb, run)
    stats = cycle_stats(tb, run)
    dut._log.info(f"{N_CYCLES} cycles in {run.wall_s:.1f} s wall "
                  f"({(run.t_end_ps - run.t0_ps) / PS_PER_MS / run.wall_s:.2f} ms simulated "
                  f"per wall second); PDO counters {cnt}; bus {stats}")
    assert errs == [], f"{len(errs)} discrepancies, first: {errs[:10]}"
    n4 = len(axes) * N_CYCLES
    assert cnt == {"rx": n4, "tx": n4, "rtr": 0, "len_err": 0, "missed": 0, "late": 0,
                   "unexpected": 0}, cnt
    expected_cob = {(0x080, False): N_CYCLES}
    for a in axes:
        expected_cob[(0x200 + a.node, False)] = N_CYCLES
        expected_cob[(0x180 + a.node, False)] = N_CYCLES
    assert dict(per_cob) == expected_cob, per_cob
    assert not [r for r in tb.bus.records if r.kind == "error"], "error frames on the bus"
    for k in ("unexpected", "malformed", "rx_overflow", "tx_error", "can_error"):
        assert c1[k] == c0[k], (k, c0, c1)
    for a in axes:
        st = await tb.host.rpdo_read(a.ch)
        assert st["missed"] == 0 and st["len_err"] == 0, st
        assert (await tb.host.tpdo_status(a.ch))["late"] == 0
    tb.check_models_clean()
    await Timer(1, "ns")


@cocotb.test(timeout_time=600, timeout_unit="ms")
async def run_rtr_polled_feedback(dut):
    """Purpose: an RTR-polled feedback PDO at system level.

    Drive 1's TPDO1 gets transmission type 253 (RTR only) by SDO; the master's RPDO channel 0
    polls it with an RTR after every SYNC (PDO_CFG.RTR); drives 2..4 stay synchronous.
    Verifies over 50 cycles: one RTR 181h and one answer per cycle, the answer carrying the
    set-point applied at that cycle's SYNC (set-point k-1); every answer delivered to the host
    (SEQ + 1, SYNC counter); counters exact (tx = 4 x 50 set-points + 50 polls, rx = 4 x 50).
    """
    tb = SystemTB(dut, with_raw_node=False)
    axes = [Axis(s.node_id, ch, "rtr" if s.node_id == 1 else "sync")
            for ch, s in enumerate(tb.slaves)]
    n = 50
    # one RTR frame (no data) and the master's turnaround more than the plain cycle
    period = bits_to_us(cycle_bits(len(axes), extra_bits=worst_case_bits(0)), tb.bitrate)
    # the poll follows the four set-points (round robin) and the master leaves the bus idle
    # for about 37 us before each of its frames after the first (see "Throughput" in
    # docs/canopen_pdo_engine.md): twice the bus-only figure leaves room for both
    period = 2 * period
    await boot_and_configure(tb, tpdo_tt={1: 253})
    assert tb.slave(1).read(0x1800, 2) == 253
    await configure_master_pdos(tb, axes)
    await tb.host.pdo_clear_counters()
    run = await run_cycles(tb, axes, n, period)
    errs = check_run(tb, run)
    cnt = await tb.host.pdo_counters()
    per_cob = frames_per_cob(tb, run)
    dut._log.info(f"RTR poll: {n} cycles of {period} us; PDO counters {cnt}; "
                  f"bus {cycle_stats(tb, run)}")
    assert errs == [], f"{len(errs)} discrepancies, first: {errs[:10]}"
    assert per_cob[(0x181, True)] == n and per_cob[(0x181, False)] == n, per_cob
    # every answer follows its own poll within the cycle
    rec = [r for r in tb.bus.records if r.kind == "frame" and r.msg.arbitration_id == 0x181
           and run.t0_ps <= r.t_start_ps < run.t_end_ps]
    assert [r.msg.is_remote_frame for r in rec] == [True, False] * n
    assert cnt == {"rx": 4 * n, "tx": 5 * n, "rtr": 0, "len_err": 0, "missed": 0, "late": 0,
                   "unexpected": 0}, cnt
    tb.check_models_clean()
    await Timer(1, "ns")


@cocotb.test(timeout_time=600, timeout_unit="ms")
async def run_missing_feedback_detected(dut):
    """Purpose: the checker and the PDO engine can fail: drive 3 skips its feedback PDO in
    cycles 10..14 (fault injected in the drive model).

    Verifies: check_run reports exactly those 5 cycles (no feedback frame on the bus, no NEW
    snapshot for the host) and nothing else; PDO_CNT_MISSED = PDO_ERR.MISSED of the channel = 5;
    rx = 4 x N - 5.
    """
    tb = SystemTB(dut, with_raw_node=False)
    axes = [Axis(s.node_id, ch) for ch, s in enumerate(tb.slaves)]
    n, skip, node = 30, range(10, 15), 3
    period = bits_to_us(cycle_bits(len(axes)), tb.bitrate)
    await boot_and_configure(tb)
    await configure_master_pdos(tb, axes)
    await tb.host.pdo_clear_counters()
    drive = tb.slave(node)
    queue = drive.queue_frame
    n_sync0 = len(drive.sync_log)

    def lossy_queue(msg: can.Message, **kw) -> None:
        if msg.arbitration_id == 0x180 + node and len(drive.sync_log) - n_sync0 in skip:
            return  # the drive "forgets" its feedback of this cycle
        queue(msg, **kw)

    drive.queue_frame = lossy_queue
    run = await run_cycles(tb, axes, n, period)
    errs = check_run(tb, run)
    expected = sorted([("bus", k, node, "feedback frames 0") for k in skip]
                      + [("host", k, node, "no new feedback") for k in skip])
    assert sorted(errs) == expected, errs
    cnt = await tb.host.pdo_counters()
    assert cnt["missed"] == len(skip) and cnt["rx"] == 4 * n - len(skip), cnt
    assert (await tb.host.rpdo_read(node - 1))["missed"] == len(skip)
    tb.check_models_clean()
    await Timer(1, "ns")


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_rpdo_sync_count(dut):
    """Purpose: PDO_SEQ.SYNC_COUNT is the counter of the SYNC the PDO belongs to (regression
    test of the off-by-one this bench found: the core used to pass the next SYNC's counter).

    One drive with its default TPDO1 (181h, 6 bytes, every SYNC), SYNC every 2 ms with counter
    overflow 4, no set-points. Verifies: PDO_SEQ.SYNC_COUNT of the feedback received after the
    SYNC with counter byte c is c (CiA 301: the counter of the SYNC the PDO belongs to).
    """
    tb = SystemTB(dut, node_ids=(1,), with_raw_node=False)
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: tb.slave(1).nmt_state == NmtState.PRE_OPERATIONAL, 5_000, 50)
    await tb.host.nmt(NMT_START, 1)
    await tb.wait_for(tb.all_operational, 2_000, 10, "operational")
    await tb.host.rpdo_config(0, 0x181, 6, 1)
    await tb.host.sync_config(2000, overflow=4)
    got = []
    for i in range(3):
        await tb.wait_for(lambda i=i: len(tb.frames(0x181)) > i, 3_000, 20)
        await Timer(100, "us")  # the master reads the frame from the MCP2510
        sync_byte = tb.frames(0x080)[-1].msg.data[0]
        got.append((sync_byte, (await tb.host.rpdo_read(0))["sync_count"]))
    await tb.host.sync_config(0, enable=False)
    dut._log.info(f"(SYNC counter byte on the bus, PDO_SEQ.SYNC_COUNT): {got}")
    assert all(c == s for c, s in got), f"SYNC counter vs stored SYNC_COUNT: {got}"


# ============================================================================ benchmark
def stuffing_payloads(cob_ids: Sequence[int], count: int, seed: int) -> list[bytes]:
    """``count`` distinct 8-byte payloads, each maximising the summed frame length (stuff
    bits) of the data frames ``cob_ids`` carrying it, found by deterministic hill climbing
    (the CRC makes the stuffing of its field depend on every data bit)."""
    rng = random.Random(seed)

    def score(d: bytes) -> int:
        return sum(frame_length_bits(can.Message(arbitration_id=c, data=d,
                                                 is_extended_id=False)) for c in cob_ids)

    out: list[bytes] = []
    while len(out) < count:
        best = bytes(rng.getrandbits(8) for _ in range(8))
        bv = score(best)
        for _ in range(2500):
            b = bytearray(best)
            for _ in range(rng.randint(1, 3)):
                i = rng.randrange(64)
                b[i // 8] ^= 1 << (i % 8)
            v = score(bytes(b))
            if v >= bv:
                best, bv = bytes(b), v
        if best not in out:
            out.append(best)
    return out


def axes_theoretical(period_us: int, bitrate: int, counter: bool = True) -> int:
    """Largest n with SYNC + n x (8-byte set-point + 8-byte feedback), every frame at its
    worst-case stuffed length with the 3-bit intermission, within one SYNC period."""
    budget = period_us * bitrate // 1_000_000
    return (budget - cycle_bits(0, counter)) // (2 * worst_case_bits(PDO_BYTES))


@cocotb.test(timeout_time=3000, timeout_unit="ms", skip=os.environ.get("BENCH") != "1")
async def run_bench_pdo_axes(dut):
    """Benchmark: axes per 1 ms SYNC cycle at 1 Mbit/s, measured against the bus-only bound.

    Theoretical: :func:`axes_theoretical` (SYNC with its counter byte, as run here). Measured:
    the system runs n = theoretical, then n = theoretical + 1 drives (the extra drive is NMT
    started for the second run), with set-points chosen for maximum bit stuffing (the feedback
    carries the same 8 bytes two cycles later); a run stops at the first cycle with a feedback
    PDO missing for the host, a late TPDO, a missed RPDO cycle or a set-point/feedback frame
    outside its cycle on the bus; a passing n runs 1000 cycles and must pass check_run.
    """
    period_us = 1000
    n_theo = axes_theoretical(period_us, SYSTEM["CAN_BITRATE_BPS"])
    tb = SystemTB(dut, node_ids=tuple(range(1, n_theo + 2)), with_raw_node=False)
    assert tb.bitrate == SYSTEM["CAN_BITRATE_BPS"]
    table = {ch: stuffing_payloads([0x201 + ch, 0x181 + ch], 8, seed=ch)
             for ch in range(len(tb.slaves))}

    def sp_stuffed(ch: int, k: int) -> bytes:
        return table[ch][k % len(table[ch])]

    await boot_and_configure(tb, start=[s.node_id for s in tb.slaves[:n_theo]])
    results: dict[int, dict] = {}
    for n in (n_theo, n_theo + 1):
        axes = [Axis(s.node_id, ch) for ch, s in enumerate(tb.slaves[:n])]
        if n > n_theo:
            await nmt_start(tb, [a.node for a in axes[n_theo:]])
            await tb.wait_for(tb.all_operational, 2_000, 10, "operational")
        await configure_master_pdos(tb, axes)
        await tb.host.pdo_clear_counters()
        run = await run_cycles(tb, axes, N_CYCLES, period_us, sp_stuffed, stop_on_error=True)
        errs = check_run(tb, run)
        cnt = await tb.host.pdo_counters()
        ok = run.n_cycles == N_CYCLES and not errs and not cnt["late"] and not cnt["missed"]
        first = min((e for e in errs if e[1] > 0), default=None, key=lambda e: e[1])
        results[n] = {"ok": ok, "run": run, "errs": errs, "cnt": cnt, "first": first,
                      "stats": cycle_stats(tb, run) if run.n_cycles > 2 else {}}
        dut._log.info(f"n = {n}: {'pass' if ok else 'FAIL'}, {run.n_cycles} cycles "
                      f"({run.wall_s:.0f} s wall); counters {cnt}; first discrepancy {first}; "
                      f"{len(errs)} discrepancies: {errs[:8]}; bus {results[n]['stats']}")
        await Timer(2, "ms")
    measured = max([n for n, r in results.items() if r["ok"]], default=0)
    stats = results[n_theo]["stats"]
    pdo_bits = [frame_length_bits(can.Message(arbitration_id=c, data=d, is_extended_id=False))
                for ch, ps in table.items() for d in ps for c in (0x201 + ch, 0x181 + ch)]
    fail = results[n_theo + 1]
    record("canopen_pdo_cycle", {
        "pdo_axes_theoretical_1mbps": n_theo,
        "pdo_axes_theoretical_1mbps_sync_without_counter":
            axes_theoretical(period_us, tb.bitrate, counter=False),
        "pdo_axes_per_1ms_cycle_1mbps": measured,
        "pdo_cycle_bus_load_pct": stats.get("bus_load_pct", 0.0),
        "pdo_cycle_busy_after_sync_us_max": stats.get("busy_after_sync_us_max", 0.0),
        "pdo_cycle_busy_after_sync_us_worst_stuffing": stats.get("busy_after_sync_us_wc_max",
                                                                 0.0),
        "pdo_cycle_setpoint_gap_us_max": stats.get("setpoint_gap_us_max", 0.0),
        "pdo_cycle_pdo_frame_bits_min": min(pdo_bits),
        "pdo_cycle_pdo_frame_bits_max": max(pdo_bits),
        "pdo_cycle_n_plus_1_first_bad_cycle": fail["first"][1] if fail["first"] else 0,
        "pdo_cycle_1000_wall_s": round(results[n_theo]["run"].wall_s, 1),
    })
    dut._log.info(f"theoretical {n_theo}, measured {measured}; PDO frames {min(pdo_bits)}.."
                  f"{max(pdo_bits)} bits (bound {worst_case_bits(PDO_BYTES)})")
    assert measured == n_theo, {n: (r["ok"], r["first"], r["cnt"]) for n, r in results.items()}
    tb.check_models_clean()
    await Timer(1, "ns")


# ============================================================================ pytest entry
@pytest.mark.sim
@pytest.mark.timeout(1800)  # about 5.5 min alone; more under `make test -n auto`
def test_pdo_cycle_1000(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_pdo_cycle", name=request.node.name,
               parameters=SYSTEM_CANOPEN_ONLY, stop_time_ms=4000, ieee_asserts="disable",
               testcase="run_pdo_exchange_1000_cycles")


@pytest.mark.sim
def test_pdo_cycle_rtr_and_missing(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_pdo_cycle", name=request.node.name,
               parameters=SYSTEM, stop_time_ms=2000, ieee_asserts="disable",
               testcase=["run_rtr_polled_feedback", "run_missing_feedback_detected",
                         "run_rpdo_sync_count"])


@pytest.mark.sim
@pytest.mark.bench
@pytest.mark.timeout(1800)
def test_bench_pdo_cycle(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_pdo_cycle", name=request.node.name,
               parameters=SYSTEM_CANOPEN_ONLY, stop_time_ms=4000, ieee_asserts="disable",
               testcase="run_bench_pdo_axes", extra_env={"BENCH": "1"})
