"""Benchmark: Omni-ID clock drift, four slaves at -100/-50/+50/+100 ppm (AT-9), pure Python.

No simulator: the transaction-level models of ``sim_models.omni`` (master, four slaves with
feedback, 1 Mbit/s, T_s = 1 ms, N = 10 000 cycles), once with the Omni SYNC every K = 100
cycles (option ii) and once without. Metrics (simulated time, exact; definitions in
``docs/omni_drift.md``):

* ``drift_skew_max_us_{sync,nosync}``: max over slaves and samples of
  ``|s_n - (m_n + D_i)|`` (slave sample instant vs master cycle instant + nominal latency);
* ``drift_inter_slave_skew_max_us_{sync,nosync}``: max over n of ``max_i s_i,n - min_i s_i,n``;
* ``drift_dropout_pct_{sync,nosync}``: Eq 2-2 over all four slaves.
"""

from __future__ import annotations

import pytest

from sim_models.omni import experiments as E
from sim_models.sim_time import PS_PER_US
from tb.tblib.metrics import record


@pytest.mark.bench
def test_bench_drift_four_slaves() -> None:
    metrics: dict[str, float] = {}
    for sync in (True, False):
        r = E.at9_four_slaves(10_000, sync=sync, feedback=True)
        key = "sync" if sync else "nosync"
        metrics[f"drift_skew_max_us_{key}"] = r["skew_max_ps"] / PS_PER_US
        metrics[f"drift_inter_slave_skew_max_us_{key}"] = r["inter_slave_skew_max_ps"] / PS_PER_US
        metrics[f"drift_dropout_pct_{key}"] = r["dropout_pct"]
        if sync:
            assert r["skew_max_ps"] <= max(r["bound_per_slave_ps"].values())
            assert r["inter_slave_skew_max_ps"] <= r["bound_inter_ps"]
            assert r["dropout_pct"] == 0.0
        else:
            assert r["skew_max_ps"] > max(r["bound_per_slave_ps"].values())
    record("drift", metrics)
