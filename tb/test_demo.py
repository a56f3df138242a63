"""The demo (``make demo``): the CANopen master running a small 4-axis drive network.

Scenario: the master initialises its MCP2510; four CiA 402-style drives (nodes 1..4, crystals
at -100/-50/+50/+100 ppm) boot; the host configures heartbeat supervision, loads the master's
configuration list (per drive: RPDO1 and TPDO1 re-mapped, TPDO1 on every SYNC, heartbeat
producer 1017h = 10 ms; 56 SDO downloads) and starts it: the master configures each drive by
SDO and then NMT-starts it (the thesis' boot sequence); the host reads each drive's device name
by a segmented SDO upload, sets up a PDO cycle (a set-point PDO to each drive and a feedback
PDO from each, every SYNC) and runs SYNC every 2 ms with a counter (4 axes x two 6-byte PDOs
need about 0.9 ms of the bus per cycle); drive 3 then drops off the bus and the master reports
it. The test writes a timeline, a summary and the bus trace (candump .log and .asc) to
``build/demo/`` and asserts the outcome, so the demo is also a system smoke test in
``make test``.
"""

from __future__ import annotations

import json
from collections import Counter

import cocotb
import pytest
from cocotb.triggers import Timer

from sim_models.canopen_slave import NmtState
from sim_models.sim_time import PS_PER_MS, PS_PER_US
from tb.tblib.drive_config import drive_entries
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.runner import ROOT, run_cocotb
from tb.tblib.system_tb import SystemTB

OUT = ROOT / "build" / "demo"
NMT_NAMES = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational", 0x81: "reset node",
             0x82: "reset communication"}
STATE_NAMES = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}


def classify(can_id: int, rtr: bool) -> str:
    fc, node = can_id >> 7, can_id & 0x7F
    if can_id == 0x000:
        return "NMT"
    if can_id == 0x080:
        return "SYNC"
    if fc == 0x1:
        return "EMCY"
    if fc in (0x3, 0x5, 0x7, 0x9):
        return "TPDO (drive -> master)"
    if fc in (0x4, 0x6, 0x8, 0xA):
        return "RPDO (master -> drive)"
    if fc == 0xB:
        return "SDO response"
    if fc == 0xC:
        return "SDO request"
    if fc == 0xE:
        return "guarding RTR" if rtr else "heartbeat / boot-up"
    return f"other (node {node})"


def timeline_line(t_ps: int, text: str) -> str:
    return f"{t_ps / PS_PER_MS:10.3f} ms  {text}"


@cocotb.test(timeout_time=500, timeout_unit="ms")
async def run_demo(dut):
    """Purpose: the demo scenario end to end (see the module docstring).

    Verifies: the configuration list configures and starts all four drives (no failure); its
    values (PDO mappings, heartbeat time) are in the drives' object dictionaries and the drives
    reach operational inside the drive; the host's SDO uploads return the drives' names; SYNC
    runs with an exact 2 ms period on the idle bus; the set-points reach the drives; the
    dropped drive is reported lost (and only that one).
    """
    OUT.mkdir(parents=True, exist_ok=True)
    tb = SystemTB(dut, ppm=(-100, -50, 50, 100))
    events: list[tuple[int, str]] = []

    def note(text: str) -> None:
        events.append((sim_time_ps(), text))

    await tb.reset()
    await tb.wait_master_ready()
    note("master: MCP2510 initialised, FSM in St1 (application-layer interface)")
    for slot, s in enumerate(tb.slaves):
        await tb.host.node_config(slot, s.node_id, "heartbeat", 25)
    note("host: heartbeat consumer 25 ms configured for nodes 1-4")
    await tb.wait_for(lambda: all(s.nmt_state == NmtState.PRE_OPERATIONAL for s in tb.slaves),
                      5_000, 50, "boot-ups")
    await Timer(300, "us")
    entries = [e for s in tb.slaves for e in drive_entries(s.node_id, hb_ms=10)]
    await tb.host.acfg_load(entries)
    note(f"host: configuration list loaded ({len(entries)} SDO downloads for nodes 1-4)")
    acfg = await tb.host.acfg_run(start_nodes=True)
    note(f"master: configuration list done, {acfg['nodes_ok']} nodes configured and started, "
         f"{acfg['nodes_fail']} failed")
    await tb.wait_for(tb.all_operational, 2_000, 10, "operational")
    note("all drives operational (state read inside each drive)")
    names = [await tb.host.sdo_upload(s.node_id, 0x1008, 0) for s in tb.slaves]
    shown = sorted({n.decode(errors="replace") for n in names})
    note(f"host: segmented SDO upload of 1008h (device name) from drives 1-4: {shown}")
    for ch, s in enumerate(tb.slaves):
        # set-point to the drive's RPDO1 (controlword + target position), feedback from its
        # TPDO1 (statusword + actual position), both every SYNC
        await tb.host.tpdo_config(ch, 0x200 + s.node_id, 6, 1)
        await tb.host.tpdo_write(ch, (0x000F).to_bytes(2, "little")
                                 + (10_000 * s.node_id).to_bytes(4, "little"))
        await tb.host.rpdo_config(ch, 0x180 + s.node_id, 6, 1)
    note("host: PDOs configured: set-points 201h..204h and feedback 181h..184h every SYNC")
    await tb.host.sync_config(period_us=2000, overflow=16)
    note("host: SYNC 2000 us, counter overflow 16 (4 axes x 2 PDOs: ~43 % bus load)")
    await Timer(40, "ms")
    feedback = [await tb.host.rpdo_read(ch) for ch in range(4)]
    note("host: feedback PDO sequence numbers " + ", ".join(str(f["seq"]) for f in feedback)
         + "; target positions inside the drives "
         + ", ".join(str(s.read(0x607A, 0)) for s in tb.slaves))
    tb.slave(3).power_off()
    note("drive 3 loses power")
    t_off = sim_time_ps()
    lost_at = None
    while sim_time_ps() < t_off + 60 * PS_PER_MS:
        st = await tb.host.node_status(2)
        if st["lost"]:
            lost_at = sim_time_ps()
            note("master: node 3 heartbeat lost (NODE_STATUS.LOST, interrupt)")
            break
        await Timer(500, "us")
    await Timer(10, "ms")
    await tb.host.sync_config(period_us=0, enable=False)
    await Timer(2, "ms")

    # ------------------------------------------------------------------ report
    frames = tb.frames()
    for r in frames:
        cid, data = r.msg.arbitration_id, bytes(r.msg.data)
        if cid == 0x000:
            events.append((r.t_start_ps, f"bus: NMT {NMT_NAMES.get(data[0], hex(data[0]))} "
                                         f"node {data[1] or 'all'}"))
        elif 0x701 <= cid <= 0x77F and data == b"\x00":
            events.append((r.t_start_ps, f"bus: boot-up of node {cid - 0x700}"))
        elif 0x081 <= cid <= 0x0FF:
            events.append((r.t_start_ps, f"bus: EMCY from node {cid - 0x080}"))
    events.sort()
    counts = Counter(classify(r.msg.arbitration_id, r.msg.is_remote_frame) for r in frames)
    sync = tb.sync_sof_times()
    periods = [b - a for a, b in zip(sync, sync[1:])]
    t0, t1 = frames[0].t_start_ps, frames[-1].t_end_ps
    load = tb.bus.load(t0, t1)
    nodes = []
    for slot, s in enumerate(tb.slaves):
        st = await tb.host.node_status(slot)
        nodes.append({"node": s.node_id, "ppm": s.clock.ppm,
                      "state_in_master": STATE_NAMES.get(st["nmt_state"], hex(st["nmt_state"])),
                      "alive": st["alive"], "lost": st["lost"],
                      "state_in_drive": s.nmt_state.name})
    counters = await tb.host.counters()
    pdo_counters = await tb.host.pdo_counters()
    summary = {
        "simulated_ms": round((t1 - t0) / PS_PER_MS, 3),
        "frames_by_type": dict(sorted(counts.items())),
        "bus_load_pct": round(100 * load, 2),
        "sync_frames": len(sync),
        "sync_period_us_min_max": [min(periods) / PS_PER_US, max(periods) / PS_PER_US],
        "sync_jitter_us": (max(periods) - min(periods)) / PS_PER_US,
        "loss_detected_ms_after_power_off": round((lost_at - t_off) / PS_PER_MS, 3)
        if lost_at else None,
        "nodes": nodes,
        "master_counters": counters,
        "pdo_counters": pdo_counters,
    }
    lines = ["CANopen master demo: 4-axis drive network, 1 Mbit/s, SYNC 2 ms", "",
             "Timeline"] + [timeline_line(t, e) for t, e in events] + ["", "Summary"]
    lines += ["  frames by type: " + ", ".join(f"{k}: {v}" for k, v in counts.most_common())]
    lines += [f"  bus load: {summary['bus_load_pct']} %   SYNC frames: {len(sync)}   "
              f"SYNC period {min(periods) / PS_PER_US:.3f}..{max(periods) / PS_PER_US:.3f} us "
              f"(jitter {summary['sync_jitter_us']:.3f} us)"]
    lines += [f"  node {n['node']} ({n['ppm']:+.0f} ppm): master sees {n['state_in_master']}, "
              f"alive={n['alive']}, lost={n['lost']}; drive reports {n['state_in_drive']}"
              for n in nodes]
    lines += [f"  loss of node 3 detected {summary['loss_detected_ms_after_power_off']} ms "
              f"after it lost power (heartbeat 10 ms, consumer time 25 ms)"]
    lines += ["  master counters: " + ", ".join(f"{k}={v}" for k, v in counters.items() if v)]
    lines += ["  PDO engine: " + ", ".join(f"{k}={v}" for k, v in pdo_counters.items() if v)]
    (OUT / "report.txt").write_text("\n".join(lines) + "\n")
    (OUT / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    tb.bus.write_trace(OUT / "demo_bus.log")
    tb.bus.write_trace(OUT / "demo_bus.asc")

    # ------------------------------------------------------------------ checks
    assert lost_at is not None, "the master did not report node 3"
    assert [n["lost"] for n in nodes] == [False, False, True, False], nodes
    assert acfg["nodes_ok"] == 4 and acfg["nodes_fail"] == 0, acfg
    assert names == [s.read_raw(0x1008, 0) for s in tb.slaves]
    for s in tb.slaves:
        assert s.read(0x1017, 0) == 10, f"node {s.node_id} 1017h not set by SDO"
        assert s.read(0x1A00, 1) == 0x6041_0010 and s.read(0x1600, 2) == 0x607A_0020
        assert s.read(0x607A, 0) == 10_000 * s.node_id, f"node {s.node_id} set-point"
    assert all(f["seq"] >= 18 for f in feedback), feedback
    assert counters["unexpected"] == 0, counters
    idle = [b - a for a, b in zip(sync[:20], sync[1:20])]
    assert set(idle) == {2000 * PS_PER_US}, set(idle)
    tb.check_models_clean()
    await Timer(1, "ns")


@pytest.mark.sim
def test_demo(request):
    run_cocotb(toplevel="canopen_master_top", module="tb.test_demo", name=request.node.name,
               parameters={"CLK_FREQ_HZ": 20_000_000, "SPI_SCLK_HZ": 5_000_000,
                           "OSC_FREQ_HZ": 16_000_000, "CAN_BITRATE_BPS": 1_000_000,
                           "MAX_NODES": 4, "RESET_WAIT_US": 20},
               stop_time_ms=2000, ieee_asserts="disable")


