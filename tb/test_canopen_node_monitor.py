"""Bench of ``canopen_node_monitor``: error control (heartbeat consumer, node guarding), boot-up
with automatic NMT start, per-node NMT state and the EMCY FIFO, against CiA 301 reference slaves.

Environment (all Python, see ``sim_models/``): four :class:`CanopenSlave` reference slaves
(nodes 1..4, clocks at 0/+100/-100/+50 ppm) on a timing-accurate 1 Mbit/s CAN bus. The bench
plays the master's FSM: every frame the master node (a ``QueueNode``) receives is handed to the
DUT with ``rx_valid_i`` (St7) and the bench waits for ``rx_done_o``; frames the DUT requests are
taken with ``tx_ack_i`` (St10) and sent on the bus by the master node. ``tick_ms_i`` and
``time_ms_i`` come from the bench, exactly every ms of simulated time.

Timing checks are exact: a loss must be reported at the (T+1)-th ms tick after the DUT took
the node's last message (T = consumer time, or guard time x life time factor), which is more
than T ms and at most T ms + 1 ms + 2 clock cycles after that message was handed over.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass

import can
import cocotb
import pytest
from cocotb.triggers import (
    ClockCycles,
    Event,
    FallingEdge,
    First,
    ReadOnly,
    RisingEdge,
    Timer,
    ValueChange,
)

from sim_models.can_bus import CanBus, QueueNode
from sim_models.canopen_slave import CanopenSlave, NmtState, build_slaves, make_message
from sim_models.sim_time import PS_PER_MS, Scheduler
from tb.tblib.bench_nodes import StrobeMonitor
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.host_driver import NMT_RESET_NODE, NMT_START
from tb.tblib.model_clock import ModelClock, sim_time_ps
from tb.tblib.runner import param, run_cocotb

CLK_HZ = int(os.environ.get("TB_CLK_HZ", "10000000"))
BITRATE = 1_000_000
NODES = (1, 2, 3, 4)
PPM = (0, 100, -100, 50)
BOOT_MS = 2  # slaves send their boot-up this long after the bench starts them

MODE_OFF, MODE_HB, MODE_GUARD = 0, 1, 2


@dataclass
class SlotCfg:
    node: int = 0
    mode: int = MODE_OFF
    time_ms: int = 0
    life: int = 0
    autostart: bool = False
    reset_on_loss: bool = False


@dataclass
class RxRecord:
    """One frame handed to the DUT: sampling edge, frame, time_ms_i then, DUT answer."""

    t_ps: int
    msg: can.Message
    time_ms: int
    cycles: int = 0
    reply: bool = False
    unexpected: bool = False
    malformed: bool = False


@dataclass
class TxRecord:
    """One frame taken from the DUT (tx_ack_i edge) and sent on the bus."""

    t_ps: int
    msg: can.Message


class MasterNode(QueueNode):
    """The master's CAN node: queues received frames for the bench FSM and wakes it."""

    def __init__(self, wake: Event) -> None:
        super().__init__("master", BITRATE)
        self.inbox: list[can.Message] = []
        self._wake_fsm = wake

    def on_rx(self, msg: can.Message, t_ps: int) -> None:
        super().on_rx(msg, t_ps)
        self.inbox.append(msg)
        self._wake_fsm.set()


class TB:
    """DUT + bench FSM + ms time base + CAN bus with the reference slaves."""

    def __init__(self, dut, *, slaves: bool = True) -> None:
        self.dut = dut
        self.n = param("MAX_NODES")
        self.depth = param("EMCY_DEPTH")
        self.period_ps = start_clock(dut.clk_i, CLK_HZ)
        self.sched = Scheduler()
        self.sched.run_until(sim_time_ps())
        self.clock = ModelClock(self.sched)
        self.bus = CanBus(self.sched, BITRATE)
        self._wake = Event()
        self.master = MasterNode(self._wake)
        self.bus.attach(self.master)
        self.want_slaves = slaves
        self.slaves: dict[int, CanopenSlave] = {}
        # slot of each node: 1..4 -> 0..3, spread over the slots when there are more
        step = 2 if self.n >= 8 else 1
        self.slot_of = {node: (i * step + step - 1) for i, node in enumerate(NODES)}
        self.cfg = [SlotCfg() for _ in range(self.n)]
        self.rx_log: list[RxRecord] = []
        self.tx_log: list[TxRecord] = []
        self.tick_edges: list[int] = []  # rising edge sampling each tick_ms_i
        self.count_changes: list[int] = []  # emcy_count_o went up
        self.time_ms = 0
        self.tx_enabled = True
        self.strobes = StrobeMonitor(dut, ["ev_lost", "ev_toggle", "ev_bootup", "ev_emcy"])
        self.events = self.strobes.events
        for sig in (dut.tick_ms_i, dut.time_ms_i, dut.st_clear_i, dut.emcy_clear_i,
                    dut.emcy_pop_i, dut.tx_ack_i, dut.rx_valid_i, dut.rx_id_i, dut.rx_rtr_i,
                    dut.rx_dlc_i, dut.rx_data_i, dut.st_rd_slot_i, dut.st_rd_nmt_i,
                    dut.cfg_tl_we_i,
                    dut.cfg_tl_slot_i, dut.cfg_tl_time_i, dut.cfg_tl_life_i, dut.cfg_tl_ok_i):
            sig.value = 0
        #: (time, life) of each slot as written into the DUT's time RAM since reset (the host
        #: block's NODE_TIME write port: one slot per cycle); None = not written (reads 0)
        self.tl_written: list[tuple[int, int] | None] = [None] * self.n
        self._tl_wake = Event()
        self.apply_cfg()

    # ------------------------------------------------------------------ set-up
    async def start(self) -> None:
        """Reset the DUT, start the time base and the FSM, power the slaves on."""
        # the time RAM is written while reset is held (it has no reset; cfg_tl_ok_i is driven
        # here), so the first configuration is in place at reset like the other cfg inputs
        self.dut.rst_n_i.value = 0
        cocotb.start_soon(self._tl_writer())
        await ClockCycles(self.dut.clk_i, self.n + 2)
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)
        cocotb.start_soon(self._ms_timebase())
        cocotb.start_soon(self._fsm())
        cocotb.start_soon(self._count_monitor())
        if self.want_slaves:
            self.clock.sync()
            for s in build_slaves(self.sched, self.bus, list(NODES), ppm=list(PPM),
                                  boot_time_ps=BOOT_MS * PS_PER_MS):
                self.slaves[s.node_id] = s

    def slot(self, node: int, **kw) -> int:
        """Configure the slot of ``node`` (attributes of SlotCfg); returns the slot index."""
        k = self.slot_of[node]
        c = self.cfg[k]
        c.node = node
        for key, v in kw.items():
            setattr(c, key, v)
        return k

    def apply_cfg(self) -> None:
        n, d = self.n, self.dut
        vals = {"node": 0, "mode": 0, "auto": 0, "rol": 0}
        for k, c in enumerate(self.cfg):
            vals["node"] |= c.node << (7 * k)
            vals["mode"] |= c.mode << (2 * k)
            vals["auto"] |= int(c.autostart) << k
            vals["rol"] |= int(c.reset_on_loss) << k
        assert vals["node"] < 1 << (7 * n)
        d.cfg_node_i.value = vals["node"]
        d.cfg_mode_i.value = vals["mode"]
        d.cfg_autostart_i.value = vals["auto"]
        d.cfg_reset_on_loss_i.value = vals["rol"]
        self._tl_wake.set()  # time and life factor: through the write port

    async def _tl_writer(self) -> None:
        """The host block's NODE_TIME write port: every slot whose (time, life) differs from
        what the DUT holds is written, one slot per cycle (strobe, slot, word), and its bit of
        cfg_tl_ok_i is set with the write's edge, as canopen_host_regs does."""
        d = self.dut
        ok = 0
        while True:
            await FallingEdge(d.clk_i)
            d.cfg_tl_we_i.value = 0
            d.cfg_tl_ok_i.value = ok
            todo = [k for k, c in enumerate(self.cfg)
                    if self.tl_written[k] != (c.time_ms, c.life)
                    and not (self.tl_written[k] is None and (c.time_ms, c.life) == (0, 0))]
            if not todo:
                self._tl_wake.clear()
                await self._tl_wake.wait()
                continue
            k = todo[0]
            c = self.cfg[k]
            d.cfg_tl_we_i.value = 1
            d.cfg_tl_slot_i.value = k
            d.cfg_tl_time_i.value = c.time_ms
            d.cfg_tl_life_i.value = c.life
            self.tl_written[k] = (c.time_ms, c.life)
            ok |= 1 << k

    def model(self, fn, *args, **kw):
        """Call a model method at the current simulated time."""
        self.clock.sync()
        return fn(*args, **kw)

    # ------------------------------------------------------------------ time base
    async def _ms_timebase(self) -> None:
        dut = self.dut
        await FallingEdge(dut.clk_i)
        while True:
            self.time_ms += 1
            dut.time_ms_i.value = self.time_ms
            dut.tick_ms_i.value = 1
            self.tick_edges.append(sim_time_ps() + self.period_ps // 2)
            await Timer(self.period_ps, "ps")
            dut.tick_ms_i.value = 0
            await Timer(PS_PER_MS - self.period_ps, "ps")

    # ------------------------------------------------------------------ the FSM
    async def _fsm(self) -> None:
        """St7 first (every received frame), then St10 (a requested frame), one at a time;
        inputs change at falling edges only."""
        dut = self.dut
        while True:
            await FallingEdge(dut.clk_i)
            if self.master.inbox:
                await self._deliver(self.master.inbox.pop(0))
            elif self.tx_enabled and dut.tx_req_o.value == 1:
                await self._take_tx()
            else:
                self._wake.clear()
                await First(self._wake.wait(), RisingEdge(dut.tx_req_o))

    def poke(self) -> None:
        self._wake.set()

    def inject(self, msg: can.Message) -> None:
        """Hand ``msg`` to the DUT as if the master node had received it now."""
        self.master.inbox.append(msg)
        self._wake.set()

    async def _deliver(self, msg: can.Message) -> RxRecord:
        """Hand one frame to the DUT (called at a falling edge) and wait for rx_done_o."""
        dut = self.dut
        dut.rx_id_i.value = msg.arbitration_id
        dut.rx_rtr_i.value = int(msg.is_remote_frame)
        dut.rx_dlc_i.value = msg.dlc
        data = b"" if msg.is_remote_frame else bytes(msg.data)
        dut.rx_data_i.value = int.from_bytes(data.ljust(8, b"\0"), "little")
        dut.rx_valid_i.value = 1
        await RisingEdge(dut.clk_i)
        rec = RxRecord(sim_time_ps(), msg, int(dut.time_ms_i.value))
        dut.rx_valid_i.value = 0
        limit = self.n + 4
        while True:
            await RisingEdge(dut.clk_i)
            rec.cycles += 1
            await ReadOnly()
            if dut.rx_done_o.value == 1:
                break
            assert rec.cycles < limit, f"no rx_done_o within {limit} cycles for {msg}"
        rec.reply = dut.rx_reply_o.value == 1
        rec.unexpected = dut.rx_unexpected_o.value == 1
        rec.malformed = dut.rx_malformed_o.value == 1
        if rec.reply:
            assert dut.tx_req_o.value == 1, "rx_reply_o without a frame on tx_req_o"
        self.rx_log.append(rec)
        return rec

    async def _take_tx(self) -> None:
        """Take the presented frame (called at a falling edge) and send it on the bus."""
        dut = self.dut
        rtr = dut.tx_rtr_o.value == 1
        dlc = int(dut.tx_dlc_o.value)
        data = b"" if rtr else int(dut.tx_data_o.value).to_bytes(8, "little")[:dlc]
        msg = make_message(int(dut.tx_id_o.value), data, remote=rtr, dlc=dlc)
        dut.tx_ack_i.value = 1
        await RisingEdge(dut.clk_i)
        dut.tx_ack_i.value = 0
        self.tx_log.append(TxRecord(sim_time_ps(), msg))
        self.clock.sync()
        self.master.send(msg)

    # ------------------------------------------------------------------ monitors
    async def _count_monitor(self) -> None:
        """Times at which emcy_count_o went up."""
        sig, last = self.dut.emcy_count_o, 0
        while True:
            await ValueChange(sig)
            v = int(sig.value) if sig.value.is_resolvable else 0
            if v > last:
                self.count_changes.append(sim_time_ps())
            last = v

    def ev(self, name: str, slot: int) -> list[int]:
        """Times of the strobes of ``name`` for ``slot``."""
        return [t for t, v in self.events[name] if v >> slot & 1]

    def bit(self, sig: str, slot: int) -> int:
        return int(getattr(self.dut, sig).value) >> slot & 1

    async def st_read(self, slot: int, field: str) -> int:
        """A read of the status RAM port (``field`` "nmt" or "last") as the host registers do:
        slot on ``st_rd_slot_i``, the word on ``st_rd_nmt_i``, the registered data one cycle
        later. Ends at a falling edge."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.st_rd_slot_i.value = slot
        dut.st_rd_nmt_i.value = int(field == "nmt")
        await RisingEdge(dut.clk_i)
        await FallingEdge(dut.clk_i)
        return int(dut.st_rd_data_o.value)

    async def st_watch(self, slot: int, out: list[int]) -> None:
        """The status RAM port held on the NMT state of ``slot``: every cycle's read data into
        ``out`` (a word that is not 0/1 in every bit fails at once)."""
        dut = self.dut
        await FallingEdge(dut.clk_i)
        dut.st_rd_slot_i.value = slot
        dut.st_rd_nmt_i.value = 1
        await RisingEdge(dut.clk_i)
        while True:
            await FallingEdge(dut.clk_i)
            v = dut.st_rd_data_o.value
            assert v.is_resolvable, f"st_rd_data_o = {v} reading slot {slot}'s NMT state"
            out.append(int(v))

    # ------------------------------------------------------------------ actions
    async def wait_ms(self, ms: float) -> None:
        await Timer(round(ms * PS_PER_MS), "ps")

    async def pulse(self, sig, value: int = 1) -> None:
        await FallingEdge(self.dut.clk_i)
        sig.value = value
        await RisingEdge(self.dut.clk_i)
        sig.value = 0

    def rx_from(self, node: int, *, cob: int = 0x700) -> list[RxRecord]:
        return [r for r in self.rx_log if r.msg.arbitration_id == cob + node
                and not r.msg.is_remote_frame]

    def tx_frames(self, can_id: int, *, rtr: bool | None = None) -> list[TxRecord]:
        return [t for t in self.tx_log if t.msg.arbitration_id == can_id
                and (rtr is None or t.msg.is_remote_frame == rtr)]

    def nmt_sent(self, cs: int, node: int) -> list[TxRecord]:
        return [t for t in self.tx_frames(0x000) if bytes(t.msg.data) == bytes([cs, node])]

    async def bring_up(self, *, hb_ms: int = 0) -> None:
        """Wait for the boot-ups and the NMT starts (nodes in autostart slots must be
        operational); then set every slave's heartbeat producer time (1017h) to ``hb_ms``."""
        await self.wait_ms(BOOT_MS + 1.5)
        for node, s in self.slaves.items():
            if self.cfg[self.slot_of[node]].autostart:
                assert s.nmt_state is NmtState.OPERATIONAL, f"node {node} is {s.nmt_state}"
            if hb_ms:
                self.model(s.write, 0x1017, 0, hb_ms)

    # ------------------------------------------------------------------ checkers
    def expected_loss_edge(self, t_rx_ps: int, timeout_ms: int) -> int:
        """The DUT takes a message 2 cycles after the edge sampling rx_valid_i; the loss is
        due at the (timeout+1)-th tick sampled strictly after that."""
        t_apply = t_rx_ps + 2 * self.period_ps
        later = [t for t in self.tick_edges if t > t_apply]
        assert len(later) > timeout_ms, "simulation did not run long enough"
        return later[timeout_ms]

    def check_loss(self, slot: int, node: int, timeout_ms: int, *, after_ps: int = 0,
                   count: int = 1) -> int:
        """Exactly ``count`` losses of ``slot`` after ``after_ps``; the last one exactly at the
        expected tick after the last message of ``node`` before it. Returns its time."""
        losses = [t for t in self.ev("ev_lost", slot) if t > after_ps]
        assert len(losses) == count, f"slot {slot}: {len(losses)} losses, expected {count}"
        t_lost = losses[-1]
        last = [r for r in self.rx_from(node) if r.t_ps < t_lost and not r.unexpected]
        assert last, "no message before the loss"
        t_rx = last[-1].t_ps
        t_exp = self.expected_loss_edge(t_rx, timeout_ms)
        dt = t_lost - t_rx
        assert t_lost == t_exp, (
            f"slot {slot}: loss {dt / PS_PER_MS:.6f} ms after the last message, expected "
            f"{(t_exp - t_rx) / PS_PER_MS:.6f} ms (timeout {timeout_ms} ms)")
        assert timeout_ms * PS_PER_MS < dt <= (timeout_ms + 1) * PS_PER_MS + 2 * self.period_ps
        return t_lost

    def check_rx_latency(self) -> None:
        assert self.rx_log, "no frame was handed over"
        worst = max(r.cycles for r in self.rx_log)
        assert worst <= self.n + 4
        assert all(r.cycles == 2 for r in self.rx_log if not r.reply)


# ============================================================================== tests
@cocotb.test(timeout_time=60, timeout_unit="ms")
async def run_bootup_autostart(dut):
    """Purpose: boot-up handling and automatic NMT start.

    Verifies: before any frame every slot reads 0 through the status RAM port (no reset of
    the RAM); each node's boot-up sets st_bootup, st_nmt = 00h and one ev_bootup in its slot;
    slots with autostart answer rx_reply_o (with tx_req_o already up) and the NMT start
    [01h, node] goes on the bus, so those slaves become operational, the slot without autostart
    stays pre-operational; heartbeats then report 05h / 7Fh and the reception time in st_last;
    st_clear clears the sticky bit; rx_done_o comes 2 cycles after rx_valid_i (5 with a reply).
    The port held on one slot's NMT state in every cycle (the state word is written one cycle
    after the time word and forwarded to a read at its write edge) reads only 00h through the
    boot-up and then 00h before 05h, never an undefined word.
    """
    tb = TB(dut)
    for node in NODES:
        tb.slot(node, mode=MODE_HB, time_ms=20, autostart=node != 4)
    tb.apply_cfg()
    # the status RAM has no reset: a slot not heard since reset reads 0 (never a stale word)
    for k in range(tb.n):
        assert await tb.st_read(k, "nmt") == 0 and await tb.st_read(k, "last") == 0
    watched: list[int] = []
    watch = cocotb.start_soon(tb.st_watch(tb.slot_of[1], watched))
    await tb.start()
    await tb.wait_ms(BOOT_MS + 1.5)
    watch.cancel()
    assert watched and set(watched) == {0}
    for node in NODES:
        k = tb.slot_of[node]
        assert len(tb.ev("ev_bootup", k)) == 1
        assert tb.bit("st_bootup_o", k) == 1 and await tb.st_read(k, "nmt") == 0
        boots = tb.rx_from(node)
        assert len(boots) == 1 and bytes(boots[0].msg.data) == b"\x00"
        assert boots[0].reply == (node != 4)
        assert len(tb.nmt_sent(NMT_START, node)) == (node != 4)
    assert tb.slaves[4].nmt_state is NmtState.PRE_OPERATIONAL
    for node in (1, 2, 3):
        assert tb.slaves[node].nmt_state is NmtState.OPERATIONAL
    for s in tb.slaves.values():
        tb.model(s.write, 0x1017, 0, 5)
    watched = []
    watch = cocotb.start_soon(tb.st_watch(tb.slot_of[1], watched))
    await tb.wait_ms(12)
    watch.cancel()
    first = watched.index(0x05)
    assert set(watched[:first]) == {0} and set(watched[first:]) == {0x05}, sorted(set(watched))
    for node in NODES:
        k = tb.slot_of[node]
        last = tb.rx_from(node)[-1]
        assert await tb.st_read(k, "nmt") == (0x7F if node == 4 else 0x05)
        assert await tb.st_read(k, "last") == last.time_ms
        assert tb.bit("st_alive_o", k) == 1 and tb.bit("st_lost_o", k) == 0
    await tb.pulse(dut.st_clear_i, 1 << tb.slot_of[2])
    await ReadOnly()
    assert tb.bit("st_bootup_o", tb.slot_of[2]) == 0 and tb.bit("st_bootup_o", tb.slot_of[1])
    assert not any(r.unexpected or r.malformed for r in tb.rx_log)
    tb.check_rx_latency()
    assert max(r.cycles for r in tb.rx_log) == 5


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_heartbeat_loss_and_rearm(dut):
    """Purpose: heartbeat consumer timing, re-arm, reset-on-loss, consumer time 0.

    Verifies: a powered-off producer is reported lost exactly at the (T+1)-th tick after its
    last heartbeat (T < dt <= T + 1 ms), once, with st_alive = 0 and st_lost sticky, and no
    other slot is affected; a node with consumer time 0 is never lost; after a power cycle the
    boot-up and the new heartbeats make it alive again while st_lost stays until st_clear, and
    a second loss is reported again; with reset-on-loss the NMT reset-node [81h, node] is sent,
    the slave reboots, is started again (autostart) and reports its boot-up.
    """
    tb = TB(dut)
    hb, t_cons = 5, 12
    for node in NODES:
        tb.slot(node, mode=MODE_HB, time_ms=0 if node == 4 else t_cons, autostart=True,
                reset_on_loss=node == 3)
    tb.apply_cfg()
    await tb.start()
    await tb.bring_up(hb_ms=hb)
    await tb.wait_ms(3 * hb)
    k2, k3, k4 = tb.slot_of[2], tb.slot_of[3], tb.slot_of[4]
    assert all(tb.bit("st_alive_o", tb.slot_of[n]) for n in NODES)
    t0 = sim_time_ps()
    # node 2 disappears; node 3 stops its heartbeat; node 4 (T = 0) too
    await tb.wait_ms(random.uniform(0, 1))
    tb.model(tb.slaves[2].power_off)
    await tb.wait_ms(random.uniform(0, 1))
    tb.model(tb.slaves[3].mute_heartbeat)
    tb.model(tb.slaves[4].mute_heartbeat)
    await tb.wait_ms(t_cons + 2 * hb)
    t_lost = tb.check_loss(k2, 2, t_cons, after_ps=t0)
    assert tb.bit("st_alive_o", k2) == 0 and tb.bit("st_lost_o", k2) == 1
    assert tb.ev("ev_lost", tb.slot_of[1]) == [] and tb.ev("ev_lost", k4) == []
    assert tb.bit("st_alive_o", tb.slot_of[1]) == 1 and tb.bit("st_alive_o", k4) == 1
    # reset-on-loss: node 3 lost, reset, boots, is started again
    tb.check_loss(k3, 3, t_cons, after_ps=t0)
    resets = tb.nmt_sent(NMT_RESET_NODE, 3)
    assert len(resets) == 1 and resets[0].t_ps > tb.ev("ev_lost", k3)[0]
    await tb.wait_ms(BOOT_MS + 1)
    assert len(tb.ev("ev_bootup", k3)) == 2 and len(tb.nmt_sent(NMT_START, 3)) == 2
    assert tb.slaves[3].nmt_state is NmtState.OPERATIONAL
    # node 2 comes back: boot-up, heartbeat configured again, alive, st_lost still sticky
    tb.model(tb.slaves[2].power_on)
    await tb.wait_ms(BOOT_MS + 1)
    tb.model(tb.slaves[2].write, 0x1017, 0, hb)
    await tb.wait_ms(2 * hb)
    assert tb.bit("st_alive_o", k2) == 1 and tb.bit("st_lost_o", k2) == 1
    assert len(tb.ev("ev_lost", k2)) == 1, "a loss must be reported once"
    await tb.pulse(dut.st_clear_i, 1 << k2)
    await ReadOnly()
    assert tb.bit("st_lost_o", k2) == 0
    await tb.wait_ms(random.uniform(0, 1))
    tb.model(tb.slaves[2].power_off)
    await tb.wait_ms(t_cons + 2 * hb)
    tb.check_loss(k2, 2, t_cons, after_ps=t_lost, count=1)
    assert tb.bit("st_lost_o", k2) == 1
    # node 3 booted again without a heartbeat (1017h = 0 after its reset): not supervised
    assert len(tb.ev("ev_lost", k3)) == 1 and len(tb.nmt_sent(NMT_RESET_NODE, 3)) == 1
    assert tb.ev("ev_lost", k4) == [] and tb.ev("ev_lost", tb.slot_of[1]) == []
    assert not any(r.unexpected or r.malformed for r in tb.rx_log)
    tb.check_rx_latency()


@cocotb.test(timeout_time=200, timeout_unit="ms")
async def run_guarding_toggle_and_life(dut):
    """Purpose: node guarding: RTR cadence, toggle rule, life time, recovery.

    Verifies: every slot sends an RTR on 700h + node (dlc 1) every guard time; the replies'
    toggle bits alternate from 0 after the boot-up without error; one reply repeating its
    toggle (guarding_bad_toggle) gives exactly one ev_toggle and sticky st_toggle and the check
    resynchronises; a powered-off node is lost exactly at the (G x factor + 1)-th tick after its
    last reply, polling goes on, and after its power-on boot-up (toggle restarts at 0) it is
    alive again without a toggle error; a node guarded with life time factor 0 (node 4: RTRs
    and toggle check, no life time supervision) is never reported lost while it is off.
    """
    tb = TB(dut)
    g, f = 5, 3
    for node in NODES:
        tb.slot(node, mode=MODE_GUARD, time_ms=g, life=0 if node == 4 else f, autostart=True)
    tb.apply_cfg()
    await tb.start()
    await tb.bring_up()
    await tb.wait_ms(4 * g)
    for node in NODES:
        k = tb.slot_of[node]
        assert tb.bit("st_alive_o", k) == 1 and await tb.st_read(k, "nmt") == 0x05
        rtrs = tb.tx_frames(0x700 + node, rtr=True)
        assert all(t.msg.dlc == 1 for t in rtrs)
        # one RTR every G ms: requested at a tick, taken within the same ms
        gaps = {round((b.t_ps - a.t_ps) / PS_PER_MS) for a, b in zip(rtrs, rtrs[1:])}
        assert gaps == {g}, f"node {node}: RTR gaps {gaps}"
        replies = [r for r in tb.rx_from(node) if r.msg.data[0] != 0]
        assert [r.msg.data[0] >> 7 for r in replies] == [i % 2 for i in range(len(replies))]
    assert all(tb.events[k] == [] for k in ("ev_toggle", "ev_lost"))
    # a repeated toggle bit
    tb.model(tb.slaves[2].guarding_bad_toggle)
    await tb.wait_ms(3 * g)
    k2 = tb.slot_of[2]
    assert len(tb.ev("ev_toggle", k2)) == 1 and tb.bit("st_toggle_o", k2) == 1
    assert len(tb.events["ev_toggle"]) == 1
    # node 3 disappears, and node 4 (factor 0: not supervised)
    k3, k4 = tb.slot_of[3], tb.slot_of[4]
    t0 = sim_time_ps()
    await tb.wait_ms(random.uniform(0, g))
    tb.model(tb.slaves[3].power_off)
    tb.model(tb.slaves[4].power_off)
    await tb.wait_ms(g * f + 2 * g)
    tb.check_loss(k3, 3, g * f, after_ps=t0)
    assert tb.bit("st_alive_o", k3) == 0
    n_rtr = len(tb.tx_frames(0x703, rtr=True))
    n_rtr4 = len(tb.tx_frames(0x704, rtr=True))
    await tb.wait_ms(2 * g)
    assert len(tb.tx_frames(0x703, rtr=True)) == n_rtr + 2, "polling must go on"
    assert len(tb.tx_frames(0x704, rtr=True)) == n_rtr4 + 2, "factor 0: polling goes on"
    assert tb.ev("ev_lost", k4) == [] and tb.bit("st_alive_o", k4) == 1, "factor 0: never lost"
    tb.model(tb.slaves[3].power_on)
    tb.model(tb.slaves[4].power_on)
    await tb.wait_ms(BOOT_MS + 3 * g)
    assert len(tb.ev("ev_bootup", k3)) == 2 and tb.bit("st_alive_o", k3) == 1
    assert len(tb.ev("ev_bootup", k4)) == 2
    assert tb.slaves[3].nmt_state is NmtState.OPERATIONAL
    assert len(tb.events["ev_toggle"]) == 1 and len(tb.events["ev_lost"]) == 1
    for node in (1, 2, 4):
        assert tb.bit("st_alive_o", tb.slot_of[node]) == 1
    assert not any(r.unexpected or r.malformed for r in tb.rx_log)
    tb.check_rx_latency()


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_tx_queue_round_robin(dut):
    """Purpose: requests that are due together are queued, merged, served round robin.

    Verifies: while the FSM takes nothing, tx_req_o stays up with the same frame (no hang, no
    change), the boot-ups are still processed; afterwards every slot's NMT start and one
    (merged) RTR are sent in round-robin order (within a slot start before RTR, the frame
    already presented first), none is lost, and the periodic polling then continues.
    """
    tb = TB(dut)
    g = 5
    for node in NODES:
        tb.slot(node, mode=MODE_GUARD, time_ms=g, life=40, autostart=True)
    tb.apply_cfg()
    tb.tx_enabled = False
    await tb.start()
    await tb.wait_ms(1)
    first = int(dut.tx_id_o.value)
    for _ in range(12):
        await tb.wait_ms(1)
        await ReadOnly()
        assert dut.tx_req_o.value == 1 and int(dut.tx_id_o.value) == first
        assert int(dut.tx_rtr_o.value) == 1
    assert len(tb.events["ev_bootup"]) == 4 and sum(r.reply for r in tb.rx_log) == 4
    await FallingEdge(dut.clk_i)
    tb.tx_enabled = True
    tb.poke()
    await tb.wait_ms(1)
    order = [(t.msg.arbitration_id, t.msg.is_remote_frame, bytes(t.msg.data))
             for t in tb.tx_log[:8]]
    want = [(0x701, True, b"")]
    want += [(0x000, False, bytes([NMT_START, n])) for n in (2, 3, 4, 1)]
    want += [(0x700 + n, True, b"") for n in (2, 3, 4)]
    assert order == want, order
    assert all(s.nmt_state is NmtState.OPERATIONAL for s in tb.slaves.values())
    await tb.wait_ms(3 * g)
    for node in NODES:
        assert len(tb.tx_frames(0x700 + node, rtr=True)) == 4
        assert tb.bit("st_alive_o", tb.slot_of[node]) == 1
    assert tb.events["ev_lost"] == [] and tb.events["ev_toggle"] == []
    tb.check_rx_latency()


@cocotb.test(timeout_time=100, timeout_unit="ms")
async def run_emcy_fifo(dut):
    """Purpose: EMCY consumer FIFO.

    Verifies: EMCYs from every node (also one in no slot) come out of the FIFO in bus order
    with node-ID, the 8 bytes and time_ms_i at reception, while the host pops at random
    moments or in the first cycle an entry is announced; a pop of an empty FIFO does nothing;
    with the host not popping, EMCY_DEPTH entries are kept, the later ones are dropped with
    emcy_lost set until emcy_clear, and ev_emcy counts exactly the entries taken, each in the
    cycle emcy_count_o counts it.
    """
    tb = TB(dut)
    for node in (1, 2, 3):
        tb.slot(node, autostart=True)
    tb.apply_cfg()
    await tb.start()
    await tb.wait_ms(BOOT_MS + 1.5)
    tb.model(tb.slaves[4].emcy, 0x0000, 0)  # pre-operational: allowed
    popped: list[tuple[int, bytes, int]] = []
    state = {"pop": True}

    async def popper():
        # half of the time eager: pop at the first falling edge after emcy_count_o changed,
        # i.e. in the first cycle an entry is announced
        dut_ = tb.dut
        while True:
            wait = Timer(random.randint(1, 300) * tb.period_ps, "ps")
            if random.random() < 0.5:
                await First(ValueChange(dut_.emcy_count_o), wait)
            else:
                await wait
            await FallingEdge(dut_.clk_i)
            if not state["pop"]:
                continue
            if int(dut_.emcy_count_o.value) == 0:
                dut_.emcy_pop_i.value = 1  # must be ignored
                await RisingEdge(dut_.clk_i)
                dut_.emcy_pop_i.value = 0
                continue
            popped.append((int(dut_.emcy_node_o.value),
                           int(dut_.emcy_data_o.value).to_bytes(8, "little"),
                           int(dut_.emcy_time_o.value)))
            dut_.emcy_pop_i.value = 1
            await RisingEdge(dut_.clk_i)
            dut_.emcy_pop_i.value = 0

    cocotb.start_soon(popper())
    rng = random.Random(7)
    for i in range(12):
        node = NODES[i % 4]
        msef = bytes(rng.getrandbits(8) for _ in range(5))
        tb.model(tb.slaves[node].emcy, 0x1000 + 0x111 * i, i & 0xFF, msef)
        await tb.wait_ms(rng.uniform(0, 0.3))
    await tb.wait_ms(3)
    emcys = [r for r in tb.rx_log if 0x081 <= r.msg.arbitration_id <= 0x0FF]
    assert len(emcys) == 13
    want = [(r.msg.arbitration_id - 0x80, bytes(r.msg.data), r.time_ms) for r in emcys]
    assert popped == want
    assert int(dut.emcy_count_o.value) == 0 and dut.emcy_lost_o.value == 0
    assert len(tb.events["ev_emcy"]) == 13
    assert not any(r.unexpected or r.malformed for r in emcys)
    # overflow: nobody pops
    state["pop"] = False
    await tb.wait_ms(0.1)
    n0 = len(tb.rx_log)
    for i in range(tb.depth + 3):
        tb.model(tb.slaves[NODES[i % 4]].emcy, 0x5000 + i, 0x01, bytes([i]))
    await tb.wait_ms(3)
    burst = [r for r in tb.rx_log[n0:] if 0x081 <= r.msg.arbitration_id <= 0x0FF]
    assert len(burst) == tb.depth + 3
    assert int(dut.emcy_count_o.value) == tb.depth and dut.emcy_lost_o.value == 1
    assert len(tb.events["ev_emcy"]) == 13 + tb.depth
    assert tb.count_changes[-tb.depth:] == [t for t, _ in tb.events["ev_emcy"][-tb.depth:]]
    got = []
    for _ in range(tb.depth):
        await FallingEdge(dut.clk_i)
        got.append((int(dut.emcy_node_o.value), int(dut.emcy_data_o.value).to_bytes(8, "little"),
                    int(dut.emcy_time_o.value)))
        dut.emcy_pop_i.value = 1
        await RisingEdge(dut.clk_i)
        dut.emcy_pop_i.value = 0
    await ReadOnly()
    assert got == [(r.msg.arbitration_id - 0x80, bytes(r.msg.data), r.time_ms)
                   for r in burst[:tb.depth]]
    assert int(dut.emcy_count_o.value) == 0 and dut.emcy_lost_o.value == 1
    await tb.pulse(dut.emcy_clear_i)
    await ReadOnly()
    assert dut.emcy_lost_o.value == 0
    tb.check_rx_latency()


@cocotb.test(timeout_time=40, timeout_unit="ms")
async def run_unexpected_and_malformed(dut):
    """Purpose: classification of frames the monitor does not want.

    Verifies (frames from a raw node, no slaves): SYNC 080h (any length), RTRs, other function
    codes, nodes in no slot (also their boot-up) and a guarding reply with no RTR out for it
    are flagged rx_unexpected_o; an error-control frame with DLC /= 1 and an EMCY with DLC /= 8
    rx_malformed_o; none of them changes a slot or the FIFO; a heartbeat, the answer to the
    slot's RTR and an EMCY of node 127 (in no slot) are accepted without a flag.
    """
    tb = TB(dut, slaves=False)
    tb.slot(1, mode=MODE_HB, time_ms=1000)
    tb.slot(2, mode=MODE_HB, time_ms=1000)
    tb.slot(3, mode=MODE_GUARD, time_ms=1000, life=1)
    tb.apply_cfg()
    await tb.start()
    raw = tb.bus.attach(QueueNode("raw", BITRATE))
    await tb.wait_ms(2)  # the first RTR to node 3 has gone out
    assert len(tb.tx_frames(0x703, rtr=True)) == 1
    u, m, ok = "unexpected", "malformed", "ok"
    cases = [
        (make_message(0x080, b""), u),
        (make_message(0x080, bytes(8)), u),
        (make_message(0x701, b"", remote=True, dlc=1), u),
        (make_message(0x081, b"", remote=True, dlc=8), u),
        (make_message(0x705, b"\x05"), u),
        (make_message(0x705, b"\x00"), u),
        (make_message(0x181, bytes(8)), u),
        (make_message(0x700, b"\x05"), u),
        (make_message(0x701, b"\x05\x00"), m),
        (make_message(0x701, b""), m),
        (make_message(0x082, bytes(4)), m),
        (make_message(0x082, bytes(7)), m),
        (make_message(0x701, b"\x05"), ok),
        (make_message(0x703, b"\x7f"), ok),    # answers the RTR
        (make_message(0x703, b"\x84"), u),     # nothing asked for it: ignored
        (make_message(0x0FF, bytes(range(8))), ok),
    ]
    for msg, _ in cases:
        tb.model(raw.send, msg)
    await tb.wait_ms(4)
    got = [r for r in tb.rx_log if r.msg.arbitration_id != 0x703 or not r.msg.is_remote_frame]
    assert len(got) == len(cases)
    for rec, (msg, want) in zip(got, cases):
        flags = (rec.unexpected, rec.malformed)
        exp = {u: (True, False), m: (False, True), ok: (False, False)}[want]
        assert flags == exp and not rec.reply, f"{msg}: {flags}, expected {want}"
    k1, k2, k3 = (tb.slot_of[n] for n in (1, 2, 3))
    assert tb.events["ev_bootup"] == [] and tb.events["ev_toggle"] == []
    assert await tb.st_read(k1, "nmt") == 0x05 and await tb.st_read(k2, "nmt") == 0
    assert await tb.st_read(k3, "nmt") == 0x7F and tb.bit("st_alive_o", k2) == 0
    accepted = [r for r in got if r.msg.arbitration_id == 0x703][0]
    assert await tb.st_read(k3, "last") == accepted.time_ms
    assert int(dut.emcy_count_o.value) == 1 and len(tb.events["ev_emcy"]) == 1
    assert int(dut.emcy_node_o.value) == 0x7F
    assert int(dut.emcy_data_o.value) == int.from_bytes(bytes(range(8)), "little")
    tb.check_rx_latency()


@cocotb.test(timeout_time=40, timeout_unit="ms")
async def run_frame_and_tick_same_cycle(dut):
    """Purpose: the tie between a received heartbeat and the ms tick.

    Verifies (heartbeats injected so that the DUT applies them at computed edges): a heartbeat
    applied in the cycle of a tick restarts the consumer timer and that tick is not counted;
    one applied in the cycle of the tick that would expire the timer prevents the loss; one
    applied a cycle before a tick has that tick counted. Each loss comes at the (T+1)-th tick.
    """
    tb = TB(dut, slaves=False)
    t_cons = 3
    k = tb.slot(1, mode=MODE_HB, time_ms=t_cons)
    tb.apply_cfg()
    await tb.start()
    hb = make_message(0x701, b"\x05")
    period = tb.period_ps

    async def inject_applied_at(t_apply: int) -> None:
        # the FSM sets rx_valid_i at the first falling edge after the injection, the DUT
        # applies the frame at the second rising edge after the one sampling rx_valid_i
        await Timer(t_apply - 2 * period - period // 2 - period // 4 - sim_time_ps(), "ps")
        n = len(tb.rx_log)
        tb.inject(hb)
        await Timer(5 * period, "ps")
        assert len(tb.rx_log) == n + 1 and tb.rx_log[-1].t_ps + 2 * period == t_apply

    await tb.wait_ms(1.5)
    t_tick = tb.tick_edges[-1] + PS_PER_MS  # a future tick edge
    await inject_applied_at(t_tick)
    # the timer would expire at the (T+1)-th tick after it: a heartbeat in that very cycle
    await inject_applied_at(t_tick + (t_cons + 1) * PS_PER_MS)
    await tb.wait_ms(t_cons + 2)
    assert t_tick + (t_cons + 1) * PS_PER_MS in tb.tick_edges
    t_lost = tb.check_loss(k, 1, t_cons)
    assert t_lost == t_tick + 2 * (t_cons + 1) * PS_PER_MS
    # one cycle before a tick: that tick counts
    t_tick = tb.tick_edges[-1] + PS_PER_MS
    await inject_applied_at(t_tick - period)
    await tb.wait_ms(t_cons + 2)
    assert tb.check_loss(k, 1, t_cons, after_ps=t_lost) == t_tick + t_cons * PS_PER_MS
    tb.check_rx_latency()


@cocotb.test(timeout_time=40, timeout_unit="ms", expect_fail=True)
async def run_loss_checker_can_fail(dut):
    """Purpose: prove that the loss-time checker fails on a wrong expectation.

    Verifies: check_loss (used by the tests above) accepts the true consumer time of the slot
    and raises an AssertionError when told it is one ms longer (cocotb expect_fail).
    """
    tb = TB(dut)
    tb.slot(1, mode=MODE_HB, time_ms=4, autostart=True)
    tb.apply_cfg()
    await tb.start()
    await tb.bring_up(hb_ms=2)
    await tb.wait_ms(6)
    t0 = sim_time_ps()
    tb.model(tb.slaves[1].power_off)
    await tb.wait_ms(8)
    tb.check_loss(tb.slot_of[1], 1, 4, after_ps=t0)  # the truth passes
    tb.check_loss(tb.slot_of[1], 1, 4 + 1, after_ps=t0)  # a wrong expectation must fail


# ============================================================================ pytest entry
FULL = {"MAX_NODES": 4, "EMCY_DEPTH": 8}
WIDE = {"MAX_NODES": 8, "EMCY_DEPTH": 5}


@pytest.mark.sim
@pytest.mark.parametrize("generics", [FULL, WIDE], ids=["4slots", "8slots-fifo5"])
def test_canopen_node_monitor(request, generics):
    # WIDE: the nodes in slots 1/3/5/7 with unused slots between, a FIFO depth that is not a
    # power of two
    run_cocotb(toplevel="canopen_node_monitor", module="tb.test_canopen_node_monitor",
               name=request.node.name, parameters=generics, stop_time_ms=2000)
