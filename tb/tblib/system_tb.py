"""The full system around ``canopen_master_top``: what the system bench and the demo share.

DUT pins -> behavioural MCP2510 (``sim_models.mcp2510``) -> timing-accurate CAN bus
(``sim_models.can_bus``) <- CiA 301 reference slaves (``sim_models.canopen_slave``, on the
PyPI ``canopen`` library's object dictionary and SDO server) and an optional raw ``QueueNode``
for garbage/extra traffic. The host side is the Avalon-MM driver
(:class:`tb.tblib.host_driver.CanopenMasterHost`), the only way the benches touch the core.

An FSM monitor records every state change of ``fsm_state_o`` and maps it to the transition ids
of ``tb/tblib/fsm_states.py`` (self-loops are not visible on the state code; T1, T6 and T18 are
inferred from the events that cause them).
"""

from __future__ import annotations

import cocotb
from cocotb.triggers import Timer, ValueChange

from sim_models.can_bus import CanBus, NodeClock, QueueNode
from sim_models.canopen_slave import CanopenSlave, NmtState, build_slaves
from sim_models.mcp2510.chip import Mcp2510
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler
from tb.tblib.clkrst import reset_active_low, start_clock
from tb.tblib.fsm_states import TRANSITIONS, State
from tb.tblib.host_driver import CanopenMasterHost
from tb.tblib.mcp2510_pins import Mcp2510Pins
from tb.tblib.model_clock import ModelClock, sim_time_ps
from tb.tblib.runner import param

#: visible transitions by (from, to); self-loops (T1, T6, T18, G5) are not in this map
PAIR_TO_TID = {(t.src, t.dst): t.tid for t in TRANSITIONS
               if t.src != t.dst and t.tid != "G4"}


class FsmMonitor:
    """Records the FSM's state changes and counts the transitions taken."""

    def __init__(self, state_sig) -> None:
        self.sig = state_sig
        self.covered: dict[str, int] = {}
        self.log: list[tuple[int, State]] = []
        self._prev: State | None = None
        self._t_prev = 0
        #: clock period in ps, to tell a one-cycle pass through St12 from a wait in it (T18)
        self.clk_ps = 0
        cocotb.start_soon(self._run())

    def _note(self, tid: str) -> None:
        self.covered[tid] = self.covered.get(tid, 0) + 1

    async def _run(self) -> None:
        while True:
            await ValueChange(self.sig)
            if not self.sig.value.is_resolvable:
                continue
            s = State(int(self.sig.value))
            now = sim_time_ps()
            prev, self._prev = self._prev, s
            t_prev, self._t_prev = self._t_prev, now
            self.log.append((now, s))
            if prev is None:
                continue
            if prev == State.S_CAN_TX and now - t_prev > self.clk_ps:
                self._note("T18")  # St12 waited for the controller (self-loop)
            if s == State.S_ERROR and prev not in (State.S_HUB,):
                self._note("G4")
            tid = PAIR_TO_TID.get((prev, s))
            if tid is not None:
                self._note(tid)

    def infer_self_loops(self, *, init_failed: bool = False, ext_dropped: bool = False) -> None:
        """Self-loops the state code cannot show, inferred from the event that causes them."""
        if init_failed:
            self._note("T1")
        if ext_dropped:
            self._note("T6")
        self._note("G5")


class SystemTB:
    """canopen_master_top + MCP2510 model + CAN bus + reference slaves + host driver."""

    def __init__(self, dut, *, node_ids=(1, 2, 3, 4), ppm=None, boot_time_ms: float = 1.0,
                 with_raw_node: bool = True, slave_kwargs=None) -> None:
        """``slave_kwargs``: node-ID -> extra CanopenSlave arguments of that slave (e.g. its
        clock and control loop, ``sim_models.canopen_slave.drift.drive_kwargs``)."""
        self.dut = dut
        self.clk_hz = param("CLK_FREQ_HZ")
        self.bitrate = param("CAN_BITRATE_BPS")
        start_clock(dut.clk_i, self.clk_hz)
        self.sched = Scheduler()
        self.sched.run_until(sim_time_ps())
        self.clock = ModelClock(self.sched)
        self.bus = CanBus(self.sched, self.bitrate)
        self.chip = Mcp2510(self.sched, osc_hz=param("OSC_FREQ_HZ"), name="master_mcp2510")
        self.bus.attach(self.chip)
        if not slave_kwargs:
            self.slaves: list[CanopenSlave] = build_slaves(
                self.sched, self.bus, list(node_ids), ppm=list(ppm) if ppm else None,
                boot_time_ps=int(boot_time_ms * PS_PER_MS))
        else:  # as build_slaves, with per-node arguments (a "clock" there replaces ppm)
            self.slaves = []
            for i, n in enumerate(node_ids):
                kw = {"boot_time_ps": int(boot_time_ms * PS_PER_MS), **slave_kwargs.get(n, {})}
                if "clock" not in kw and ppm:
                    kw["clock"] = NodeClock(ppm[i])
                s = CanopenSlave(self.sched, n, bitrate_bps=self.bitrate, **kw)
                self.bus.attach(s)
                self.slaves.append(s)
        self.raw = QueueNode("raw", self.bitrate) if with_raw_node else None
        if self.raw is not None:
            self.bus.attach(self.raw)
        self.pins = Mcp2510Pins(
            self.chip, self.clock,
            cs_n=dut.spi_cs_n_o, sck=dut.spi_sck_o, mosi=dut.spi_mosi_o, miso=dut.spi_miso_i,
            int_n=dut.mcp_int_n_i, rx0bf_n=dut.mcp_rx0bf_n_i, rx1bf_n=dut.mcp_rx1bf_n_i,
            txrts_n=dut.mcp_txrts_n_o, reset_n=dut.mcp_reset_n_o,
        )
        self.host = CanopenMasterHost(dut, dut.clk_i)
        self.fsm = FsmMonitor(dut.fsm_state_o)
        self.fsm.clk_ps = 10**12 // self.clk_hz

    # ------------------------------------------------------------------ helpers
    def slave(self, node_id: int) -> CanopenSlave:
        return next(s for s in self.slaves if s.node_id == node_id)

    async def reset(self) -> None:
        await reset_active_low(self.dut.clk_i, self.dut.rst_n_i)

    async def wait_for(self, cond, timeout_us: float, step_us: float = 20,
                       what: str = "condition") -> int:
        """Poll ``cond`` every ``step_us`` of simulated time; returns the time it held."""
        t_end = sim_time_ps() + int(timeout_us * PS_PER_US)
        while not cond():
            assert sim_time_ps() < t_end, f"{what} not met within {timeout_us} us"
            await Timer(step_us, "us")
        return sim_time_ps()

    async def wait_master_ready(self) -> None:
        await self.wait_for(lambda: int(self.dut.fsm_state_o.value) == State.S_HUB
                            and self.chip.mode == "normal", 2_000, 5, "master in St1")

    def frames(self, can_id: int | None = None):
        """Successful frames on the bus (optionally one COB-ID)."""
        return [r for r in self.bus.records
                if r.kind == "frame" and (can_id is None or r.msg.arbitration_id == can_id)]

    def sync_sof_times(self) -> list[int]:
        return [r.t_start_ps for r in self.frames(0x080)]

    def all_operational(self) -> bool:
        return all(s.nmt_state == NmtState.OPERATIONAL for s in self.slaves if s.powered)

    def check_models_clean(self) -> None:
        assert self.chip.violations == [], self.chip.violations
        assert self.pins.slave.violations == [], self.pins.slave.violations
