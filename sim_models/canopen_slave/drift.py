"""Clock drift of CiA 402 drives on a CANopen SYNC cycle: dropout decision, skew, drift model and
a transaction-level reference network (pure Python).

The CANopen counterpart of ``sim_models.omni.experiments`` (the thesis' dropout definition,
Eq 2-2 / 2-3, applied to a CiA 301 SYNC cycle). Timing of the cycle (CiA 301, synchronous
RPDO, transmission type 1..240):

* cycle k is ``[SYNC k, SYNC k+1)``; the master sends set-point k right after SYNC k;
* the drive applies the set-point received before a SYNC at that SYNC, so SYNC k+1 applies
  set-point k (``rpdo_applied``);
* the drive's control loop (:class:`~sim_models.canopen_slave.slave.CanopenSlave` with
  ``control_source=("applied", n)``) samples the applied value on its own drifting clock. The
  sample that belongs to cycle c should see set-point ``c - lag`` (``lag`` = 1 for the applied
  value; 0 for a loop that samples the RPDO on reception).

Which sample belongs to which cycle (the thesis' "n-th sample needs the n-th command"): the
first tick at or after ``SYNC 1 + D + phase - T_s/2`` (D = nominal SYNC latency, SOF to the
drive's reception at the end of frame) belongs to cycle 1 and every later tick of the drive's
``control_log`` to the next cycle. A re-aligned drive keeps its ticks at ``SYNC + D + phase``;
a free-running one drifts by ``rho·T_s`` per cycle (``rho`` = period error, positive = the
drive's period is longer, as in ``sim_models.omni``), and once its sample crosses a SYNC apply
instant it samples one set-point off, for good: every later sample is a dropout, exactly as the
thesis counts it.

A sample is a **dropout** when the value it took is not set-point ``c - lag``: ``stale`` (an
older set-point, e.g. sampled before the SYNC applied the new one), ``too_new`` (a later one:
the needed set-point was overwritten by the next SYNC before the drive sampled it),
``missing`` (nothing arrived yet) or ``foreign`` (a value no cycle of the run carries). Set-points
that no sample ever took are listed in ``never_sampled`` (lost / overwritten commands).

Drift model (adapted from the Omni-ID one): the offset of sample n from its cycle's SYNC SOF is
``t_dif(n) = t_dif(0) + n·rho·T_s``; the sample holds the right set-point while
``D < t_dif(n) < T_s + D`` (between the apply at this cycle's SYNC and the next SYNC's), so the
onset is ``ceil((T_s + D - t_dif(0)) / (rho·T_s))`` for rho > 0 and ``ceil((t_dif(0) - D) /
(|rho|·T_s))`` for rho < 0 (:func:`n_drift_model`, with D the SYNC latency instead of the
command latency).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Hashable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import can

from sim_models.can_bus import CanBus, QueueNode, frame_length_bits
from sim_models.canopen_slave.network import make_message
from sim_models.canopen_slave.pdo import encode_map_entry
from sim_models.canopen_slave.slave import CanopenSlave
from sim_models.omni.experiments import n_drift_model as omni_n_drift_model
from sim_models.omni.slave import clock_for_period_error
from sim_models.sim_time import PS_PER_MS, Scheduler

__all__ = [
    "DriveDrift",
    "DriveSpec",
    "ReferenceRun",
    "clock_for_period_error",
    "evaluate_drive",
    "inter_slave_skew_ps",
    "n_drift_model",
    "n_drift_model_per_sync",
    "position_setpoint",
    "run_reference",
    "sync_counter",
    "sync_latency_ps",
]

DROPOUT_KINDS = ("stale", "too_new", "missing", "foreign")


# ==========================================================================================
# encoding, clocks, model formulas
# ==========================================================================================


def position_setpoint(axis: int, k: int) -> bytes:
    """Set-point of cycle k for master channel ``axis`` (0-based) as a 4-byte target position
    607Ah: ``axis << 24 | k`` little-endian (the position half of ``tb``'s ``sp_default``): it
    changes every cycle and differs between axes. Unique for k < 2^24."""
    if not 0 <= k < 1 << 24:
        raise ValueError(f"cycle {k} out of range for the 24-bit cycle field")
    return (axis << 24 | k).to_bytes(4, "little")


def sync_counter(k: int, overflow: int) -> int | None:
    """Counter byte of the k-th SYNC (1-based) with 1019h = ``overflow`` (None: no counter)."""
    return None if overflow == 0 else (k - 1) % overflow + 1


def sync_frame(counter: int | None) -> can.Message:
    return make_message(0x080, b"" if counter is None else bytes([counter]))


def sync_latency_ps(bitrate_bps: int, counter: int | None = None) -> int:
    """SOF of a SYNC to its reception at the end of frame: ``(frame bits - 3)`` bit times (the
    instant a drive applies its synchronous RPDOs)."""
    bits = frame_length_bits(sync_frame(counter)) - 3
    return bits * 10**12 // bitrate_bps


def n_drift_model(t_dif0_ps: float, rho_ppm: float, period_ps: int, d_ps: float) -> int:
    """Index of the first dropout sample of a free-running drive (0 = the sample of the first
    counted cycle, offset ``t_dif0_ps`` from its SYNC's SOF); ``d_ps`` = SYNC latency (the
    apply instant). A lagging drive (rho > 0) drops once ``t_dif(n) >= T_s + D`` (the next SYNC
    applied the next set-point first), a leading one once ``t_dif(n) <= D`` (it samples before
    its SYNC applied the set-point). The Omni-ID formula with the SYNC's latency in place of
    the command's."""
    return omni_n_drift_model(t_dif0_ps, rho_ppm, period_ps, d_ps)


def n_drift_model_per_sync(t_dif0_ps: float, rho_ppm: float, period_ps: int,
                           d_of_cycle: Callable[[int], int], lag: int = 1,
                           n_max: int = 10**6) -> int | None:
    """:func:`n_drift_model` with each SYNC's own latency (a SYNC counter byte's stuff bits make
    it vary by up to 2 bit times): sample n (cycle ``c = 1 + lag + n``, offset ``t_dif0 +
    n·rho·T_s`` from the SOF of SYNC c) is lost once ``t_dif(n) >= T_s + d_of_cycle(c + 1)``
    (rho > 0) or ``t_dif(n) <= d_of_cycle(c)`` (rho < 0). None if not within ``n_max``."""
    step = rho_ppm * 1e-6 * period_ps
    if step == 0:
        raise ValueError("no drift, no onset")
    for n in range(n_max):
        c = 1 + lag + n
        t = t_dif0_ps + n * step
        if (step > 0 and t >= period_ps + d_of_cycle(c + 1)) or (
                step < 0 and t <= d_of_cycle(c)):
            return n
    return None


# ==========================================================================================
# evaluation of one drive
# ==========================================================================================


@dataclass
class DriveDrift:
    """Measured figures of one drive's control loop over a run (times in true ps)."""

    name: str
    rho_ppm: float
    n: int  #: samples counted (cycles 1 + lag .. N - 1)
    n_dropout: int
    p_pct: float  #: Eq 2-2: 100 · N_dropout / N
    n_drift: int  #: Eq 2-3: N - N_dropout
    onset_cycle: int | None  #: cycle of the first dropout sample
    onset_sample: int | None  #: its index, 0 = the sample of the first counted cycle
    kinds: dict[str, int]  #: dropouts by kind (DROPOUT_KINDS)
    status: dict[str, int]  #: ControlTick.status (new / overwritten / missing) of the samples
    never_sampled: list[int]  #: set-points needed by a counted cycle that no sample took
    nominal_latency_ps: int  #: D of the skew definition
    phase_ps: int
    skew_max_ps: int  #: max |s_c - (SYNC_c + D + phase)| over the counted samples
    rephases: int  #: SYNC re-phases of the drive during the run
    t_dif0_ps: int | None  #: offset of the first counted sample from its SYNC's SOF
    samples: dict[int, int] = field(repr=False)  #: cycle -> sample instant (cycles 1..N)
    offsets_ps: list[int] = field(repr=False)  #: t_dif of every counted sample, in order
    dropouts: list[tuple[int, str]] = field(repr=False)  #: (cycle, kind)

    def summary(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("samples", "offsets_ps", "dropouts"):
            d.pop(k)
        return d


def evaluate_drive(slave: CanopenSlave, sync_times_ps: Sequence[int],
                   expected: Callable[[int], Hashable], *, period_ps: int,
                   nominal_latency_ps: int, phase_ps: int = 0, lag: int = 1,
                   rho_ppm: float = 0.0) -> DriveDrift:
    """The dropout decision and the skew of one drive (see the module docstring).

    ``sync_times_ps[k - 1]`` is the SOF of SYNC k (k = 1..N, as the master sent them);
    ``expected(j)`` the value the drive's control source delivers for set-point j (j = 1..N).
    Cycles c = 1 + lag .. N - 1 are counted (a cycle's window is closed by the next SYNC; the
    last one has none, so a late sample would still see its set-point there); the sample
    assigned to cycle c should hold ``expected(c - lag)``. ``samples`` holds every cycle
    1..N (for the inter-drive skew)."""
    n_cycles = len(sync_times_ps)
    if n_cycles == 0:
        raise ValueError("no SYNC")
    inverse = {expected(j): j for j in range(1, n_cycles + 1)}
    if len(inverse) != n_cycles:
        raise ValueError("expected() must give a distinct value per set-point")
    log = slave.control_log
    t_anchor = sync_times_ps[0] + nominal_latency_ps + phase_ps - period_ps // 2
    i0 = next((i for i, t in enumerate(log) if t.t_ps >= t_anchor), len(log))
    samples: dict[int, int] = {}
    offsets: list[int] = []
    dropouts: list[tuple[int, str]] = []
    status: Counter = Counter()
    sampled: set[int] = set()
    skew = 0
    onset_cycle = onset_sample = None
    first_counted = 1 + lag
    for i in range(i0, len(log)):
        c = 1 + i - i0
        if c > n_cycles:
            break
        tick = log[i]
        samples[c] = tick.t_ps
        if not first_counted <= c < n_cycles:
            continue
        t_sync = sync_times_ps[c - 1]
        offsets.append(tick.t_ps - t_sync)
        skew = max(skew, abs(tick.t_ps - (t_sync + nominal_latency_ps + phase_ps)))
        status[tick.status] += 1
        want = c - lag
        got = None if tick.value is None else inverse.get(tick.value)
        if got is not None:
            sampled.add(got)
        if got == want:
            continue
        kind = ("missing" if tick.value is None else "foreign" if got is None
                else "stale" if got < want else "too_new")
        dropouts.append((c, kind))
        if onset_cycle is None:
            onset_cycle, onset_sample = c, c - first_counted
    n = len(offsets)
    needed = range(1, n_cycles - lag) if n else range(0)
    t_first, t_last = sync_times_ps[0], sync_times_ps[-1] + period_ps
    rephases = sum(1 for t, _l, _c in slave.rephase_log if t_first <= t < t_last)
    kinds = Counter(k for _, k in dropouts)
    return DriveDrift(
        slave.name, rho_ppm, n, len(dropouts), 100.0 * len(dropouts) / n if n else 0.0,
        n - len(dropouts), onset_cycle, onset_sample, {k: kinds[k] for k in DROPOUT_KINDS},
        dict(status), [j for j in needed if j not in sampled], nominal_latency_ps, phase_ps,
        skew, rephases, offsets[0] if offsets else None, samples, offsets, dropouts)


def inter_slave_skew_ps(results: Sequence[DriveDrift]) -> list[int]:
    """Per cycle sampled by every drive: latest minus earliest sample instant."""
    common = set.intersection(*(set(r.samples) for r in results)) if results else set()
    return [max(r.samples[c] for r in results) - min(r.samples[c] for r in results)
            for c in sorted(common)]


# ==========================================================================================
# transaction-level reference network
# ==========================================================================================


@dataclass(frozen=True)
class DriveSpec:
    """One drive of a drift experiment.

    ``rho_ppm`` is the period error of its crystal; ``resync`` / ``k`` / ``phase_ps`` are the
    control loop's ``control_resync`` / ``control_resync_k`` / ``control_phase_ps``; ``axis``
    the master channel whose set-point PDO (200h + axis + 1) it consumes (default: its own,
    node - 1; another drive's makes it a second consumer of that PDO, e.g. a gantry axis);
    ``feedback``: its TPDO1 (6064h, every SYNC) stays valid."""

    node: int
    rho_ppm: float
    resync: str = "sync"
    k: int = 1
    phase_ps: int = 0
    axis: int | None = None
    feedback: bool = True

    @property
    def channel(self) -> int:
        return self.node - 1 if self.axis is None else self.axis


def drive_kwargs(spec: DriveSpec, period_ps: int) -> dict[str, Any]:
    """CanopenSlave arguments of a drive's control loop (clock and re-alignment)."""
    return {"clock": clock_for_period_error(spec.rho_ppm), "control_period_ps": period_ps,
            "control_source": ("applied", 1), "control_resync": spec.resync,
            "control_resync_k": spec.k, "control_phase_ps": spec.phase_ps}


@dataclass
class ReferenceRun:
    sync_times_ps: list[int]
    slaves: list[CanopenSlave]
    master: QueueNode
    bus: CanBus
    sched: Scheduler


def run_reference(specs: Sequence[DriveSpec], n_cycles: int, *, period_ps: int = PS_PER_MS,
                  bitrate_bps: int = 1_000_000, overflow: int = 240,
                  sp: Callable[[int, int], bytes] = position_setpoint,
                  first_sync_ps: int = 5 * PS_PER_MS,
                  drop: Sequence[tuple[int, int]] = (),
                  delay_ps: dict[tuple[int, int], int] | None = None) -> ReferenceRun:
    """Drives on an ideal master: SYNC k at ``first_sync_ps + (k - 1)·T_s`` (counter byte with
    1019h = ``overflow``, 0 = none), then set-point k of every channel (RPDO 200h + ch + 1,
    ``sp(ch, k)``, 4 bytes into 607Ah, synchronous type 1) right after it. Drives boot at
    t = 0 (1 ms), are configured directly in their OD and started by NMT at 3 ms.

    Fault injection for the checker: ``drop`` = (channel, k) set-points never sent;
    ``delay_ps`` = (channel, k) -> extra delay of that set-point after SYNC k."""
    sched = Scheduler()
    bus = CanBus(sched, bitrate_bps)
    master = QueueNode("master", bitrate_bps)
    bus.attach(master)
    slaves = []
    for s in specs:
        slave = CanopenSlave(sched, s.node, bitrate_bps=bitrate_bps, **drive_kwargs(s, period_ps))
        bus.attach(slave)
        slaves.append(slave)
    sched.run_until(2 * PS_PER_MS)
    for s, slave in zip(specs, slaves):
        # the configuration the RTL bench writes by SDO (tb/tblib/pdo_cycle.py), written here
        # directly into the OD: RPDO1 = 607Ah, synchronous; TPDO1 = 6064h, every SYNC
        slave.write(0x1400, 1, 0x200 + s.channel + 1)
        slave.write(0x1400, 2, 1)
        slave.write(0x1600, 0, 0)
        slave.write(0x1600, 1, encode_map_entry(0x607A, 0, 32))
        slave.write(0x1600, 0, 1)
        slave.write(0x1A00, 0, 0)
        slave.write(0x1A00, 1, encode_map_entry(0x6064, 0, 32))
        slave.write(0x1A00, 0, 1)
        slave.write(0x1800, 1, (0 if s.feedback else 0x8000_0000) | 0x180 + s.node)
        if overflow:
            slave.write(0x1019, 0, overflow)
    channels = sorted({s.channel for s in specs})
    master.send(make_message(0x000, b"\x01\x00"))
    sched.run_until(3 * PS_PER_MS)
    sync_times = [first_sync_ps + (k - 1) * period_ps for k in range(1, n_cycles + 1)]
    dropped = set(drop)
    delays = delay_ps or {}

    def cycle(k: int) -> None:
        master.send(sync_frame(sync_counter(k, overflow)))
        for ch in channels:
            if (ch, k) in dropped:
                continue
            msg = make_message(0x200 + ch + 1, sp(ch, k))
            if (ch, k) in delays:
                sched.call_later(delays[(ch, k)], master.send, msg)
            else:
                master.send(msg)

    for k, t in enumerate(sync_times, 1):
        sched.call_at(t, cycle, k)
    sched.run_until(sync_times[-1] + 2 * period_ps)
    return ReferenceRun(sync_times, slaves, master, bus, sched)
