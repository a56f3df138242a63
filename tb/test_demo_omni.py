"""The Omni-ID demo (second part of ``make demo``): the master RTL running the NCTU thesis'
four-wheel omni-directional robot network in Omni-ID mode (CTRL.OMNI).

Scenario: master node id 02h, wheels 04h, 08h, 10h, 20h (Table 4-2) on crystals at -100, -50,
+50, +100 ppm; the host switches the master to Omni-ID mode, sends each wheel its control
parameter (Fig 4-19 forwarded form), starts all nodes, and runs a 2 ms cycle: the four wheel
set-points travel in one broadcast 102h per cycle, an Omni SYNC 080h every 10 cycles re-phases
the wheels' sample clocks, each wheel answers with a 6-byte feedback frame, and a node query
every 10 cycles checks that every wheel is alive. Wheel 10h then loses its transmitter; the
master reports it missing and stops all nodes. The test writes ``build/demo/omni_report.txt``
(timeline and summary), ``omni_summary.json`` and the bus trace, and asserts the outcome.
"""

from __future__ import annotations

import json
from collections import Counter
from types import SimpleNamespace

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.omni import codec as oc
from sim_models.omni.experiments import delivery_latency_ps, evaluate_slave
from sim_models.sim_time import PS_PER_MS, PS_PER_US
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.omni_system import (
    BITRATE,
    MASTER_ID,
    SlaveSpec,
    cycle_log,
    make_slave,
    run_rtl_cycle,
)
from tb.tblib.runner import ROOT, run_cocotb
from tb.tblib.system_tb import SystemTB

OUT = ROOT / "build" / "demo"
PERIOD_US = 2000
SYNC_K = 10
N_CYCLES = 40
CUT_CYCLE = 28
WHEELS = [
    SlaveSpec(0x04, 1, -100.0, "sync_frame", oc.FC_PD_010),
    SlaveSpec(0x08, 2, -50.0, "sync_frame", oc.FC_PD_011),
    SlaveSpec(0x10, 3, 50.0, "sync_frame", oc.FC_PD_101),
    SlaveSpec(0x20, 4, 100.0, "sync_frame", oc.FC_PD_110),
]


def classify(can_id: int, rtr: bool) -> str:
    fc, node = can_id >> 8, can_id & 0xFF
    if can_id == 0x080 and not rtr:
        return "Omni SYNC"
    if fc == 0:
        if can_id == 0:
            return "node query" if rtr else "NMT"
        return "query reply"
    if fc == oc.FC_BCAST_8X1:
        return "broadcast set-points"
    if fc == oc.FC_PARAM:
        return "parameter"
    if fc in (oc.FC_PD_010, oc.FC_PD_011, oc.FC_PD_101, oc.FC_PD_110) and node == MASTER_ID:
        return "feedback"
    return "other"


@cocotb.test(timeout_time=500, timeout_unit="ms")
async def run_demo_omni(dut):
    """Purpose: the Omni-ID demo scenario end to end (see the module docstring).

    Verifies: every wheel stored its parameter; every wheel sampled the command of its cycle
    (dropout 0 while running) with a per-wheel skew within |rho|·K·T_s + 2 bit times; the node
    queries before the cut found every wheel, the first one after it reports wheel 10h (slot 2)
    missing and the master sends NMT stop all; the cycle instants are exactly 2 ms apart.
    """
    OUT.mkdir(parents=True, exist_ok=True)
    tb = SystemTB(dut, node_ids=(), with_raw_node=False)
    period_ps = PERIOD_US * PS_PER_US
    wheels = [tb.bus.attach(make_slave(tb.sched, s, period_ps, SYNC_K)) for s in WHEELS]
    events: list[tuple[int, str]] = []

    def note(text: str) -> None:
        events.append((sim_time_ps(), text))

    await tb.reset()
    await tb.wait_master_ready()
    note("master: MCP2510 initialised, FSM in St1")
    host = tb.host
    await host.omni_mode(True)
    note("host: CTRL.OMNI = 1 (Omni-ID mode: one protocol on this bus)")
    for s in WHEELS:
        await host.omni_param(s.node, oc.DTYPE_PARAMETER, (100).to_bytes(2, "big"))
        await Timer(300, "us")
    note("host: parameter frames (type 01h, value 100) to wheels 04h..20h")
    state = {"cut": None}

    async def on_cycle(k: int) -> None:
        if k == CUT_CYCLE:
            wheels[2].listen_only = True
            state["cut"] = sim_time_ps()
            note("wheel 10h loses its transmitter")

    mon = await run_rtl_cycle(tb, WHEELS, period_us=PERIOD_US, n_cycles=N_CYCLES,
                              sync_k=SYNC_K, poll_m=10, query_win_us=1000,
                              stop_on_missing=True, on_cycle=on_cycle)
    st = await host.omni_status()
    counters = await host.omni_counters()

    # ------------------------------------------------------------------ report
    frames = tb.frames()
    for r in frames:
        cid, data = r.msg.arbitration_id, bytes(r.msg.data)
        if cid == 0 and not r.msg.is_remote_frame:
            what = "start" if data[1] == 1 else "stop"
            events.append((r.t_start_ps, f"bus: NMT {what} {'all' if data[0] == 0 else data[0]}"))
        elif cid == 0 and r.msg.is_remote_frame:
            events.append((r.t_start_ps, "bus: node query (RTR 000h)"))
    events.sort()
    counts = Counter(classify(r.msg.arbitration_id, r.msg.is_remote_frame) for r in frames)
    cyc = cycle_log(tb, mon, N_CYCLES)
    fires = mon.fires[:N_CYCLES]
    periods = {b - a for a, b in zip(fires, fires[1:])}
    d_sync = delivery_latency_ps(BITRATE, oc.omni_sync_frame())
    running = CUT_CYCLE - 1  # samples before the cut
    res = [evaluate_slave(m, SimpleNamespace(cycle_log=cyc), running, s.ppm, d_sync)
           for s, m in zip(WHEELS, wheels)]
    t0, t1 = frames[0].t_start_ps, frames[-1].t_end_ps
    stop = [r for r in frames if r.msg.arbitration_id == 0 and not r.msg.is_remote_frame
            and r.msg.data[1] == 0]
    summary = {
        "simulated_ms": round((t1 - t0) / PS_PER_MS, 3),
        "frames_by_type": dict(sorted(counts.items())),
        "bus_load_pct": round(100 * tb.bus.load(fires[0], fires[-1]), 2),
        "cycle_period_us": sorted(p / PS_PER_US for p in periods),
        "wheels": [{"node": f"{s.node:02X}h", "ppm": s.ppm, "samples": r.n,
                    "dropout": r.n_dropout, "skew_max_us": round(r.skew_max_ps / 1e6, 3)}
                   for s, r in zip(WHEELS, res)],
        "missing_bitmap": st["missing"],
        "stop_all_ms_after_cut": round((stop[0].t_start_ps - state["cut"]) / PS_PER_MS, 3)
        if stop and state["cut"] else None,
        "omni_counters": counters,
    }
    lines = ["Omni-ID demo: NCTU four-wheel robot network, 1 Mbit/s, cycle 2 ms, "
             "Omni SYNC every 10 cycles", "", "Timeline"]
    lines += [f"{t / PS_PER_MS:10.3f} ms  {e}" for t, e in events]
    lines += ["", "Summary",
              "  frames by type: " + ", ".join(f"{k}: {v}" for k, v in counts.most_common()),
              f"  bus load while cycling: {summary['bus_load_pct']} %   cycle period "
              f"{summary['cycle_period_us']} us"]
    lines += [f"  wheel {w['node']} ({w['ppm']:+.0f} ppm): {w['samples']} samples before the "
              f"cut, dropout {w['dropout']}, max skew {w['skew_max_us']} us"
              for w in summary["wheels"]]
    lines += [f"  missing: slot bitmap {st['missing']:#x}; NMT stop all "
              f"{summary['stop_all_ms_after_cut']} ms after the cut",
              "  master counters: " + ", ".join(f"{k}={v}" for k, v in counters.items() if v)]
    (OUT / "omni_report.txt").write_text("\n".join(lines) + "\n")
    (OUT / "omni_summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    tb.bus.write_trace(OUT / "omni_bus.log")

    # ------------------------------------------------------------------ checks
    assert periods == {period_ps}, periods
    for s, m, r in zip(WHEELS, wheels, res):
        assert m.parameters.get(oc.DTYPE_PARAMETER) == (100).to_bytes(2, "big"), s
        assert r.n_dropout == 0 and r.n >= running - 2, (s, r.summary())
        assert r.skew_max_ps <= abs(s.ppm) * 1e-6 * SYNC_K * period_ps + 2 * 10**6, (s, r)
    assert st["missing"] == 1 << 2 and counters["node_missing"] == 1, (st, counters)
    assert stop and stop[0].t_start_ps > state["cut"]
    assert not any(m.started for m in wheels)
    tb.check_models_clean()
    await Timer(1, "ns")


@pytest.mark.sim
def test_demo_omni(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_demo_omni",
               name=request.node.name,
               parameters={"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000,
                           "OSC_FREQ_HZ": 16_000_000, "CAN_BITRATE_BPS": BITRATE,
                           "MAX_NODES": 4, "RESET_WAIT_US": 20},
               stop_time_ms=2000, ieee_asserts="disable")
