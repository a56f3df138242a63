"""OmniSlave behaviours: NMT, node query, parameters, broadcast slot, sample loop, re-phase
modes, feedback, T_post; OmniMaster: feasibility rule (the RTL's) and refusal, node
monitoring."""

from __future__ import annotations

import pytest

from sim_models.can_bus import CanBus, QueueNode, frame_length_bits
from sim_models.canopen_slave import make_message
from sim_models.omni import (
    InfeasibleConfiguration,
    OmniMaster,
    OmniSlave,
    broadcast_dlc,
    check_feasibility,
    clock_for_period_error,
    setpoint_value,
)
from sim_models.omni import codec as oc
from sim_models.omni.master_model import wc_bits
from sim_models.omni.slave import FEEDBACK_DLC
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler

RATE = 1_000_000
T_S = PS_PER_MS


class Rig:
    def __init__(self, **slave_kwargs) -> None:
        self.sched = Scheduler()
        self.bus = CanBus(self.sched, RATE)
        self.pc = self.bus.attach(QueueNode("pc", RATE))
        kw = {"bitrate_bps": RATE, "period_ps": T_S, **slave_kwargs}
        self.slaves = [self.bus.attach(OmniSlave(self.sched, n, **kw))
                       for n in oc.THESIS_SLAVE_IDS]

    def send(self, *msgs) -> None:
        self.pc.send(*msgs)

    def run(self, dt_ps: int) -> None:
        self.sched.run_until(self.sched.now_ps + dt_ps)

    def eof(self, msg) -> int:
        return self.bus.duration_ps(frame_length_bits(msg) - 3)


def test_nmt_states_and_sample_loop() -> None:
    rig = Rig(feedback=False)
    s4, s8 = rig.slaves[0], rig.slaves[1]
    rig.run(3 * T_S)
    assert not s4.started and not s4.control_log  # stopped after power-up
    rig.send(oc.nmt_frame(0x04, oc.NMT_START))
    rig.run(T_S // 2)
    assert s4.started and not s8.started
    t_rx = rig.eof(oc.nmt_frame(4, 1)) + 3 * T_S
    rig.send(oc.nmt_frame(0, oc.NMT_START), make_message(0, b"\x04\x07"))
    rig.run(5 * T_S)
    assert s8.started
    assert s4.rejected and s4.rejected[0][2].startswith("NMT state 7")
    ticks = [t.t_ps for t in s4.control_log]
    assert ticks[:5] == [t_rx + (k + 1) * T_S for k in range(5)]  # 0 ppm: exact grid
    rig.send(oc.nmt_frame(0, oc.NMT_STOP))
    rig.run(T_S // 2)
    n = len(s4.control_log)
    rig.run(5 * T_S)
    assert not s4.started and len(s4.control_log) == n
    assert [st for _, st in s4.state_log] == [True, False]


def test_node_query_reply_in_both_states() -> None:
    rig = Rig()
    rig.send(oc.node_query_frame())
    rig.run(T_S)
    replies = [r.msg.arbitration_id for r in rig.bus.records if r.msg.is_remote_frame
               and r.msg.arbitration_id]
    assert replies == [0x04, 0x08, 0x10, 0x20]
    assert all(r.msg.dlc == 0 for r in rig.bus.records)
    assert all(len(s.query_log) == 1 for s in rig.slaves)


def test_parameters_stored_by_type_only_for_own_id() -> None:
    rig = Rig()
    rig.send(oc.data_frame(oc.FC_PARAM, 0x08, 0x02, 0x01, 0x64, 2),
             oc.data_frame(oc.FC_PARAM, 0x08, 0x02, 0x33, -5, 4),
             oc.data_frame(oc.FC_PD_010, 0x08, 0x02, 0x01, 7, 2))
    rig.run(T_S)
    s8 = rig.slaves[1]
    assert s8.parameters == {0x01: b"\x00\x64", 0x33: (-5).to_bytes(4, "big", signed=True)}
    assert all(not s.parameters for s in rig.slaves if s is not s8)


def test_broadcast_slot_per_axis_and_sender_filter() -> None:
    rig = Rig(feedback=False)
    rig.send(oc.nmt_frame(0, oc.NMT_START))
    rig.run(T_S // 2)
    rig.send(oc.broadcast_frame(oc.FC_BCAST_8X1, 0x02, [11, -22, 33, -44]))
    rig.send(oc.broadcast_frame(oc.FC_BCAST_8X1, 0x03, [1, 2, 3, 4]))  # not the master
    rig.run(T_S)
    assert [s.control_log[0].value for s in rig.slaves] == [11, -22, 33, -44]
    assert [s.control_log[0].status for s in rig.slaves] == ["new"] * 4


def test_feedback_frame_layout() -> None:
    rig = Rig()
    rig.send(oc.nmt_frame(0, oc.NMT_START))
    rig.run(T_S // 2)
    rig.send(oc.broadcast_frame(oc.FC_BCAST_8X1, 0x02, [5, 6, 7, -8]))
    rig.run(T_S)
    fb = {r.msg.arbitration_id: bytes(r.msg.data) for r in rig.bus.records
          if r.msg.arbitration_id in (0x202, 0x302, 0x502, 0x602)}
    # [sender][type 00][echo int16][sample index uint16]
    assert fb == {0x202: bytes([4, 0, 0, 5, 0, 0]), 0x302: bytes([8, 0, 0, 6, 0, 0]),
                  0x502: bytes([0x10, 0, 0, 7, 0, 0]), 0x602: bytes([0x20, 0, 0xFF, 0xF8, 0, 0])}
    assert {len(v) for v in fb.values()} == {FEEDBACK_DLC}


def test_clock_for_period_error() -> None:
    for rho in (3618.0, -3618.0, 100.0, -50.0):
        clock = clock_for_period_error(rho)
        t_true = clock.true_ps(clock.local_ps(0) + 5 * PS_PER_MS)
        assert abs(t_true - 5 * PS_PER_MS * (1 + rho * 1e-6)) <= 1


def test_dropout_decision_against_cycle_value() -> None:
    """Sample n needs set-point (n + cycle_offset); stale, missing and early values drop."""
    rig = Rig(feedback=False)
    s4 = rig.slaves[0]
    rig.send(oc.nmt_frame(0, oc.NMT_START))
    rig.run(T_S // 2)  # tick 0 at ~1.06 ms
    for c in (0, 2, 2):  # cycle 0, then cycle 2 early (tick 1 wants 1), tick 2 stale? no:
        rig.send(oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [setpoint_value(c, a)
                                                       for a in (1, 2, 3, 4)]))
        rig.run(T_S)
    log = s4.control_log
    assert [(t.expected_cycle, t.value, t.dropout) for t in log[:3]] == [
        (0, 0, False), (1, 2, True), (2, 2, False)]
    rig.run(T_S)
    assert log[3].status == "missing" and log[3].dropout


def test_thesis_rephase_on_every_kth_broadcast() -> None:
    """K = 3: samples 0, 3, 6 are placed by the broadcast reception (+ phase)."""
    rho, phase = 2000.0, 50 * PS_PER_US
    sched = Scheduler()
    bus = CanBus(sched, RATE)
    master = bus.attach(OmniMaster(sched, bitrate_bps=RATE, period_ps=T_S, n_cycles=12))
    slave = bus.attach(OmniSlave(sched, 0x04, bitrate_bps=RATE, period_ps=T_S,
                                 clock=clock_for_period_error(rho), feedback=False,
                                 resync="thesis", resync_k=3, sample_phase_ps=phase))
    master.start()
    sched.run_until(14 * T_S)
    rx = [t for t, m in slave.rx_log if m.arbitration_id == 0x102]
    log = slave.control_log
    assert [t.tick for t in log if t.rephase] == [0, 3, 6, 9]
    assert len(slave.rephase_log) == 4
    clock = slave.clock
    for t in log:
        if t.rephase:
            r = rx[t.tick]
            assert t.t_ps == clock.true_ps(clock.local_ps(r) + phase)
        else:
            prev = log[t.tick - 1]
            assert t.t_ps == clock.true_ps(prev.t_local_ps + T_S) or \
                abs(t.t_ps - clock.true_ps(prev.t_local_ps + T_S)) <= 1
    assert not any(t.dropout for t in log if t.expected_cycle < 12)


@pytest.mark.parametrize("rho, pulled_in", [(1000.0, True), (-1000.0, False)])
def test_sync_frame_rephase_pulls_in_or_defers(rho: float, pulled_in: bool) -> None:
    sched = Scheduler()
    bus = CanBus(sched, RATE)
    master = bus.attach(OmniMaster(sched, bitrate_bps=RATE, period_ps=T_S, n_cycles=25,
                                   sync_every=10))
    slave = bus.attach(OmniSlave(sched, 0x04, bitrate_bps=RATE, period_ps=T_S,
                                 clock=clock_for_period_error(rho), feedback=False,
                                 resync="sync_frame"))
    master.start()
    sched.run_until(27 * T_S)
    syncs = [t for t, m in slave.rx_log if oc.is_omni_sync(m)]
    assert len(syncs) == 3 and [r[0] for r in slave.rephase_log] == syncs
    by_tick = {t.tick: t for t in slave.control_log}
    # the SYNC of cycle 10: the slow slave's pending sample 10 is pulled in to the SYNC; the
    # fast slave had already taken sample 10 before it, its next sample is a period later
    t10, t11 = by_tick[10], by_tick[11]
    if pulled_in:
        assert t10.rephase and t10.t_ps == syncs[1]
    else:
        clock = slave.clock
        assert not t10.rephase and t10.t_ps < syncs[1]
        assert t11.rephase and t11.t_ps == clock.true_ps(clock.local_ps(syncs[1]) + T_S)
    assert not any(t.dropout for t in slave.control_log if t.expected_cycle < 25)


def test_t_post_delays_reception() -> None:
    t_post = 88_800 * 1000
    rig = Rig(feedback=False, t_post_ps=t_post)
    rig.send(oc.nmt_frame(0, oc.NMT_START))
    rig.run(T_S // 2)
    msg = oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [1, 2, 3, 4])
    t0 = rig.sched.now_ps
    rig.send(msg)
    rig.run(T_S)
    assert rig.slaves[0].control_log[0].value_t_ps == t0 + rig.eof(msg) + t_post


def test_master_refuses_infeasible_configuration() -> None:
    feas = check_feasibility(125_000, 8, T_S)
    assert not feas.ok and "infeasible" in feas.reason and feas.cmd_wc_ps == 135 * 8_000_000
    with pytest.raises(InfeasibleConfiguration, match="125000 bit/s, DLC 8"):
        OmniMaster(Scheduler(), bitrate_bps=125_000, period_ps=T_S, n_axes=7)
    assert check_feasibility(1_000_000, 8, T_S).ok
    OmniMaster(Scheduler(), bitrate_bps=125_000, period_ps=T_S, n_axes=7,
               allow_infeasible=True)
    # the RTL rule counts the feedback slots: the trace's DLC 5 broadcast fits 1 ms at
    # 125 kbit/s (105 bits = 840 us), not with one 6-byte feedback frame (+115 bits)
    OmniMaster(Scheduler(), bitrate_bps=125_000, period_ps=T_S, n_axes=4)
    with pytest.raises(InfeasibleConfiguration, match="feedback 115 = 220 bits"):
        OmniMaster(Scheduler(), bitrate_bps=125_000, period_ps=T_S, n_axes=4,
                   feedback_dlcs=(FEEDBACK_DLC,))


def test_feasibility_rule_is_the_rtl_rule() -> None:
    """bits = wc(broadcast DLC) [+ wc(0) SYNC] + sum wc(feedback DLC); feasible iff
    bits * t_bit + margin <= T_s (docs/omni_engine.md "Feasibility")."""
    assert [wc_bits(n) for n in range(16)] == [55 + 10 * n for n in range(9)] + [135] * 7
    with pytest.raises(ValueError):
        wc_bits(16)
    f = check_feasibility(1_000_000, 5, 620 * PS_PER_US, sync=True, feedback_dlcs=(6,) * 4)
    assert (f.bits, f.cmd_bits, f.sync_bits, f.feedback_bits) == (620, 105, 55, 460)
    assert f.ok and f.busy_ps == f.min_period_ps == 620 * PS_PER_US
    assert not check_feasibility(1_000_000, 5, 620 * PS_PER_US - 1, sync=True,
                                 feedback_dlcs=(6,) * 4).ok
    # the margin is an option (experiments), 0 by default as in the RTL
    assert not check_feasibility(1_000_000, 5, 620 * PS_PER_US, sync=True,
                                 feedback_dlcs=(6,) * 4, margin_ps=1).ok
    m = check_feasibility(1_000_000, 5, 720 * PS_PER_US, sync=True, feedback_dlcs=(6,) * 4,
                          margin_ps=100 * PS_PER_US)
    assert m.ok and m.min_period_ps == 720 * PS_PER_US
    # the Omni SYNC counts wc(0) = 55 bits (its real length is fixed and shorter)
    assert frame_length_bits(oc.omni_sync_frame()) <= check_feasibility(
        RATE, 0, T_S, sync=True).sync_bits == 55
    # exact at a rate that is not a whole number of ns per bit: 135 bits at 3 Mbit/s = 45 us
    assert check_feasibility(3_000_000, 8, 45 * PS_PER_US).ok
    assert not check_feasibility(3_000_000, 8, 45 * PS_PER_US - 1).ok
    # broadcast DLC of the engine's OMNI_CFG layouts (sender byte included)
    assert broadcast_dlc(4) == 5 and broadcast_dlc(8, with_sender=False) == 8
    assert broadcast_dlc(4, oc.FC_BCAST_4X2, with_sender=True) == 8  # SENDER ignored
    for bad in ((0,), (8,), (9, oc.FC_BCAST_8X1, False), (5, oc.FC_BCAST_4X2)):
        with pytest.raises(ValueError):
            broadcast_dlc(*bad)


def test_master_node_monitoring_detects_missing_slave() -> None:
    sched = Scheduler()
    bus = CanBus(sched, RATE)
    master = bus.attach(OmniMaster(sched, bitrate_bps=RATE, period_ps=T_S, query_every=4,
                                   query_nodes=oc.THESIS_SLAVE_IDS))
    slaves = [bus.attach(OmniSlave(sched, n, bitrate_bps=RATE, period_ps=T_S))
              for n in oc.THESIS_SLAVE_IDS]
    master.start()
    sched.run_until(10 * T_S)
    assert len(master.query_log) >= 1 and not master.error
    slaves[2].bitrate_bps = None  # node 0x10 leaves the bus
    t_off = sched.now_ps
    sched.run_until(30 * T_S)
    assert master.error
    t_query, t_check, missing = next(q for q in master.query_log if q[2])
    assert missing == (0x10,) and t_query >= t_off and t_check - t_query == T_S
    stops = [t for t, m in master.tx_log if m.arbitration_id == 0 and bytes(m.data) == b"\0\0"]
    assert stops and stops[0] > t_check
    assert not any(s.started for s in slaves if s is not slaves[2])
