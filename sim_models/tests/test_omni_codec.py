"""Omni-ID codec (AT-1), the platform's event table (AT-2) and frame timing (AT-4)."""

from __future__ import annotations

import pytest

from sim_models.can_bus import (
    CanBus,
    QueueNode,
    arbitration_bits,
    frame_bits,
    stuff,
    worst_case_bits,
)
from sim_models.canopen_slave import make_message
from sim_models.omni import OmniMaster, OmniSlave
from sim_models.omni import codec as oc
from sim_models.sim_time import PS_PER_MS, PS_PER_S, Scheduler

#: Table 3-3 (first and last id of each function code)
TABLE_3_3 = {0: (0, 255), 1: (257, 511), 2: (513, 767), 3: (769, 1023), 4: (1025, 1279),
             5: (1281, 1535), 6: (1537, 1791), 7: (1793, 2047)}


def test_at1_id_codec_every_fc_and_node() -> None:
    for fc in range(8):
        for node in range(256):
            can_id = oc.omni_id(fc, node)
            assert can_id == fc * 256 + node
            assert oc.decode_id(can_id) == (fc, node)
    for fc, (lo, hi) in TABLE_3_3.items():
        r = oc.fc_id_range(fc)
        assert (r.start, r.stop - 1) == (lo, hi)
        assert all(oc.valid_omni_id(i) == (i in r) for i in range(fc * 256, fc * 256 + 256))
    with pytest.raises(oc.OmniFrameError):
        oc.omni_id(8, 0)
    with pytest.raises(oc.OmniFrameError):
        oc.omni_id(1, 256)
    with pytest.raises(oc.OmniFrameError):
        oc.decode_id(0x800)


def test_nmt_query_and_sync_frames() -> None:
    start = oc.nmt_frame(0, oc.NMT_START)
    assert (start.arbitration_id, start.dlc, bytes(start.data)) == (0, 2, b"\x00\x01")
    assert oc.parse_nmt(oc.nmt_frame(0x10, oc.NMT_STOP)) == (0x10, 0)
    with pytest.raises(oc.OmniFrameError):
        oc.nmt_frame(0, 2)  # A3: only 1 (start) and 0 (stop)
    with pytest.raises(oc.OmniFrameError):
        oc.parse_nmt(make_message(0, b"\x00\x05"))
    q = oc.node_query_frame()
    assert q.is_remote_frame and q.arbitration_id == 0 and q.dlc == 0 and oc.is_node_query(q)
    reply = oc.query_reply_frame(0x08)
    assert reply.is_remote_frame and reply.arbitration_id == 0x08 and reply.dlc == 0
    sync = oc.omni_sync_frame()
    assert (sync.arbitration_id, sync.dlc, sync.is_remote_frame) == (0x080, 0, False)
    assert oc.is_omni_sync(sync)
    # a node 0x80 answering a query sends RTR 0x080: not a SYNC, and it loses arbitration
    rtr80 = oc.query_reply_frame(0x80)
    assert not oc.is_omni_sync(rtr80)
    assert arbitration_bits(sync) < arbitration_bits(rtr80)


def test_broadcast_layouts() -> None:
    # A1: [sender][axis 4][axis 3][axis 2][axis 1], signed 1-byte slots
    msg = oc.broadcast_frame(oc.FC_BCAST_8X1, 0x02, [1, 2, 3, -4])
    assert msg.arbitration_id == 0x102
    assert bytes(msg.data) == bytes([0x02, 0xFC, 3, 2, 1])
    bc = oc.parse_broadcast(msg)
    assert bc.values == (1, 2, 3, -4) and bc.sender == 2 and bc.sender_byte == 2
    # text form without the sender byte (Table 4-2: 4 bytes)
    msg4 = oc.broadcast_frame(oc.FC_BCAST_8X1, 0x02, [1, 2, 3, 4], with_sender=False)
    assert bytes(msg4.data) == bytes([4, 3, 2, 1])
    assert oc.parse_broadcast(msg4, with_sender=False).values == (1, 2, 3, 4)
    # fc 100: 4 x 2 bytes big-endian, no sender byte
    m2 = oc.broadcast_frame(oc.FC_BCAST_4X2, 0x02, [0x0102, -2, 0, 0x7FFF])
    assert m2.arbitration_id == 0x402
    assert bytes(m2.data) == bytes([0x7F, 0xFF, 0, 0, 0xFF, 0xFE, 0x01, 0x02])
    assert oc.parse_broadcast(m2).values == (0x0102, -2, 0, 0x7FFF)
    for bad in (lambda: oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [0] * 8),
                lambda: oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [128]),
                lambda: oc.broadcast_frame(oc.FC_BCAST_4X2, 2, [0], with_sender=True),
                lambda: oc.broadcast_frame(oc.FC_PD_010, 2, [0])):
        with pytest.raises(oc.OmniFrameError):
            bad()
    assert len(oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [0] * 8, with_sender=False).data) == 8


def test_data_frames() -> None:
    msg = oc.data_frame(oc.FC_PARAM, 0x04, 0x02, oc.DTYPE_PARAMETER, 100, 2)
    assert msg.arbitration_id == 0x704 and bytes(msg.data) == bytes([2, 1, 0, 0x64])
    f = oc.parse_data_frame(msg)
    assert (f.fc, f.receiver, f.sender, f.dtype, f.value()) == (7, 4, 2, 1, 100)
    fb = oc.data_frame(oc.FC_PD_011, 0x02, 0x08, oc.DTYPE_FEEDBACK, -1)
    assert fb.arbitration_id == 0x302 and bytes(fb.data) == bytes([8, 0, 0xFF, 0xFF, 0xFF, 0xFF])
    assert oc.parse_data_frame(fb).value() == -1
    with pytest.raises(oc.OmniFrameError):
        oc.data_frame(oc.FC_BCAST_8X1, 2, 1, 0, 0)
    with pytest.raises(oc.OmniFrameError):
        oc.parse_data_frame(oc.broadcast_frame(oc.FC_BCAST_8X1, 2, [1]))


def test_at2_platform_event_table() -> None:
    """PC (0x01), master (0x02) and the four slaves of Table 4-2 at 1 Mbit/s, T_s = 10 ms."""
    sched = Scheduler()
    bus = CanBus(sched, 1_000_000)
    pc = bus.attach(QueueNode("pc", 1_000_000))
    master = bus.attach(OmniMaster(sched, bitrate_bps=1_000_000, period_ps=10 * PS_PER_MS,
                                   query_every=2, query_nodes=oc.THESIS_SLAVE_IDS,
                                   n_cycles=6))
    slaves = [bus.attach(OmniSlave(sched, n, bitrate_bps=1_000_000,
                                   period_ps=10 * PS_PER_MS)) for n in oc.THESIS_SLAVE_IDS]
    pc.send(oc.node_query_frame())
    sched.run_until(PS_PER_MS)
    pc.send(make_message(0x702, bytes([0x01, 0x0C, 0, 0, 0, 0x64])))  # Fig 4-19
    sched.run_until(2 * PS_PER_MS)
    pc.send(oc.nmt_frame(0x02, oc.NMT_START))  # Fig 4-20
    sched.run_until(80 * PS_PER_MS)
    frames = [r.msg for r in bus.records if r.kind == "frame"]
    ids = {m.arbitration_id for m in frames}
    assert ids == {0x000, 0x002, 0x004, 0x008, 0x010, 0x020, 0x102, 0x202, 0x302, 0x502,
                   0x602, 0x702, 0x704, 0x708, 0x710, 0x720}
    for m in frames:
        i, d = m.arbitration_id, bytes(m.data)
        if i in (0x002, 0x004, 0x008, 0x010, 0x020):
            assert m.is_remote_frame and m.dlc == 0
        elif i == 0x000:
            assert (m.is_remote_frame and m.dlc == 0) or (m.dlc == 2 and d[1] in (0, 1))
        elif i == 0x102:
            assert m.dlc == 5 and d[0] == 0x02
        elif i in (0x202, 0x302, 0x502, 0x602):
            assert m.dlc == 6 and d[0] == {0x202: 4, 0x302: 8, 0x502: 0x10, 0x602: 0x20}[i]
        elif i == 0x702:
            assert d == bytes([0x01, 0x0C, 0, 0, 0, 0x64])
        else:
            assert d == bytes([0x02, 0x01, 0x00, 0x64])  # forwarded setting (Fig 4-19)
    # Fig 4-18: replies in ascending id order; Fig 4-20: NMT 02 01 then 00 01
    replies = [m.arbitration_id for m in frames if m.is_remote_frame and m.arbitration_id]
    assert replies[:5] == [0x02, 0x04, 0x08, 0x10, 0x20]
    nmts = [bytes(m.data) for m in frames if m.arbitration_id == 0 and not m.is_remote_frame]
    assert nmts[:2] == [b"\x02\x01", b"\x00\x01"]
    assert all(s.parameters[oc.DTYPE_PARAMETER] == b"\x00\x64" for s in slaves)
    assert all(s.started for s in slaves)
    assert master.query_log and not any(q[2] for q in master.query_log)
    assert len(master.feedback_log) >= 4 * 5


@pytest.mark.parametrize("rate", [1_000_000, 500_000, 250_000, 125_000, 100_000])
def test_at4_frame_durations_on_the_bus(rate: int) -> None:
    sched = Scheduler()
    bus = CanBus(sched, rate)
    tx = bus.attach(QueueNode("tx", rate))
    bus.attach(QueueNode("rx", rate))
    msgs = []
    for n in range(9):
        for fill in (0x00, 0xFF, 0x55):
            msgs.append(make_message(0x102, bytes([fill]) * n))
    tx.send(*msgs)
    sched.run_until(PS_PER_S // 10)
    assert len(bus.records) == len(msgs)
    for rec, msg in zip(bus.records, msgs):
        n = len(msg.data)
        bits = frame_bits(msg)
        iso = 47 + 8 * n + (len(stuff(bits)) - len(bits))
        assert rec.n_bits == iso
        assert rec.duration_ps == iso * PS_PER_S // rate
        assert rec.n_bits <= worst_case_bits(n) == 55 + 10 * n
