"""Reference CANopen slave: NMT, boot-up, heartbeat, guarding, EMCY, TX queue, power, traces.

Each test drives the slave with raw frames from a QueueNode "master" on the CanBus model and
checks the frames on the bus (content and exact simulated timing).
"""

from __future__ import annotations

from typing import Any

import can
import pytest

from sim_models.can_bus import BusRecord, CanBus, NodeClock, QueueNode
from sim_models.canopen_slave import (
    DEFAULT_EDS,
    CanopenSlave,
    NmtState,
    build_slaves,
    make_message,
)
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler

BITRATE = 1_000_000
NODE = 5


class Rig:
    """Scheduler + 1 Mbit/s bus + QueueNode master + one slave (node 5 unless told)."""

    def __init__(self, node_id: int = NODE, ppm: float = 0.0, **slave_kw: Any) -> None:
        self.sched = Scheduler()
        self.bus = CanBus(self.sched, BITRATE)
        self.master = QueueNode("master", BITRATE)
        self.bus.attach(self.master)
        self.node_id = node_id
        self.slave = CanopenSlave(self.sched, node_id, bitrate_bps=BITRATE,
                                  clock=NodeClock(ppm), **slave_kw)
        self.bus.attach(self.slave)

    @property
    def now(self) -> int:
        return self.sched.now_ps

    def run(self, dt_ps: int) -> None:
        self.sched.run_until(self.sched.now_ps + dt_ps)

    def boot(self) -> None:
        self.run(self.slave.boot_time_ps + PS_PER_MS)
        assert self.slave.nmt_state is NmtState.PRE_OPERATIONAL

    def send(self, can_id: int, data: bytes = b"", rtr: bool = False,
             run_ps: int = PS_PER_MS) -> None:
        self.master.send(make_message(can_id, data, rtr, dlc=1 if rtr else None))
        self.run(run_ps)

    def frames(self, sender: str | None = None, can_id: int | None = None,
               since: int = 0) -> list[BusRecord]:
        return [r for r in self.bus.records if r.kind == "frame" and r.t_start_ps >= since
                and (sender is None or r.sender == sender)
                and (can_id is None or r.msg.arbitration_id == can_id)]

    def nmt(self, cs: int, node: int | None = None) -> None:
        self.send(0x000, bytes([cs, self.node_id if node is None else node]))

    def sdo(self, data: bytes) -> bytes:
        t0 = self.now
        self.send(0x600 + self.node_id, bytes(data).ljust(8, b"\0"))
        replies = self.frames(self.slave.name, 0x580 + self.node_id, since=t0)
        assert len(replies) == 1, replies
        return bytes(replies[0].msg.data)

    def sdo_write(self, index: int, sub: int, value: int, size: int) -> bytes:
        cmd = 0x23 | ((4 - size) << 2)
        return self.sdo(bytes([cmd, index & 0xFF, index >> 8, sub])
                        + value.to_bytes(size, "little"))


def test_bootup_after_power_on_exact_time_and_content() -> None:
    rig = Rig(ppm=100.0, boot_time_ps=2 * PS_PER_MS)
    rig.run(5 * PS_PER_MS)
    boots = rig.frames(rig.slave.name)
    assert len(boots) == 1
    msg = boots[0].msg
    assert msg.arbitration_id == 0x705 and bytes(msg.data) == b"\x00" and msg.dlc == 1
    assert not msg.is_remote_frame and not msg.is_extended_id
    # 2 ms of a +100 ppm clock, started at true time 0 (local 0)
    expected = rig.slave.clock.true_ps(2 * PS_PER_MS)
    assert expected == 1_999_800_020  # 2e9 / 1.0001, rounded
    assert boots[0].t_start_ps == expected
    assert rig.slave.state_log == [(0, NmtState.INITIALISING),
                                   (expected, NmtState.PRE_OPERATIONAL)]
    assert rig.slave.nmt_state is NmtState.PRE_OPERATIONAL


@pytest.mark.parametrize("cs", [0x81, 0x82])
def test_reset_node_and_reset_communication(cs: int) -> None:
    rig = Rig(reset_time_ps=500 * PS_PER_US)
    rig.boot()
    # a communication object (1017h) and an application object (6060h) away from defaults
    assert rig.sdo_write(0x1017, 0, 20, 2)[0] == 0x60
    assert rig.sdo_write(0x6060, 0, 3, 1)[0] == 0x60
    rig.nmt(0x01)
    assert rig.slave.nmt_state is NmtState.OPERATIONAL
    t_cmd = rig.now
    rig.nmt(cs)
    t_rx = rig.slave.rx_log[-1][0]  # end of EOF of the NMT frame
    boots = rig.frames(rig.slave.name, 0x705, since=t_cmd)
    assert [bytes(b.msg.data) for b in boots] == [b"\x00"]
    assert boots[0].t_start_ps == t_rx + 500 * PS_PER_US
    assert rig.slave.state_log[-2:] == [(t_rx, NmtState.INITIALISING),
                                        (t_rx + 500 * PS_PER_US, NmtState.PRE_OPERATIONAL)]
    assert rig.slave.read(0x1017) == 0  # comm parameters back to defaults either way
    assert rig.slave.read(0x6060) == (0 if cs == 0x81 else 3)  # application only on 0x81
    # no heartbeat any more (1017h = 0 again)
    t = rig.now
    rig.run(60 * PS_PER_MS)
    assert rig.frames(rig.slave.name, since=t) == []


def test_every_nmt_command_broadcast_and_foreign_node() -> None:
    rig = Rig()
    rig.boot()
    steps = [
        ((0x01, NODE), NmtState.OPERATIONAL),
        ((0x02, NODE), NmtState.STOPPED),
        ((0x80, NODE), NmtState.PRE_OPERATIONAL),
        ((0x02, 0), NmtState.STOPPED),  # broadcast
        ((0x01, 0), NmtState.OPERATIONAL),
        ((0x02, 6), NmtState.OPERATIONAL),  # another node: ignored
        ((0x81, 6), NmtState.OPERATIONAL),
        ((0x80, 0), NmtState.PRE_OPERATIONAL),
        ((0x05, NODE), NmtState.PRE_OPERATIONAL),  # unknown command specifier
    ]
    for (cs, node), state in steps:
        rig.nmt(cs, node)
        assert rig.slave.nmt_state is state, (hex(cs), node)
    # broadcast reset communication resets this node too
    rig.nmt(0x82, 0)
    rig.run(rig.slave.reset_time_ps)
    assert rig.slave.nmt_state is NmtState.PRE_OPERATIONAL
    assert [s for _, s in rig.slave.state_log] == [
        NmtState.INITIALISING, NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL,
        NmtState.STOPPED, NmtState.PRE_OPERATIONAL, NmtState.STOPPED, NmtState.OPERATIONAL,
        NmtState.PRE_OPERATIONAL, NmtState.INITIALISING, NmtState.PRE_OPERATIONAL]
    # the library's own NMT view follows
    assert rig.slave.node.nmt.state == "PRE-OPERATIONAL"


def test_service_availability_per_state() -> None:
    rig = Rig()
    rig.boot()
    upload_1000 = bytes([0x40, 0x00, 0x10, 0x00])
    # pre-operational: SDO yes, SYNC consumed, no PDO, EMCY yes
    assert rig.sdo(upload_1000)[0] == 0x43
    t = rig.now
    rig.send(0x080)
    assert rig.frames(rig.slave.name, since=t) == []
    assert len(rig.slave.sync_log) == 1
    assert rig.slave.emcy(0x1000, 0x01)
    rig.run(PS_PER_MS)
    # operational: TPDO1 (type 1) after SYNC
    rig.nmt(0x01)
    t = rig.now
    rig.send(0x080)
    assert [r.msg.arbitration_id for r in rig.frames(rig.slave.name, since=t)] == [0x185]
    # stopped: no SDO answer, no PDO, no EMCY, but guarding answers (error control)
    rig.nmt(0x02)
    t = rig.now
    rig.send(0x605, upload_1000.ljust(8, b"\0"))
    rig.send(0x080)
    assert not rig.slave.emcy(0x1000, 0x01)
    rig.send(0x705, rtr=True)
    got = rig.frames(rig.slave.name, since=t)
    assert [(r.msg.arbitration_id, bytes(r.msg.data)) for r in got] == [(0x705, b"\x04")]
    assert len(rig.slave.sync_log) == 2  # SYNC ignored in stopped


@pytest.mark.parametrize("ppm, period_true_ps", [
    (0.0, 100_000_000_000),
    (100.0, 99_990_001_000),  # 100 ms / 1.0001 = 99.990001 ms
    (-100.0, 100_010_001_000),  # 100 ms / 0.9999 = 100.010001 ms
])
def test_heartbeat_period_on_local_clock_and_rearm(ppm: float, period_true_ps: int) -> None:
    rig = Rig(ppm=ppm, boot_time_ps=0)
    rig.boot()
    clock = rig.slave.clock
    assert rig.sdo_write(0x1017, 0, 100, 2)[0] == 0x60
    t_write = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x605][-1]
    rig.run(450 * PS_PER_MS)
    hbs = rig.frames(rig.slave.name, 0x705, since=t_write)
    assert len(hbs) == 4
    assert all(bytes(h.msg.data) == b"\x7f" for h in hbs)
    anchor = clock.local_ps(t_write)
    for k, h in enumerate(hbs, start=1):
        assert h.t_start_ps == clock.true_ps(anchor + k * 100 * PS_PER_MS)
    for a, b in zip(hbs, hbs[1:]):
        assert abs((b.t_start_ps - a.t_start_ps) - period_true_ps) <= 1
    # state byte follows NMT state
    rig.nmt(0x01)
    # re-arm: writing 50 ms restarts the timer from the write
    assert rig.sdo_write(0x1017, 0, 50, 2)[0] == 0x60
    t_write2 = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x605][-1]
    rig.run(120 * PS_PER_MS)
    hbs2 = rig.frames(rig.slave.name, 0x705, since=t_write2)
    anchor2 = clock.local_ps(t_write2)
    assert [h.t_start_ps for h in hbs2] == [clock.true_ps(anchor2 + k * 50 * PS_PER_MS)
                                            for k in (1, 2)]
    assert all(bytes(h.msg.data) == b"\x05" for h in hbs2)
    # 0 switches the producer off
    assert rig.sdo_write(0x1017, 0, 0, 2)[0] == 0x60
    t = rig.now
    rig.run(200 * PS_PER_MS)
    assert rig.frames(rig.slave.name, since=t) == []


def test_mute_heartbeat_keeps_timer_running() -> None:
    rig = Rig(boot_time_ps=0)
    rig.boot()
    rig.sdo_write(0x1017, 0, 10, 2)
    t_write = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x605][-1]
    rig.slave.mute_heartbeat(True)
    rig.run(35 * PS_PER_MS)
    assert rig.frames(rig.slave.name, 0x705, since=t_write) == []
    rig.slave.mute_heartbeat(False)
    rig.run(10 * PS_PER_MS)
    hbs = rig.frames(rig.slave.name, 0x705, since=t_write)
    assert [h.t_start_ps for h in hbs] == [t_write + 40 * PS_PER_MS]  # same grid as before


def test_node_guarding_toggle_bad_toggle_and_life_guarding() -> None:
    rig = Rig()
    rig.boot()
    replies: list[int] = []

    def poll() -> None:
        t = rig.now
        rig.send(0x705, rtr=True)
        got = rig.frames(rig.slave.name, 0x705, since=t)
        assert len(got) == 1 and got[0].msg.dlc == 1
        replies.append(got[0].msg.data[0])

    poll()
    poll()
    rig.nmt(0x01)
    poll()
    rig.slave.guarding_bad_toggle()
    poll()  # repeats the previous toggle (0) instead of alternating
    poll()  # then alternates again from there
    assert replies == [0x7F, 0xFF, 0x05, 0x05, 0x85]
    # heartbeat configured: guarding RTRs are not answered (CiA 301: heartbeat wins)
    rig.sdo_write(0x1017, 0, 1000, 2)
    t = rig.now
    rig.send(0x705, rtr=True)
    assert rig.frames(rig.slave.name, 0x705, since=t) == []
    rig.sdo_write(0x1017, 0, 0, 2)
    # life guarding: guard time 10 ms x factor 3 = 30 ms after the last RTR
    rig.sdo_write(0x100C, 0, 10, 2)
    rig.sdo_write(0x100D, 0, 3, 1)
    rig.send(0x705, rtr=True, run_ps=0)
    rig.run(PS_PER_MS)
    t_rtr = [t for t, m in rig.slave.rx_log if m.is_remote_frame][-1]
    assert rig.slave.life_guard_events == []
    rig.run(40 * PS_PER_MS)
    assert rig.slave.life_guard_events == [t_rtr + 30 * PS_PER_MS]
    emcy = rig.frames(rig.slave.name, 0x085)
    assert [bytes(e.msg.data) for e in emcy] == [bytes([0x30, 0x81, 0x10, 0, 0, 0, 0, 0])]


def test_emcy_frame_and_error_register() -> None:
    rig = Rig()
    rig.boot()
    t = rig.now
    assert rig.slave.emcy(0x5530, 0x81, b"\x11\x22")
    rig.run(PS_PER_MS)
    got = rig.frames(rig.slave.name, since=t)
    assert len(got) == 1
    assert got[0].msg.arbitration_id == 0x085 and got[0].msg.dlc == 8
    assert bytes(got[0].msg.data) == bytes([0x30, 0x55, 0x81, 0x11, 0x22, 0, 0, 0])
    assert rig.sdo(bytes([0x40, 0x01, 0x10, 0x00])) == bytes([0x4F, 0x01, 0x10, 0, 0x81, 0,
                                                              0, 0])
    # 1014h bit 31: EMCY invalid -> nothing sent, register still updated
    rig.sdo_write(0x1014, 0, 0x80000085, 4)
    t = rig.now
    assert not rig.slave.emcy(0x1000, 0x01)
    rig.run(PS_PER_MS)
    assert rig.frames(rig.slave.name, since=t) == []
    assert rig.slave.read(0x1001) == 0x01


def test_tx_queue_priority_fifo_and_response_delay() -> None:
    rig = Rig(response_delay_ps=200 * PS_PER_US)
    rig.boot()
    t = rig.now
    frames = [make_message(0x300, b"\x01"), make_message(0x100, b"\x02"),
              make_message(0x300, b"\x03"), make_message(0x200, b"\x04")]
    for m in frames:
        rig.slave.send_raw(m)
    rig.run(PS_PER_MS)
    got = [(r.msg.arbitration_id, r.msg.data[0]) for r in rig.frames(rig.slave.name, since=t)]
    assert got == [(0x100, 2), (0x200, 4), (0x300, 1), (0x300, 3)]
    # lost arbitration against the master is retried by the bus
    t = rig.now
    rig.slave.send_raw(make_message(0x181, b"\x55"))
    rig.master.send(make_message(0x080, b""))
    rig.run(PS_PER_MS)
    assert [r.msg.arbitration_id for r in rig.frames(since=t)] == [0x080, 0x181]
    # a reply is queued response_delay_ps (local time) after the request's end of frame
    t = rig.now
    rig.send(0x605, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    t_rx = rig.slave.rx_log[-1][0]
    reply = rig.frames(rig.slave.name, 0x585, since=t)
    assert reply[0].t_start_ps == t_rx + 200 * PS_PER_US


def test_power_off_is_silent_and_power_on_reboots() -> None:
    sched_rig = Rig(boot_time_ps=0)
    rig = sched_rig
    witness = QueueNode("witness", BITRATE)  # ACKs the master while the slave is off
    rig.bus.attach(witness)
    rig.boot()
    rig.sdo_write(0x1017, 0, 10, 2)
    rig.nmt(0x01)
    rig.run(30 * PS_PER_MS)
    assert len(rig.frames(rig.slave.name, 0x705)) >= 2
    rig.slave.power_off()
    assert rig.slave.bitrate_bps is None and rig.slave.nmt_state is NmtState.OFF
    t = rig.now
    n_rx = len(rig.slave.rx_log)
    rig.send(0x605, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    rig.send(0x080)
    rig.send(0x705, rtr=True)
    rig.run(100 * PS_PER_MS)
    assert rig.frames(rig.slave.name, since=t) == []
    assert len(rig.slave.rx_log) == n_rx
    assert all(r.kind == "frame" for r in rig.bus.records)  # the witness ACKed everything
    rig.slave.power_on()
    t_on = rig.now
    rig.run(50 * PS_PER_MS)
    got = rig.frames(rig.slave.name, since=t)
    # boot-up only: the power-on reset restored 1017h = 0
    assert [(r.t_start_ps, bytes(r.msg.data)) for r in got] == [(t_on, b"\x00")]
    assert rig.slave.nmt_state is NmtState.PRE_OPERATIONAL


def test_four_slaves_golden_cycle_and_trace_files(tmp_path: Any) -> None:
    sched = Scheduler()
    bus = CanBus(sched, BITRATE)
    master = QueueNode("master", BITRATE)
    bus.attach(master)
    slaves = build_slaves(sched, bus, [1, 2, 3, 4], ppm=[0.0, 100.0, -100.0, 50.0],
                          boot_time_ps=500 * PS_PER_US)
    sched.run_until(2 * PS_PER_MS)
    boot_ids = sorted(r.msg.arbitration_id for r in bus.records)
    assert boot_ids == [0x701, 0x702, 0x703, 0x704]
    for i, s in enumerate(slaves, start=1):
        s.write(0x6064, 0, 1000 * i)  # position actual
    master.send(make_message(0x000, b"\x01\x00"))  # start all
    for _ in range(3):
        master.send(make_message(0x080, b""))
        sched.run_until(sched.now_ps + PS_PER_MS)
    frames = [r for r in bus.records if r.kind == "frame"]
    syncs = [i for i, r in enumerate(frames) if r.msg.arbitration_id == 0x080]
    assert len(syncs) == 3
    for i in syncs:
        after = frames[i + 1:i + 5]
        assert [r.msg.arbitration_id for r in after] == [0x181, 0x182, 0x183, 0x184]
        for k, r in enumerate(after, start=1):
            # statusword 0x0040 (switch on disabled) + position actual 1000 * k
            assert bytes(r.msg.data) == (0x0040).to_bytes(2, "little") + \
                (1000 * k).to_bytes(4, "little", signed=True)
    log = tmp_path / "golden.log"
    asc = tmp_path / "golden.asc"
    bus.write_trace(log)
    bus.write_trace(asc)
    parsed = list(can.CanutilsLogReader(str(log)))
    assert [(m.arbitration_id, bytes(m.data)) for m in parsed] == \
        [(r.msg.arbitration_id, bytes(r.msg.data)) for r in frames]
    assert [m.timestamp for m in parsed] == pytest.approx(
        [r.t_start_ps / 1e12 for r in frames], abs=1e-6)
    assert len(list(can.ASCReader(str(asc)))) == len(frames)


def test_default_eds_identity_and_node_relative_cob_ids() -> None:
    rig = Rig(node_id=0x23)
    rig.boot()
    s = rig.slave
    assert DEFAULT_EDS.name == "cia402_drive.eds"
    assert s.read(0x1000) == 0x00020192
    assert s.read(0x1400, 1) == 0x223 and s.read(0x1800, 1) == 0x1A3
    assert s.read(0x1401, 1) == 0x80000323  # RPDO2 not valid by default
    assert s.read(0x1014) == 0xA3 and s.read(0x1200, 2) == 0x5A3
    assert s.read(0x1A00, 1) == 0x60410010 and s.read(0x1A00, 2) == 0x60640020
    assert s.read(0x1600, 1) == 0x60400010 and s.read(0x1600, 2) == 0x607A0020
    assert s.read(0x1018, 4) == 0x5E000023
    assert len(s.read(0x1008)) > 4  # segmented upload material


def test_heartbeat_consumer_timeout_on_local_clock() -> None:
    rig = Rig(ppm=-100.0)
    rig.boot()
    # 1016h sub1: monitor node 0x7F (e.g. the master) with 20 ms
    assert rig.sdo_write(0x1016, 1, (0x7F << 16) | 20, 4)[0] == 0x60
    rig.run(50 * PS_PER_MS)
    assert rig.slave.heartbeat_timeouts == []  # not armed before the first heartbeat
    for _ in range(3):
        rig.send(0x77F, b"\x05", run_ps=15 * PS_PER_MS)  # every 15 ms: fine
    assert rig.slave.heartbeat_timeouts == []
    t_last = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x77F][-1]
    rig.run(30 * PS_PER_MS)
    clock = rig.slave.clock
    t_out = clock.true_ps(clock.local_ps(t_last) + 20 * PS_PER_MS)
    assert rig.slave.heartbeat_timeouts == [(t_out, 0x7F)]
    emcy = rig.frames(rig.slave.name, 0x085)
    assert [bytes(e.msg.data) for e in emcy] == [bytes([0x30, 0x81, 0x10, 0x7F, 0, 0, 0, 0])]
    assert emcy[0].t_start_ps == t_out
