"""The Omni-ID robot network around ``canopen_master_top`` (CTRL.OMNI): what the Omni-ID system
bench and the Omni-ID demo share.

Drifting Omni-ID reference slaves (:class:`sim_models.omni.slave.OmniSlave`) on the system bench's
bus, a monitor of the master's cycle instants (TX2RTS# falls), the host sequence that runs the
cycle (set-points of cycle k+1 written in the interrupt of cycle k), and the same network run with
the transaction-level reference master for the cross-check.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import cocotb
from cocotb.triggers import RisingEdge, Timer, ValueChange

from sim_models.can_bus import CanBus
from sim_models.omni import codec as oc
from sim_models.omni.master_model import OmniMaster
from sim_models.omni.slave import OmniSlave, clock_for_period_error, setpoint_value
from sim_models.sim_time import Scheduler
from tb.tblib import regmap as R
from tb.tblib.model_clock import sim_time_ps
from tb.tblib.system_tb import SystemTB

BITRATE = 1_000_000
TAU_PS = 10**12 // BITRATE
MASTER_ID = oc.THESIS_MASTER_ID
FB_DLC = 6


@dataclass(frozen=True)
class SlaveSpec:
    node: int
    axis: int
    ppm: float  #: period error (+ = longer period, the slave lags)
    resync: str
    fc: int | None  #: feedback function code, None = the slave sends no feedback
    start_delay_ps: int | None = None
    sample_phase_ps: int = 0  #: sync_frame: sample this long after the SYNC's reception
    cycle_offset: int | None = None  #: sample n needs cycle n + offset (slave default if None)


def make_slave(sched: Scheduler, spec: SlaveSpec, period_ps: int, k: int,
               bitrate: int = BITRATE) -> OmniSlave:
    return OmniSlave(sched, spec.node, bitrate_bps=bitrate, period_ps=period_ps,
                     clock=clock_for_period_error(spec.ppm), master_id=MASTER_ID,
                     axis=spec.axis, feedback_fc=spec.fc, feedback=spec.fc is not None,
                     resync=spec.resync, resync_k=k, start_delay_ps=spec.start_delay_ps,
                     sample_phase_ps=spec.sample_phase_ps, cycle_offset=spec.cycle_offset)


class TxRtsMonitor:
    """Times of every TX2RTS# fall (the master's cycle instants)."""

    def __init__(self, sig) -> None:
        self.sig = sig
        self.fires: list[int] = []
        cocotb.start_soon(self._run())

    async def _run(self) -> None:
        prev = 1
        while True:
            await ValueChange(self.sig)
            v = self.sig.value
            if not v.is_resolvable:
                continue
            bit = (int(v) >> 2) & 1
            if prev == 1 and bit == 0:
                self.fires.append(sim_time_ps())
            prev = bit


async def run_rtl_cycle(tb: SystemTB, slaves: list[SlaveSpec], *, period_us: int,
                        n_cycles: int, sync_k: int, sync_mode: int = 1, poll_m: int = 0,
                        query_win_us: int = 1000, stop_on_missing: bool = False,
                        on_cycle: Callable[[int], Awaitable[None]] | None = None
                        ) -> TxRtsMonitor:
    """Configure the master in Omni-ID mode, start the nodes and run ``n_cycles`` cycles with
    the set-points of cycle k written in the interrupt of cycle k-1."""
    host = tb.host
    n_axes = len(slaves)
    await host.omni_mode(True)
    await host.omni_config(master_id=MASTER_ID, n_axes=n_axes, sender=True,
                           sync_mode=sync_mode, sync_k=sync_k, poll_m=poll_m,
                           query_win_us=query_win_us, stop_on_missing=stop_on_missing)
    for slot, s in enumerate(x for x in slaves if x.fc is not None):
        await host.omni_slot(slot, s.node, s.fc, FB_DLC)
    await host.write("SYNC_PERIOD_US", period_us)
    await Timer(5, "us")  # the feasibility sum runs over the node table
    st = await host.omni_status()
    assert not st["INFEASIBLE"] and not st["CFG_ERR"], st
    await host.omni_setpoints([setpoint_value(0, a + 1) for a in range(n_axes)])
    await host.irq_clear(0xFF)
    await host.irq_enable("SYNC")
    mon = TxRtsMonitor(tb.dut.mcp_txrts_n_o)
    await host.omni_nmt(0, True)
    await host.write("CTRL", R.CTRL_OMNI | R.CTRL_SYNC_EN)
    for k in range(n_cycles):
        await RisingEdge(tb.dut.irq_o)          # cycle k fired
        await host.irq_clear("SYNC")
        await host.omni_setpoints([setpoint_value(k + 1, a + 1) for a in range(n_axes)])
        if on_cycle is not None:
            await on_cycle(k)
    await host.write("CTRL", R.CTRL_OMNI)       # stop the cycle
    await Timer(2 * period_us, "us")
    return mon


def cycle_log(tb: SystemTB, mon: TxRtsMonitor, n_cycles: int) -> list[tuple[int, int]]:
    """(k, SOF of cycle k's cycle frame) for k < n_cycles."""
    recs = tb.frames()
    out = []
    for k, t_fire in enumerate(mon.fires[:n_cycles]):
        first = next(r for r in recs if r.t_start_ps >= t_fire)
        out.append((k, first.t_start_ps))
    return out


def python_reference(slaves: list[SlaveSpec], *, period_ps: int, n_cycles: int, k: int,
                     first_cycle_delay_ps: int, bitrate: int = BITRATE):
    """The same network with the transaction-level reference master."""
    sched = Scheduler()
    bus = CanBus(sched, bitrate)
    master = OmniMaster(sched, bitrate_bps=bitrate, period_ps=period_ps, n_axes=len(slaves),
                        sync_every=k, n_cycles=n_cycles,
                        first_cycle_delay_ps=first_cycle_delay_ps)
    bus.attach(master)
    models = [bus.attach(make_slave(sched, s, period_ps, k, bitrate)) for s in slaves]
    master.start()
    sched.run_until(period_ps * (n_cycles + 3))
    return master, models
