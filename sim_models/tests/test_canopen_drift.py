"""CiA 402 drives with drifting control loops on a CANopen SYNC cycle (sim_models.canopen_slave
.drift): the SYNC re-phase of CanopenSlave, the control source "applied at SYNC", the dropout
decision, the drift model and the checker's failure on a lost or late set-point."""

from __future__ import annotations

import pytest

from sim_models.canopen_slave import CanopenSlave
from sim_models.canopen_slave.drift import (
    DriveSpec,
    evaluate_drive,
    inter_slave_skew_ps,
    n_drift_model,
    n_drift_model_per_sync,
    position_setpoint,
    run_reference,
    sync_counter,
    sync_latency_ps,
)
from sim_models.sim_time import PS_PER_MS, PS_PER_US, Scheduler
from sim_models.tests.test_canopen_slave import NODE, Rig

T = PS_PER_MS
TAU = 10**12 // 1_000_000
HALF = T // 2


def evaluate(run, specs, overflow: int = 240):
    d_nom = min(sync_latency_ps(1_000_000, sync_counter(k, overflow))
                for k in range(1, max(overflow, 1) + 1))
    return [evaluate_drive(sl, run.sync_times_ps, lambda j, ch=s.channel: position_setpoint(ch, j),
                           period_ps=T, nominal_latency_ps=d_nom, phase_ps=s.phase_ps,
                           rho_ppm=s.rho_ppm)
            for s, sl in zip(specs, run.slaves)]


# ---------------------------------------------------------------------------------------------
# the slave: re-phase rule, tick index, source "applied"
# ---------------------------------------------------------------------------------------------


def test_sync_rephase_places_ticks_and_keeps_the_index() -> None:
    """Every SYNC re-anchors the grid at reception + phase; the index continues; the value is
    the set-point applied at that SYNC."""
    specs = [DriveSpec(1, 100.0, phase_ps=300 * PS_PER_US),
             DriveSpec(2, -100.0, phase_ps=300 * PS_PER_US)]
    run = run_reference(specs, 20, overflow=0)
    for s, sl in zip(specs, run.slaves):
        clock = sl.clock
        rx = [t for t, _ in sl.sync_log]
        assert [t for t, _l, _c in sl.rephase_log] == rx and len(rx) == 20
        assert {c for _t, _l, c in sl.rephase_log} == {"sync"}
        # the first SYNC: the tick before it (free-running since power-on) decides whether
        # this cycle was already sampled (less than T_s/2 before the grid point): then the
        # next tick would be a period after the grid point, and SYNC 2 re-places it
        g0 = clock.local_ps(rx[0]) + s.phase_ps
        last = [t for t in sl.control_log if t.t_ps < rx[0]][-1]
        skip = g0 - last.t_local_ps < HALF
        ticks = [t for t in sl.control_log if t.t_ps >= rx[0]]
        assert ticks[0].tick == last.tick + 1
        assert ticks[0].t_ps == clock.true_ps(clock.local_ps(rx[1 if skip else 0]) + s.phase_ps)
        # then one tick per cycle, exactly phase (local) after each SYNC's reception
        assert [t.t_ps for t in ticks[:20 - skip]] == [
            clock.true_ps(clock.local_ps(r) + s.phase_ps) for r in rx[int(skip):]]
        idx = [t.tick for t in sl.control_log]
        assert idx == list(range(idx[0], idx[0] + len(idx)))  # continues through re-phases
        assert [t.epoch for t in ticks[:20 - skip]] == list(range(1 + skip, 21))
        applied = {t: p for t, _n, p in sl.rpdo_applied}
        for t in ticks[1:20 - skip]:
            assert t.status == "new" and applied[t.value_t_ps] == t.value
            assert t.value_t_ps in rx and t.value_t_ps < t.t_ps


def test_rephase_of_a_fast_drive_that_already_sampled_this_cycle() -> None:
    """Phase 0, K = 10, a fast clock (-3618 ppm period error): its tick of the re-phase cycle
    comes before the SYNC, less than T_s/2 before the grid point, so the next tick is one period
    after the grid point (the cycle is not sampled twice)."""
    spec = DriveSpec(1, -3618.0, k=10, phase_ps=0)
    run = run_reference([spec], 40, overflow=0)
    sl = run.slaves[0]
    rx = [t for t, _ in sl.sync_log]
    assert [t for t, _l, _c in sl.rephase_log] == rx[::10]
    clock = sl.clock
    for r in rx[10::10]:
        before = [t for t in sl.control_log if t.t_ps < r][-1]
        after = next(t for t in sl.control_log if t.t_ps >= r)
        assert 0 < r - before.t_ps < HALF
        assert after.t_ps == clock.true_ps(clock.local_ps(r) + T)
        assert after.tick == before.tick + 1


@pytest.mark.parametrize("source", [("applied", 1), 1])
def test_control_source_applied_vs_reception(source) -> None:
    """("applied", 1) takes a synchronous RPDO when the SYNC applies it, 1 when it is received;
    after switching RPDO1 to type 255 both take it on reception."""
    rig = Rig(boot_time_ps=0, control_period_ps=T, control_offset_ps=HALF,
              control_source=source)
    rig.boot()
    rig.nmt(0x01)
    assert rig.sdo_write(0x1400, 2, 1, 1)[0] == 0x60  # synchronous
    t0 = rig.now
    rig.send(0x200 + NODE, b"\x0f\x00\x01\x00\x00\x00", run_ps=300 * PS_PER_US)
    rig.send(0x080, b"", run_ps=2 * T)
    t_rx = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x205][-1]
    t_sync = [t for t, _ in rig.slave.sync_log][-1]
    ticks = [t for t in rig.slave.control_log if t.t_ps > t0 and t.value is not None]
    assert ticks[0].value == b"\x0f\x00\x01\x00\x00\x00"
    assert ticks[0].value_t_ps == (t_sync if source == ("applied", 1) else t_rx)
    assert rig.sdo_write(0x1400, 2, 255, 1)[0] == 0x60  # event-driven: applied on reception
    rig.send(0x200 + NODE, b"\x0f\x00\x02\x00\x00\x00", run_ps=2 * T)
    t_rx = [t for t, m in rig.slave.rx_log if m.arbitration_id == 0x205][-1]
    last = rig.slave.control_log[-1]
    assert last.value == b"\x0f\x00\x02\x00\x00\x00" and last.value_t_ps == t_rx


def test_control_resync_arguments_are_checked() -> None:
    sched = Scheduler()
    kw = {"bitrate_bps": 1_000_000, "control_period_ps": T}
    for bad in ({"control_resync": "pll"}, {"control_resync": "sync", "control_phase_ps": T},
                {"control_resync": "sync", "control_resync_k": 0}):
        with pytest.raises(ValueError):
            CanopenSlave(sched, 3, **kw, **bad)
    with pytest.raises(ValueError):
        CanopenSlave(sched, 3, bitrate_bps=1_000_000, control_resync="sync")


# ---------------------------------------------------------------------------------------------
# drift: free-running onset, re-aligned drives
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("rho, resync, phase", [
    (3618.0, "first_sync", 700 * PS_PER_US),
    (-3618.0, "first_sync", 500 * PS_PER_US),
    (1000.0, "first_sync", 900 * PS_PER_US),
    (-1000.0, "first_sync", 150 * PS_PER_US),
    (3618.0, "none", None),
    (-3618.0, "none", None),
])
def test_free_running_onset_is_the_drift_model(rho: float, resync: str,
                                               phase: int | None) -> None:
    """Without re-alignment the first dropout is where n_drift_model puts it (SYNC without a
    counter byte: a constant SYNC latency, so exactly), and every later sample is lost: too new
    for a slow drive, stale for a fast one (the thesis' Eq 2-2 / 2-3 counting). "first_sync":
    anchored once, phase after the first SYNC; "none": free-running from power-on, its phase
    is where its first tick after SYNC 1's apply instant happens to be."""
    n = 300
    d = sync_latency_ps(1_000_000)
    assert d == 48 * PS_PER_US
    spec = DriveSpec(1, rho, resync, phase_ps=phase or 0)
    run = run_reference([spec], n, overflow=0)
    if phase is None:
        t1 = run.sync_times_ps[0] + d
        first = next(t.t_ps for t in run.slaves[0].control_log if t.t_ps >= t1)
        spec = DriveSpec(1, rho, resync, phase_ps=first - t1)
    (r,) = evaluate(run, [spec], overflow=0)
    model = n_drift_model(r.t_dif0_ps, rho, T, d)
    assert r.onset_sample == model, (r.summary(), model)
    assert r.n == n - 2 and r.n_dropout == r.n - model and r.n_drift == model
    kind = "too_new" if rho > 0 else "stale"
    assert r.kinds[kind] == r.n_dropout and r.n_dropout > 0
    assert [c for c, _ in r.dropouts] == list(range(r.onset_cycle, n))
    assert r.rephases == (1 if resync == "first_sync" else 0)
    # the sample crossed the SYNC apply instant at the onset
    off = r.offsets_ps
    if rho > 0:
        assert off[model - 1] < T + d <= off[model]
    else:
        assert off[model] <= d < off[model - 1]


def test_onset_with_a_counter_byte() -> None:
    """With the SYNC counter byte (1019h = 240) its stuff bits move the apply instant by up to
    2 bit times: at +-3618 ppm (3.6 us per cycle) the onset is the model's with the shortest
    SYNC within one sample; at +-100 ppm (0.1 us per cycle) the two extreme SYNC lengths give
    models 20 samples apart. The model with each SYNC's own latency is exact in every case."""
    specs = [DriveSpec(1, 3618.0, "first_sync", phase_ps=700 * PS_PER_US),
             DriveSpec(2, -3618.0, "first_sync", phase_ps=500 * PS_PER_US),
             DriveSpec(3, 100.0, "first_sync", phase_ps=975 * PS_PER_US),
             DriveSpec(4, -100.0, "first_sync", phase_ps=25 * PS_PER_US)]
    run = run_reference(specs, 400)

    def d_of(c: int) -> int:
        return sync_latency_ps(1_000_000, sync_counter(c, 240))

    d_max = max(d_of(c) for c in range(1, 241))
    for s, r in zip(specs, evaluate(run, specs)):
        model = n_drift_model(r.t_dif0_ps, s.rho_ppm, T, r.nominal_latency_ps)
        other = n_drift_model(r.t_dif0_ps, s.rho_ppm, T, d_max)
        assert r.onset_sample is not None
        assert min(model, other) <= r.onset_sample <= max(model, other)
        if abs(s.rho_ppm) > 1000:
            assert abs(r.onset_sample - model) <= 1, (r, model)
        assert r.onset_sample == n_drift_model_per_sync(r.t_dif0_ps, s.rho_ppm, T, d_of)


@pytest.mark.parametrize("k, rhos", [(1, (-100.0, -50.0, 50.0, 100.0)),
                                     (10, (-100.0, -50.0, 50.0, 100.0)),
                                     (10, (-3618.0, 3618.0)),
                                     (100, (-3618.0, 3618.0))])
def test_rephase_every_k_syncs_keeps_dropout_zero_and_skew_bounded(k: int, rhos) -> None:
    """Drives re-aligned every K SYNCs half a period after the SYNC: no dropout, per-drive skew
    <= |rho|·K·T_s + 2 bit times (SYNC counter stuffing), inter-drive skew <= (|rho_i| +
    |rho_j|)·K·T_s + 2 bit times."""
    n = 300
    specs = [DriveSpec(i + 1, rho, k=k, phase_ps=HALF) for i, rho in enumerate(rhos)]
    run = run_reference(specs, n)
    res = evaluate(run, specs)
    for s, r in zip(specs, res):
        assert r.n == n - 2 and r.n_dropout == 0 and not r.never_sampled, r.summary()
        assert r.status == {"new": n - 2}
        assert r.rephases == (n + k - 1) // k
        assert r.skew_max_ps <= abs(s.rho_ppm) * 1e-6 * k * T + 2 * TAU, r.summary()
        # it is the drift, not only the jitter: K periods of drift show up
        if k >= 10:
            assert r.skew_max_ps >= abs(s.rho_ppm) * 1e-6 * (k - 1) * T, r.summary()
    inter = inter_slave_skew_ps(res)
    assert len(inter) == n
    spread = sorted(abs(x) for x in rhos)[-2:]
    assert max(inter) <= sum(spread) * 1e-6 * k * T + 2 * TAU


def test_leading_drive_needs_a_phase_beyond_its_drift() -> None:
    """K = 10 at -3618 ppm drifts 36.2 us ahead between re-phases. Sampling 20 us after the SYNC
    the last 5 samples of every window come before their SYNC applied the set-point (stale),
    and the re-phase rule brings the index back (no lasting slip); at 50 us nothing is lost."""
    n = 200
    bad, good = (DriveSpec(1, -3618.0, k=10, phase_ps=20 * PS_PER_US),
                 DriveSpec(2, -3618.0, k=10, phase_ps=50 * PS_PER_US))
    run = run_reference([bad, good], n, overflow=0)
    r_bad, r_good = evaluate(run, [bad, good], overflow=0)
    assert r_good.n_dropout == 0
    # window of SYNC m (m = 1, 11, 21, ...): samples m + 6 .. m + 10 are early
    want = [c for c in range(2, n) if (c - 1) % 10 in (6, 7, 8, 9, 0)]
    assert [c for c, _ in r_bad.dropouts] == want
    assert set(r_bad.kinds) == {"stale", "too_new", "missing", "foreign"}
    assert r_bad.kinds["stale"] == len(want) and r_bad.n_dropout == len(want)


# ---------------------------------------------------------------------------------------------
# the checker fails on a lost, late or foreign set-point
# ---------------------------------------------------------------------------------------------


def test_dropout_checker_sees_a_lost_and_a_late_setpoint() -> None:
    """Set-point 50 of channel 0 never sent: the sample of cycle 51 is stale, set-point 50 was
    never sampled. Set-point 60 of channel 1 sent 1.3 ms late (after set-point 61): nothing is
    applied at SYNC 61 (cycle 61 stale), SYNC 62 applies the late 60 (cycle 62 stale) and 61 is
    lost. A drive checked against another channel's set-points: every sample is foreign."""
    n = 100
    specs = [DriveSpec(1, 100.0, phase_ps=HALF), DriveSpec(2, -100.0, phase_ps=HALF)]
    run = run_reference(specs, n, drop=[(0, 50)], delay_ps={(1, 60): T + 300 * PS_PER_US})
    r0, r1 = evaluate(run, specs)
    assert r0.dropouts == [(51, "stale")] and r0.never_sampled == [50], r0.summary()
    assert r0.n_dropout == 1 and r0.onset_cycle == 51 and r0.status["missing"] == 1
    assert r1.dropouts == [(61, "stale"), (62, "stale")] and r1.never_sampled == [61]
    assert r1.status["missing"] == 1
    wrong = evaluate_drive(run.slaves[0], run.sync_times_ps, lambda j: position_setpoint(1, j),
                           period_ps=T, nominal_latency_ps=r0.nominal_latency_ps,
                           phase_ps=HALF)
    assert wrong.n_dropout == wrong.n == n - 2 and wrong.kinds["foreign"] == n - 2
    # the same run without the faults is clean
    clean = evaluate(run_reference(specs, n), specs)
    assert [r.n_dropout for r in clean] == [0, 0]
