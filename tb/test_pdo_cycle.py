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

The cycle, the drive configuration and the checker live in ``tb/tblib/pdo_cycle.py`` (shared
with the drive clock-drift bench ``tb/test_canopen_drift.py``).
"""

from __future__ import annotations

import os
import random
from collections.abc import Sequence

import can
import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.can_bus import frame_length_bits, worst_case_bits
from sim_models.canopen_slave import NmtState
from sim_models.sim_time import PS_PER_MS
from tb.tblib.host_driver import NMT_START
from tb.tblib.metrics import record
from tb.tblib.pdo_cycle import (
    N_CYCLES,
    PDO_BYTES,
    SYSTEM,
    SYSTEM_CANOPEN_ONLY,
    Axis,
    bits_to_us,
    boot_and_configure,
    check_run,
    configure_master_pdos,
    cycle_bits,
    cycle_stats,
    frames_per_cob,
    run_cycles,
    take_out_axes,
)
from tb.tblib.runner import run_cocotb
from tb.tblib.system_tb import SystemTB


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
    the largest n for which a 1000-cycle run passes: the system runs n = theoretical + 1, then
    n = theoretical, theoretical - 1, ... until a run passes (the drives of a run are NMT
    started, the others stopped and their master channels invalid, so nothing is sent to or
    expected from them), with set-points chosen for maximum bit
    stuffing (the feedback carries the same 8 bytes two cycles later); a run stops at the first
    cycle with a feedback PDO missing for the host, a late TPDO, a missed RPDO cycle or a
    set-point/feedback frame outside its cycle on the bus; a passing n runs 1000 cycles and must
    pass check_run. The passing run's cycles, extrapolated to every frame at its worst-case
    stuffed length, must still end within the period.
    """
    period_us = 1000
    n_theo = axes_theoretical(period_us, SYSTEM["CAN_BITRATE_BPS"])
    tb = SystemTB(dut, node_ids=tuple(range(1, n_theo + 2)), with_raw_node=False)
    assert tb.bitrate == SYSTEM["CAN_BITRATE_BPS"]
    table = {ch: stuffing_payloads([0x201 + ch, 0x181 + ch], 8, seed=ch)
             for ch in range(len(tb.slaves))}

    def sp_stuffed(ch: int, k: int) -> bytes:
        return table[ch][k % len(table[ch])]

    await boot_and_configure(tb, start=[s.node_id for s in tb.slaves])
    results: dict[int, dict] = {}
    every_axis = [Axis(s.node_id, ch) for ch, s in enumerate(tb.slaves)]
    for n in range(n_theo + 1, 0, -1):
        axes = every_axis[:n]
        await take_out_axes(tb, every_axis[n:])
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
        if ok:
            break
    measured = max([n for n, r in results.items() if r["ok"]], default=0)
    stats = results[measured]["stats"] if measured else {}
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
        "pdo_cycle_1000_wall_s": round(results[measured]["run"].wall_s, 1) if measured else 0,
    })
    dut._log.info(f"theoretical {n_theo}, measured {measured}; PDO frames {min(pdo_bits)}.."
                  f"{max(pdo_bits)} bits (bound {worst_case_bits(PDO_BYTES)})")
    assert measured == n_theo, {n: (r["ok"], r["first"], r["cnt"]) for n, r in results.items()}
    # the master is not the limit even when every frame has its worst-case stuffed length
    assert stats["busy_after_sync_us_wc_max"] <= period_us, stats
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
