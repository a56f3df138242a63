"""Clock-drift experiments of the NCTU thesis on the Python models (AT-5..AT-10, AT-13).

Transaction-level and pure Python: an :class:`~sim_models.omni.master_model.OmniMaster` and
one or more :class:`~sim_models.omni.slave.OmniSlave` on a
:class:`~sim_models.can_bus.CanBus`, all on one :class:`~sim_models.sim_time.Scheduler`. Each
``run_*``/``at*`` function builds a fresh network, runs it and returns plain dataclasses /
dicts (JSON-friendly) with the measured figures *and* the model figures they are checked
against; the model formulas (digest §3.2, §5.3) live here too:

* offset of sample n: ``t_dif(n) = s_n - m_n`` (slave sample instant minus master cycle
  instant), model ``t_dif(0) + n·ρ·T_s`` while free-running;
* delivery latency of a frame: ``D = (frame bits - 3)·τ_bit + T_post`` (SOF to end of EOF,
  the slave's reception timestamp; the master's frame starts at its cycle instant on an idle
  bus, so ``T_pre = T_wait = 0``);
* a free-running sample n holds the command of its own cycle iff ``D_n < t_dif(n) < T_s +
  D_{n+1}``; the first n outside is the dropout onset, model :func:`n_drift_model`;
* dropout rate (Eq 2-2) ``p = N_dropout / N`` and ``N_drift = N - N_dropout`` (Eq 2-3);
* re-phase interval (AT-10) :func:`k_max`: ``K <= floor((T_s - D - margin) / (|ρ|·T_s))``.

Drift is given as the digest's *period error* ρ in ppm (positive: the slave's period is longer
and its samples lag more and more); see :func:`~sim_models.omni.slave.clock_for_period_error`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from typing import Any

from sim_models.can_bus import CanBus, frame_length_bits, worst_case_bits
from sim_models.omni import codec as oc
from sim_models.omni.master_model import OmniMaster, check_feasibility
from sim_models.omni.slave import FEEDBACK_DLC, OmniSlave, clock_for_period_error
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler

__all__ = [
    "RATES",
    "SlaveResult",
    "TwoNodeRun",
    "at5_drift_reproduction",
    "at6_sync_removes_drift",
    "at9_four_slaves",
    "at10_stress",
    "at13_sync_step",
    "check_at5",
    "check_at6",
    "default_k",
    "delivery_latency_ps",
    "evaluate_slave",
    "inter_slave_skew_ps",
    "k_max",
    "n_drift_model",
    "run_two_node",
    "sweep",
]

#: bit rates of the thesis' experiments (kbit/s x 1000)
RATES = (100_000, 125_000, 250_000, 500_000, 1_000_000)
#: the thesis' measured drift (0.72 ms in 199 ms) as a period error
THESIS_RHO_PPM = 3618.0
#: the thesis' measured slave post-processing time (Table 2-1)
THESIS_T_POST_PS = 88_800_000
#: margin left before the next command when the sweeps choose K (:func:`default_k`): 10 % of
#: T_s, the digest's 0.1 ms at 1 ms (AT-10)
K_MARGIN_FRACTION = Fraction(1, 10)


# ==========================================================================================
# model formulas
# ==========================================================================================


def delivery_latency_ps(bitrate_bps: int, msg: Any, t_post_ps: int = 0) -> int:
    """SOF to the receiver's timestamp: ``(frame bits - 3)`` bit times + ``T_post`` (true ps,
    transmitter and receiver at 0 ppm)."""
    bus = CanBus(Scheduler(), bitrate_bps)
    return bus.duration_ps(frame_length_bits(msg) - 3) + t_post_ps


def n_drift_model(t_dif0_ps: float, rho_ppm: float, period_ps: int, d_ps: float) -> int:
    """Index of the first free-running dropout (digest §3.2, AT-5): a lagging slave (ρ > 0)
    drops once ``t_dif(n) >= T_s + D`` (the next command already overwrote this one), a
    leading slave (ρ < 0) once ``t_dif(n) <= D`` (the command is not there yet)."""
    step = rho_ppm * 1e-6 * period_ps
    if step > 0:
        return max(0, math.ceil((period_ps + d_ps - t_dif0_ps) / step))
    if step < 0:
        return max(0, math.ceil((t_dif0_ps - d_ps) / -step))
    raise ValueError("no drift, no onset")


def k_max(period_ps: int, d_ps: int, margin_ps: int, rho_ppm: float) -> int:
    """Largest re-phase interval K with ``K·|ρ|·T_s <= T_s - D - margin`` (AT-10)."""
    return max(1, int((period_ps - d_ps - margin_ps) / (abs(rho_ppm) * 1e-6 * period_ps)))


# ==========================================================================================
# evaluation of one slave
# ==========================================================================================


@dataclass
class SlaveResult:
    """Measured figures of one slave (times in ps)."""

    name: str
    rho_ppm: float
    n: int  #: samples counted (expected cycle in 0 .. n_cycles - 1)
    n_dropout: int
    p_pct: float  #: Eq 2-2
    n_drift: int  #: Eq 2-3: N - N_dropout
    onset: int | None  #: index of the first dropout sample
    offsets_ps: list[int] = field(repr=False)  #: t_dif(n) = s_n - m_n for every sample n
    nominal_latency_ps: int = 0  #: D_i of the skew definition
    skew_max_ps: int = 0  #: max_n |s_n - (m_n + D_i)|
    rephases: int = 0
    dropout_ticks: list[int] = field(default_factory=list, repr=False)  #: every dropout n
    skew_max_tick: int | None = None  #: the sample n of skew_max_ps (first one)

    def summary(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("offsets_ps")
        d.pop("dropout_ticks")
        return d


def evaluate_slave(slave: Any, master: Any, n_cycles: int, rho_ppm: float,
                   nominal_latency_ps: int = 0) -> SlaveResult:
    """Dropout (Eq 2-2, 2-3) over the samples whose command cycle was sent, and the offsets
    ``s_n - m_n`` of the samples whose own cycle exists.

    ``slave`` needs ``name``, ``control_log`` (:class:`~sim_models.omni.slave.OmniTick`),
    ``rephase_log``, ``value_fn`` and ``axis``; ``master`` needs ``cycle_log`` ((c, m_c)
    pairs, e.g. the RTL's cycle instants). A sample is a dropout when the value it took is
    not ``value_fn(expected_cycle, axis)``: decided here from the logged value, not taken
    from the slave's own flag, so a log is checked independently of the slave's decision."""
    cycles = dict(master.cycle_log)
    counted = [t for t in slave.control_log
               if t.expected_cycle >= 0 and t.expected_cycle < n_cycles]
    drops = [t.tick for t in counted
             if t.value is None or t.value != slave.value_fn(t.expected_cycle, slave.axis)]
    samples = [(t.tick, t.t_ps - cycles[t.tick]) for t in slave.control_log
               if t.tick in cycles]
    offsets = [o for _, o in samples]
    n = len(counted)
    skew, skew_tick = 0, None
    for tick, o in samples:
        if skew_tick is None or abs(o - nominal_latency_ps) > skew:
            skew, skew_tick = abs(o - nominal_latency_ps), tick
    return SlaveResult(slave.name, rho_ppm, n, len(drops), 100.0 * len(drops) / n if n else 0.0,
                       n - len(drops), drops[0] if drops else None, offsets,
                       nominal_latency_ps, skew, len(slave.rephase_log), drops, skew_tick)


def inter_slave_skew_ps(control_logs: list[list[Any]], cycle_log: list[tuple[int, int]]
                        ) -> dict[int, int]:
    """Inter-slave sample skew per sample index n: ``max_i s_{i,n} - min_i s_{i,n}``, for
    every n of the master's ``cycle_log`` that every slave sampled."""
    cycles = dict(cycle_log)
    by_tick: dict[int, list[int]] = {}
    for log in control_logs:
        for t in log:
            if t.tick in cycles:
                by_tick.setdefault(t.tick, []).append(t.t_ps)
    return {n: max(v) - min(v) for n, v in sorted(by_tick.items())
            if len(v) == len(control_logs)}


# ==========================================================================================
# two-node experiment (thesis Ch.2 / Ch.3): one master, one slave, no feedback
# ==========================================================================================


@dataclass
class TwoNodeRun:
    """One two-node run and what the models predict for it."""

    bitrate_bps: int
    dlc: int
    period_ps: int
    rho_ppm: float
    resync: str
    k: int
    n_cycles: int
    feasible: bool
    reason: str
    result: SlaveResult
    d_min_ps: int  #: min / max delivery latency of the commands actually sent
    d_max_ps: int
    t_dif0_ps: int | None  #: measured offset of sample 0
    master: OmniMaster = field(repr=False)
    slave: OmniSlave = field(repr=False)
    bus: CanBus = field(repr=False)

    def summary(self) -> dict[str, Any]:
        return {"bitrate_bps": self.bitrate_bps, "dlc": self.dlc, "period_ps": self.period_ps,
                "rho_ppm": self.rho_ppm, "resync": self.resync, "k": self.k,
                "n_cycles": self.n_cycles, "feasible": self.feasible, "reason": self.reason,
                "d_min_ps": self.d_min_ps, "d_max_ps": self.d_max_ps,
                "t_dif0_ps": self.t_dif0_ps, "sample_phase_ps": self.slave.sample_phase_ps,
                "aborted": len(self.master.aborted_log), **self.result.summary()}


def run_two_node(bitrate_bps: int, dlc: int, period_ps: int, rho_ppm: float, n_cycles: int,
                 *, resync: str = "none", k: int = 10, sample_phase_ps: int = 0,
                 initial_offset_ps: int | None = None, t_post_ps: int = 0,
                 allow_infeasible: bool = True, late_frames: dict[int, int] | None = None,
                 drop_cycles: frozenset[int] | set[int] = frozenset()) -> TwoNodeRun:
    """Master (0 ppm, node 0x02) + one slave (node 0x04, axis 1, period error ``rho_ppm``).

    The command is an fc 001 broadcast of ``dlc`` bytes (sender byte + ``dlc - 1`` slots).
    ``initial_offset_ps`` places the slave's free-running sample 0 at ``m_0 + offset`` (it is
    ignored in thesis mode, where sample 0 is the first command). ``late_frames`` maps a cycle
    index to an extra delay of that cycle's command, ``drop_cycles`` lists cycles whose
    command is never sent (fault injection for the checkers)."""
    if dlc < 2:
        raise ValueError("the command needs a sender byte and at least one slot (DLC >= 2)")
    sched = Scheduler()
    bus = CanBus(sched, bitrate_bps)
    sync_every = k if resync == "sync_frame" else 0
    master = OmniMaster(sched, bitrate_bps=bitrate_bps, period_ps=period_ps, n_axes=dlc - 1,
                        sync_every=sync_every, n_cycles=n_cycles,
                        allow_infeasible=allow_infeasible)
    bus.attach(master)
    clock = clock_for_period_error(rho_ppm)
    start_delay = None
    if initial_offset_ps is not None:
        d_nmt = delivery_latency_ps(bitrate_bps, oc.nmt_frame(0, oc.NMT_START), t_post_ps)
        true_delay = period_ps + initial_offset_ps - d_nmt
        if true_delay < 0:
            raise ValueError("initial offset earlier than the NMT start reception")
        start_delay = round(true_delay * clock.scale)
    slave = OmniSlave(sched, 0x04, bitrate_bps=bitrate_bps, period_ps=period_ps, clock=clock,
                      feedback=False, resync=resync, resync_k=k,
                      sample_phase_ps=sample_phase_ps, start_delay_ps=start_delay,
                      t_post_ps=t_post_ps)
    bus.attach(slave)
    if late_frames or drop_cycles:
        _inject_faults(master, late_frames or {}, frozenset(drop_cycles))
    master.start()
    sched.run_until(period_ps * (n_cycles + 3))
    sent = [(t, m) for t, m in master.tx_log if m.arbitration_id == master.command_frame(0)
            .arbitration_id]
    lat = [delivery_latency_ps(bitrate_bps, m, t_post_ps) for _, m in sent]
    res = evaluate_slave(slave, master, n_cycles, rho_ppm)
    return TwoNodeRun(bitrate_bps, dlc, period_ps, rho_ppm, resync, k, n_cycles,
                      master.feasibility.ok, master.feasibility.reason, res,
                      min(lat) if lat else 0, max(lat) if lat else 0,
                      res.offsets_ps[0] if res.offsets_ps else None, master, slave, bus)


def _inject_faults(master: OmniMaster, late: dict[int, int], dropped: frozenset[int]) -> None:
    """Delay the command of the cycles in ``late`` by the given ps, do not send the command
    of the cycles in ``dropped`` (the cycle instant is still logged; checker self-tests)."""
    original = master._on_cycle

    def patched(c: int) -> None:
        if (c in late or c in dropped) and (master.n_cycles is None or c < master.n_cycles):
            master.cycle_log.append((c, master.sched.now_ps))
            if c in late:
                master.sched.call_later(late[c], master.queue_frame, master.command_frame(c))
            return
        original(c)

    master._cycle_timer.fn = patched


# ==========================================================================================
# AT-5: drift reproduction without sync
# ==========================================================================================


def at5_drift_reproduction(n_cycles: int = 1000, *, rho_ppm: float = THESIS_RHO_PPM,
                           t_dif0_ps: int = 1_740 * PS_PER_US) -> dict[str, Any]:
    """T_s 5 ms, ρ = +3618 ppm, t_dif(0) = 1.74 ms, 1 Mbit/s, 2-byte command, no sync.

    ``rho_ppm`` / ``t_dif0_ps`` are the slave's real drift and start offset (the thesis'
    values by default); the model figures always use the thesis' ρ, so a different slave
    makes :func:`check_at5` fail (its self-test)."""
    period = 5 * PS_PER_MS
    run = run_two_node(1_000_000, 2, period, rho_ppm, n_cycles, initial_offset_ps=t_dif0_ps)
    off = run.result.offsets_ps
    d_mean = (run.d_min_ps + run.d_max_ps) / 2
    model_onset = n_drift_model(off[0], THESIS_RHO_PPM, period, d_mean)
    return {
        "t_dif0_ms": off[0] / PS_PER_MS,
        "offset_after_40_ms": off[40] / PS_PER_MS,
        "offset_after_40_model_ms": (off[0] + 40 * THESIS_RHO_PPM * 1e-6 * period) / PS_PER_MS,
        "n_drift_model": model_onset,
        "n_drift_model_bounds": (n_drift_model(off[0], THESIS_RHO_PPM, period, run.d_min_ps),
                                 n_drift_model(off[0], THESIS_RHO_PPM, period, run.d_max_ps)),
        "onset_measured": run.result.onset,
        "n_drift_eq23": run.result.n_drift,
        "n": run.result.n,
        "p_pct": run.result.p_pct,
        "p_model_pct": 100.0 * (run.result.n - model_onset) / run.result.n,
        "offsets_ps": off,
        "run": run,
    }


def check_at5(r: dict[str, Any]) -> list[str]:
    """AT-5 pass criteria on an :func:`at5_drift_reproduction` result; returns the failures
    (empty = pass):

    * t_dif(0) = 1.74 ms; offset after 40 periods 2.46 ms ± 0.02 ms (thesis Figs 2-15/2-16);
    * every offset on the model line ``t_dif(0) + n·ρ·T_s`` (ρ = +3618 ppm) within 2 ps;
    * model onset in the digest's 180..191; measured onset and ``N_drift`` (Eq 2-3) within
      ±1 of it; p within one sample of ``(N - N_drift,model) / N``."""
    fails = []
    if abs(r["t_dif0_ms"] - 1.74) > 1e-6:
        fails.append(f"t_dif(0) = {r['t_dif0_ms']:.6f} ms, not 1.74 ms")
    if abs(r["offset_after_40_ms"] - 2.46) > 0.02:
        fails.append(f"offset after 40 periods {r['offset_after_40_ms']:.4f} ms, "
                     "not 2.46 ± 0.02 ms")
    off = r["offsets_ps"]
    step = THESIS_RHO_PPM * 1e-6 * 5 * PS_PER_MS
    off_line = [n for n in range(len(off)) if abs(off[n] - (off[0] + n * step)) > 2]
    if off_line:
        fails.append(f"offset off the model line t_dif(0) + n·ρ·T_s at samples {off_line[:5]}"
                     f"{' ...' if len(off_line) > 5 else ''}")
    if not 180 <= r["n_drift_model"] <= 191:
        fails.append(f"model onset {r['n_drift_model']} outside 180..191")
    if r["onset_measured"] is None or abs(r["onset_measured"] - r["n_drift_model"]) > 1:
        fails.append(f"onset {r['onset_measured']} not within ±1 of the model "
                     f"{r['n_drift_model']}")
    if abs(r["n_drift_eq23"] - r["n_drift_model"]) > 1:
        fails.append(f"N_drift (Eq 2-3) {r['n_drift_eq23']} not within ±1 of the model "
                     f"{r['n_drift_model']}")
    if abs(r["p_pct"] - r["p_model_pct"]) > 100.0 / r["n"] + 1e-9:
        fails.append(f"p = {r['p_pct']:.3f} % not within one sample of the model "
                     f"{r['p_model_pct']:.3f} %")
    return fails


# ==========================================================================================
# AT-6 / AT-7 / AT-8: sync removes drift-induced loss; bit-rate x length sweeps
# ==========================================================================================


def at6_sync_removes_drift(dlc: int, n_cycles: int = 3000, k: int = 10,
                           bitrate_bps: int = 1_000_000, period_ps: int = 5 * PS_PER_MS,
                           sample_phase_ps: int = 0, *, rho_ppm: float = THESIS_RHO_PPM
                           ) -> dict[str, Any]:
    """AT-5 plus the thesis re-phase every K samples; offset band model
    ``[D_min, D_max + K·ρ·T_s + 1 τ_bit]`` with the thesis' ρ (``rho_ppm`` is the slave's
    real drift, for the checker's self-test). Checked by :func:`check_at6`."""
    run = run_two_node(bitrate_bps, dlc, period_ps, rho_ppm, n_cycles, resync="thesis",
                       k=k, sample_phase_ps=sample_phase_ps)
    tau = 10**12 // bitrate_bps
    lo = run.d_min_ps + sample_phase_ps
    hi = run.d_max_ps + sample_phase_ps + int(k * THESIS_RHO_PPM * 1e-6 * period_ps) + tau
    off = run.result.offsets_ps
    return {"dlc": dlc, "k": k, "n_cycles": n_cycles, "p_pct": run.result.p_pct,
            "n": run.result.n, "n_dropout": run.result.n_dropout, "offsets_ps": off,
            "offset_min_ps": min(off), "offset_max_ps": max(off), "band_model_ps": (lo, hi),
            "spread_ps": run.d_max_ps - run.d_min_ps,
            "first_k_max_ps": max(off[:k]), "last_k_max_ps": max(off[-k:]), "run": run}


def check_at6(r: dict[str, Any]) -> list[str]:
    """AT-6 pass criteria on an :func:`at6_sync_removes_drift` result (offsets recomputed
    from ``offsets_ps``); returns the failures (empty = pass):

    * dropout 0 % over at least N - 1 samples;
    * every offset inside the band ``[D_min, D_max + K·ρ·T_s + τ_bit]``;
    * no secular growth: the peak offset of every re-phase interval (samples jK .. jK+K-1)
      lies within the command-latency spread ``D_max - D_min`` (stuff bits) of the first
      interval's peak, and the last interval's peak is not above the first's + spread."""
    fails = []
    off, k = r["offsets_ps"], r["k"]
    if r["p_pct"] != 0.0 or r["n"] < r["n_cycles"] - 1:
        fails.append(f"dropout {r['p_pct']:.3f} % over {r['n']} samples, not 0 % over "
                     f">= {r['n_cycles'] - 1}")
    lo, hi = r["band_model_ps"]
    out = [n for n, o in enumerate(off) if not lo <= o <= hi]
    if out:
        fails.append(f"offset outside the band [{lo}, {hi}] ps at samples {out[:5]}"
                     f"{' ...' if len(out) > 5 else ''}")
    peaks = [max(off[i:i + k]) for i in range(0, len(off) - k + 1, k)]
    spread = r["spread_ps"]
    grown = [j for j, pk in enumerate(peaks) if abs(pk - peaks[0]) > spread]
    if grown:
        fails.append(f"secular growth: peak of re-phase interval(s) {grown[:5]} more than the "
                     f"latency spread {spread} ps from the first interval's {peaks[0]} ps")
    if max(off[-k:]) > max(off[:k]) + spread:
        fails.append(f"secular growth: last interval peak {max(off[-k:])} ps > first "
                     f"{max(off[:k])} ps + spread {spread} ps")
    return fails


def stuff_jitter_ps(bitrate_bps: int, dlc: int) -> int:
    """Upper bound of the difference in length between two command frames of ``dlc`` bytes:
    the worst-case number of stuff bits, ``floor((34 + 8n - 1) / 4)`` bit times."""
    return (worst_case_bits(dlc) - (47 + 8 * dlc)) * 10**12 // bitrate_bps


def default_k(bitrate_bps: int, dlc: int, period_ps: int, rho_ppm: float,
              sample_phase_ps: int = 0, t_post_ps: int = 0) -> int:
    """K of the sweeps: :func:`k_max` with the worst-case command latency, the sample phase
    and a margin of :data:`K_MARGIN_FRACTION` of T_s (a choice of K, not the feasibility
    rule, which has no margin)."""
    feas = check_feasibility(bitrate_bps, dlc, period_ps)
    d = feas.cmd_wc_ps + t_post_ps + sample_phase_ps
    return k_max(period_ps, d, int(period_ps * K_MARGIN_FRACTION), rho_ppm)


def sweep(period_ps: int, *, rates: tuple[int, ...] = RATES,
          dlcs: tuple[int, ...] = tuple(range(2, 9)), n_cycles: int = 3000,
          sync: bool = True, rho_ppm: float = THESIS_RHO_PPM,
          initial_offset_fraction: float = 0.348, jitter_phase: bool = True
          ) -> list[dict[str, Any]]:
    """Bit rate x data length, two nodes, slave period error ``rho_ppm``.

    Without sync the slave free-runs from ``t_dif(0) = 0.348·T_s`` (the thesis' 1.74 ms at
    5 ms). With sync it uses the thesis re-phase with K = :func:`default_k` (at least 1) and,
    with ``jitter_phase``, samples :func:`stuff_jitter_ps` after the reference reception (with
    φ = 0, the thesis' own choice, a next command with more stuff bits than the reference can
    arrive after the first sample: the knife edge described in docs/omni_drift.md).
    Infeasible cells (AT-8) are still run (``allow_infeasible``) and flagged."""
    cells = []
    for rate in rates:
        for dlc in dlcs:
            if sync:
                phase = stuff_jitter_ps(rate, dlc) if jitter_phase else 0
                k = default_k(rate, dlc, period_ps, rho_ppm, phase)
                run = run_two_node(rate, dlc, period_ps, rho_ppm, n_cycles, resync="thesis",
                                   k=k, sample_phase_ps=phase)
            else:
                run = run_two_node(rate, dlc, period_ps, rho_ppm, n_cycles,
                                   initial_offset_ps=int(initial_offset_fraction * period_ps))
            cells.append(run.summary())
    return cells


# ==========================================================================================
# AT-9: four slaves with realistic crystals
# ==========================================================================================


def at9_four_slaves(n_cycles: int = 10_000, *, sync: bool = True, k: int = 100,
                    rhos: tuple[float, ...] = (-100.0, -50.0, 50.0, 100.0),
                    bitrate_bps: int = 1_000_000, period_ps: int = PS_PER_MS,
                    feedback: bool = True) -> dict[str, Any]:
    """Thesis' node ids 0x04..0x20 at period errors ``rhos``, 4-axis fc 001 broadcast, Omni
    SYNC every K cycles (option ii) or none. Skew definitions (docs/omni_drift.md):

    * per-slave skew: ``max_n |s_n - (m_n + D_i)|`` with D_i the SYNC delivery latency (the
      slave's nominal sample instant after a re-phase, T_post = 0, φ = 0); without sync D_i is
      the NMT-start latency (the free-running grid is anchored there);
    * inter-slave sample skew: ``max_n (max_i s_{i,n} - min_i s_{i,n})``."""
    sched = Scheduler()
    bus = CanBus(sched, bitrate_bps)
    master = OmniMaster(sched, bitrate_bps=bitrate_bps, period_ps=period_ps, n_axes=4,
                        sync_every=k if sync else 0, n_cycles=n_cycles,
                        feedback_dlcs=(FEEDBACK_DLC,) * len(rhos) if feedback else ())
    bus.attach(master)
    slaves = []
    for node, rho in zip(oc.THESIS_SLAVE_IDS, rhos):
        s = OmniSlave(sched, node, bitrate_bps=bitrate_bps, period_ps=period_ps,
                      clock=clock_for_period_error(rho), feedback=feedback,
                      resync="sync_frame")
        bus.attach(s)
        slaves.append(s)
    master.start()
    sched.run_until(period_ps * (n_cycles + 3))
    ref = oc.omni_sync_frame() if sync else oc.nmt_frame(0, oc.NMT_START)
    d_nom = delivery_latency_ps(bitrate_bps, ref)
    results = [evaluate_slave(s, master, n_cycles, rho, d_nom) for s, rho in zip(slaves, rhos)]
    inter = list(inter_slave_skew_ps([s.control_log for s in slaves], master.cycle_log)
                 .values())
    n_all = sum(r.n for r in results)
    drops = sum(r.n_dropout for r in results)
    tau = 10**12 // bitrate_bps
    return {
        "sync": sync, "k": k, "n_cycles": n_cycles, "nominal_latency_ps": d_nom,
        "slaves": results,
        "skew_max_ps": max(r.skew_max_ps for r in results),
        "inter_slave_skew_max_ps": max(inter),
        "inter_slave_skew_ps": inter,
        "dropout_pct": 100.0 * drops / n_all,
        "bound_per_slave_ps": {r.name: int(abs(r.rho_ppm) * 1e-6 * k * period_ps) + 2 * tau
                               for r in results},
        "bound_inter_ps": int((max(rhos) - min(rhos)) * 1e-6 * k * period_ps) + 2 * tau,
        "bus_load": bus.load(0, period_ps * (n_cycles + 1)),
        "master": master, "slave_models": slaves,
    }


# ==========================================================================================
# AT-10: stress drift ±3618 ppm at 1 ms
# ==========================================================================================


def at10_stress(rho_ppm: float, *, sync: bool, n_cycles: int = 2000,
                t_post_ps: int = THESIS_T_POST_PS) -> dict[str, Any]:
    """T_s 1 ms, 2-byte command, 1 Mbit/s, T_post = 88.8 µs (Table 2-1).

    With sync: thesis re-phase, K = :func:`k_max` with the measured D and a 0.1 ms margin. A
    lagging slave (ρ > 0) samples at the reception (φ = 0, the thesis); a leading slave
    (ρ < 0) samples φ = T_s - D - margin/2 after it: half the margin before the next command,
    and its drift has the room ``T_s - D - margin`` (the same K) plus the other half.
    Without sync: free-running from t_dif(0) = T_s / 2, onset checked against the model."""
    period = PS_PER_MS
    margin = 100 * PS_PER_US
    d_probe = run_two_node(1_000_000, 2, period, rho_ppm, 4, t_post_ps=t_post_ps)
    d = d_probe.d_max_ps
    if sync:
        k = k_max(period, d, margin, rho_ppm)
        phase = 0 if rho_ppm > 0 else period - d - margin // 2
        run = run_two_node(1_000_000, 2, period, rho_ppm, n_cycles, resync="thesis", k=k,
                           sample_phase_ps=phase, t_post_ps=t_post_ps)
        return {"rho_ppm": rho_ppm, "sync": True, "k": k, "phase_ps": phase, "d_ps": d,
                "p_pct": run.result.p_pct, "n": run.result.n, "run": run}
    run = run_two_node(1_000_000, 2, period, rho_ppm, n_cycles, initial_offset_ps=period // 2,
                       t_post_ps=t_post_ps)
    off0 = run.result.offsets_ps[0]
    return {"rho_ppm": rho_ppm, "sync": False, "d_ps": d, "t_dif0_ps": off0,
            "onset_measured": run.result.onset,
            "n_drift_model": n_drift_model(off0, rho_ppm, period,
                                           (run.d_min_ps + run.d_max_ps) / 2),
            "n_drift_eq23": run.result.n_drift, "p_pct": run.result.p_pct,
            "n": run.result.n, "run": run}


# ==========================================================================================
# AT-13: the period shortened by a hard re-phase
# ==========================================================================================


def at13_sync_step(resync: str, rho_ppm: float, *, k: int = 10, n_cycles: int = 200,
                   bitrate_bps: int = 1_000_000, period_ps: int = PS_PER_MS,
                   dlc: int = 2) -> list[dict[str, int]]:
    """For every re-phase interval but the first (start transient): the measured change of
    the slave's period at the re-phase versus the accumulated drift since the previous one.

    * period before the re-phased sample (true ps): ``s_r - s_{r-1}``; deviation from the
      free-running slave period ``T_slave = T_s·(1 + ρ)``: ``T_slave - (s_r - s_{r-1})``
      (positive = shortened);
    * accumulated drift (model): ``j·(T_slave - T_s) - (D_r - D_prev)`` with j the samples
      since the previous re-phase and D the reference frames' delivery latencies (constant
      for the Omni SYNC, content-dependent for the thesis' command frames)."""
    run = run_two_node(bitrate_bps, dlc, period_ps, rho_ppm, n_cycles, resync=resync, k=k)
    slave, master = run.slave, run.master
    t_slave = slave.clock.true_ps(slave.clock.local_ps(0) + period_ps)
    d_sync = delivery_latency_ps(bitrate_bps, oc.omni_sync_frame())

    def ref_latency(n: int) -> int:  # reference frame of the re-phased sample n
        if resync == "thesis":
            return delivery_latency_ps(bitrate_bps, master.command_frame(n))
        return d_sync

    out = []
    log = slave.control_log
    prev: int | None = None
    seen = 0
    for i, tick in enumerate(log):
        if not tick.rephase:
            continue
        seen += 1
        if seen >= 3 and prev is not None:  # from the 2nd interval on (no start transient)
            j = i - prev
            period_before = tick.t_ps - log[i - 1].t_ps
            model = j * (t_slave - period_ps) - (ref_latency(tick.tick)
                                                 - ref_latency(log[prev].tick))
            out.append({"sample": tick.tick, "j": j, "period_before_ps": period_before,
                        "shortening_ps": t_slave - period_before, "model_ps": model})
        prev = i
    return out
