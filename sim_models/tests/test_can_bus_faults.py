"""Fault confinement tests of sim_models.can_bus: ACK/CRC/bit-rate errors, TEC/REC, bus-off."""

from __future__ import annotations

import can
import pytest

from sim_models.can_bus import (
    BITRATE_ERROR_BIT,
    BUS_OFF_RECOVERY_BITS,
    CanBus,
    QueueNode,
    frame_length_bits,
    stuffed_length,
)
from sim_models.sim_time import PS_PER_MS, Scheduler

RATE = 125_000
BIT_PS = 8_000_000
SYNC = can.Message(arbitration_id=0x080, is_extended_id=False)
SYNC_STUFFED = 38  # see test_can_bus.test_frame_bits_sync_by_hand


def std(ident: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=ident, data=data, is_extended_id=False)


def make_bus(*nodes: tuple[str, int | None]) -> tuple[Scheduler, CanBus, list[QueueNode]]:
    sched = Scheduler()
    bus = CanBus(sched, RATE)
    return sched, bus, [bus.attach(QueueNode(name, rate)) for name, rate in nodes]


def counters(*nodes: QueueNode) -> list[tuple[int, int]]:
    return [(n.tec, n.rec) for n in nodes]


# ------------------------------------------------------------------------------------------
# ACK errors
# ------------------------------------------------------------------------------------------


def test_lone_node_ack_errors_end_error_passive_not_bus_off() -> None:
    assert stuffed_length(SYNC) == SYNC_STUFFED
    sched, bus, (a,) = make_bus(("a", RATE))
    a.send(SYNC)
    sched.run(200 * PS_PER_MS)  # hundreds of retransmissions
    errs = bus.records
    assert len(errs) > 100
    assert all(r.kind == "error" and r.reason == "ack" and r.sender == "a" for r in errs)
    # ACK error detected at the ACK slot, error flag from the ACK delimiter: L + 2 + 17 bits
    assert all(r.n_bits == SYNC_STUFFED + 2 + 17 for r in errs)
    assert all(r.t_end_ps - r.t_start_ps == r.n_bits * BIT_PS for r in errs)
    # TEC += 8 up to error-passive (16 errors), then the passive ACK-error exception
    assert a.tec == 128 and a.error_state == "error_passive"
    assert a.state_changes == [
        (errs[15].t_start_ps + (SYNC_STUFFED + 2) * BIT_PS, "error_active", "error_passive")]
    assert [t for t, _ in a.errors[:3]] == [r.t_start_ps + 40 * BIT_PS for r in errs[:3]]
    assert len(a.errors) - len(errs) in (0, 1)  # +1 if the last error frame is in flight
    # retransmission back to back while error-active, 8 bits of suspend transmission after
    gaps = [(n.t_start_ps - p.t_end_ps) // BIT_PS for p, n in zip(errs, errs[1:])]
    assert gaps[:15] == [0] * 15
    assert set(gaps[15:]) == {8}
    assert a.sent == [] and a.queue == [SYNC]
    # a second node appears: the frame is acknowledged, TEC 128 -> 127 (error-active again)
    b = bus.attach(QueueNode("b", RATE))
    sched.run(sched.now_ps + 2 * PS_PER_MS)
    assert [r.kind for r in bus.records[-1:]] == ["frame"]
    assert a.tec == 127 and a.error_state == "error_active"
    assert a.state_changes[-1][1:] == ("error_passive", "error_active")
    assert [m.arbitration_id for _, m in b.received] == [0x080]
    assert bus.stats["errors_ack"] == bus.stats["error_frames"] == len(bus.records) - 1


def test_ack_error_exception_only_when_error_passive() -> None:
    sched, bus, (a,) = make_bus(("a", RATE))
    a.set_error_counters(tec=124)
    a.send(SYNC)
    sched.run_until(60 * BIT_PS)
    assert a.tec == 132 and a.error_state == "error_passive"  # +8 while active
    sched.run_until(200 * BIT_PS)
    assert a.tec == 132  # no change while passive


def test_listen_only_node_never_acks_transmits_or_counts() -> None:
    sched, bus, (a,) = make_bus(("a", RATE))
    spy = bus.attach(QueueNode("spy", RATE, listen_only=True))
    spy.send(std(0x001))
    a.send(SYNC)
    sched.run_until(300 * BIT_PS)
    assert bus.records and all(r.reason == "ack" and r.sender == "a" for r in bus.records)
    assert spy.received == [] and spy.sent == [] and counters(spy) == [(0, 0)]
    assert len(spy.bus_errors) >= len(bus.records)
    # with an ACKing node the frame goes through; the listen-only node receives it
    b = bus.attach(QueueNode("b", RATE))
    sched.run(sched.now_ps + 5 * PS_PER_MS)
    frames = [r for r in bus.records if r.kind == "frame"]
    assert [r.sender for r in frames] == ["a"]
    assert set(frames[0].receivers) == {"spy", "b"}
    assert [m.arbitration_id for _, m in spy.received] == [0x080]
    assert spy.sent == [] and counters(spy) == [(0, 0)] and b.rec == 0


# ------------------------------------------------------------------------------------------
# injected CRC errors
# ------------------------------------------------------------------------------------------


def test_corrupt_next_frame_then_successful_retransmission() -> None:
    sched, bus, (a, b, c) = make_bus(("a", RATE), ("b", RATE), ("c", RATE))
    snapshots: list[list[tuple[int, int]]] = []
    bus.add_listener(lambda r: snapshots.append(counters(a, b, c)))
    bus.corrupt_next_frame()
    a.send(SYNC)
    sched.run(5 * PS_PER_MS)
    err, ok = bus.records
    assert (err.kind, err.reason, err.sender) == ("error", "crc", "a")
    # detected at the ACK delimiter, error flag from the next bit: L + 3 + 17 bits
    assert err.n_bits == SYNC_STUFFED + 3 + 17
    assert err.t_end_ps == err.n_bits * BIT_PS
    assert ok.kind == "frame" and ok.t_start_ps == err.t_end_ps  # error-active: no suspend
    assert snapshots == [[(8, 0), (0, 1), (0, 1)], [(7, 0), (0, 0), (0, 0)]]
    assert a.errors == [((SYNC_STUFFED + 3) * BIT_PS, "crc")]
    assert b.bus_errors == c.bus_errors == [((SYNC_STUFFED + 3) * BIT_PS, "crc")]
    assert [t for t, _ in b.received] == [ok.t_start_ps + 48 * BIT_PS]  # only one copy
    assert a.sent == [(ok.t_start_ps + 48 * BIT_PS, SYNC)]
    assert bus.stats["errors_crc"] == 1 and bus.stats["frames_ok"] == 1


def test_corrupt_next_frame_of_one_sender() -> None:
    sched, bus, (a, b, c) = make_bus(("a", RATE), ("b", RATE), ("c", RATE))
    bus.corrupt_next_frame(sender="b", count=2)
    a.send(std(0x100))
    b.send(std(0x200))
    sched.run(10 * PS_PER_MS)
    assert [(r.sender, r.kind) for r in bus.records] == [
        ("a", "frame"), ("b", "error"), ("b", "error"), ("b", "frame")]
    assert counters(a, b, c) == [(0, 1), (15, 0), (0, 1)]
    with pytest.raises(ValueError):
        bus.corrupt_next_frame(count=0)


def test_error_passive_transmitter_crc_error_still_counts() -> None:
    sched, bus, (a, b) = make_bus(("a", RATE), ("b", RATE))
    a.set_error_counters(tec=130)
    bus.corrupt_next_frame()
    a.send(SYNC)
    sched.run(5 * PS_PER_MS)
    err, ok = bus.records
    assert a.tec == 137  # +8 (receivers flag actively), then -1
    # error-passive: 8 bits of suspend transmission after each of its transmissions
    assert ok.t_start_ps == err.t_end_ps + 8 * BIT_PS


def test_passive_rec_reset_and_decrement() -> None:
    sched, bus, (a, b, c) = make_bus(("a", RATE), ("b", RATE), ("c", RATE))
    b.set_error_counters(rec=200)
    c.set_error_counters(rec=5)
    assert b.error_state == "error_passive" and b.state_changes[-1][2] == "error_passive"
    a.send(SYNC)
    sched.run(2 * PS_PER_MS)
    assert b.rec == 127 and b.error_state == "error_active"
    assert c.rec == 4


# ------------------------------------------------------------------------------------------
# suspend transmission
# ------------------------------------------------------------------------------------------


def test_suspend_transmission_of_error_passive_node() -> None:
    sched, bus, (a, b) = make_bus(("a", RATE), ("b", RATE))
    a.set_error_counters(tec=200)
    a.send(std(0x100), std(0x101))
    sched.run(5 * PS_PER_MS)
    f1, f2 = bus.records
    assert f2.t_start_ps == f1.t_end_ps + 8 * BIT_PS
    assert bus.idle


def test_other_node_may_start_during_suspend_transmission() -> None:
    sched, bus, (a, b) = make_bus(("a", RATE), ("b", RATE))
    a.set_error_counters(tec=200)
    a.send(std(0x100), std(0x101), std(0x102))
    t1 = frame_length_bits(std(0x100)) * BIT_PS  # end of a's first frame
    # b starts 3 bits into a's suspend window; a then only receives, and competes normally
    # (no suspend: it did not transmit) at the following idle point
    sched.call_at(t1 + 3 * BIT_PS, b.send, std(0x300))
    sched.run(10 * PS_PER_MS)
    f1, f2, f3, f4 = bus.records
    assert (f1.sender, f1.t_start_ps, f1.t_end_ps) == ("a", 0, t1)
    assert (f2.sender, f2.t_start_ps) == ("b", t1 + 3 * BIT_PS)
    assert (f3.sender, f3.t_start_ps) == ("a", f2.t_end_ps)
    assert (f4.sender, f4.t_start_ps) == ("a", f3.t_end_ps + 8 * BIT_PS)
    assert a.lost == []


# ------------------------------------------------------------------------------------------
# bus-off
# ------------------------------------------------------------------------------------------


def test_force_bus_off_and_recovery_after_1408_bits() -> None:
    sched, bus, (a, b, c) = make_bus(("a", RATE), ("b", RATE), ("c", RATE))
    t0 = 3 * BIT_PS
    sched.call_at(t0, bus.force_bus_off, a)
    sched.call_at(t0, a.send, std(0x100))
    sched.call_at(t0, b.send, std(0x200))
    sched.run_until(t0 + 200 * BIT_PS)
    assert a.error_state == "bus_off" and a.tec > 255
    assert a.state_changes == [(t0, "error_active", "bus_off")]
    # a neither transmits nor receives; b's frame goes to c only
    assert [(r.sender, r.receivers) for r in bus.records] == [("b", ("c",))]
    assert a.received == [] and a.activity  # it still sees SOFs
    sched.run(t0 + 100 * PS_PER_MS)
    t_rec = t0 + BUS_OFF_RECOVERY_BITS * BIT_PS
    assert BUS_OFF_RECOVERY_BITS == 1408
    assert a.state_changes == [(t0, "error_active", "bus_off"),
                               (t_rec, "bus_off", "error_active")]
    assert (a.tec, a.rec) == (0, 0)
    # the pending frame competes as soon as a recovered (bus idle)
    assert (bus.records[-1].sender, bus.records[-1].t_start_ps) == ("a", t_rec)


def test_bus_off_without_automatic_recovery() -> None:
    sched, bus, (a, b) = make_bus(("a", RATE), ("b", RATE))
    a.auto_bus_off_recovery = False
    bus.force_bus_off(a)
    sched.run(50 * PS_PER_MS)
    assert a.error_state == "bus_off" and not a.bus_off_recovery_pending
    t1 = sched.now_ps
    a.request_bus_off_recovery()
    sched.run(t1 + 1407 * BIT_PS)
    assert a.error_state == "bus_off"
    sched.run(t1 + 1408 * BIT_PS)
    assert a.error_state == "error_active" and a.tec == 0


def test_crc_errors_drive_transmitter_bus_off() -> None:
    sched, bus, (a, b, c) = make_bus(("a", RATE), ("b", RATE), ("c", RATE))
    a.set_error_counters(tec=250)
    bus.corrupt_next_frame(sender="a")
    a.send(SYNC)
    b.send(std(0x200))
    sched.run(5 * PS_PER_MS)
    err = bus.records[0]
    t_flag = (SYNC_STUFFED + 3) * BIT_PS
    assert (err.reason, a.tec) == ("crc", 258)
    assert a.state_changes[-1] == (t_flag, "error_passive", "bus_off")
    assert [r.sender for r in bus.records[1:]] == ["b"]  # a does not retransmit while off
    t_rec = t_flag + BUS_OFF_RECOVERY_BITS * BIT_PS
    sched.run(t_rec + 60 * BIT_PS)
    assert a.error_state == "error_active"
    last = bus.records[-1]
    assert (last.sender, last.kind, last.t_start_ps) == ("a", "frame", t_rec)


def test_reset_fault_confinement() -> None:
    sched, bus, (a,) = make_bus(("a", RATE))
    bus.force_bus_off(a)
    assert a.bus_off_recovery_pending
    a.reset_fault_confinement()
    assert (a.tec, a.rec, a.error_state) == (0, 0, "error_active")
    assert not a.bus_off_recovery_pending


# ------------------------------------------------------------------------------------------
# bit-rate mismatch
# ------------------------------------------------------------------------------------------


def test_mismatched_receiver_destroys_frames_until_error_passive() -> None:
    sched, bus, (a, b, m) = make_bus(("a", RATE), ("b", RATE), ("m", 250_000))
    frames = [std(0x181, bytes([k])) for k in range(20)]
    a.send(*frames)
    sched.run(100 * PS_PER_MS)
    errs = [r for r in bus.records if r.kind == "error"]
    ok = [r for r in bus.records if r.kind == "frame"]
    assert [r.kind for r in bus.records] == ["error"] * 16 + ["frame"] * 20
    assert all(r.reason == "bitrate" and r.detector == "m" and r.sender == "a" for r in errs)
    assert all(r.n_bits == BITRATE_ERROR_BIT + 1 + 17 == 37 for r in errs)
    # 16 errors: a TEC 128 and m REC 128 (error-passive, its flag can no longer destroy)
    passive_at = errs[15].t_start_ps + 20 * BIT_PS
    assert m.state_changes == [(passive_at, "error_active", "error_passive")]
    assert a.state_changes == [(passive_at, "error_active", "error_passive"),
                               (ok[0].t_start_ps + (ok[0].n_bits - 3) * BIT_PS,
                                "error_passive", "error_active")]
    # then traffic flows: b gets everything in order, m nothing
    assert [bytes(msg.data) for _, msg in b.received] == [bytes([k]) for k in range(20)]
    assert m.received == [] and all(r.receivers == ("b",) for r in ok)
    assert a.tec == 128 - 20 and b.rec == 0 and m.rec == 255
    assert m.error_state == "error_passive"
    assert len(a.errors) == 16 and set(reason for _, reason in a.errors) == {"bitrate"}


def test_mismatched_transmitter_goes_bus_off() -> None:
    sched, bus, (b, m) = make_bus(("b", RATE), ("m", 100_000))
    m.send(SYNC)
    sched.run_until(12 * PS_PER_MS)
    # 32 errors of +8: 16 back to back, then 8-bit suspend gaps, then bus-off at TEC 256
    errs = bus.records
    assert len(errs) == 32 and m.error_state == "bus_off" and m.tec == 256
    assert all(r.reason == "bitrate" and r.detector == "m" for r in errs)
    assert b.received == [] and b.rec == 32 and b.error_state == "error_active"
    assert [s[2] for s in m.state_changes] == ["error_passive", "bus_off"]
    # b's own traffic now flows (no ACK from the bus-off node -> ACK error though)
    b.send(std(0x200))
    c = bus.attach(QueueNode("c", RATE))
    sched.run_until(14 * PS_PER_MS)
    assert bus.records[-1].sender == "b" and bus.records[-1].kind == "frame"
    assert [msg.arbitration_id for _, msg in c.received] == [0x200]


def test_lone_mismatched_transmitter_sees_ack_errors() -> None:
    sched, bus, (m,) = make_bus(("m", 250_000))
    m.send(SYNC)
    sched.run_until(60 * PS_PER_MS)
    assert {r.reason for r in bus.records} == {"ack"}
    assert m.error_state == "error_passive" and m.tec == 128


@pytest.mark.parametrize(("rate", "decodes"), [(125_600, True), (124_400, True),
                                               (125_700, False), (124_300, False)])
def test_bitrate_tolerance(rate: int, decodes: bool) -> None:
    sched, bus, (a, x) = make_bus(("a", RATE), ("x", rate))
    a.send(SYNC)
    sched.run_until(60 * BIT_PS)
    assert bus.records[0].kind == ("frame" if decodes else "error")
    assert bool(x.received) == decodes


def test_recovery_policy_as_class_attribute_and_idle_hook() -> None:
    class ManualNode(QueueNode):
        auto_bus_off_recovery = False

        def __init__(self, name: str) -> None:
            super().__init__(name, RATE)
            self.idle_at: list[int] = []

        def on_bus_idle(self, t_ps: int) -> None:
            self.idle_at.append(t_ps)

    sched, bus, (a,) = make_bus(("a", RATE))
    manual = bus.attach(ManualNode("manual"))
    bus.force_bus_off(manual)
    a.send(SYNC)
    sched.run(30 * PS_PER_MS)
    assert manual.error_state == "bus_off" and not manual.bus_off_recovery_pending
    # a is alone on the bus now (bus-off nodes do not ACK): ACK errors only
    assert {r.reason for r in bus.records} == {"ack"}
    assert manual.idle_at == [r.t_end_ps for r in bus.records]
