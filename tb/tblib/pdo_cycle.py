"""The CANopen SYNC cycle of the system bench: drives configured by SDO, set-points written by the
host every cycle, feedback read back, and the checker of every cycle.

Shared by the PDO exchange bench (``tb/test_pdo_cycle.py``) and the drive clock-drift bench
(``tb/test_canopen_drift.py``). The system is ``tb/tblib/system_tb.py`` (``canopen_master_top``
RTL, behavioural MCP2510, bit-exact CAN bus, CiA 301 reference drives).

* :func:`boot_and_configure` configures every drive by SDO from the master's own SDO client,
  the CiA 301 way (PDO invalidated, re-mapped, validated), with the mapping of
  :class:`PdoMaps` (default RPDO1 = 607Ah + 60FFh, TPDO1 = 6064h + 606Ch, 8 bytes each),
  and enables the drive (CiA 402 controlword);
* :func:`run_cycles`: the host, woken by the SYNC interrupt, commits the next cycle's
  set-points (``sp(channel, k)``, which encode cycle and axis) and reads every feedback PDO;
* the drive applies set-point k at SYNC k+1 and its CiA 402 model copies the targets into the
  actual values, so the feedback of cycle c carries the set-point of cycle c-2;
* :func:`check_run` compares, for every cycle and axis, the bus, what each drive received and
  applied, and what the host read, and returns every discrepancy.
"""

from __future__ import annotations

import math
import time
from bisect import bisect_left
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from cocotb.triggers import RisingEdge, Timer

from sim_models.can_bus import worst_case_bits
from sim_models.canopen_slave import NmtState
from sim_models.canopen_slave.cia402 import DriveState
from sim_models.sim_time import PS_PER_US
from tb.tblib.host_driver import NMT_START, NMT_STOP
from tb.tblib.model_clock import sim_time_ps
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
CW_SHUTDOWN, CW_ENABLE_OPERATION = 0x0006, 0x000F


def map_entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


Entry = tuple[int, int, int]


@dataclass(frozen=True)
class PdoMaps:
    """The drive's RPDO1 (set-point) and TPDO1 (feedback) mappings, (index, sub, bits) each.
    The CiA 402 model copies the targets into the actual values at every SYNC (607Ah -> 6064h,
    60FFh -> 606Ch), so with ``tpdo`` the actual values of ``rpdo``'s targets the feedback
    carries the set-point's bytes."""

    rpdo: tuple[Entry, ...] = ((0x607A, 0, 32), (0x60FF, 0, 32))
    tpdo: tuple[Entry, ...] = ((0x6064, 0, 32), (0x606C, 0, 32))

    @property
    def rpdo_bytes(self) -> int:
        return sum(bits for *_, bits in self.rpdo) // 8

    @property
    def tpdo_bytes(self) -> int:
        return sum(bits for *_, bits in self.tpdo) // 8


#: 8-byte set-point (target position + velocity) and feedback (position + velocity actual)
MAPS_DEFAULT = PdoMaps()
#: 4-byte set-point (target position) and feedback (position actual value)
MAPS_POSITION = PdoMaps(rpdo=((0x607A, 0, 32),), tpdo=((0x6064, 0, 32),))


def cycle_bits(n_axes: int, counter: bool = True, extra_bits: int = 0,
               pdo_bytes: int = PDO_BYTES) -> int:
    """Bus bits of one SYNC cycle under worst-case stuffing (3-bit intermission included):
    the SYNC (1 data byte with a counter, else 0) and per axis one set-point and one feedback
    PDO of ``pdo_bytes`` (8 by default)."""
    return (worst_case_bits(1 if counter else 0) + n_axes * 2 * worst_case_bits(pdo_bytes)
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


def sp_position(axis: int, k: int) -> bytes:
    """4-byte set-point of cycle k for axis (0-based) for :data:`MAPS_POSITION`: the target
    position of :func:`sp_default` (``sim_models.canopen_slave.drift.position_setpoint``)."""
    return sp_default(axis, k)[:4]


# ============================================================================ host side
async def configure_drive(tb: SystemTB, node: int, *, tpdo_tt: int = 1,
                          maps: PdoMaps = MAPS_DEFAULT, rpdo_cob: int | None = None,
                          feedback: bool = True) -> None:
    """Configure one drive by SDO from the master, the CiA 301 way (invalidate, map, validate),
    then enable it (CiA 402 controlword: shutdown, enable operation). ``rpdo_cob``: the
    set-point PDO it consumes (default its own, 200h + node); ``feedback=False`` leaves its
    TPDO1 invalid."""
    h = tb.host
    rpdo, tpdo = 0x200 + node if rpdo_cob is None else rpdo_cob, 0x180 + node

    async def u32(index: int, sub: int, v: int) -> None:
        await h.sdo_download(node, index, sub, v.to_bytes(4, "little"))

    async def u8(index: int, sub: int, v: int) -> None:
        await h.sdo_download(node, index, sub, bytes([v]))

    await u32(0x1400, 1, 0x8000_0000 | 0x200 + node)
    await u8(0x1600, 0, 0)
    for sub, e in enumerate(maps.rpdo, 1):
        await u32(0x1600, sub, map_entry(*e))
    await u8(0x1600, 0, len(maps.rpdo))
    await u8(0x1400, 2, 1)  # synchronous: applied at the next SYNC
    if rpdo != 0x200 + node:  # another CAN-ID: only while the PDO is invalid
        await u32(0x1400, 1, 0x8000_0000 | rpdo)
    await u32(0x1400, 1, rpdo)
    await u32(0x1800, 1, 0x8000_0000 | tpdo)
    if feedback:
        await u8(0x1A00, 0, 0)
        for sub, e in enumerate(maps.tpdo, 1):
            await u32(0x1A00, sub, map_entry(*e))
        await u8(0x1A00, 0, len(maps.tpdo))
        await u8(0x1800, 2, tpdo_tt)
        await u32(0x1800, 1, tpdo)
    for cw in (CW_SHUTDOWN, CW_ENABLE_OPERATION):
        await h.sdo_download(node, 0x6040, 0, cw.to_bytes(2, "little"))


async def boot_and_configure(tb: SystemTB, *, tpdo_tt: dict[int, int] | None = None,
                             start: Sequence[int] | None = None,
                             maps: PdoMaps = MAPS_DEFAULT,
                             consumers: dict[int, int] | None = None) -> None:
    """Reset, wait for the boot-ups, configure every drive by SDO, NMT-start ``start`` (all by
    default) and check inside the drives that it worked. ``consumers``: node -> node whose
    set-point PDO it consumes instead of its own (a second consumer of that PDO, e.g. a gantry
    axis), without feedback."""
    consumers = consumers or {}
    await tb.reset()
    await tb.wait_master_ready()
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    await Timer(300, "us")
    for s in tb.slaves:
        n = s.node_id
        await configure_drive(tb, n, tpdo_tt=(tpdo_tt or {}).get(n, 1), maps=maps,
                              rpdo_cob=0x200 + consumers[n] if n in consumers else None,
                              feedback=n not in consumers)
    for s in tb.slaves:
        n = s.node_id
        assert [s.read(0x1600, i) for i in range(len(maps.rpdo) + 1)] == [
            len(maps.rpdo), *(map_entry(*e) for e in maps.rpdo)]
        assert s.read(0x1400, 1) == 0x200 + consumers.get(n, n) and s.read(0x1400, 2) == 1
        if n in consumers:
            assert s.read(0x1800, 1) == 0x8000_0180 + n
        else:
            assert [s.read(0x1A00, i) for i in range(len(maps.tpdo) + 1)] == [
                len(maps.tpdo), *(map_entry(*e) for e in maps.tpdo)]
            assert s.read(0x1800, 1) == 0x180 + n
        assert s.drive_state == DriveState.OPERATION_ENABLED, (s.node_id, s.drive_state)
    nodes = [s.node_id for s in tb.slaves] if start is None else list(start)
    await nmt_start(tb, nodes)


async def nmt_start(tb: SystemTB, nodes: Sequence[int]) -> None:
    """NMT start: one command for all slaves, else one per node (``host.nmt`` waits until
    the previous command left NMT_CMD)."""
    for node in [0] if sorted(nodes) == sorted(s.node_id for s in tb.slaves) else nodes:
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
    maps: PdoMaps = MAPS_DEFAULT


def drive_values(tb: SystemTB, node: int,
                 maps: PdoMaps = MAPS_DEFAULT) -> tuple[bytes, bytes]:
    """Inside the drive before a run: (actual values of the feedback mapping, e.g. 6064h +
    606Ch, what SYNC 1 will copy into them). The latter is the targets of the set-point
    mapping (607Ah + 60FFh), or the synchronous RPDO1 the drive received after the previous
    run's last SYNC (it is applied at the next SYNC, before the copy)."""
    s = tb.slave(node)
    pending = s._rpdo[0].pending  # model state: (payload, t_rx) or None
    return (b"".join(s.read_raw(i, sub) for i, sub, _ in maps.tpdo),
            pending[0] if pending is not None
            else b"".join(s.read_raw(i, sub) for i, sub, _ in maps.rpdo))


async def configure_master_pdos(tb: SystemTB, axes: Sequence[Axis],
                                maps: PdoMaps = MAPS_DEFAULT) -> None:
    sp_len, fb_len = maps.rpdo_bytes, maps.tpdo_bytes
    for a in axes:
        await tb.host.tpdo_config(a.ch, 0x200 + a.node, sp_len, 1)
        if a.mode == "rtr":
            await tb.host.rpdo_config(a.ch, 0x180 + a.node, fb_len, 253, rtr_poll=True)
        else:
            await tb.host.rpdo_config(a.ch, 0x180 + a.node, fb_len, 1)


async def take_out_axes(tb: SystemTB, axes: Sequence[Axis]) -> None:
    """Take ``axes`` out of the cycle: NMT-stop their drives (they send nothing) and set the
    master's TPDO/RPDO channels of them invalid (no set-point sent, no feedback expected: an
    RPDO channel left armed would count a missed cycle every SYNC)."""
    for a in axes:
        if tb.slave(a.node).nmt_state != NmtState.STOPPED:
            await tb.host.nmt(NMT_STOP, a.node)
    await tb.wait_for(lambda: all(tb.slave(a.node).nmt_state == NmtState.STOPPED
                                  for a in axes), 2_000, 10, "stopped")
    for a in axes:
        await tb.host.tpdo_config(a.ch, 0x200 + a.node, PDO_BYTES, 1, valid=False)
        await tb.host.rpdo_config(a.ch, 0x180 + a.node, PDO_BYTES, 1, valid=False)


async def wait_sync_irq(tb: SystemTB) -> None:
    if int(tb.dut.irq_o.value) != 1:
        await RisingEdge(tb.dut.irq_o)


async def run_cycles(tb: SystemTB, axes: Sequence[Axis], n_cycles: int, period_us: int,
                     sp: Callable[[int, int], bytes] = sp_default, *,
                     first_read_us: float | None = None, deadline_us: float | None = None,
                     stop_on_error: bool = False, maps: PdoMaps = MAPS_DEFAULT) -> Run:
    """Run ``n_cycles`` SYNC cycles; SYNC is off before and after.

    Per cycle the host, woken by the SYNC interrupt, clears it, reads SYNC_COUNT, commits the
    next set-points (they go out after the next SYNC), waits until every feedback channel shows
    NEW (or until ``deadline_us`` after the SYNC) and reads the snapshot of every channel.
    ``stop_on_error``: stop at the first cycle with a missing feedback, a late TPDO or a missed
    RPDO cycle (the throughput bench). ``maps``: the drives' PDO mappings (lengths).
    """
    h = tb.host
    mask = sum(1 << a.ch for a in axes)
    bitrate = tb.bitrate
    if first_read_us is None:  # the SYNC and one minimum-length PDO per feedback channel
        first_read_us = bits_to_us(worst_case_bits(1) + len(axes) * (47 + 8 * maps.tpdo_bytes),
                                   bitrate)
    if deadline_us is None:
        deadline_us = period_us - 60
    run = Run(list(axes), n_cycles, sp, sim_time_ps(), period_us, maps=maps)
    run.init_fb = {a.node: drive_values(tb, a.node, maps) for a in axes}
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
            # SYNC off with SYNC_OVERFLOW unchanged: a change would restart the counter at 1
            # in the next run and counter_of() counts SYNCs since reset
            await h.sync_stop()
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
                await h.sync_stop()
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
        drive_errs = check_drive(tb, run, a.node, a.ch)
        errs += drive_errs
        if drive_errs and drive_errs[0][1] == 0:
            continue
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


def check_drive(tb: SystemTB, run: Run, node: int, ch: int) -> list[tuple[str, int, int, str]]:
    """Inside drive ``node`` (consumer of channel ``ch``'s set-point PDO 200h + ch's node):
    it consumed every SYNC, received set-point k between its SYNC k and SYNC k+1 (exactly
    once) and applied it at SYNC k+1 (k < N; the last one has no next SYNC)."""
    errs: list[tuple[str, int, int, str]] = []
    n = run.n_cycles
    cob = 0x200 + run.axes[[a.ch for a in run.axes].index(ch)].node
    s = tb.slave(node)
    st = [t for t, _ in s.sync_log if run.t0_ps <= t < run.t_end_ps]
    if len(st) != n:
        return [("drive", 0, node, f"{len(st)} SYNCs consumed, expected {n}")]
    st.append(run.t_end_ps)
    rx = [(t, bytes(m.data)) for t, m in s.rx_log if run.t0_ps <= t < run.t_end_ps
          and m.arbitration_id == cob and not m.is_remote_frame]
    rx_by_k: dict[int, list[bytes]] = {}
    for t, d in rx:
        rx_by_k.setdefault(bisect_left(st, t), []).append(d)
    applied = {t: p for t, pdo, p in s.rpdo_applied
               if pdo == 1 and run.t0_ps <= t < run.t_end_ps}
    for k in range(1, n + 1):
        got = rx_by_k.get(k, [])
        if got != [run.sp(ch, k)]:
            errs.append(("drive", k, node, f"received {[g.hex() for g in got]}"))
        if k < n and applied.get(st[k]) != run.sp(ch, k):
            errs.append(("drive", k, node, "set-point not applied at SYNC k+1"))
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
        "frame_bits_min_pdo": min(r.n_bits for r in frames if r.msg.dlc
                                  == max(run.maps.rpdo_bytes, run.maps.tpdo_bytes)),
    }


def frames_per_cob(tb: SystemTB, run: Run) -> Counter:
    return Counter((r.msg.arbitration_id, r.msg.is_remote_frame) for r in tb.bus.records
                   if r.kind == "frame" and run.t0_ps <= r.t_start_ps < run.t_end_ps)


