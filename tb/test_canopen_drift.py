"""Clock drift of CiA 402 drives on the CANopen SYNC cycle of the master RTL (the CANopen
counterpart of the Omni-ID drift experiment, docs/omni_drift.md "CANopen mode").

The system of ``tb/tblib/system_tb.py`` (``canopen_master_top`` RTL, CANopen-only build,
behavioural MCP2510, bit-exact CAN bus) runs the PDO cycle of ``tb/tblib/pdo_cycle.py`` at
1 Mbit/s with a 1 ms SYNC: every drive is configured by SDO (RPDO1 = target position 607Ah,
synchronous; TPDO1 = position actual 6064h, every SYNC: 4 bytes each, so four axes fit 1 ms)
and the host commits the set-point of every cycle (``sp_position``: axis << 24 | cycle).

Each drive (``sim_models.canopen_slave``) runs its control loop (1 ms) on its own crystal and
samples the set-point the CiA 301 way: the synchronous RPDO applied at the SYNC
(``control_source=("applied", 1)``), so the sample of cycle c should hold set-point c - 1.
Drives 1..4 (-100, -50, +50, +100 ppm period error) re-align their tick grid on every SYNC
(K = 1), half a period after it; further drives are second consumers of an axis' set-point PDO
(gantry axes: no feedback, no extra bus load) whose loop locks once at the first SYNC and then
runs free. ``sim_models.canopen_slave.drift.evaluate_drive`` decides per tick whether the
sampled value is the one of its cycle (dropout) and measures the skew; the same drives on the
ideal reference master (``run_reference``) give the figures the RTL run must match.
"""

from __future__ import annotations

import json
import os

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave.drift import (
    DriveSpec,
    drive_kwargs,
    evaluate_drive,
    inter_slave_skew_ps,
    n_drift_model,
    n_drift_model_per_sync,
    position_setpoint,
    run_reference,
    sync_counter,
    sync_latency_ps,
)
from sim_models.sim_time import PS_PER_US
from tb.tblib.metrics import record
from tb.tblib.pdo_cycle import (
    MAPS_POSITION,
    SYNC_OVERFLOW,
    SYSTEM_CANOPEN_ONLY,
    Axis,
    boot_and_configure,
    check_drive,
    check_run,
    configure_master_pdos,
    run_cycles,
    sp_position,
)
from tb.tblib.runner import ROOT, run_cocotb
from tb.tblib.system_tb import SystemTB

OUT = ROOT / "build" / "canopen_drift"
PERIOD_US = 1000
T_PS = PERIOD_US * PS_PER_US
HALF = T_PS // 2
TAU_PS = 10**12 // SYSTEM_CANOPEN_ONLY["CAN_BITRATE_BPS"]
RHOS = (-100.0, -50.0, 50.0, 100.0)
#: the four axes, re-aligned on every SYNC, sampling half a period after it (the middle of the
#: window between two SYNC apply instants: +-T_s/2 of drift tolerated between re-phases)
AXES = [DriveSpec(i + 1, rho, "sync", 1, HALF) for i, rho in enumerate(RHOS)]
#: short run: two gantry drives at the thesis' drift (+-3618 ppm), locked once at SYNC 1 (700 /
#: 500 us after it) and free-running: the drift model puts their onsets at samples 81 / 137
FREE_SHORT = [DriveSpec(5, 3618.0, "first_sync", phase_ps=700 * PS_PER_US, axis=0,
                        feedback=False),
              DriveSpec(6, -3618.0, "first_sync", phase_ps=500 * PS_PER_US, axis=1,
                        feedback=False)]
N_SHORT = int(os.environ.get("CANOPEN_DRIFT_CYCLES", "200"))
#: benchmark: the four crystals once more as free-running gantry drives, each locked at SYNC 1
#: 25 us inside the edge of its window it drifts towards (a fast drive 25 us after the SYNC's
#: apply instant, a slow one 25 us before the next SYNC's): onsets near 250 / 500 samples
EDGE_US = 25
FREE_BENCH = [DriveSpec(5 + i, rho, "first_sync",
                        phase_ps=(EDGE_US if rho < 0 else PERIOD_US - EDGE_US) * PS_PER_US,
                        axis=i, feedback=False) for i, rho in enumerate(RHOS)]
N_BENCH = 1000


def nominal_sync_latency_ps() -> int:
    """D of the skew definition: the shortest SYNC of the run (its counter byte's stuff bits
    make the others up to 2 bit times longer)."""
    return min(sync_latency_ps(SYSTEM_CANOPEN_ONLY["CAN_BITRATE_BPS"],
                               sync_counter(k, SYNC_OVERFLOW))
               for k in range(1, SYNC_OVERFLOW + 1))


def sync_latency_of_cycle(c: int) -> int:
    """Latency of SYNC c (its counter byte, 1019h = SYNC_OVERFLOW, the run starting at 1)."""
    return sync_latency_ps(SYSTEM_CANOPEN_ONLY["CAN_BITRATE_BPS"],
                           sync_counter(c, SYNC_OVERFLOW))


def evaluate_all(specs, slaves, sync_times):
    d = nominal_sync_latency_ps()
    return [evaluate_drive(sl, sync_times, lambda j, ch=s.channel: position_setpoint(ch, j),
                           period_ps=T_PS, nominal_latency_ps=d, phase_ps=s.phase_ps,
                           rho_ppm=s.rho_ppm) for s, sl in zip(specs, slaves)]


async def drift_cell(dut, specs: list[DriveSpec], n_cycles: int):
    """Boot, configure by SDO, run ``n_cycles`` and check the cycle; returns the bench, the
    run, the SYNC SOF times, the drives' figures and the reference master's."""
    tb = SystemTB(dut, node_ids=tuple(s.node for s in specs), with_raw_node=False,
                  slave_kwargs={s.node: drive_kwargs(s, T_PS) for s in specs})
    axes = [Axis(s.node, s.channel) for s in specs if s.feedback]
    consumers = {s.node: axes[s.channel].node for s in specs if not s.feedback}
    await boot_and_configure(tb, maps=MAPS_POSITION, consumers=consumers)
    await configure_master_pdos(tb, axes, MAPS_POSITION)
    await tb.host.pdo_clear_counters()
    run = await run_cycles(tb, axes, n_cycles, PERIOD_US, sp_position, maps=MAPS_POSITION)
    errs = check_run(tb, run)
    for s in specs:
        if not s.feedback:
            errs += check_drive(tb, run, s.node, s.channel)
    assert errs == [], f"{len(errs)} discrepancies, first: {errs[:10]}"
    cnt = await tb.host.pdo_counters()
    n4 = len(axes) * n_cycles
    assert cnt == {"rx": n4, "tx": n4, "rtr": 0, "len_err": 0, "missed": 0, "late": 0,
                   "unexpected": 0}, cnt
    syncs = [t for t in tb.sync_sof_times() if run.t0_ps <= t < run.t_end_ps]
    assert len(syncs) == n_cycles
    periods = {b - a for a, b in zip(syncs, syncs[1:])}
    # the core fires the SYNC from a preloaded buffer by TX2RTS on its microsecond timer and
    # the cycle leaves the bus idle before the next SYNC: the SYNC grid is exact
    assert periods == {T_PS}, sorted(periods)
    res = evaluate_all(specs, tb.slaves, syncs)
    ref = run_reference(specs, n_cycles, period_ps=T_PS, overflow=SYNC_OVERFLOW,
                        sp=position_setpoint)
    ref_res = evaluate_all(specs, ref.slaves, ref.sync_times_ps)
    for s, r, q in zip(specs, res, ref_res):
        dut._log.info("drive %d (%+g ppm, %s, phase %.0f us): n=%d dropout=%d onset=%s "
                      "(cycle %s) skew=%.3f us rephases=%d | reference: dropout=%d onset=%s "
                      "skew=%.3f us", s.node, s.rho_ppm, s.resync, s.phase_ps / 1e6, r.n,
                      r.n_dropout, r.onset_sample, r.onset_cycle, r.skew_max_ps / 1e6,
                      r.rephases, q.n_dropout, q.onset_sample, q.skew_max_ps / 1e6)
    dut._log.info("SYNC periods on the bus: %s ps; %.1f s wall for %d cycles",
                  sorted(periods), run.wall_s, n_cycles)
    assert run.first_sync == 0  # SYNC c carries counter c (sync_latency_of_cycle)
    tb.check_models_clean()
    return tb, run, syncs, res, ref_res


def check_realigned(specs, res, ref_res, n_cycles: int) -> list[int]:
    """Re-aligned drives: no dropout, every SYNC re-phased, skew within |rho|·K·T_s + 2 bit
    times, equal to the reference master's within 2 bit times; returns the inter-drive skews."""
    mine = [(s, r, q) for s, r, q in zip(specs, res, ref_res) if s.resync == "sync"]
    for s, r, q in mine:
        assert r.n == n_cycles - 2 and r.n_dropout == 0 and not r.never_sampled, r.summary()
        assert r.rephases == n_cycles, r.summary()
        bound = abs(s.rho_ppm) * 1e-6 * s.k * T_PS + 2 * TAU_PS
        assert r.skew_max_ps <= bound, (r.summary(), bound)
        assert q.n_dropout == 0 and abs(r.skew_max_ps - q.skew_max_ps) <= 2 * TAU_PS, (r, q)
    inter = inter_slave_skew_ps([r for _, r, _ in mine])
    assert len(inter) == n_cycles
    two = sorted(abs(s.rho_ppm) * s.k for s, _, _ in mine)[-2:]
    bound = sum(two) * 1e-6 * T_PS + 2 * TAU_PS
    assert max(inter) <= bound, (max(inter), bound)
    return inter


@cocotb.test(timeout_time=1500, timeout_unit="ms")
async def run_drift_realign_and_free_running(dut):
    """Purpose: CiA 402 drives with drifting control loops on the master RTL's SYNC cycle:
    re-alignment on every SYNC against free-running loops (the thesis' drift experiment in
    CANopen mode), over a short run.

    Four drives at -100/-50/+50/+100 ppm re-align on every SYNC (K = 1) half a period after it;
    two gantry drives (consumers of axis 1's / axis 2's set-point PDO) at +3618 / -3618 ppm lock
    once at SYNC 1 and run free. Verifies: every cycle's set-point reached every drive in its
    cycle and was applied at the next SYNC, feedback and host reads exact (check_run,
    check_drive), PDO counters exact; re-aligned drives: dropout 0, a re-phase at every SYNC,
    per-drive skew <= |rho|·K·T_s + 2 bit times, inter-drive sample skew <= (100 + 100) ppm ·
    K·T_s + 2 bit times; free-running drives: dropout onset = the drift model ±1 (the SYNC
    counter byte's stuffing moves the apply instant by up to 2 bit times) and exactly the
    model with each SYNC's own latency, every later sample lost; SYNC SOFs exactly 1 ms
    apart; the same drives on the ideal reference master (exact 1 ms grid): the same dropout
    count and onset, skews within 2 bit times.
    """
    specs = AXES + FREE_SHORT
    n = N_SHORT
    _tb, _run, _syncs, res, ref_res = await drift_cell(dut, specs, n)
    inter = check_realigned(specs, res, ref_res, n)
    d = nominal_sync_latency_ps()
    table = []
    for s, r, q in zip(specs, res, ref_res):
        entry = {"node": s.node, "rho_ppm": s.rho_ppm, "resync": s.resync,
                 "phase_us": s.phase_ps / 1e6, "rtl": r.summary(), "reference": q.summary()}
        if s.resync == "first_sync":
            model = n_drift_model(r.t_dif0_ps, s.rho_ppm, T_PS, d)
            exact = n_drift_model_per_sync(r.t_dif0_ps, s.rho_ppm, T_PS, sync_latency_of_cycle)
            entry["onset_model"], entry["onset_model_per_sync"] = model, exact
            assert r.onset_sample is not None and abs(r.onset_sample - model) <= 1, (r, model)
            assert r.onset_sample == exact, (r.summary(), exact)
            assert [c for c, _ in r.dropouts] == list(range(r.onset_cycle, n)), r.summary()
            assert r.rephases == 1
            # the same SYNC grid and SYNC frames as the reference master: the same samples
            assert (q.onset_sample, q.n_dropout) == (r.onset_sample, r.n_dropout), (r, q)
        table.append(entry)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "short_run.json").write_text(json.dumps(
        {"cycles": n, "period_us": PERIOD_US, "nominal_sync_latency_us": d / 1e6,
         "inter_slave_skew_max_us": max(inter) / 1e6, "drives": table}, indent=2) + "\n")
    await Timer(1, "ns")


@cocotb.test(timeout_time=5000, timeout_unit="ms", skip=os.environ.get("BENCH") != "1")
async def run_bench_canopen_drift(dut):
    """Benchmark: drift figures of four drives at -100/-50/+50/+100 ppm over 1000 SYNC cycles,
    re-aligned on every SYNC (K = 1, half a period after it) and free-running.

    The free-running ones are the same four crystals as gantry drives on the same set-point
    PDOs, locked once at SYNC 1, 25 us inside the edge of the window each drifts towards.
    Verifies as the short run (set-points, re-aligned drives' bounds, reference master);
    the free-running onsets lie between the drift model with the shortest and with the longest
    SYNC and equal the model with each SYNC's own latency, and equal the reference master's.
    Records canopen_drift_skew_max_us_{sync,nosync}, canopen_drift_dropout_pct_{sync,nosync},
    canopen_drift_inter_slave_skew_max_us_sync, the free-running onsets and the wall time.
    """
    specs = AXES + FREE_BENCH
    n = N_BENCH
    _tb, run, _syncs, res, ref_res = await drift_cell(dut, specs, n)
    inter = check_realigned(specs, res, ref_res, n)
    sync_r = [r for s, r in zip(specs, res) if s.resync == "sync"]
    free = [(s, r, q) for s, r, q in zip(specs, res, ref_res) if s.resync == "first_sync"]
    free_r = [r for _, r, _ in free]
    d = nominal_sync_latency_ps()
    d_max = max(sync_latency_of_cycle(c) for c in range(1, SYNC_OVERFLOW + 1))
    metrics = {
        "canopen_drift_skew_max_us_sync": max(r.skew_max_ps for r in sync_r) / 1e6,
        "canopen_drift_skew_max_us_nosync": max(r.skew_max_ps for r in free_r) / 1e6,
        "canopen_drift_dropout_pct_sync": round(100.0 * sum(r.n_dropout for r in sync_r)
                                                / sum(r.n for r in sync_r), 3),
        "canopen_drift_dropout_pct_nosync": round(100.0 * sum(r.n_dropout for r in free_r)
                                                  / sum(r.n for r in free_r), 3),
        "canopen_drift_inter_slave_skew_max_us_sync": max(inter) / 1e6,
        "canopen_drift_1000_wall_s": round(run.wall_s, 1),
    }
    table = []
    for s, r, q in free:
        lo = n_drift_model(r.t_dif0_ps, s.rho_ppm, T_PS, d)
        hi = n_drift_model(r.t_dif0_ps, s.rho_ppm, T_PS, d_max)
        exact = n_drift_model_per_sync(r.t_dif0_ps, s.rho_ppm, T_PS, sync_latency_of_cycle)
        onset = -1 if r.onset_sample is None else r.onset_sample
        metrics[f"canopen_drift_onset_nosync_{int(s.rho_ppm):+d}ppm".replace("+", "p")
                .replace("-", "m")] = onset
        table.append({"node": s.node, "rho_ppm": s.rho_ppm, "phase_us": s.phase_ps / 1e6,
                      "onset": r.onset_sample, "onset_model_range": sorted((lo, hi)),
                      "onset_model_per_sync": exact, "t_dif0_us": r.t_dif0_ps / 1e6,
                      "dropout": r.n_dropout, "n": r.n, "skew_max_us": r.skew_max_ps / 1e6,
                      "reference": q.summary()})
        # the model with the shortest / longest SYNC bounds the onset (the counter byte's
        # stuff bits move the apply instant by up to 2 bit times)
        assert r.onset_sample is not None and min(lo, hi) - 1 <= onset <= max(lo, hi) + 1, (
            r.summary(), lo, hi)
        assert onset == exact, (r.summary(), exact)
        assert q.onset_sample == r.onset_sample and q.n_dropout == r.n_dropout, (r, q)
    record("canopen_drift", metrics)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench.json").write_text(json.dumps(
        {"cycles": n, "metrics": metrics, "free_running": table,
         "realigned": [r.summary() for r in sync_r]}, indent=2) + "\n")
    dut._log.info("metrics %s", metrics)
    await Timer(1, "ns")


# ============================================================================ pytest entry
@pytest.mark.sim
@pytest.mark.timeout(1200)
def test_canopen_drift(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_canopen_drift",
               name=request.node.name, parameters=SYSTEM_CANOPEN_ONLY, stop_time_ms=3000,
               ieee_asserts="disable", testcase="run_drift_realign_and_free_running")


@pytest.mark.sim
@pytest.mark.bench
@pytest.mark.timeout(2400)
def test_bench_canopen_drift(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_canopen_drift",
               name=request.node.name, parameters=SYSTEM_CANOPEN_ONLY, stop_time_ms=6000,
               ieee_asserts="disable", testcase="run_bench_canopen_drift",
               extra_env={"BENCH": "1"})
