"""Reference CANopen slave: SDO server (raw CiA 301 frames), PDO engine, CiA 402, control loop."""

from __future__ import annotations

import struct

import pytest

from sim_models.can_bus import frame_length_bits
from sim_models.canopen_slave import (
    DriveState,
    NmtState,
    SimPeriodicTask,
    encode_map_entry,
    make_message,
)
from sim_models.sim_time import PS_PER_MS, PS_PER_US
from sim_models.tests.test_canopen_slave import NODE, Rig


def _idx(index: int, sub: int) -> bytes:
    return struct.pack("<HB", index, sub)


def _abort_code(reply: bytes) -> int:
    assert reply[0] == 0x80, reply.hex()
    return struct.unpack_from("<L", reply, 4)[0]


def _sdo_upload(rig: Rig, index: int, sub: int) -> bytes:
    """Expedited or segmented upload with raw frames; returns the data."""
    r = rig.sdo(bytes([0x40]) + _idx(index, sub))
    assert r[1:4] == _idx(index, sub)
    if r[0] & 0x02:  # expedited
        assert r[0] & 0xF3 == 0x43
        return r[4:8 - ((r[0] >> 2) & 3)]
    assert r[0] == 0x41  # segmented, size indicated
    size = struct.unpack_from("<L", r, 4)[0]
    data = b""
    toggle = 0
    while True:
        seg = rig.sdo(bytes([0x60 | toggle << 4]))
        assert seg[0] & 0xE0 == 0x00 and (seg[0] >> 4) & 1 == toggle
        data += seg[1:8 - ((seg[0] >> 1) & 7)]
        toggle ^= 1
        if seg[0] & 0x01:
            break
    assert len(data) == size
    return data


def _sdo_download_segmented(rig: Rig, index: int, sub: int, payload: bytes) -> list[bytes]:
    r = rig.sdo(bytes([0x21]) + _idx(index, sub) + struct.pack("<L", len(payload)))
    assert r[:4] == bytes([0x60]) + _idx(index, sub), r.hex()
    replies = []
    toggle = 0
    for off in range(0, len(payload), 7):
        chunk = payload[off:off + 7]
        last = off + 7 >= len(payload)
        cmd = (toggle << 4) | ((7 - len(chunk)) << 1) | int(last)
        replies.append(rig.sdo(bytes([cmd]) + chunk.ljust(7, b"\0")))
        toggle ^= 1
    return replies


def _configure_pdo(rig: Rig, comm: int, tt: int | None = None,
                   mapping: list[tuple[int, int, int]] | None = None, **subs: int) -> None:
    """CiA 301 reconfiguration sequence: invalidate, params, sub0 = 0, entries, sub0, valid."""
    cob = rig.slave.read(comm, 1)
    assert rig.sdo_write(comm, 1, cob | 0x80000000, 4)[0] == 0x60
    if tt is not None:
        assert rig.sdo_write(comm, 2, tt, 1)[0] == 0x60
    for sub, (value, size) in {3: (subs.get("inhibit"), 2), 5: (subs.get("event_ms"), 2),
                               6: (subs.get("start"), 1)}.items():
        if value is not None:
            assert rig.sdo_write(comm, sub, value, size)[0] == 0x60
    if mapping is not None:
        mp = comm + 0x200
        assert rig.sdo_write(mp, 0, 0, 1)[0] == 0x60
        for i, (index, sub, bits) in enumerate(mapping, start=1):
            assert rig.sdo_write(mp, i, encode_map_entry(index, sub, bits), 4)[0] == 0x60
        assert rig.sdo_write(mp, 0, len(mapping), 1)[0] == 0x60
    assert rig.sdo_write(comm, 1, cob & 0x7FF, 4)[0] == 0x60


def _sync(rig: Rig, counter: int | None = None) -> None:
    rig.send(0x080, b"" if counter is None else bytes([counter]))


def _payloads(rig: Rig, can_id: int, since: int = 0) -> list[bytes]:
    return [bytes(r.msg.data) for r in rig.frames(rig.slave.name, can_id, since=since)]


# ---------------------------------------------------------------------------------------------
# SDO
# ---------------------------------------------------------------------------------------------


def test_sdo_expedited_upload_and_download() -> None:
    rig = Rig()
    rig.boot()
    assert rig.sdo(bytes([0x40]) + _idx(0x1000, 0)) == \
        bytes([0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00])
    assert rig.sdo(bytes([0x40]) + _idx(0x1018, 1))[:5] == bytes([0x43, 0x18, 0x10, 1, 0xFF])
    # 1, 2 and 4 bytes: ccs 0x2F / 0x2B / 0x23, answered by 0x60 echoing the index
    assert rig.sdo(bytes([0x2F]) + _idx(0x6060, 0) + b"\x08\0\0\0") == \
        bytes([0x60]) + _idx(0x6060, 0) + bytes(4)
    assert rig.sdo(bytes([0x2B]) + _idx(0x1017, 0) + b"\x00\0\0\0")[0] == 0x60
    assert rig.sdo(bytes([0x23]) + _idx(0x607A, 0) + struct.pack("<l", -5000))[0] == 0x60
    assert rig.sdo(bytes([0x40]) + _idx(0x6060, 0)) == \
        bytes([0x4F]) + _idx(0x6060, 0) + b"\x08\0\0\0"
    assert rig.sdo(bytes([0x40]) + _idx(0x6061, 0))[4] == 8  # mode display follows
    assert rig.sdo(bytes([0x40]) + _idx(0x607A, 0)) == \
        bytes([0x43]) + _idx(0x607A, 0) + struct.pack("<l", -5000)
    assert rig.slave.read(0x607A) == -5000
    # size not indicated (0x22): the library takes 4 bytes
    assert rig.sdo(bytes([0x22]) + _idx(0x60FF, 0) + struct.pack("<l", 77))[0] == 0x60
    assert rig.slave.read(0x60FF) == 77


def test_sdo_segmented_upload_of_device_name() -> None:
    rig = Rig()
    rig.boot()
    name = rig.slave.od[0x1008].default.encode("ascii")
    assert len(name) > 14  # several segments
    assert _sdo_upload(rig, 0x1008, 0) == name


def test_sdo_segmented_download_300_bytes_domain() -> None:
    rig = Rig()
    rig.boot()
    payload = bytes((i * 7 + 3) & 0xFF for i in range(300))
    replies = _sdo_download_segmented(rig, 0x2000, 0, payload)
    assert len(replies) == 43  # ceil(300 / 7)
    assert [r[0] for r in replies] == [0x20 | ((i & 1) << 4) for i in range(43)]
    assert rig.slave.read_raw(0x2000) == payload
    assert _sdo_upload(rig, 0x2000, 0) == payload


@pytest.mark.parametrize("request_bytes, code", [
    (bytes([0x40]) + _idx(0x3000, 0), 0x06020000),  # no object
    (bytes([0x40]) + _idx(0x1018, 9), 0x06090011),  # no sub-index
    (bytes([0x23]) + _idx(0x1000, 0) + bytes(4), 0x06010002),  # write read-only
    (bytes([0x2F]) + _idx(0x1008, 0) + b"x\0\0\0", 0x06010002),  # write const
    (bytes([0x40]) + _idx(0x2002, 0), 0x06010001),  # read write-only
    (bytes([0x2B]) + _idx(0x1005, 0) + bytes(4), 0x06070010),  # 2 bytes into UNSIGNED32
    (bytes([0x21]) + _idx(0x3000, 0) + struct.pack("<L", 20), 0x06020000),  # segmented
    (bytes([0x21]) + _idx(0x6041, 0) + struct.pack("<L", 20), 0x06010002),  # segmented ro
    (bytes([0xE0]) + _idx(0x1000, 0), 0x05040001),  # unknown command specifier
])
def test_sdo_aborts(request_bytes: bytes, code: int) -> None:
    rig = Rig()
    rig.boot()
    reply = rig.sdo(request_bytes)
    assert _abort_code(reply) == code
    if code != 0x05040001:
        assert reply[1:4] == request_bytes[1:4]  # index and sub-index echoed


def test_sdo_segmented_upload_toggle_error_aborts() -> None:
    rig = Rig()
    rig.boot()
    assert rig.sdo(bytes([0x40]) + _idx(0x1008, 0))[0] == 0x41
    assert rig.sdo(bytes([0x60]))[0] & 0xE0 == 0x00
    assert _abort_code(rig.sdo(bytes([0x60]))) == 0x05030000  # toggle not alternated


def test_sdo_frames_shorter_than_8_bytes_are_ignored() -> None:
    rig = Rig()
    rig.boot()
    t = rig.now
    rig.send(0x605, bytes([0x40, 0x00, 0x10, 0x00]))
    assert rig.frames(rig.slave.name, since=t) == []


# ---------------------------------------------------------------------------------------------
# PDO configuration rules
# ---------------------------------------------------------------------------------------------


def test_pdo_mapping_rules_enforced_by_sdo_aborts() -> None:
    rig = Rig()
    rig.boot()
    w = rig.sdo_write
    entry = encode_map_entry(0x606C, 0, 32)
    assert _abort_code(w(0x1A00, 1, entry, 4)) == 0x06010000  # PDO valid
    assert _abort_code(w(0x1A00, 0, 0, 1)) == 0x06010000
    assert w(0x1800, 1, 0x80000185, 4)[0] == 0x60  # invalidate
    assert _abort_code(w(0x1A00, 1, entry, 4)) == 0x06010000  # sub0 still 2
    assert w(0x1A00, 0, 0, 1)[0] == 0x60
    assert _abort_code(w(0x1A00, 1, encode_map_entry(0x1008, 0, 32), 4)) == 0x06040041
    assert _abort_code(w(0x1A00, 1, encode_map_entry(0x3000, 0, 32), 4)) == 0x06040041
    assert _abort_code(w(0x1A00, 1, encode_map_entry(0x2002, 0, 32), 4)) == 0x06040041  # wo
    assert _abort_code(w(0x1A00, 1, encode_map_entry(0x6041, 0, 32), 4)) == 0x06040041  # >16
    assert _abort_code(w(0x1600, 1, entry, 4)) == 0x06010000  # RPDO1 still valid
    for sub in (1, 2, 3):
        assert w(0x1A00, sub, encode_map_entry(0x6064, 0, 32), 4)[0] == 0x60
    assert _abort_code(w(0x1A00, 0, 3, 1)) == 0x06040042  # 96 bits
    assert _abort_code(w(0x1A00, 0, 9, 1)) == 0x06040042
    assert w(0x1A00, 0, 2, 1)[0] == 0x60
    assert _abort_code(w(0x1800, 1, 0x80000186 | 1 << 29, 4)) == 0x06090030  # 29-bit
    assert w(0x1800, 1, 0x186, 4)[0] == 0x60  # valid again, new CAN-ID
    assert _abort_code(w(0x1800, 1, 0x187, 4)) == 0x06090030  # CAN-ID change while valid
    assert _abort_code(w(0x1800, 3, 10, 2)) == 0x06090030  # inhibit time while valid
    assert _abort_code(w(0x1800, 2, 245, 1)) == 0x06090030  # reserved transmission type
    assert _abort_code(w(0x1400, 2, 252, 1)) == 0x06090030  # RTR types: TPDO only
    assert _abort_code(w(0x1403, 1, 0x505, 4)) == 0x06090030  # RPDO4 has no mapping
    assert w(0x1800, 2, 3, 1)[0] == 0x60  # transmission type may change while valid
    # the new mapping is used: two position values on 0x186
    rig.slave.write(0x6064, 0, 0x01020304)
    rig.nmt(0x01)
    for _ in range(3):
        _sync(rig)
    assert _payloads(rig, 0x186) == [struct.pack("<ll", 0x01020304, 0x01020304)]


# ---------------------------------------------------------------------------------------------
# TPDOs
# ---------------------------------------------------------------------------------------------


def test_tpdo_every_sync_sampled_at_sync_right_after_it() -> None:
    rig = Rig()
    rig.boot()
    rig.nmt(0x01)
    for pos in (100, -200, 300):
        rig.slave.write(0x6064, 0, pos)
        t = rig.now
        _sync(rig)
        sync_rec = rig.frames(rig.master.name, 0x080, since=t)[0]
        tpdo = rig.frames(rig.slave.name, 0x185, since=t)
        assert len(tpdo) == 1
        assert tpdo[0].t_start_ps == sync_rec.t_end_ps  # queued at the SYNC, next on the bus
        assert bytes(tpdo[0].msg.data) == struct.pack("<Hl", 0x0040, pos)


def test_tpdo_every_nth_sync_and_sync_start_value() -> None:
    rig = Rig()
    rig.boot()
    _configure_pdo(rig, 0x1800, tt=3)
    rig.nmt(0x01)
    sent_after = []
    for i in range(1, 10):
        rig.slave.write(0x6064, 0, i)
        t = rig.now
        _sync(rig)
        if _payloads(rig, 0x185, since=t):
            sent_after.append(i)
            assert _payloads(rig, 0x185, since=t) == [struct.pack("<Hl", 0x40, i)]
    assert sent_after == [3, 6, 9]
    # SYNC start value 2 with a counting SYNC: first at counter 2, then every 3rd SYNC
    rig.nmt(0x80)
    _configure_pdo(rig, 0x1800, tt=3, start=2)
    rig.nmt(0x01)
    t = rig.now
    counters = []
    for c in [5, 6, 1, 2, 3, 4, 5, 6, 1, 2]:
        t1 = rig.now
        _sync(rig, c)
        if _payloads(rig, 0x185, since=t1):
            counters.append(c)
    assert counters == [2, 5, 2]
    assert [c for _, c in rig.slave.sync_log[-3:]] == [6, 1, 2]
    assert len(_payloads(rig, 0x185, since=t)) == 3


def test_tpdo_acyclic_sync_and_rtr_types() -> None:
    rig = Rig()
    rig.boot()
    _configure_pdo(rig, 0x1800, tt=0)
    _configure_pdo(rig, 0x1801, tt=252, mapping=[(0x6064, 0, 32)])
    _configure_pdo(rig, 0x1802, tt=253, mapping=[(0x6064, 0, 32)])
    rig.nmt(0x01)
    t = rig.now
    _sync(rig)  # first SYNC after start: type 0 sends once
    _sync(rig)  # nothing changed: nothing
    assert len(_payloads(rig, 0x185, since=t)) == 1
    rig.slave.write(0x6064, 0, 42)
    _sync(rig)
    assert _payloads(rig, 0x185, since=t)[-1] == struct.pack("<Hl", 0x40, 42)
    rig.slave.request_tpdo(1)  # application request
    _sync(rig)
    assert len(_payloads(rig, 0x185, since=t)) == 3
    assert _payloads(rig, 0x285, since=t) == []  # 252: only on RTR
    # 252 answers an RTR with the value sampled at the last SYNC, 253 with the current value
    rig.slave.write(0x6064, 0, 43)
    rig.send(0x285, rtr=True)
    rig.send(0x385, rtr=True)
    assert _payloads(rig, 0x285, since=t) == [struct.pack("<l", 42)]
    assert _payloads(rig, 0x385, since=t) == [struct.pack("<l", 43)]
    # RTR not allowed (bit 30)
    rig.nmt(0x80)
    _configure_pdo(rig, 0x1802)
    rig.sdo_write(0x1802, 1, 0x80000385, 4)
    rig.sdo_write(0x1802, 1, 0x40000385, 4)
    rig.nmt(0x01)
    t = rig.now
    rig.send(0x385, rtr=True)
    assert _payloads(rig, 0x385, since=t) == []


@pytest.mark.parametrize("ppm", [0.0, 100.0])
def test_tpdo_event_driven_inhibit_and_event_timer_on_local_clock(ppm: float) -> None:
    rig = Rig(ppm=ppm)
    rig.boot()
    clock = rig.slave.clock
    # TPDO2: velocity actual, type 255, inhibit 10 ms (100 x 100 us), event timer 50 ms
    _configure_pdo(rig, 0x1801, tt=255, mapping=[(0x606C, 0, 32)], inhibit=100, event_ms=50)
    rig.send(0x000, bytes([0x01, NODE]), run_ps=0)
    rig.run(PS_PER_MS)
    t_start = rig.slave.state_log[-1][0]
    # once on entering operational (queued at the NMT frame's EOF, sent after intermission)
    assert [t for t, _ in rig.slave.tpdo_log(2)] == [t_start]
    assert len(rig.frames(rig.slave.name, 0x285)) == 1
    rig.run(1 * PS_PER_MS)
    rig.slave.write(0x606C, 0, 7)  # within the inhibit time: deferred
    t_change = rig.now
    rig.run(1 * PS_PER_MS)
    rig.slave.write(0x606C, 0, 8)  # still inhibited: merged into one frame
    rig.run(20 * PS_PER_MS)
    sent = rig.frames(rig.slave.name, 0x285)
    t_inhibit_end = clock.true_ps(clock.local_ps(t_start) + 10 * PS_PER_MS)
    assert t_change < t_inhibit_end
    assert [(r.t_start_ps, bytes(r.msg.data)) for r in sent[1:]] == \
        [(t_inhibit_end, struct.pack("<l", 8))]
    rig.slave.write(0x606C, 0, 8)  # same value: not an event
    rig.run(60 * PS_PER_MS)
    sent = rig.frames(rig.slave.name, 0x285)
    # event timer: 50 ms after the previous transmission, same data
    t_event = clock.true_ps(clock.local_ps(t_inhibit_end) + 50 * PS_PER_MS)
    assert [(r.t_start_ps, bytes(r.msg.data)) for r in sent[2:]] == \
        [(t_event, struct.pack("<l", 8))]
    # not in pre-operational
    rig.nmt(0x80)
    t = rig.now
    rig.slave.write(0x606C, 0, 9)
    rig.run(100 * PS_PER_MS)
    assert rig.frames(rig.slave.name, 0x285, since=t) == []


# ---------------------------------------------------------------------------------------------
# RPDOs
# ---------------------------------------------------------------------------------------------


def test_rpdo_synchronous_applied_at_sync_and_event_applied_immediately() -> None:
    rig = Rig()
    rig.boot()
    _configure_pdo(rig, 0x1400, tt=1)
    _configure_pdo(rig, 0x1401)  # RPDO2: 6040h + 60FFh, type 255 (default), made valid
    rig.nmt(0x01)
    rig.send(0x205, struct.pack("<Hl", 0x0006, 1000))
    assert rig.slave.read(0x607A) == 0 and rig.slave.read(0x6040) == 0
    rig.send(0x205, struct.pack("<Hl", 0x0006, 2000))  # overwrites the pending one
    _sync(rig)
    assert rig.slave.read(0x607A) == 2000 and rig.slave.read(0x6040) == 6
    assert rig.slave.drive_state is DriveState.READY_TO_SWITCH_ON
    assert [(n, p) for _, n, p in rig.slave.rpdo_applied] == \
        [(1, struct.pack("<Hl", 0x0006, 2000))]
    rig.send(0x305, struct.pack("<Hl", 0x0006, -33))
    assert rig.slave.read(0x60FF) == -33  # type 255: immediately
    # stopped / pre-operational: RPDOs are not processed
    rig.nmt(0x80)
    rig.send(0x305, struct.pack("<Hl", 0x0006, 44))
    assert rig.slave.read(0x60FF) == -33


def test_rpdo_wrong_length_recorded_with_emcy() -> None:
    rig = Rig()
    rig.boot()
    rig.nmt(0x01)
    t = rig.now
    rig.send(0x205, b"\x06\x00\x01")  # 3 bytes, mapping needs 6
    rig.send(0x205, b"\x06\x00\x01")  # still wrong: recorded, no second EMCY
    assert rig.slave.read(0x6040) == 0  # dropped
    errs = rig.slave.rpdo_length_errors
    assert [(e.pdo, e.cob_id, e.received, e.expected, e.applied) for e in errs] == \
        [(1, 0x205, 3, 6, False)] * 2
    assert _payloads(rig, 0x085, since=t) == [bytes([0x10, 0x82, 0x10, 0x05, 0x02, 0, 0, 0])]
    rig.send(0x205, struct.pack("<Hl", 6, 5))  # correct: error state cleared
    rig.send(0x205, struct.pack("<Hl", 6, 9) + b"\xAA\xBB")  # too long: used, EMCY 8220h
    assert rig.slave.read(0x607A) == 9
    assert errs[-1].received == 8 and errs[-1].applied
    assert _payloads(rig, 0x085, since=t)[-1][:3] == bytes([0x20, 0x82, 0x10])


# ---------------------------------------------------------------------------------------------
# CiA 402
# ---------------------------------------------------------------------------------------------


def test_cia402_state_machine_via_rpdo_with_tpdo_feedback() -> None:
    rig = Rig()
    rig.boot()
    rig.nmt(0x01)

    def cycle(cw: int, target: int) -> bytes:
        rig.send(0x205, struct.pack("<Hl", cw, target))  # RPDO1 type 255
        t = rig.now
        _sync(rig)
        return _payloads(rig, 0x185, since=t)[0]

    assert cycle(0x0000, 0)[:2] == struct.pack("<H", 0x0040)  # switch on disabled
    assert cycle(0x0006, 0)[:2] == struct.pack("<H", 0x0021)  # ready to switch on
    assert cycle(0x0007, 0)[:2] == struct.pack("<H", 0x0033)  # switched on
    assert cycle(0x000F, 500) == struct.pack("<Hl", 0x0037, 0)  # enabled; TPDO sampled first
    assert cycle(0x000F, 600) == struct.pack("<Hl", 0x0037, 500)  # actual follows target
    assert rig.slave.read(0x6064) == 600
    t = rig.now
    rig.slave.drive_fault(0x7300, b"\x01")
    rig.run(PS_PER_MS)
    assert rig.slave.read(0x6041) == 0x0008
    assert _payloads(rig, 0x085, since=t) == [bytes([0x00, 0x73, 0x01, 0x01, 0, 0, 0, 0])]
    assert cycle(0x000F, 600)[:2] == struct.pack("<H", 0x0008)  # stays in fault
    assert cycle(0x0080, 600)[:2] == struct.pack("<H", 0x0040)  # fault reset edge
    assert _payloads(rig, 0x085, since=t)[-1] == bytes(8)  # EMCY error reset, register 0
    assert cycle(0x0006, 600)[:2] == struct.pack("<H", 0x0021)
    assert cycle(0x0002, 600)[:2] == struct.pack("<H", 0x0040)  # quick stop -> disabled
    states = [s for _, s in rig.slave.drive_log]
    assert states[:6] == [DriveState.SWITCH_ON_DISABLED, DriveState.READY_TO_SWITCH_ON,
                          DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED,
                          DriveState.FAULT, DriveState.SWITCH_ON_DISABLED]


# ---------------------------------------------------------------------------------------------
# Local control loop
# ---------------------------------------------------------------------------------------------


def _reference_status(ticks: list[int], arrivals: list[int]) -> list[str]:
    out = []
    prev = -1
    for t in ticks:
        n = sum(1 for a in arrivals if prev < a <= t)
        out.append("new" if n == 1 else "overwritten" if n > 1 else "missing")
        prev = t
    return out


@pytest.mark.parametrize("ppm, slip", [(200.0, "missing"), (-200.0, "overwritten")])
def test_control_loop_drift_and_resync(ppm: float, slip: str) -> None:
    period = 1 * PS_PER_MS
    rig = Rig(ppm=ppm, boot_time_ps=0, control_period_ps=period,
              control_offset_ps=period // 2)
    rig.boot()
    rig.nmt(0x01)
    clock = rig.slave.clock
    # The master sends RPDO1 every 1 ms of true time. Each frame ends (arrives) 6 us before
    # (fast slave) or after (slow slave) the nominal tick (k + 0.5) ms; the slave's ticks
    # drift by 0.2 us per ms, so the arrival and the tick swap order once, near tick 30.
    side = -1 if ppm > 0 else 1
    for j in range(3, 63):
        msg = make_message(0x205, struct.pack("<Hl", 0, j))
        eof = rig.bus.duration_ps(frame_length_bits(msg) - 3)
        t_sof = period // 2 + j * period + side * 6 * PS_PER_US - eof
        rig.sched.call_at(t_sof, rig.master.send, msg)
    rig.run(63 * PS_PER_MS - rig.now)
    log = rig.slave.control_log
    assert len(log) >= 60
    # tick k at local power-on + offset + k * period
    for tick in log:
        assert tick.t_ps == clock.true_ps(period // 2 + tick.tick * period)
        assert tick.t_local_ps == clock.local_ps(tick.t_ps)
        assert tick.epoch == 0
    arrivals = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x205]
    assert len(arrivals) == 60
    expected = _reference_status([t.t_ps for t in log], arrivals)
    assert [t.status for t in log] == expected
    first = next(i for i, t in enumerate(log) if t.arrivals)
    statuses = [t.status for t in log[first:]]
    assert statuses.count(slip) == 1 and statuses.count("new") == len(statuses) - 1
    assert abs(statuses.index(slip) + first - 30) <= 1
    for tick in log:
        if tick.status != "missing":
            assert tick.value_t_ps in arrivals and tick.value_t_ps <= tick.t_ps
            assert tick.value == rig.slave.rpdo_applied[arrivals.index(tick.value_t_ps)][2]
    # resync (e.g. on a SYNC): tick 0 of epoch 1 at that instant, then every period
    t_res = rig.now + 300 * PS_PER_US
    rig.sched.call_at(t_res, rig.slave.resync)
    rig.run(clock.true_ps(clock.local_ps(t_res) + 3 * period) + 1 - rig.now)
    after = [t for t in rig.slave.control_log if t.epoch == 1]
    assert [t.tick for t in after] == [0, 1, 2, 3]
    assert after[0].t_ps == t_res
    assert [t.t_ps for t in after] == [clock.true_ps(clock.local_ps(t_res) + k * period)
                                       for k in range(4)]
    assert rig.slave.resync_log == [(t_res, clock.local_ps(t_res))]


def test_control_loop_object_source_and_power_off_stops_ticks() -> None:
    rig = Rig(boot_time_ps=0, control_period_ps=PS_PER_MS, control_source=(0x607A, 0))
    rig.boot()
    rig.sdo_write(0x607A, 0, 1234, 4)
    rig.run(PS_PER_MS)
    ticks = [t for t in rig.slave.control_log if t.status == "new"]
    assert ticks and ticks[0].value == 1234
    rig.slave.power_off()
    n = len(rig.slave.control_log)
    rig.run(10 * PS_PER_MS)
    assert len(rig.slave.control_log) == n
    assert rig.slave.nmt_state is NmtState.OFF


def test_library_send_periodic_runs_on_sim_time() -> None:
    rig = Rig(ppm=100.0, boot_time_ps=0)
    rig.boot()
    task = rig.slave.network.send_periodic(0x3F0, b"\x01\x02", 0.010)
    assert isinstance(task, SimPeriodicTask)
    t0 = rig.now
    rig.run(25 * PS_PER_MS)
    task.update(b"\x03")
    rig.run(10 * PS_PER_MS)
    task.stop()
    rig.run(30 * PS_PER_MS)
    got = rig.frames(rig.slave.name, 0x3F0)
    clock = rig.slave.clock
    assert [r.t_start_ps for r in got] == [clock.true_ps(clock.local_ps(t0) + k * 10 * PS_PER_MS)
                                           for k in (1, 2, 3)]
    assert [bytes(r.msg.data) for r in got] == [b"\x01\x02", b"\x01\x02", b"\x03"]
