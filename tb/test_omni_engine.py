"""Bench of ``omni_engine``: the Omni-ID protocol engine of the master (NCTU thesis).

The bench plays the master core around the engine at 10 MHz with ``tick_us_i`` every 10th
cycle: it preloads the cycle frame (``cyc_take_i``: copies ``cyc_id_o``/``cyc_dlc_o``/
``cyc_data_o`` at that edge, as the core copies them into TXB2) and fires it (``cycle_i``), takes
the engine's frames (``tx_req_o`` / ``tx_ack_i``, FSM St8/St11) and hands received frames over
(``rx_valid_i`` .. ``rx_done_o``, FSM St5, :func:`tb.tblib.frame_handover.hand_over_frame`). The
host side writes the engine's register port directly (window offsets of ``OMNI_REGISTERS``).

Expected frames come from the independent reference codec :mod:`sim_models.omni.codec`
(Table 3-3 / 4-2 layouts, ambiguities A1, A3, A6, A12), the feasibility bits from
:func:`sim_models.can_bus.worst_case_bits`; the cycle / commit / window rules from
docs/omni_engine.md, written here as small reference functions, not read from the RTL.

Checkers on every frame: a frame on ``tx_req_o`` never changes before ``tx_ack_i``;
``rx_done_o`` within 4 cycles of ``rx_valid_i`` (6 for a query), ``rx_reply_o`` only with
``tx_req_o`` = 1 and never with ``rx_unexpected_o``.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

import can
import cocotb
import pytest
from cocotb.triggers import ClockCycles, FallingEdge, ReadOnly, RisingEdge

from sim_models.can_bus import worst_case_bits
from sim_models.canopen_slave.network import make_message
from sim_models.omni import codec as oc
from sim_models.omni.master_model import broadcast_dlc, check_feasibility
from sim_models.sim_time import PS_PER_US
from tb.tblib import regmap as R
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.frame_handover import hand_over_frame
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.runner import param, run_cocotb

CLK_HZ = 10_000_000
CLK_PS = 10**12 // CLK_HZ
TICK_CYCLES = 10  # tick_us_i every 10 cycles = 1 us
MASTER = oc.THESIS_MASTER_ID
SLAVES = oc.THESIS_SLAVE_IDS  # 0x04, 0x08, 0x10, 0x20
FB_FC = oc.THESIS_FEEDBACK_FC
RX_BOUND = 4
RX_BOUND_QUERY = 6
#: counter read lag (docs/omni_engine.md): an event counted at edge e shows in every read with
#: the address on reg_addr_i CNT_LAG cycles later (amounts registered: 1, bank: S + 3, S = 9)
CNT_LAG = 13


def slot_lag(n_slots: int) -> int:
    """Slot counter read lag (docs/omni_engine.md): a missed cycle closed at edge e shows in
    OMNI_SLOT_ERR.MISSED in every read with the address on reg_addr_i slot_lag cycles later
    (the MISSED sweep visits a slot every 2 * N_SLOTS cycles; + 4 for the registered events,
    the pending count, host copy and read register)."""
    return 2 * n_slots + 4

#: frame builder (docs/omni_engine.md): the cycle frame of a COMMIT or OMNI_CFG write at edge e
#: is on cyc_* from edge e + BUILD_CYCLES on; a take before sends the previous frame and keeps
#: PENDING
BUILD_CYCLES = 10


def off(name: str) -> int:
    return R.OMNI_REGISTERS[name].addr - R.REG_OMNI_WIN


def frame_key(msg: can.Message) -> tuple[int, int, int, bytes]:
    data = b"" if msg.is_remote_frame else bytes(msg.data[:msg.dlc])
    return (msg.arbitration_id, int(msg.is_remote_frame), msg.dlc, data)


def as_msg(fid: int, rtr: int, dlc: int, data: int) -> can.Message:
    if rtr:
        return make_message(fid, b"", remote=True, dlc=dlc)
    return make_message(fid, data.to_bytes(8, "little")[:min(dlc, 8)])


@dataclass
class TxRec:
    t_ps: int  #: edge that sampled tx_ack_i
    msg: can.Message


class TB:
    def __init__(self, dut) -> None:
        self.dut = dut
        self.n_slots = param("N_SLOTS")
        self.bitrate = param("BITRATE_BPS")
        start_clock(dut.clk_i, CLK_HZ)
        for sig in (dut.enable_i, dut.cycle_i, dut.cyc_take_i, dut.reg_we_i, dut.reg_addr_i,
                    dut.reg_wdata_i, dut.rx_valid_i, dut.rx_id_i, dut.rx_rtr_i, dut.rx_dlc_i,
                    dut.rx_data_i, dut.tx_ack_i, dut.tick_us_i):
            sig.value = 0
        dut.period_us_i.value = 10_000
        self.auto_ack = True
        self.ack_delay = 2
        self.tx_log: list[TxRec] = []
        self.tick_edges: list[int] = []
        self.ev_edges: list[int] = []
        self.takes: list[can.Message] = []  #: frame copied at each cyc_take_i

    async def start(self, enable: bool = True) -> None:
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        cocotb.start_soon(self._ticker())
        cocotb.start_soon(self._taker())
        cocotb.start_soon(self._ev_counter())
        await FallingEdge(self.dut.clk_i)
        self.dut.enable_i.value = int(enable)

    # ------------------------------------------------------------------ bench core
    async def _ticker(self) -> None:
        dut = self.dut
        while True:
            await ClockCycles(dut.clk_i, TICK_CYCLES - 1, rising=False)
            dut.tick_us_i.value = 1
            await RisingEdge(dut.clk_i)
            self.tick_edges.append(sim_time_ps())
            await FallingEdge(dut.clk_i)
            dut.tick_us_i.value = 0

    async def _ev_counter(self) -> None:
        dut = self.dut
        while True:
            await RisingEdge(dut.clk_i)
            await ReadOnly()
            if dut.ev_o.value == 1:
                self.ev_edges.append(sim_time_ps())

    def _tx_frame(self) -> tuple[int, int, int, int]:
        d = self.dut
        return (int(d.tx_id_o.value), int(d.tx_rtr_o.value), int(d.tx_dlc_o.value),
                int(d.tx_data_o.value))

    async def _taker(self) -> None:
        dut = self.dut
        while True:
            await FallingEdge(dut.clk_i)
            if dut.tx_req_o.value != 1 or not self.auto_ack:
                continue
            frame = self._tx_frame()
            for _ in range(self.ack_delay):
                await FallingEdge(dut.clk_i)
                assert dut.tx_req_o.value == 1, "tx_req_o withdrawn before tx_ack_i"
                assert self._tx_frame() == frame, "frame changed while tx_req_o = 1"
            dut.tx_ack_i.value = 1
            await RisingEdge(dut.clk_i)
            dut.tx_ack_i.value = 0
            self.tx_log.append(TxRec(sim_time_ps(), as_msg(*frame)))

    # ------------------------------------------------------------------ host port
    async def write(self, name: str, value: int) -> int:
        """Write a register; returns the edge that sampled it."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.reg_addr_i.value = off(name)
        dut.reg_wdata_i.value = value
        dut.reg_we_i.value = 1
        await RisingEdge(dut.clk_i)
        t = sim_time_ps()
        dut.reg_we_i.value = 0
        return t

    async def read(self, name: str) -> int:
        dut = self.dut
        if name.startswith("OMNI_CNT_"):
            # counter bank read lag: an event of cycle e shows in reads from cycle e + CNT_LAG
            await ClockCycles(dut.clk_i, CNT_LAG, rising=False)
        elif name == "OMNI_SLOT_ERR":
            await ClockCycles(dut.clk_i, slot_lag(self.n_slots), rising=False)
        await FallingEdge(dut.clk_i)
        dut.reg_addr_i.value = off(name)
        await RisingEdge(dut.clk_i)
        await ReadOnly()
        return int(dut.reg_rdata_o.value)

    async def field(self, reg: str, fld: str) -> int:
        return R.get_field(reg, fld, await self.read(reg))

    async def configure(self, *, n_axes: int = 4, bc4x2: bool = False, sender: bool = True,
                        sync_mode: bool = False, stop: bool = False, k: int = 1, m: int = 0,
                        qwin: int = 1000, slots=None, master: int = MASTER) -> None:
        """Configure and wait until the cycle frame of the configuration is built."""
        await self.write("OMNI_CFG", R.make("OMNI_CFG", MASTER_ID=master, N_AXES=n_axes,
                                            BCAST_4X2=int(bc4x2), SENDER=int(sender),
                                            SYNC_MODE=int(sync_mode), STOP_ON_MISSING=int(stop)))
        await self.write("OMNI_SYNC_K", k)
        await self.write("OMNI_POLL", m)
        await self.write("OMNI_QUERY_WIN", qwin)
        for i, (node, fc, dlc) in enumerate(slots or []):
            await self.slot_cfg(i, node, fc, dlc)
        await self.idle(BUILD_CYCLES)

    async def slot_cfg(self, slot: int, node: int, fc: int, dlc: int, valid: bool = True):
        await self.write("OMNI_SEL", slot)
        await self.write("OMNI_SLOT_CFG", R.make("OMNI_SLOT_CFG", NODE=node, FC=fc,
                                                 VALID=int(valid), DLC=dlc))

    async def set_points(self, values: list[int], commit: bool = True,
                         settle: bool = True) -> int | None:
        """Write the staging set-points and COMMIT (returns the commit edge); with settle,
        wait until the commit's cycle frame is built."""
        vals = [v & 0xFFFF for v in values] + [0] * (8 - len(values))
        for i in range(4):
            await self.write(f"OMNI_SP{2 * i}{2 * i + 1}", vals[2 * i] | vals[2 * i + 1] << 16)
        if commit:
            t = await self.write("OMNI_CTRL", R.OMNI_CTRL_COMMIT)
            if settle:
                await self.idle(BUILD_CYCLES)
            return t
        return None

    # ------------------------------------------------------------------ core side
    def cyc_frame(self) -> can.Message:
        d = self.dut
        return as_msg(int(d.cyc_id_o.value), 0, int(d.cyc_dlc_o.value), int(d.cyc_data_o.value))

    async def take(self) -> can.Message:
        """cyc_take_i for one cycle; returns the frame copied at that edge."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.cyc_take_i.value = 1
        await RisingEdge(dut.clk_i)
        msg = self.cyc_frame()  # values before the edge's updates (inertial)
        dut.cyc_take_i.value = 0
        self.takes.append(msg)
        return msg

    async def fire(self) -> int:
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.cycle_i.value = 1
        await RisingEdge(dut.clk_i)
        t = sim_time_ps()
        dut.cycle_i.value = 0
        return t

    async def cycle(self, gap: int = 30) -> can.Message:
        """One core cycle: preload (take), wait, fire, wait."""
        msg = await self.take()
        await ClockCycles(self.dut.clk_i, gap // 2, rising=False)
        await self.fire()
        await ClockCycles(self.dut.clk_i, gap // 2, rising=False)
        return msg

    async def rx(self, msg: can.Message, bound: int = RX_BOUND) -> tuple[int, int, int, int]:
        """Hand a frame over; returns (edge of rx_valid_i, latency, reply, unexpected)."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        t, lat = await hand_over_frame(dut, msg, bound)
        reply = int(dut.rx_reply_o.value)
        unexp = int(dut.rx_unexpected_o.value)
        if reply:
            assert dut.tx_req_o.value == 1, "rx_reply_o without tx_req_o"
            assert not unexp, "rx_reply_o with rx_unexpected_o"
        await FallingEdge(dut.clk_i)
        return t, lat, reply, unexp

    async def idle(self, cycles: int = 20) -> None:
        await ClockCycles(self.dut.clk_i, cycles, rising=False)

    def sent(self, since: int = 0) -> list[tuple[int, int, int, bytes]]:
        return [frame_key(r.msg) for r in self.tx_log[since:]]


def feedback(slave: int, value: int, dlc: int = 6, master: int = MASTER) -> can.Message:
    return oc.data_frame(FB_FC[slave], master, slave, oc.DTYPE_FEEDBACK, value, size=dlc - 2)


PLATFORM_SLOTS = [(n, FB_FC[n], 6) for n in SLAVES]


# ==================================================================================== tests
@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_codec_table_4_2(dut):
    """Purpose: AT-1/AT-2: every id the engine emits or accepts is fc*256 + node (Table 3-3),
    exactly the Table 4-2 set for master 2 and slaves 4, 8, 16, 32.

    Verifies: NMT 0x000 [00][01] (Fig 4-20), query RTR 0x000, reply RTR 0x002 to a query
    (rx_reply_o), broadcast 0x102 (trace form, DLC 5), feedback 0x202/0x302/0x502/0x602
    accepted, parameters 0x704..0x720 [02][01][00][64] (Fig 4-19).
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=4, sender=True, m=1, qwin=50, slots=PLATFORM_SLOTS)
    await tb.write("OMNI_NMT", R.make("OMNI_NMT", NODE=0, STATE=oc.NMT_START))
    bc = await tb.cycle()
    assert frame_key(bc) == frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, MASTER, [0] * 4))
    assert frame_key(bc) == (0x102, 0, 5, bytes([2, 0, 0, 0, 0])), "Fig 4-20 trace row 3"
    _, lat, reply, unexp = await tb.rx(oc.node_query_frame(), RX_BOUND_QUERY)
    assert reply == 1 and not unexp
    for s in SLAVES:
        _, _, reply, unexp = await tb.rx(feedback(s, 0))
        assert not unexp and not reply
    for s in SLAVES:
        await tb.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=s, TYPE=1, DLC=4))
        await tb.write("OMNI_PARAM_LO", 0x6400)
        await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)
        await tb.idle(8)
    await tb.idle(40)
    sent = tb.sent()
    expect = [frame_key(oc.nmt_frame(0, oc.NMT_START)), frame_key(oc.node_query_frame()),
              frame_key(oc.query_reply_frame(MASTER))]
    expect += [frame_key(oc.data_frame(oc.FC_PARAM, s, MASTER, oc.DTYPE_PARAMETER, 100, 2))
               for s in SLAVES]
    assert sent == expect, f"{sent} != {expect}"
    assert [f[3].hex(" ") for f in sent[3:]] == ["02 01 00 64"] * 4, "Fig 4-19 rows 2-5"
    ids = {f[0] for f in sent} | {bc.arbitration_id} | {oc.omni_id(FB_FC[s], MASTER)
                                                         for s in SLAVES}
    for i in ids:
        fc, node = oc.decode_id(i)
        assert i == fc * 256 + node and oc.valid_omni_id(i)
    assert ids == {0x000, 0x002, 0x102, 0x202, 0x302, 0x502, 0x602, 0x704, 0x708, 0x710,
                   0x720}
    assert await tb.read("OMNI_CNT_UNEXPECTED") == 0
    assert await tb.read("OMNI_CNT_FB_RX") == 4


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_broadcast_layouts(dut):
    """Purpose: both broadcast layouts with N = 1..max equal the reference codec (A1, A2).

    Verifies: fc 001 with and without sender byte (N 1..7 / 1..8), fc 100 (N 1..4): id, DLC
    and bytes of the cycle frame copied at cyc_take_i; N beyond the layout -> CFG_ERR and
    feasible_o = 0.
    """
    tb = TB(dut)
    await tb.start()
    rng = random.Random(1)
    for fc, snd, nmax in ((oc.FC_BCAST_8X1, True, 7), (oc.FC_BCAST_8X1, False, 8),
                          (oc.FC_BCAST_4X2, False, 4)):
        w = 1 if fc == oc.FC_BCAST_8X1 else 2
        for n in range(1, nmax + 2):
            await tb.configure(n_axes=n, bc4x2=fc == oc.FC_BCAST_4X2, sender=snd)
            if n > nmax:
                await tb.idle(30)
                assert await tb.field("OMNI_STATUS", "CFG_ERR") == 1
                assert dut.feasible_o.value == 0
                continue
            lim = 1 << (8 * w - 1)
            vals = [rng.randrange(-lim, lim) for _ in range(n)]
            await tb.set_points([v & ((1 << 8 * w) - 1) for v in vals])
            got = await tb.take()
            exp = oc.broadcast_frame(fc, MASTER, vals, with_sender=snd if w == 1 else False)
            assert frame_key(got) == frame_key(exp), f"fc {fc:03b} N {n}: {got} != {exp}"
            assert await tb.field("OMNI_STATUS", "CFG_ERR") == 0


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_double_buffer(dut):
    """Purpose: a take sends the set of the newest COMMIT at least BUILD_CYCLES before it (a
    COMMIT followed by another within BUILD_CYCLES is never sent); a COMMIT is applied
    (PENDING falls) at the first take BUILD_CYCLES or more after it; a frame is never torn.

    Verifies: 300 random steps (staging writes, commits, takes 0..2*BUILD_CYCLES cycles after
    the commit, take in the commit's cycle): every taken frame equals the reference (the set
    of the newest commit at least BUILD_CYCLES before the take edge, zeros before any), PENDING
    is 1 exactly while the newest commit has not been taken that way; staging writes without
    commit never show; both sides of the build boundary are hit.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=8, sender=False)
    rng = random.Random(2)
    staging = [0] * 8
    commits: list[tuple[int, list[int]]] = [(0, [0] * 8)]  # (commit edge, set)
    pending = False
    hits = {"early": 0, "built": 0}
    dut_ = dut

    def expected(t_take: int) -> list[int]:
        """Set of the newest commit at least BUILD_CYCLES before the take edge whose frame was
        finished (no newer commit within BUILD_CYCLES after it)."""
        build = BUILD_CYCLES * CLK_PS
        done = [v for i, (t, v) in enumerate(commits)
                if t_take - t >= build
                and (i + 1 == len(commits) or commits[i + 1][0] - t >= build)]
        return done[-1]

    def take_done(t_take: int) -> None:
        nonlocal pending
        if pending:
            if t_take - commits[-1][0] >= BUILD_CYCLES * CLK_PS:
                pending = False
                hits["built"] += 1
            else:
                hits["early"] += 1

    for step in range(300):
        op = rng.random()
        if op < 0.4:
            staging = [rng.randrange(256) for _ in range(8)]
            t = await tb.set_points(staging, commit=rng.random() < 0.7, settle=False)
            if t is not None:
                commits.append((t, staging))
                pending = True
                await tb.idle(rng.choice([0, 1, BUILD_CYCLES - 3, BUILD_CYCLES - 2,
                                          BUILD_CYCLES - 1, BUILD_CYCLES, 2 * BUILD_CYCLES]))
        elif op < 0.5 and pending:
            # commit and take sampled at the same edge: the take uses the old state
            await FallingEdge(dut_.clk_i)
            dut_.reg_addr_i.value = off("OMNI_CTRL")
            dut_.reg_wdata_i.value = R.OMNI_CTRL_COMMIT
            dut_.reg_we_i.value = 1
            dut_.cyc_take_i.value = 1
            await RisingEdge(dut_.clk_i)
            t = sim_time_ps()
            got = tb.cyc_frame()
            dut_.reg_we_i.value = 0
            dut_.cyc_take_i.value = 0
            assert list(reversed(got.data)) == expected(t), f"step {step}: same-edge take"
            take_done(t)
            commits.append((t, staging))
            pending = True
        else:
            got = await tb.take()
            t = sim_time_ps()
            assert list(reversed(got.data)) == expected(t), f"step {step}: {got}"
            take_done(t)
        assert await tb.field("OMNI_STATUS", "PENDING") == int(pending)
    assert hits["early"] >= 5 and hits["built"] >= 5, hits


def sync_cycles(n_cycles: int, k: int) -> list[bool]:
    """Reference: cycle k (0-based, from the first cycle_i after enable) is a SYNC cycle when
    k mod K = 0; its cycle frame is the one copied at the take before cycle_i number k."""
    return [c % k == 0 for c in range(n_cycles)]


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_config_change_frame(dut):
    """Purpose: an OMNI_CFG write changes the cycle frame whole, BUILD_CYCLES after the write.

    Verifies: for every distance 0..BUILD_CYCLES + 2 cycles between an OMNI_CFG write (N_AXES
    3 <-> 5, SENDER on/off, master id) and a take: the taken frame is the reference frame of
    the old configuration before BUILD_CYCLES and of the new one from BUILD_CYCLES on (id, DLC
    and bytes of one configuration, never a mix); a second write inside the build restarts it.
    """
    tb = TB(dut)
    await tb.start()
    vals = [0x11, 0x22, 0x33, 0x44, 0x55]
    await tb.configure(n_axes=3, sender=True)
    await tb.set_points(vals)

    def cfg(n: int, snd: bool, master: int) -> int:
        return R.make("OMNI_CFG", MASTER_ID=master, N_AXES=n, SENDER=int(snd))

    def ref(n: int, snd: bool, master: int) -> tuple:
        return frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, master, vals[:n], with_sender=snd))

    old, new = (3, True, MASTER), (5, False, MASTER + 1)
    for dist in range(BUILD_CYCLES + 3):
        for a, b in ((old, new), (new, old)):
            t_w = await tb.write("OMNI_CFG", cfg(*b))
            await tb.idle(max(dist - 1, 0))
            got = await tb.take()
            d = (sim_time_ps() - t_w) // CLK_PS
            exp = ref(*b) if d >= BUILD_CYCLES else ref(*a)
            assert frame_key(got) == exp, f"{d} cycles after the write: {got}"
            await tb.idle(BUILD_CYCLES)  # b's frame is built before the next write
    # a second write inside the build: the frame of the first never shows
    await tb.write("OMNI_CFG", cfg(*new))
    await tb.idle(BUILD_CYCLES - 4)
    t_w = await tb.write("OMNI_CFG", cfg(*old))
    await tb.idle(BUILD_CYCLES - 2)
    got = await tb.take()
    assert (sim_time_ps() - t_w) // CLK_PS == BUILD_CYCLES - 1
    assert frame_key(got) == ref(*old), "restarted build: the first write's frame showed"
    got = await tb.take()
    assert frame_key(got) == ref(*old)


@cocotb.test(timeout_time=30, timeout_unit="ms")
async def run_sync_mode_selection(dut):
    """Purpose: SYNC_MODE 1 chooses the Omni SYNC as cycle frame at exactly the cycles
    k mod K = 0 over >= 3K cycles, and sends that cycle's broadcast through tx_req_o.

    Verifies: K = 3 and K = 5 (+ 1 extra cycle), positions exact; the broadcast after each
    SYNC carries the active set of that cycle; mode 0 never sends the SYNC; OMNI_CYCLE counts
    cycle_i; the count restarts when enable_i toggles.
    """
    tb = TB(dut)
    await tb.start()
    for k in (3, 5):
        await FallingEdge(dut.clk_i)
        dut.enable_i.value = 0
        await tb.configure(n_axes=2, sender=True, sync_mode=True, k=k)
        await tb.idle(2)
        dut.enable_i.value = 1
        await tb.idle(2)
        n = 3 * k + 1
        start = len(tb.tx_log)
        kinds = []
        for c in range(n):
            await tb.set_points([c, c + 1])
            msg = await tb.cycle()
            kinds.append(oc.is_omni_sync(msg))
            if not kinds[-1]:
                assert frame_key(msg) == frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, MASTER,
                                                                      [c, c + 1]))
            assert await tb.read("OMNI_CYCLE") == c + 1
        assert kinds == sync_cycles(n, k), f"K={k}: {kinds}"
        after = tb.sent(start)
        assert after == [frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, MASTER, [c, c + 1]))
                         for c in range(n) if c % k == 0]
    await FallingEdge(dut.clk_i)
    dut.enable_i.value = 0
    await tb.configure(n_axes=2, sync_mode=False, k=2)
    await FallingEdge(dut.clk_i)
    dut.enable_i.value = 1
    for _ in range(4):
        assert not oc.is_omni_sync(await tb.cycle())


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_nmt_refused_and_priority(dut):
    """Purpose: NMT frames (A3), nothing lost silently, the documented priority.

    Verifies: NMT [node][state]; a second NMT / PARAM_SEND while queued is refused
    (NMT_BUSY / PARAM_BUSY, OMNI_CNT_REFUSED), PARAM_* writes while queued are refused; with
    every item due at once the order is NMT, broadcast after SYNC, query, reply, parameter.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, sender=True, sync_mode=True, k=1, m=1, qwin=5)
    tb.auto_ack = False
    await tb.write("OMNI_NMT", R.make("OMNI_NMT", NODE=8, STATE=0))
    await tb.write("OMNI_NMT", R.make("OMNI_NMT", NODE=9, STATE=1))  # presented: refused
    await tb.idle(3)
    await tb.write("OMNI_NMT", R.make("OMNI_NMT", NODE=9, STATE=1))  # queued behind it
    await tb.write("OMNI_NMT", R.make("OMNI_NMT", NODE=10, STATE=1))  # refused
    assert await tb.field("OMNI_STATUS", "NMT_BUSY") == 1
    await tb.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=4, TYPE=1, DLC=2))
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)  # refused
    await tb.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=5, TYPE=1, DLC=2))  # refused
    assert await tb.field("OMNI_STATUS", "PARAM_BUSY") == 1
    await tb.rx(oc.node_query_frame(), RX_BOUND_QUERY)  # reply queued
    await tb.cycle()  # SYNC cycle with the query: broadcast + query queued
    assert await tb.read("OMNI_CNT_REFUSED") == 4
    tb.auto_ack = True
    await tb.idle(60)
    assert tb.sent() == [
        frame_key(oc.nmt_frame(8, 0)), frame_key(oc.nmt_frame(9, 1)),
        frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, MASTER, [0])),
        frame_key(oc.node_query_frame()), frame_key(oc.query_reply_frame(MASTER)),
        frame_key(make_message(0x704, bytes([MASTER, 1])))]


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_parameter_frames_and_mailbox(dut):
    """Purpose: parameter frames byte-exact as Fig 4-19, the parameter mailbox.

    Verifies: the PC's 0x702 [01][0C][00 00 00 64] lands in the mailbox (sender, type, DLC,
    content, NEW, ev_o); a second one sets OVERRUN; W1C; fc 111 to another node and a DLC 1
    frame are unexpected; the master's forwarded frames 0x704.. [02][01][00][64] (DLC 4) and a
    full 8-byte frame.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure()
    pc = oc.data_frame(oc.FC_PARAM, MASTER, oc.THESIS_PC_ID, oc.DTYPE_CONTROLLER_SETTING, 100)
    assert bytes(pc.data).hex(" ") == "01 0c 00 00 00 64" and pc.arbitration_id == 1794
    ev0 = len(tb.ev_edges)
    _, _, _, unexp = await tb.rx(pc)
    assert not unexp and len(tb.ev_edges) == ev0 + 1
    info = await tb.read("OMNI_PMB_INFO")
    assert tuple(R.get_field("OMNI_PMB_INFO", f, info)
                 for f in ("SENDER", "TYPE", "DLC", "NEW", "OVERRUN")) == (1, 0x0C, 6, 1, 0)
    lo, hi = await tb.read("OMNI_PMB_LO"), await tb.read("OMNI_PMB_HI")
    assert (lo | hi << 32).to_bytes(6, "little")[:4] == bytes([0, 0, 0, 0x64])
    await tb.rx(pc)
    assert await tb.field("OMNI_PMB_INFO", "OVERRUN") == 1
    await tb.write("OMNI_PMB_INFO", R.OMNI_PMB_INFO_NEW | R.OMNI_PMB_INFO_OVERRUN)
    assert await tb.read("OMNI_PMB_INFO") & (R.OMNI_PMB_INFO_NEW | R.OMNI_PMB_INFO_OVERRUN) == 0
    for bad in (oc.data_frame(oc.FC_PARAM, 4, 1, 1, 5), make_message(0x702, b"\x01")):
        assert (await tb.rx(bad))[3] == 1
    assert await tb.read("OMNI_CNT_PARAM_RX") == 2
    start = len(tb.tx_log)
    for s in SLAVES:
        await tb.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=s, TYPE=1, DLC=4))
        await tb.write("OMNI_PARAM_LO", 0x6400)
        await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)
        await tb.idle(8)
    await tb.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=0x20, TYPE=0x0C, DLC=8))
    await tb.write("OMNI_PARAM_LO", 0x44332211)
    await tb.write("OMNI_PARAM_HI", 0x6655)
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)
    await tb.idle(10)
    fig = [(1796, 0, 4, bytes.fromhex("02 01 00 64")), (1800, 0, 4, bytes.fromhex("02 01 00 64")),
           (1808, 0, 4, bytes.fromhex("02 01 00 64")), (1824, 0, 4, bytes.fromhex("02 01 00 64"))]
    assert tb.sent(start) == fig + [frame_key(oc.data_frame(
        oc.FC_PARAM, 0x20, MASTER, 0x0C, bytes.fromhex("11 22 33 44 55 66")))]


async def query_cycle(tb: TB) -> int:
    """Take + fire a cycle that queries; returns the edge that sampled the query's tx_ack_i."""
    start = len(tb.tx_log)
    await tb.take()
    await tb.fire()
    while len(tb.tx_log) == start:
        await FallingEdge(tb.dut.clk_i)
    rec = tb.tx_log[start]
    assert frame_key(rec.msg) == frame_key(oc.node_query_frame())
    return rec.t_ps


async def close_edge(tb: TB, t_ack: int, w: int) -> int:
    """Reference: the edge sampling the w-th tick_us_i strobe after the ack edge (the ticks
    are periodic, so it is predicted from the first one)."""
    while not any(t > t_ack for t in tb.tick_edges):
        await FallingEdge(tb.dut.clk_i)
    first = min(t for t in tb.tick_edges if t > t_ack)
    return first + (w - 1) * TICK_CYCLES * CLK_PS


async def rx_at(tb: TB, msg: can.Message, t_edge: int) -> None:
    """Hand ``msg`` over so that rx_valid_i is sampled at edge ``t_edge``."""
    while sim_time_ps() + CLK_PS + CLK_PS // 2 < t_edge:
        await FallingEdge(tb.dut.clk_i)
    t_valid, *_ = await tb.rx(msg)
    assert t_valid == t_edge, (t_valid, t_edge)


@cocotb.test(timeout_time=30, timeout_unit="ms")
async def run_query_window_exact(dut):
    """Purpose: node monitoring (§2.3 b, A11, A12): query every M cycles, replies counted
    inside the window with exact edges, MISSING / ALIVE / counter / ev_o, STOP_ON_MISSING.

    Verifies: M = 2: queries at cycles 0 and 2 only; window W = 20 us from tx_ack_i of the
    query: a reply sampled one edge before the edge that samples the W-th tick after the ack
    counts, one sampled at that edge does not; missing slots sticky (W1C) with the lowest
    missing slot's node-ID in OMNI_MISSING.NODE, ALIVE, counter = missing slots, one ev_o;
    STOP_ON_MISSING queues NMT stop all [00][00]; a reply from a node in no slot is
    unexpected.
    """
    tb = TB(dut)
    await tb.start()
    w = 20
    await tb.configure(n_axes=1, m=2, qwin=w, stop=True, slots=PLATFORM_SLOTS)
    tb.ack_delay = 3
    # cycle 0: slave 0x20 one edge too late
    t_ack = await query_cycle(tb)
    for s in SLAVES[:3]:
        await tb.rx(oc.query_reply_frame(s))
    assert await tb.field("OMNI_STATUS", "QUERY_OPEN") == 1
    t_close = await close_edge(tb, t_ack, w)
    ev0 = len(tb.ev_edges)
    await rx_at(tb, oc.query_reply_frame(SLAVES[3]), t_close)
    await tb.idle(20)
    assert await tb.read("OMNI_ALIVE") == 0b0111
    # MISSING = slot 3, NODE = its node-ID (the lowest missing slot's)
    assert await tb.read("OMNI_MISSING") == 0b1000 | SLAVES[3] << 8
    assert await tb.read("OMNI_CNT_NODE_MISSING") == 1
    assert len(tb.ev_edges) == ev0 + 1
    assert frame_key(tb.tx_log[-1].msg) == frame_key(oc.nmt_frame(0, oc.NMT_STOP))
    await tb.write("OMNI_MISSING", 0xFF)
    assert await tb.read("OMNI_MISSING") == 0
    # cycle 1: no query
    n = len(tb.tx_log)
    await tb.cycle()
    await tb.idle(20)
    assert len(tb.tx_log) == n
    # cycle 2: every reply in time, the last one edge before the close
    t_ack = await query_cycle(tb)
    for s in SLAVES[:3]:
        await tb.rx(oc.query_reply_frame(s))
    t_close = await close_edge(tb, t_ack, w)
    await rx_at(tb, oc.query_reply_frame(SLAVES[3]), t_close - CLK_PS)
    await tb.idle(20)
    assert await tb.read("OMNI_ALIVE") == 0b1111
    assert await tb.read("OMNI_MISSING") == 0
    assert await tb.read("OMNI_CNT_NODE_MISSING") == 1
    assert len(tb.tx_log) == n + 1, "no stop without a missing node"
    _, _, _, unexp = await tb.rx(oc.query_reply_frame(0x40))
    assert unexp == 1


@cocotb.test(timeout_time=30, timeout_unit="ms")
async def run_feedback_storage_and_missed(dut):
    """Purpose: process-data feedback (Table 4-2) storage, errors and missed cycles.

    Verifies: 12 cycles, slaves dropping feedback by a random pattern: snapshots equal the
    last frame (bytes as received, SEQ, CYCLE = OMNI_CYCLE at reception), NEW / ACK / W1C,
    ev_o per stored frame; wrong DLC -> LEN_ERR (slot and counter), wrong sender / fc /
    receiver / invalid slot -> unexpected; per-slot MISSED and the total equal the reference
    (the first cycle_i is not checked, a frame in a cycle counts for that cycle).
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, slots=PLATFORM_SLOTS)
    rng = random.Random(3)
    seq = dict.fromkeys(SLAVES, 0)
    last: dict[int, tuple[bytes, int]] = {}
    missed = dict.fromkeys(SLAVES, 0)
    ev0 = len(tb.ev_edges)
    for c in range(12):
        await tb.cycle(gap=10)
        for s in SLAVES:
            if rng.random() < 0.3:
                missed[s] += 1  # reference: cycle c is checked at cycle_i number c + 1
                continue
            msg = feedback(s, rng.randrange(1 << 31))
            await tb.rx(msg)
            seq[s] += 1
            last[s] = (bytes(msg.data), c + 1)
    await tb.fire()  # closes cycle 11
    for i, s in enumerate(SLAVES):
        await tb.write("OMNI_SEL", i)
        lo, hi = await tb.read("OMNI_FB_LO"), await tb.read("OMNI_FB_HI")
        info = await tb.read("OMNI_FB_INFO")
        data = (lo | hi << 32).to_bytes(8, "little")
        assert data[:6] == last[s][0] and data[6:] == bytes(2)
        assert R.get_field("OMNI_FB_INFO", "SEQ", info) == seq[s]
        assert R.get_field("OMNI_FB_INFO", "CYCLE", info) == last[s][1]
        assert await tb.field("OMNI_SEL", "NEW") == 1
        assert await tb.field("OMNI_SLOT_ERR", "MISSED") == missed[s], s
    assert await tb.read("OMNI_CNT_MISSED") == sum(missed.values())
    assert len(tb.ev_edges) - ev0 == sum(seq.values()) == await tb.read("OMNI_CNT_FB_RX")
    assert await tb.read("OMNI_FB_NEW") == 0b1111
    await tb.write("OMNI_SEL", R.make("OMNI_SEL", SLOT=1, ACK=1))
    await tb.write("OMNI_FB_NEW", 0b0001)
    assert await tb.read("OMNI_FB_NEW") == 0b1100
    # length error and unexpected frames
    await tb.rx(feedback(0x04, 7, dlc=4))
    await tb.write("OMNI_SEL", 0)
    assert await tb.field("OMNI_SLOT_ERR", "LEN_ERR") == 1
    assert await tb.read("OMNI_CNT_LEN_ERR") == 1
    bad = [oc.data_frame(oc.FC_PD_010, MASTER, 0x08, 0, 1),  # sender of another fc
           oc.data_frame(oc.FC_PD_010, 3, 0x04, 0, 1),  # not to the master
           oc.data_frame(oc.FC_PD_010, MASTER, 0x40, 0, 1),  # no slot
           make_message(0x202, b""),  # no sender byte
           oc.broadcast_frame(oc.FC_BCAST_8X1, 5, [1]), oc.omni_sync_frame()]
    for msg in bad:
        assert (await tb.rx(msg))[3] == 1, msg
    assert await tb.read("OMNI_CNT_UNEXPECTED") == len(bad)
    assert await tb.read("OMNI_CNT_FB_RX") == sum(seq.values())
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_CLR_COUNTERS)
    assert await tb.read("OMNI_CNT_UNEXPECTED") == 0
    assert await tb.field("OMNI_SLOT_ERR", "LEN_ERR") == 0


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_feasibility(dut):
    """Purpose: feasible_o / INFEASIBLE against the worst-case bus time of one cycle.

    Verifies: OMNI_BUS_BITS = worst_case_bits(broadcast) [+ worst_case_bits(0) for the SYNC]
    + one worst_case_bits(DLC) per valid slot; feasible_o = bits * t_bit <= period, at
    periods just below / at the limit, for several configurations and the generic bit rate;
    at 125 kbit/s and 1 ms: DLC 8 infeasible, DLC 5 feasible, DLC 5 + a 6-byte feedback not.
    """
    tb = TB(dut)
    await tb.start()
    rate = tb.bitrate
    cells = [(4, True, False, [(n, FB_FC[n], 6) for n in SLAVES]),
             (8, False, True, [(n, FB_FC[n], 8) for n in SLAVES]),
             (7, True, True, [(4, 2, 8)] * min(tb.n_slots, 8)),
             (1, True, False, [])]
    for n_axes, snd, sync, slots in cells:
        for i in range(tb.n_slots):
            await tb.slot_cfg(i, 0, 0, 0, valid=False)
        await tb.configure(n_axes=n_axes, sender=snd, sync_mode=sync, slots=slots)
        bits = worst_case_bits(n_axes + snd) + (worst_case_bits(0) if sync else 0)
        bits += sum(worst_case_bits(d) for _, _, d in slots)
        await tb.idle(30)
        assert await tb.read("OMNI_BUS_BITS") == bits
        limit_us = -(-bits * 10**6 // rate)  # smallest period that fits
        for period, ok in ((limit_us - 1, False), (limit_us, True), (1000, bits * 10**6 <=
                                                                     1000 * rate)):
            await FallingEdge(dut.clk_i)
            dut.period_us_i.value = period
            await tb.idle(30)
            assert int(dut.feasible_o.value) == int(ok), (n_axes, sync, period, bits)
            assert await tb.field("OMNI_STATUS", "INFEASIBLE") == int(not ok)
    if rate == 125_000:
        # the thesis' 1 ms cells (AT-8): a DLC 8 cycle frame alone does not fit (1080 us); the
        # trace's DLC 5 broadcast fits (840 us) but not with one 6-byte feedback (+920 us)
        for n_axes, slots, ok in ((7, [], False), (4, [], True), (4, [(4, 2, 6)], False)):
            for i in range(tb.n_slots):
                await tb.slot_cfg(i, 0, 0, 0, valid=False)
            await tb.configure(n_axes=n_axes, sender=True, slots=slots)
            await FallingEdge(dut.clk_i)
            dut.period_us_i.value = 1000
            await tb.idle(30)
            assert int(dut.feasible_o.value) == int(ok), (n_axes, slots)


def engine_layouts() -> list[tuple[int, bool, int]]:
    """(fc, SENDER bit, N_AXES) for every layout plus the CFG_ERR neighbours: fc 001 with
    sender N 0..8, without N 1..9, fc 100 N 1..5 (SENDER set on odd N: the engine ignores it
    for fc 100)."""
    out = [(oc.FC_BCAST_8X1, True, n) for n in range(0, 9)]
    out += [(oc.FC_BCAST_8X1, False, n) for n in range(1, 10)]
    out += [(oc.FC_BCAST_4X2, n % 2 == 1, n) for n in range(1, 6)]
    return out


def python_feasibility(rate: int, fc: int, snd: bool, n_axes: int, sync: bool,
                       fb_dlcs: list[int], period_us: int):
    """The Python reference check for an engine configuration; None where the engine must
    report CFG_ERR (no broadcast layout for N_AXES)."""
    try:
        dlc = broadcast_dlc(n_axes, fc, snd)
    except ValueError:
        return None
    return check_feasibility(rate, dlc, period_us * PS_PER_US, sync=sync, feedback_dlcs=fb_dlcs)


@cocotb.test(timeout_time=60, timeout_unit="ms")
async def run_feasibility_crosscheck(dut):
    """Purpose: the RTL feasibility check and the Python reference
    (sim_models.omni.master_model.check_feasibility) are one rule.

    Verifies: for every broadcast layout (fc 001 with / without sender byte, fc 100, N_AXES
    including the CFG_ERR values), SYNC_MODE 0 / 1 and four node tables (none, the thesis'
    4 x 6-byte feedback, random valid / invalid slots with DLC 0..15, 8 x DLC 8): OMNI_BUS_BITS
    = Feasibility.bits; at the smallest period Python accepts (bits * t_bit rounded up to a
    whole us), one us less, one us more, 1 ms and a random period: INFEASIBLE and feasible_o =
    not Feasibility.ok, within 2 * N_SLOTS + 8 cycles of the change (docs/omni_engine.md);
    CFG_ERR configurations are infeasible at any period.
    """
    tb = TB(dut)
    await tb.start()
    rate, n_slots = tb.bitrate, tb.n_slots
    settle = 2 * n_slots + 8
    fcs = list(FB_FC.values())
    rand_table = [(random.randrange(1, 256), random.choice(fcs), random.randrange(16),
                   random.random() < 0.6) for _ in range(n_slots)]
    tables = [[], [(n, FB_FC[n], 6, True) for n in SLAVES], rand_table,
              [(SLAVES[i % 4], FB_FC[SLAVES[i % 4]], 8, True) for i in range(n_slots)]]
    checked = boundary = 0
    for table in tables:
        for i in range(n_slots):
            node, fc, dlc, valid = table[i] if i < len(table) else (0, 0, 0, False)
            await tb.slot_cfg(i, node, fc, dlc, valid)
        fb = [dlc for _, _, dlc, valid in table if valid]
        for fc, snd, n_axes in engine_layouts():
            for sync in (False, True):
                await tb.configure(n_axes=n_axes, bc4x2=fc == oc.FC_BCAST_4X2, sender=snd,
                                   sync_mode=sync)
                ref = python_feasibility(rate, fc, snd, n_axes, sync, fb, 1000)
                if ref is None:
                    periods = [1000, 10**6]
                else:
                    limit_us = -(-ref.busy_ps // PS_PER_US)
                    periods = [limit_us - 1, limit_us, limit_us + 1, 1000,
                               random.randrange(1, 2 * limit_us)]
                for period in periods:
                    await FallingEdge(dut.clk_i)
                    dut.period_us_i.value = period
                    await tb.idle(settle)
                    exp = python_feasibility(rate, fc, snd, n_axes, sync, fb, period)
                    ok = exp is not None and exp.ok
                    where = (f"fc {fc:03b} sender {snd} N {n_axes} sync {sync} fb {fb} "
                             f"period {period} us: {exp.reason if exp else 'CFG_ERR'}")
                    assert int(dut.feasible_o.value) == int(ok), where
                    assert await tb.field("OMNI_STATUS", "INFEASIBLE") == int(not ok), where
                    assert await tb.field("OMNI_STATUS", "CFG_ERR") == int(exp is None), where
                    if exp is not None:
                        assert await tb.field("OMNI_BUS_BITS", "BITS") == exp.bits, where
                        # exact boundary: bits * t_bit <= T_s
                        assert exp.ok == (exp.bits * 10**6 <= period * rate), where
                    checked += 1
                if ref is not None:
                    # both sides of the boundary are among the periods checked
                    assert python_feasibility(rate, fc, snd, n_axes, sync, fb,
                                              limit_us).ok
                    assert not python_feasibility(rate, fc, snd, n_axes, sync, fb,
                                                  limit_us - 1).ok
                    boundary += 1
    dut._log.info("feasibility cross-check at %d bit/s: %d (configuration, period) cells, "
                  "%d boundaries", rate, checked, boundary)


@cocotb.test(timeout_time=30, timeout_unit="ms")
async def run_period_change_wraps(dut):
    """Purpose: the cycle-instant wrap of k mod K and k mod M (compared with K - 1 / M - 1
    registered at the host write) at the edges: K or M lowered below the current count, K = 0
    acting as 1, M = 0 (no query).

    Verifies: SYNC_MODE 1, K = 5 for cycles 0..2, then K = 2: cycle 3 is a broadcast (count 3),
    the count wraps at that cycle instant (3 >= K - 1), so cycles 4, 6 are SYNC cycles and 5, 7
    not (a wrap on equality would count on to 65535 and miss them); K = 0: every cycle a SYNC.
    Queries: M = 4 for cycles 0..1 (query at 0), then M = 2: no query at cycle 2 (count 2),
    wrap, queries at 3 and 5; M = 0: no query.
    """
    tb = TB(dut)
    await tb.start(enable=False)
    await tb.configure(n_axes=1, sender=False, sync_mode=True, k=5, m=4, qwin=1)
    await tb.idle(2)
    dut.enable_i.value = 1
    await tb.idle(2)

    async def run_cycle() -> tuple[bool, bool]:
        start = len(tb.tx_log)
        msg = await tb.cycle(gap=60)
        queried = any(frame_key(r.msg) == frame_key(oc.node_query_frame())
                      for r in tb.tx_log[start:])
        return oc.is_omni_sync(msg), queried

    got = [await run_cycle() for _ in range(2)]
    await tb.write("OMNI_POLL", 2)
    got.append(await run_cycle())
    await tb.write("OMNI_SYNC_K", 2)
    got += [await run_cycle() for _ in range(5)]
    syncs = [g[0] for g in got]
    polls = [g[1] for g in got]
    assert syncs == [True, False, False, False, True, False, True, False], syncs
    assert polls == [True, False, False, True, False, True, False, True], polls
    await tb.write("OMNI_SYNC_K", 0)
    await tb.write("OMNI_POLL", 0)
    got = [await run_cycle() for _ in range(3)]
    assert [g[0] for g in got] == [True] * 3, got
    # the last cycle with M = 2 counted 1 -> the first with M = 0 wraps; M = 0 never polls
    assert [g[1] for g in got] == [False] * 3, got


async def read_every_cycle(tb: TB, name: str, cycles: int) -> list[int]:
    """The register read with the address on reg_addr_i in each of ``cycles`` cycles."""
    dut = tb.dut
    vals = []
    for _ in range(cycles):
        await FallingEdge(dut.clk_i)
        dut.reg_addr_i.value = off(name)
        await RisingEdge(dut.clk_i)
        await ReadOnly()
        vals.append(int(dut.reg_rdata_o.value))
    return vals


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_counter_read_lag(dut):
    """Purpose: the counters in the counter bank keep every event and show it within the
    documented read lag (CNT_LAG cycles); a clear reads 0 from the next cycle; a slot's
    MISSED shows within slot_lag cycles.

    Verifies: per unexpected frame (counted at the edge after rx_done_o's), reads in every
    cycle: never decreasing, the new count at the latest CNT_LAG cycles after the counting edge
    and exactly the number of frames; 8 missed slots in one cycle instant count 8 at once
    (amount 8 of the 4-bit amount); OMNI_CTRL.CLR_COUNTERS: 0 in the read of the next cycle.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, slots=[(0x10 + s, 2, 2) for s in range(tb.n_slots)])
    last = 0
    for n in range(1, 6):
        await tb.rx(oc.omni_sync_frame())
        vals = await read_every_cycle(tb, "OMNI_CNT_UNEXPECTED", CNT_LAG + 2)
        assert all(a <= b for a, b in zip(vals, vals[1:])), vals
        assert vals[0] >= last and vals[CNT_LAG - 1] == n and vals[-1] == n, (n, vals)
        last = n
    # cycle 0 not checked, cycle 1: every slot missed at the second cycle_i; the per-slot
    # MISSED of the last slot (selected) from the closing edge on: 0 until it shows, then 1,
    # at the latest slot_lag cycles after the closing edge
    lag = slot_lag(tb.n_slots)
    await tb.write("OMNI_SEL", tb.n_slots - 1)
    await tb.cycle()
    await tb.take()
    await tb.fire()
    vals = [R.get_field("OMNI_SLOT_ERR", "MISSED", v)
            for v in await read_every_cycle(tb, "OMNI_SLOT_ERR", lag + 2)]
    assert vals[lag - 1:] == [1] * 3 and set(vals) == {0, 1}, vals
    assert vals == sorted(vals), vals
    vals = await read_every_cycle(tb, "OMNI_CNT_MISSED", CNT_LAG + 2)
    assert vals[-1] == tb.n_slots, vals
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_CLR_COUNTERS)
    # the slot counters read 0 from the second read after the clear (their valid flags are
    # registered with the host copy's read)
    assert (await read_every_cycle(tb, "OMNI_SLOT_ERR", 3))[1:] == [0, 0]
    vals = await read_every_cycle(tb, "OMNI_CNT_MISSED", CNT_LAG + 2)
    assert vals == [0] * (CNT_LAG + 2), vals
    assert (await read_every_cycle(tb, "OMNI_CNT_UNEXPECTED", 1)) == [0]


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_slot_counters_sweep_and_match(dut):
    """Purpose: the slot counters share one RAM word per slot between the match cycle (SEQ,
    LEN_ERR) and the MISSED sweep; neither write may lose or mix up the other's update.

    Verifies: slave 1 sends a frame of the wrong length in every cycle (so its MISSED is
    pending in every cycle), slave 2 a good one every third cycle, slave 3 every other cycle,
    slave 4 in every cycle; slave 1's frame comes 0 .. 4 * N_SLOTS + 3 cycles after each
    cycle_i, so its hand-over and match cycle fall on every phase of the sweep, including the
    sweep's write of slot 1. Per slot: MISSED = checked cycles without a good frame (all
    different), SEQ = good frames, LEN_ERR = wrong-length frames; OMNI_CNT_MISSED = the sum.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, slots=PLATFORM_SLOTS)
    await tb.cycle()  # the first cycle_i is not checked
    offsets = range(4 * tb.n_slots + 4)
    good = {k: 0 for k in range(4)}
    wrong = {k: 0 for k in range(4)}
    for n, off_cycles in enumerate(offsets):
        await tb.take()
        await tb.fire()
        await ClockCycles(dut.clk_i, off_cycles, rising=False)
        plan = {0: "wrong", 1: "good" if n % 3 == 0 else None, 2: "good" if n % 2 else None,
                3: "good"}
        for k, kind in plan.items():
            if kind is None:
                continue
            await tb.rx(feedback(SLAVES[k], n, dlc=4 if kind == "wrong" else 6))
            (good if kind == "good" else wrong)[k] += 1
    await tb.take()
    await tb.fire()
    checked = len(offsets) + 1
    missed = {k: checked - good[k] for k in range(4)}
    assert len(set(missed.values())) == 4, missed
    for k in range(4):
        await tb.write("OMNI_SEL", k)
        word = await tb.read("OMNI_SLOT_ERR")
        err = {f: R.get_field("OMNI_SLOT_ERR", f, word) for f in ("MISSED", "LEN_ERR")}
        assert err == {"MISSED": missed[k], "LEN_ERR": wrong[k]}, (k, err, missed, wrong)
        info = await tb.read("OMNI_FB_INFO")
        assert R.get_field("OMNI_FB_INFO", "SEQ", info) == good[k], (k, good)
    assert await tb.read("OMNI_CNT_MISSED") == sum(missed.values())


@cocotb.test(timeout_time=20, timeout_unit="ms")
async def run_slot_counters_clear_during_sweep(dut):
    """Purpose: CLR_COUNTERS while the MISSED sweep is adding a cycle's misses leaves every
    slot counter at 0 (the visit in flight must not write the old count back).

    Verifies: all four slots miss every cycle; 120 times CLR_COUNTERS 0 .. 2 * N_SLOTS + 4
    cycles after a cycle_i, after a random pause (so the clear meets every phase of the
    sweep, including the read of the selected slot): MISSED of that slot reads 0 slot_lag
    cycles later, and 1 after the next cycle_i (fails if a clear in the read cycle of a visit
    does not restart it).
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, slots=PLATFORM_SLOTS)
    await tb.write("OMNI_SEL", 3)
    await tb.cycle()  # the first cycle_i is not checked
    rng = random.Random(7)
    for n in range(120):
        # a random pause moves the sweep's position against cycle_i
        await ClockCycles(dut.clk_i, rng.randrange(2 * tb.n_slots), rising=False)
        await tb.take()
        await tb.fire()
        off_cycles = rng.randrange(2 * tb.n_slots + 5)
        await ClockCycles(dut.clk_i, off_cycles, rising=False)
        await tb.write("OMNI_CTRL", R.OMNI_CTRL_CLR_COUNTERS)
        assert await tb.field("OMNI_SLOT_ERR", "MISSED") == 0, (n, off_cycles)
    await tb.take()
    await tb.fire()
    assert await tb.field("OMNI_SLOT_ERR", "MISSED") == 1


@cocotb.test(timeout_time=10, timeout_unit="ms")
async def run_disabled_idle(dut):
    """Purpose: enable_i = 0: no frames, received frames only answered, counted nowhere.

    Verifies: NMT / PARAM_SEND refused (counted), no tx_req_o, cycle_i ignored (OMNI_CYCLE
    0), a query, a feedback and a stray frame get rx_done_o without reply / unexpected and
    change no counter or flag.
    """
    tb = TB(dut)
    await tb.start(enable=False)
    await tb.configure(n_axes=1, m=1, slots=PLATFORM_SLOTS)
    await tb.write("OMNI_NMT", 1)
    await tb.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)
    for _ in range(3):
        await tb.cycle(gap=6)
    for msg in (oc.node_query_frame(), feedback(0x04, 1), make_message(0x555, b"\x01")):
        _, _, reply, unexp = await tb.rx(msg)
        assert not reply and not unexp
    await tb.idle(20)
    assert tb.tx_log == [] and dut.tx_req_o.value == 0
    assert await tb.read("OMNI_CYCLE") == 0
    assert await tb.read("OMNI_FB_NEW") == 0
    for name in ("FB_RX", "UNEXPECTED", "TX", "MISSED", "PARAM_RX"):
        assert await tb.read(f"OMNI_CNT_{name}") == 0, name
    assert await tb.read("OMNI_CNT_REFUSED") == 2
    assert await tb.field("OMNI_STATUS", "ENABLED") == 0


@cocotb.test(timeout_time=10, timeout_unit="ms", expect_fail=True)
async def run_broadcast_checker_can_fail(dut):
    """Purpose: prove the frame checker fails on a wrong expectation (expect_fail).

    Verifies: comparing a taken broadcast with the codec frame of the set-points with axes 1
    and 2 swapped fails.
    """
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=2, sender=True)
    await tb.set_points([1, 2])
    got = await tb.take()
    assert frame_key(got) == frame_key(oc.broadcast_frame(oc.FC_BCAST_8X1, MASTER, [2, 1]))


@cocotb.test(timeout_time=10, timeout_unit="ms", expect_fail=True)
async def run_window_checker_can_fail(dut):
    """Purpose: prove the query-window check fails when a reply comes one edge too late
    (expect_fail): ALIVE would have to show slot 0."""
    tb = TB(dut)
    await tb.start()
    await tb.configure(n_axes=1, m=1, qwin=2, slots=PLATFORM_SLOTS[:1])
    await tb.take()
    await tb.fire()
    await tb.idle(60)
    await tb.rx(oc.query_reply_frame(SLAVES[0]))
    assert await tb.read("OMNI_ALIVE") == 1


@pytest.mark.parametrize("bitrate", [1_000_000, 125_000])
def test_omni_engine(request, bitrate):
    tests = None if bitrate == 1_000_000 else ["run_feasibility", "run_feasibility_crosscheck"]
    run_cocotb(toplevel="omni_engine", module="tb.test_omni_engine", name=request.node.name,
               parameters={"N_SLOTS": 8, "BITRATE_BPS": bitrate, "MASTER_ID_DEFAULT": 2},
               testcase=tests)
