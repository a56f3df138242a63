"""Unit tests of sim_models.can_bus: bit level, arbitration, timing, records, traces, load."""

from __future__ import annotations

import random
import re
from fractions import Fraction

import can
import pytest

from sim_models.can_bus import (
    BusRecord,
    CanBus,
    CanBusProtocolError,
    CanNode,
    NodeClock,
    QueueNode,
    arbitration_bits,
    crc15,
    frame_bits,
    frame_length_bits,
    stuff,
    stuffed_length,
    worst_case_bits,
)
from sim_models.sim_time import PS_PER_MS, Scheduler

RATE = 125_000
BIT_PS = 8_000_000  # one bit at 125 kbit/s


def std(ident: int, data: bytes = b"", *, rtr: bool = False, dlc: int | None = None):
    return can.Message(arbitration_id=ident, data=data, is_extended_id=False,
                       is_remote_frame=rtr, dlc=dlc)


def ext(ident: int, data: bytes = b"", *, rtr: bool = False, dlc: int | None = None):
    return can.Message(arbitration_id=ident, data=data, is_extended_id=True,
                       is_remote_frame=rtr, dlc=dlc)


def make_bus(*names: str, rate: int = RATE) -> tuple[Scheduler, CanBus, list[QueueNode]]:
    sched = Scheduler()
    bus = CanBus(sched, rate)
    nodes = [bus.attach(QueueNode(n, rate)) for n in names]
    return sched, bus, nodes


# ------------------------------------------------------------------------------------------
# independent reference implementations (deliberately written differently from the model)
# ------------------------------------------------------------------------------------------


def crc15_polydiv(bits: list[int]) -> int:
    """Remainder of M(x) * x^15 divided by the CAN generator, by long division on an int."""
    generator = (1 << 15) | 0x4599
    value = int("".join(map(str, bits)) or "0", 2) << 15
    for shift in range(value.bit_length() - 16, -1, -1):
        if value >> (shift + 15) & 1:
            value ^= generator << shift
    return value


def stuff_count_regex(bits: list[int]) -> int:
    """Number of stuff bits, found by repeatedly searching the first run of 5 in a string."""
    s = "".join(map(str, bits))
    count, pos = 0, 0
    while True:
        m = re.compile(r"00000|11111").search(s, pos)
        if m is None:
            return count
        end = m.end()
        s = s[:end] + ("1" if s[end - 1] == "0" else "0") + s[end:]
        count += 1
        pos = end  # the stuff bit is the first bit of the next run


def destuff(bits: list[int]) -> list[int]:
    out, run_value, run_length, skip = [], None, 0, False
    for b in bits:
        if skip:
            assert b != run_value, "stuff bit must be the complement"
            run_value, run_length, skip = b, 1, False
            continue
        out.append(b)
        run_length = run_length + 1 if b == run_value else 1
        run_value = b
        if run_length == 5:
            skip = True
    return out


def bits_of(text: str) -> list[int]:
    return [int(c) for c in text if c in "01"]


# ------------------------------------------------------------------------------------------
# CRC, frame bits, stuffing
# ------------------------------------------------------------------------------------------


def test_crc15_catalogue_check_value() -> None:
    # CRC-15/CAN check value from the CRC catalogue: ASCII "123456789", MSB first -> 0x059E.
    bits = [int(b) for c in b"123456789" for b in format(c, "08b")]
    assert crc15(bits) == 0x059E
    assert crc15_polydiv(bits) == 0x059E


def test_crc15_matches_polynomial_division() -> None:
    rng = random.Random(15)
    assert crc15([]) == 0
    assert crc15([0] * 40) == 0
    for n in (1, 2, 7, 15, 16, 19, 33, 64, 83):
        for _ in range(20):
            bits = [rng.randint(0, 1) for _ in range(n)]
            assert crc15(bits) == crc15_polydiv(bits), bits


def test_frame_bits_sync_by_hand() -> None:
    # SOF | ID 0x080 = 000 1000 0000 | RTR IDE r0 = 000 | DLC 0000 | CRC 0x1C05
    expected = bits_of("0 00010000000 000 0000") + bits_of(format(0x1C05, "015b"))
    assert crc15_polydiv(bits_of("0 00010000000 000 0000")) == 0x1C05
    assert frame_bits(std(0x080)) == expected
    # Hand stuffing: 0000 1 [16 zeros] 111 [7 zeros] 101
    #   -> a stuff '1' after each of the first three 5-zero groups, one after the 7 zeros.
    assert stuff(expected) == bits_of("0000 1 00000 1 00000 1 00000 1 0 111 00000 1 00 101")
    assert stuffed_length(std(0x080)) == 38
    assert frame_length_bits(std(0x080)) == 38 + 13 == 51


def test_frame_bits_field_layout() -> None:
    # standard remote frame: RTR = 1, DLC transmitted, no data field
    rb = frame_bits(std(0x601, rtr=True, dlc=8))
    assert len(rb) == 34
    assert rb[:19] == bits_of("0 11000000001 1 0 0 1000")
    # standard data frame with data
    db = frame_bits(std(0x701, b"\x05"))
    assert db[:27] == bits_of("0 11100000001 0 0 0 0001 00000101")
    assert db[27:] == bits_of(format(crc15_polydiv(db[:27]), "015b"))
    # extended: SOF, ID28..18, SRR=1, IDE=1, ID17..0, RTR, r1, r0, DLC, data, CRC
    ident = 0x18FF1234
    eb = frame_bits(ext(ident, b"\x11\x22"))
    head = ("0" + format(ident >> 18, "011b") + "11" + format(ident & 0x3FFFF, "018b")
            + "000" + "0010" + "00010001" + "00100010")
    assert eb[:55] == bits_of(head)
    assert eb[55:] == bits_of(format(crc15_polydiv(eb[:55]), "015b"))
    assert len(eb) == 54 + 16
    # DLC 9..15 on a classical data frame carries 8 data bytes
    long_dlc = can.Message(arbitration_id=0x123, data=bytes(range(8)), dlc=15,
                           is_extended_id=False, check=False)
    assert len(frame_bits(long_dlc)) == 34 + 64
    assert frame_bits(long_dlc)[15:19] == [1, 1, 1, 1]


def test_frame_bits_rejects_bad_messages() -> None:
    with pytest.raises(ValueError):
        frame_bits(std(0x800))
    with pytest.raises(ValueError):
        frame_bits(can.Message(arbitration_id=1, data=b"\x01", dlc=3, is_extended_id=False,
                               check=False))
    with pytest.raises(ValueError):
        frame_bits(can.Message(arbitration_id=1, is_fd=True, is_extended_id=False))


def test_stuff_rules() -> None:
    assert stuff([0, 0, 0, 0]) == [0, 0, 0, 0]
    assert stuff([0] * 5) == [0] * 5 + [1]
    assert stuff([1] * 5) == [1] * 5 + [0]
    assert stuff([0] * 10) == [0] * 5 + [1] + [0] * 5 + [1]
    # the stuff bit is the first bit of the next run: 00000 (1) 1111 -> stuff again
    assert stuff([0] * 5 + [1] * 4) == [0] * 5 + [1] + [1] * 4 + [0]
    assert stuff([0] * 5 + [1] * 3 + [0]) == [0] * 5 + [1] + [1] * 3 + [0]
    assert stuff([1, 0, 1, 0, 1, 0]) == [1, 0, 1, 0, 1, 0]
    rng = random.Random(5)
    for _ in range(300):
        bits = [rng.choice((0, 0, 0, 1)) for _ in range(rng.randint(0, 120))]
        out = stuff(bits)
        assert "000000" not in "".join(map(str, out))
        assert "111111" not in "".join(map(str, out))
        assert destuff(out) == bits
        assert len(out) - len(bits) == stuff_count_regex(bits)


def test_stuffing_across_field_boundaries_id0_dlc0() -> None:
    # id 0x000 DLC 0: SOF, 11 ID, RTR, IDE, r0, 4 DLC are all 0 and CRC(0...0) = 0, so all
    # 34 bits are 0: a stuff bit after every 5 zeros, runs spanning every field boundary.
    msg = std(0x000)
    assert frame_bits(msg) == [0] * 34
    assert stuff([0] * 34) == ([0] * 5 + [1]) * 6 + [0] * 4
    assert stuffed_length(msg) == 40
    assert frame_length_bits(msg) == 53


@pytest.mark.parametrize(
    ("msg", "stuffed", "total"),
    [
        (std(0x000), 40, 53),
        (std(0x080), 38, 51),  # SYNC
        (std(0x181, bytes([0x55] * 8)), 99, 112),
        (std(0x181, bytes(8)), 113, 126),
        (std(0x181, bytes([0xFF] * 8)), 111, 124),
        (std(0x701, b"\x05"), 45, 58),  # heartbeat, operational
        (std(0x601, rtr=True, dlc=8), 36, 49),  # remote frame: no data field
        (ext(0x18FF1234, b"\x11\x22"), 73, 86),
    ],
)
def test_exact_frame_lengths(msg: can.Message, stuffed: int, total: int) -> None:
    bits = frame_bits(msg)
    # independent count of the stuff bits
    assert len(bits) + stuff_count_regex(bits) == stuffed
    assert stuffed_length(msg) == stuffed
    assert frame_length_bits(msg) == total
    assert total == stuffed + 13


def test_data_0x55_vs_0x00_differ_by_stuffing_only() -> None:
    a, b = std(0x181, bytes([0x55] * 8)), std(0x181, bytes(8))
    assert len(frame_bits(a)) == len(frame_bits(b)) == 98
    # 0x55 data is alternating: one stuff bit (in the identifier); 64 zero bits add ~16
    assert frame_length_bits(a) == 98 + 1 + 13
    assert frame_length_bits(b) == 98 + 15 + 13


def test_worst_case_formula_values() -> None:
    assert [worst_case_bits(n) for n in (0, 1, 8)] == [55, 65, 135]
    assert [worst_case_bits(n, True) for n in (0, 1, 8)] == [80, 90, 160]
    with pytest.raises(ValueError):
        worst_case_bits(9)


def test_frame_length_never_exceeds_worst_case() -> None:
    rng = random.Random(2024)
    patterns = [0x00, 0xFF, 0x0F, 0xF0, 0x55, 0xAA, 0x3C, 0xC3, 0x1E, 0x78, 0x07, 0xE0]
    for n in range(9):
        for extended in (False, True):
            limit = worst_case_bits(n, extended)
            id_bits = 29 if extended else 11
            ids = [0, (1 << id_bits) - 1] + [rng.getrandbits(id_bits) for _ in range(40)]
            for ident in ids:
                datas = [bytes([p] * n) for p in patterns]
                datas += [bytes(rng.getrandbits(8) for _ in range(n)) for _ in range(4)]
                for data in datas:
                    msg = can.Message(arbitration_id=ident, data=data, is_extended_id=extended)
                    length = frame_length_bits(msg)
                    assert 47 + 20 * extended + 8 * n <= length <= limit, (msg, length)
                rtr = can.Message(arbitration_id=ident, is_extended_id=extended,
                                  is_remote_frame=True, dlc=n)
                assert frame_length_bits(rtr) <= worst_case_bits(0, extended)


def test_worst_case_bound_exhaustive_std_dlc0() -> None:
    # Exhaustive over all 2048 identifiers, data and remote: the longest DLC-0 standard frame
    # is id 0x000 with 53 bits. The classical bound (55) is 2 bits pessimistic: the fixed
    # IDE/r0/DLC bits break the 5-4-4-4 run pattern it assumes.
    lengths = {}
    for ident in range(2048):
        for rtr in (False, True):
            lengths[(ident, rtr)] = frame_length_bits(std(ident, rtr=rtr, dlc=0))
    longest = max(lengths.values())
    assert longest == 53 == worst_case_bits(0) - 2
    assert lengths[(0, False)] == 53
    assert min(lengths.values()) >= 47


# ------------------------------------------------------------------------------------------
# NodeClock
# ------------------------------------------------------------------------------------------


def test_node_clock_mapping() -> None:
    clk = NodeClock(ppm=100.0, phase_ps=5_000)
    assert clk.local_ps(0) == 5_000
    assert clk.local_ps(10**12) == 5_000 + 10**12 + 10**8
    assert clk.local_ps(3) == 5_003  # 3.0003 rounds to 3
    for t in (0, 1, 999, 123_456_789, 10**15 + 7):
        assert clk.true_ps(clk.local_ps(t)) == t
    slow = NodeClock(ppm=-250.0)
    assert slow.local_ps(4 * 10**9) == 4 * 10**9 - 10**6
    assert slow.true_ps(4 * 10**9 - 10**6) == 4 * 10**9
    for t in (0, 17, 10**13 + 3):
        assert abs(slow.true_ps(slow.local_ps(t)) - t) <= 1
    assert NodeClock().local_ps(777) == 777


# ------------------------------------------------------------------------------------------
# Arbitration and timing
# ------------------------------------------------------------------------------------------


def test_arbitration_order_among_four_nodes() -> None:
    sched, bus, (a, b, c, d) = make_bus("a", "b", "c", "d")
    msgs = {"a": std(0x300, b"\x01"), "b": std(0x100, b"\x02"), "c": std(0x200, b"\x03"),
            "d": std(0x180, b"\x04")}
    for node in (a, b, c, d):
        node.send(msgs[node.name])
    sched.run(PS_PER_MS * 100)
    assert [r.sender for r in bus.records] == ["b", "d", "c", "a"]
    assert all(r.kind == "frame" for r in bus.records)
    # back to back: each SOF is the end of the previous intermission, first SOF at t = 0
    assert bus.records[0].t_start_ps == 0
    for prev, nxt in zip(bus.records, bus.records[1:]):
        assert nxt.t_start_ps == prev.t_end_ps
    for r in bus.records:
        assert r.n_bits == frame_length_bits(r.msg)
        assert r.t_end_ps - r.t_start_ps == r.n_bits * BIT_PS
        assert r.msg.timestamp == r.t_start_ps / 1e12
    # losers: a lost 3 times, c twice, d once, b never
    assert [len(n.lost) for n in (a, b, c, d)] == [3, 0, 2, 1]
    assert bus.stats["arbitration_lost"] == 6
    assert bus.stats["arbitration_rounds"] == 4
    assert bus.stats["frames_ok"] == 4
    # every node received the three frames of the others, in bus order
    for node in (a, b, c, d):
        got = [m.arbitration_id for _, m in node.received]
        assert got == [r.msg.arbitration_id for r in bus.records if r.sender != node.name]
    assert bus.records[0].receivers == ("a", "c", "d")


def test_on_rx_and_tx_done_at_end_of_eof() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    msg = std(0x080)
    a.send(msg)
    sched.run(PS_PER_MS)
    (rec,) = bus.records
    eof_end = rec.t_start_ps + (51 - 3) * BIT_PS
    assert a.sent == [(eof_end, msg)]  # the very object returned by tx_candidate
    assert b.received[0][0] == eof_end
    rx = b.received[0][1]
    assert rx is not msg and rx.is_rx and rx.arbitration_id == 0x080
    assert rec.t_end_ps == 51 * BIT_PS


def test_standard_beats_extended_with_same_base_id() -> None:
    base = 0x123
    e_data = ext((base << 18) | 0x00000, b"\x01")  # extended part all dominant
    s_remote = std(base, rtr=True, dlc=1)
    s_data = std(base, b"\x02")
    assert arbitration_bits(s_data) == tuple(bits_of("00100100011 0 0"))
    assert arbitration_bits(s_remote) == tuple(bits_of("00100100011 1 0"))
    assert arbitration_bits(ext(0x12345678, rtr=True)) == tuple(
        bits_of(format(0x12345678 >> 18, "011b") + "11" + format(0x12345678 & 0x3FFFF, "018b")
                + "1"))
    # bit-level keys: std data < std remote (RTR) < ext (SRR=1 ties RTR=1, IDE decides)
    assert arbitration_bits(s_data) < arbitration_bits(s_remote) < arbitration_bits(e_data)
    sched, bus, (a, b, c) = make_bus("a", "b", "c")
    a.send(e_data)
    b.send(s_remote)
    c.send(s_data)
    sched.run(PS_PER_MS * 100)
    assert [(r.sender, r.msg.is_remote_frame, r.msg.is_extended_id) for r in bus.records] == [
        ("c", False, False), ("b", True, False), ("a", False, True)]
    # an extended frame with a lower base id still beats a standard frame
    sched, bus, (a, b) = make_bus("a", "b")
    a.send(std(0x124))
    b.send(ext(0x123 << 18 | 0x3FFFF))
    sched.run(PS_PER_MS * 10)
    assert [r.sender for r in bus.records] == ["b", "a"]


def test_late_request_waits_for_idle() -> None:
    sched, bus, (a, b, c) = make_bus("a", "b", "c")
    a.send(std(0x700, bytes(8)))  # long frame, low priority
    first_len = frame_length_bits(std(0x700, bytes(8)))
    # b asks 10 bits after SOF with a higher-priority id: it must wait for the idle point
    sched.call_at(10 * BIT_PS, b.send, std(0x001))
    # c asks during the intermission of a's frame: competes at the same idle point
    sched.call_at((first_len - 1) * BIT_PS, c.send, std(0x000))
    sched.run_until(20 * BIT_PS)
    assert not bus.idle
    sched.run(PS_PER_MS * 10)
    assert [r.sender for r in bus.records] == ["a", "c", "b"]
    assert bus.records[1].t_start_ps == first_len * BIT_PS
    assert b.lost and not a.lost
    assert bus.idle


def test_requests_at_the_same_instant_share_one_round() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    t0 = 1_000_000
    # a's request is scheduled first; b's request at the same instant must still compete.
    sched.call_at(t0, a.send, std(0x222))
    sched.call_at(t0, b.send, std(0x111))
    sched.run(PS_PER_MS * 10)
    assert [(r.sender, r.t_start_ps) for r in bus.records] == [
        ("b", t0), ("a", t0 + frame_length_bits(std(0x111)) * BIT_PS)]
    assert len(a.lost) == 1


def test_request_queued_after_the_round_at_the_same_instant_still_competes() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    t0 = 2_000_000

    def a_then_b() -> None:
        a.send(std(0x222))  # schedules the round at t0 ...
        sched.call_later(0, b.send, std(0x111))  # ... and b's request is queued after it

    sched.call_at(t0, a_then_b)
    sched.run(PS_PER_MS * 10)
    assert [(r.sender, r.t_start_ps) for r in bus.records][0] == ("b", t0)
    assert bus.stats["arbitration_rounds"] == 2


def test_remote_frames_from_several_nodes_merge() -> None:
    sched, bus, (a, b, c) = make_bus("a", "b", "c")
    ra, rb = std(0x701, rtr=True, dlc=1), std(0x701, rtr=True, dlc=1)
    a.send(ra)
    b.send(rb)
    sched.run(PS_PER_MS * 10)
    (rec,) = bus.records
    assert rec.sender == "a+b" and rec.kind == "frame"
    assert a.sent[0][1] is ra and b.sent[0][1] is rb
    assert [m.arbitration_id for _, m in c.received] == [0x701]
    assert not a.received and not b.received
    assert bus.stats["merged_frames"] == 1


def test_identical_id_data_collision_raises() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    a.send(std(0x181, b"\x01"))
    b.send(std(0x181, b"\x02"))
    with pytest.raises(CanBusProtocolError, match="0x181"):
        sched.run(PS_PER_MS)
    # remote frames with different DLC are different frames too
    sched, bus, (a, b) = make_bus("a", "b")
    a.send(std(0x701, rtr=True, dlc=1))
    b.send(std(0x701, rtr=True, dlc=0))
    with pytest.raises(CanBusProtocolError):
        sched.run(PS_PER_MS)


def test_ppm_clock_scales_frame_duration() -> None:
    for ppm in (100.0, -50.0, 0.0, 12.5):
        sched = Scheduler()
        bus = CanBus(sched, RATE)
        tx = bus.attach(QueueNode("tx", RATE, clock=NodeClock(ppm=ppm)))
        rx = bus.attach(QueueNode("rx", RATE))
        tx.send(std(0x080))
        sched.run(PS_PER_MS)
        (rec,) = bus.records
        scale = 1 + Fraction(ppm) / 10**6

        def dur(n: int, scale: Fraction = scale) -> int:
            return int(Fraction(n * BIT_PS) / scale + Fraction(1, 2))

        assert rec.t_end_ps - rec.t_start_ps == dur(51)
        assert rx.received[0][0] == dur(48)
        assert bus.frame_duration_ps(std(0x080), tx.clock) == dur(51)
    # +100 ppm: 51 bits of 8 us shrink by 40.8 ns (rounded to 1 ps)
    assert bus.duration_ps(51, NodeClock(100.0)) == 408_000_000 - 40_796
    assert bus.duration_ps(51, NodeClock(-100.0)) == 408_000_000 + 40_804


def test_records_and_listeners() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    seen: list[tuple[int, BusRecord]] = []
    bus.add_listener(lambda r: seen.append((sched.now_ps, r)))
    a.send(std(0x181, b"\x01\x02"), std(0x181, b"\x03"))
    sched.run(PS_PER_MS * 10)
    assert [r for _, r in seen] == bus.records
    assert all(t == r.t_end_ps for t, r in seen)  # called when the frame completes
    assert [bytes(r.msg.data) for r in bus.records] == [b"\x01\x02", b"\x03"]
    # node activity and idle hooks
    assert a.activity == b.activity == [r.t_start_ps for r in bus.records]


def test_bitrate_none_node_is_not_on_the_bus_but_sees_activity() -> None:
    sched, bus, (a,) = make_bus("a")
    sleeper = bus.attach(QueueNode("sleeper", None))
    sleeper.send(std(0x100))  # cannot transmit while off the bus
    a.send(std(0x080))
    sched.run(PS_PER_MS * 2)
    # no ACK from the sleeping node -> ACK errors; it never transmits or receives
    assert bus.records and all(r.reason == "ack" for r in bus.records)
    assert all(r.sender == "a" for r in bus.records)
    assert sleeper.activity[:len(bus.records)] == [r.t_start_ps for r in bus.records]
    assert sleeper.activity == a.activity
    assert not sleeper.received and not sleeper.bus_errors and sleeper.rec == 0
    # wake up: on the bus again, it ACKs a's frame and then sends its own
    sleeper.bitrate_bps = RATE
    sched.run(sched.now_ps + PS_PER_MS * 3)
    ok = [r for r in bus.records if r.kind == "frame"]
    assert [r.sender for r in ok] == ["a", "sleeper"]


def test_trace_round_trip(tmp_path) -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    frames = [std(0x080), std(0x181, bytes([1, 2, 3, 4, 5, 6, 7, 8])),
              ext(0x1ABCDEF0, b"\xde\xad"), std(0x701, rtr=True, dlc=1), std(0x701, b"\x7f")]
    sched.call_at(123_456_789, a.send, *frames[:3])
    sched.call_at(5 * PS_PER_MS, b.send, *frames[3:])
    bus.corrupt_next_frame(sender="b")  # an error frame, which is not traced
    sched.run(20 * PS_PER_MS)
    ok = [r for r in bus.records if r.kind == "frame"]
    assert len(ok) == 5 and bus.stats["error_frames"] == 1
    for suffix in (".log", ".asc"):
        path = tmp_path / f"trace{suffix}"
        bus.write_trace(path)
        back = list(can.LogReader(str(path)))
        assert len(back) == 5, suffix
        for rec, msg in zip(ok, back):
            assert msg.arbitration_id == rec.msg.arbitration_id
            assert msg.is_extended_id == rec.msg.is_extended_id
            assert msg.is_remote_frame == rec.msg.is_remote_frame
            if suffix == ".asc" or not msg.is_remote_frame:
                assert msg.dlc == rec.msg.dlc  # candump -L does not store a remote DLC
            assert bytes(msg.data) == bytes(rec.msg.data)
            assert msg.timestamp == pytest.approx(rec.t_start_ps / 1e12, abs=1e-6)
        assert back[0].timestamp == pytest.approx(123.456789e-6, abs=1e-6)
    # reproducible: no wall-clock date in the ASC file
    first = (tmp_path / "trace.asc").read_text()
    bus.write_trace(tmp_path / "again.asc")
    assert (tmp_path / "again.asc").read_text() == first
    with pytest.raises(ValueError):
        bus.write_trace(tmp_path / "trace.blf")


def test_load_for_known_sequence() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    a.send(std(0x080), std(0x080))  # 2 x 51 bits back to back from t = 0
    sched.call_at(200 * BIT_PS, b.send, std(0x000))  # 53 bits at t = 200 bits
    sched.run(PS_PER_MS * 10)
    assert [(r.t_start_ps // BIT_PS, r.t_end_ps // BIT_PS) for r in bus.records] == [
        (0, 51), (51, 102), (200, 253)]
    assert bus.load(0, 102 * BIT_PS) == 1.0
    assert bus.load(0, 204 * BIT_PS) == pytest.approx((102 + 4) / 204)
    assert bus.load(0, 200 * BIT_PS) == pytest.approx(102 / 200)
    assert bus.load(102 * BIT_PS, 200 * BIT_PS) == 0.0
    assert bus.load(50 * BIT_PS, 250 * BIT_PS) == pytest.approx((52 + 50) / 200)
    assert bus.load(0, 400 * BIT_PS) == pytest.approx((102 + 53) / 400)
    assert bus.stats["busy_ps"] == 155 * BIT_PS
    with pytest.raises(ValueError):
        bus.load(5, 5)


def test_load_counts_frame_in_flight_up_to_now() -> None:
    sched, bus, (a, b) = make_bus("a", "b")
    a.send(std(0x000))
    sched.run_until(10 * BIT_PS)
    assert bus.load(0, 20 * BIT_PS) == pytest.approx(0.5)


def test_deterministic_replay() -> None:
    def scenario() -> list[tuple]:
        sched = Scheduler()
        bus = CanBus(sched, 250_000)
        nodes = [bus.attach(QueueNode(f"n{i}", 250_000, clock=NodeClock(ppm=i * 37.0 - 50)))
                 for i in range(4)]
        rng = random.Random(99)
        for k in range(40):
            i = k % 4
            ident = 0x181 + i + 0x100 * (k // 4 % 3)  # ids are unique per node
            msg = std(ident, bytes(rng.getrandbits(8) for _ in range(k % 9)))
            sched.call_at(rng.randrange(0, 5 * PS_PER_MS), nodes[i].send, msg)
        bus.corrupt_next_frame(count=2)
        sched.run(50 * PS_PER_MS)
        return [(r.kind, r.sender, r.t_start_ps, r.t_end_ps, r.n_bits, r.msg.arbitration_id)
                for r in bus.records]

    first = scenario()
    assert len(first) == 42
    assert scenario() == first


def test_attach_rules() -> None:
    sched, bus, (a,) = make_bus("a")
    with pytest.raises(ValueError):
        bus.attach(QueueNode("a", RATE))
    with pytest.raises(ValueError):
        bus.attach(a)
    other = CanBus(sched, RATE, name="can1")
    with pytest.raises(ValueError):
        other.attach(a)
    assert isinstance(a, CanNode) and a.bus is bus and bus.nodes == (a,)
