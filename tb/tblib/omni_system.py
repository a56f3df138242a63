"""The Omni-ID robot network around ``canopen_master_top`` (CTRL.OMNI): what the Omni-ID system
bench and the Omni-ID demo share.

Drifting Omni-ID reference slaves (:class:`sim_models.omni.slave.OmniSlave`) on the system bench's
bus, a monitor of the master's cycle instants (TX2RTS# falls), the host sequence that runs the
cycle (set-points of cycle k+1 written in the interrupt of cycle k), and the same network run with
the transaction-level reference master for the cross-check. For the cells of the Python sweep
grid (thesis scheme, ``sim_models.omni.experiments.sweep``): the grid's free-running slave
anchored on the first cycle frame (:class:`AnchoredSlave`), a replay of recorded bus frames into
fresh slave models (:func:`replay_network`), the drift window model (:func:`window_model`) and
the cell comparison (:func:`compare_results`) that the benches assert empty.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass

import can
import cocotb
from cocotb.triggers import RisingEdge, Timer, ValueChange

from sim_models.can_bus import CanBus, QueueNode
from sim_models.omni import codec as oc
from sim_models.omni.experiments import SlaveResult
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
    sample_phase_ps: int = 0  #: sync_frame / thesis: sample this long after the reference
    cycle_offset: int | None = None  #: sample n needs cycle n + offset (slave default if None)
    #: resync "none": sample 0 this long (true ps) after the SOF of the first frame after the
    #: NMT start (:class:`AnchoredSlave`), i.e. ``t_dif(0)`` when that frame is cycle 0's
    anchor_offset_ps: int | None = None


class AnchoredSlave(OmniSlave):
    """Free-running slave (resync ``"none"``) whose sample 0 lies ``offset_ps`` of true time
    after the SOF of the first frame on the bus after its NMT start.

    The sweep's free-running cells (``run_two_node(initial_offset_ps=...)``) place sample 0 at
    ``m_0 + offset``; the RTL master's first cycle instant after NMT start depends on its host
    sequence, so the bench anchors the slave on the first cycle frame instead: its timer starts
    at that SOF with a first expiry of ``round(offset · clock.scale)`` local ps (the
    conversion ``run_two_node`` uses) through the slave's :meth:`OmniSlave.resync` rule,
    then runs free. ``anchor_ps`` records the SOF used (the bench checks it is cycle 0's). The
    re-anchoring counts as one entry of ``rephase_log`` (``SlaveResult.rephases`` = 1)."""

    def __init__(self, sched: Scheduler, node_id: int, *, offset_ps: int, period_ps: int,
                 clock, **kw) -> None:
        local = round(offset_ps * clock.scale)
        # the timer started at NMT start must not expire before the anchor: 100 periods
        super().__init__(sched, node_id, period_ps=period_ps, clock=clock, resync="none",
                         sample_phase_ps=local, start_delay_ps=100 * period_ps, **kw)
        self.anchor_ps: int | None = None

    def on_bus_activity(self, t_ps: int) -> None:
        if self.started and self.anchor_ps is None:
            assert not self.control_log, "sample before the anchor frame"
            self.anchor_ps = t_ps
            self.resync()


def make_slave(sched: Scheduler, spec: SlaveSpec, period_ps: int, k: int,
               bitrate: int = BITRATE) -> OmniSlave:
    kw = dict(bitrate_bps=bitrate, master_id=MASTER_ID, axis=spec.axis, feedback_fc=spec.fc,
              feedback=spec.fc is not None, cycle_offset=spec.cycle_offset)
    clock = clock_for_period_error(spec.ppm)
    if spec.anchor_offset_ps is not None:
        assert spec.resync == "none", spec
        return AnchoredSlave(sched, spec.node, offset_ps=spec.anchor_offset_ps,
                             period_ps=period_ps, clock=clock, **kw)
    return OmniSlave(sched, spec.node, period_ps=period_ps, clock=clock, resync=spec.resync,
                     resync_k=k, start_delay_ps=spec.start_delay_ps,
                     sample_phase_ps=spec.sample_phase_ps, **kw)


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
                        on_cycle: Callable[[int], Awaitable[None]] | None = None,
                        n_axes: int | None = None) -> TxRtsMonitor:
    """Configure the master in Omni-ID mode, start the nodes and run ``n_cycles`` cycles with
    the set-points of cycle k written in the interrupt of cycle k-1. ``n_axes`` (default: one
    per slave) sets the broadcast's DLC, ``n_axes + 1`` with the sender byte."""
    host = tb.host
    n_axes = len(slaves) if n_axes is None else n_axes
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
    # the same feasibility inputs as the RTL master: one feedback frame per sending slave
    master = OmniMaster(sched, bitrate_bps=bitrate, period_ps=period_ps, n_axes=len(slaves),
                        sync_every=k, n_cycles=n_cycles,
                        first_cycle_delay_ps=first_cycle_delay_ps,
                        feedback_dlcs=[FB_DLC for s in slaves if s.fc is not None])
    bus.attach(master)
    models = [bus.attach(make_slave(sched, s, period_ps, k, bitrate)) for s in slaves]
    master.start()
    sched.run_until(period_ps * (n_cycles + 3))
    return master, models


# ==========================================================================================
# cells of the Python sweep grid (thesis scheme): replay, window model, comparison
# ==========================================================================================


def replay_network(slaves: list[SlaveSpec], frames: Sequence[tuple[int, can.Message]], *,
                   period_ps: int, k: int, bitrate: int) -> list[OmniSlave]:
    """Fresh slave models on a fresh Python bus, fed by ``frames`` ((SOF, message), e.g. the
    RTL run's bus records) each sent at its SOF. On an idle bus the bit-exact bus model starts
    a frame at its request, so an unmodified replay gives the slaves exactly the receptions of
    the recorded run; a doctored list (a frame removed) shows what the checks make of it."""
    sched = Scheduler()
    bus = CanBus(sched, bitrate)
    src = bus.attach(QueueNode("replay", bitrate))
    models = [bus.attach(make_slave(sched, s, period_ps, k, bitrate)) for s in slaves]
    for t, msg in frames:
        sched.call_at(t, src.send, msg)
    sched.run_until(max(t for t, _ in frames) + 3 * period_ps)
    return models


def window_model(t_dif0_ps: int, rho_ppm: float, period_ps: int,
                 latencies_ps: Sequence[int]) -> list[int]:
    """Samples a free-running slave loses according to the drift model (experiments module
    docstring): ``t_dif(n) = t_dif(0) + n·ρ·T_s``, sample n holds its own cycle's command iff
    ``D_n < t_dif(n) < T_s + D_{n+1}`` with ``D_n`` the delivery latency of cycle n's command
    (one entry per cycle sent; after the last cycle no command overwrites the last one, so the
    last sample has no upper bound). Returns the indices outside that window."""
    step = rho_ppm * 1e-6 * period_ps
    out = []
    for n, d in enumerate(latencies_ps):
        t = t_dif0_ps + n * step
        late = n + 1 < len(latencies_ps) and t >= period_ps + latencies_ps[n + 1]
        if t <= d or late:
            out.append(n)
    return out


def compare_results(rtl: SlaveResult, ref: SlaveResult, *, tau_ps: int, count_tol: int = 0,
                    time_tol_ps: int | None = None) -> list[str]:
    """Disagreements between the RTL run's figures of one slave and the Python model's for the
    same cell (empty = agree): samples counted, dropout count and onset within ``count_tol``,
    max |offset| and every per-sample offset ``s_n - m_n`` within ``time_tol_ps`` (default two
    bit times)."""
    tol = 2 * tau_ps if time_tol_ps is None else time_tol_ps
    out = []
    if rtl.n != ref.n:
        out.append(f"samples counted {rtl.n} != {ref.n}")
    if abs(rtl.n_dropout - ref.n_dropout) > count_tol:
        out.append(f"dropout {rtl.n_dropout} != {ref.n_dropout}")
    if (rtl.onset is None) != (ref.onset is None) or (
            rtl.onset is not None and abs(rtl.onset - ref.onset) > count_tol):
        out.append(f"onset {rtl.onset} != {ref.onset}")
    if abs(rtl.skew_max_ps - ref.skew_max_ps) > tol:
        out.append(f"max |offset| {rtl.skew_max_ps} != {ref.skew_max_ps} ps")
    a, b = rtl.offsets_ps, ref.offsets_ps
    if abs(len(a) - len(b)) > count_tol:
        out.append(f"offsets of {len(a)} samples != {len(b)}")
    diff = [(n, x - y) for n, (x, y) in enumerate(zip(a, b)) if abs(x - y) > tol]
    if diff:
        out.append(f"{len(diff)} sample offsets differ by more than {tol} ps, first "
                   f"n = {diff[0][0]}: {diff[0][1]} ps")
    return out


def max_offset_diff_ps(rtl: SlaveResult, ref: SlaveResult) -> int:
    """Largest per-sample |offset difference| of two runs (over the samples both have)."""
    return max((abs(x - y) for x, y in zip(rtl.offsets_ps, ref.offsets_ps)), default=0)


async def axes_delivered(tb: SystemTB, slaves: list[SlaveSpec], models: list[OmniSlave],
                         cyc: list[tuple[int, int]], n_cycles: int,
                         period_ps: int) -> dict[int, dict[str, bool]]:
    """Per feedback-sending axis of a run: was every set-point and every feedback frame
    delivered in its cycle? For the cycles k < ``n_cycles - 1`` (the last one's sample comes
    after the host stopped the cycle, as in every evaluation here):

    * ``setpoints``: the slave's sample that needs cycle k holds cycle k's set-point, for
      every such k (no dropout, no cycle without its sample);
    * ``feedback_on_bus``: exactly one feedback frame of the axis (its fc to the master, byte
      0 = its node) starts in ``[m_k, m_k + T_s)``;
    * ``stored``: the master stored every one of the axis' feedback frames (slot SEQ = frames
      on the bus, mod 2^16) and counted no cycle without feedback (slot MISSED = 0).

    Reads each slot's feedback snapshot through the host (acknowledging it)."""
    needed = set(range(n_cycles - 1))
    frames = tb.frames()
    out: dict[int, dict[str, bool]] = {}
    for slot, (s, m) in enumerate((s, m) for s, m in zip(slaves, models) if s.fc is not None):
        good = {t.expected_cycle for t in m.control_log if t.dropout is False}
        bad = [t for t in m.control_log if t.dropout and t.expected_cycle in needed]
        fb = [r.t_start_ps for r in frames if r.msg.arbitration_id == (s.fc << 8 | MASTER_ID)
              and r.msg.dlc >= 1 and r.msg.data[0] == s.node]
        per_cycle = [sum(1 for t in fb if t0 <= t < t0 + period_ps) for k, t0 in cyc
                     if k in needed]
        snap = await tb.host.omni_feedback(slot)
        out[s.node] = {"setpoints": needed <= good and not bad,
                       "feedback_on_bus": len(per_cycle) == len(needed)
                       and set(per_cycle) == {1},
                       "stored": snap["missed"] == 0 and snap["seq"] == len(fb) % 65536}
    return out
