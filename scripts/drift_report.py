#!/usr/bin/env python3
"""Clock-drift report of the Omni-ID models (``make drift-report``).

Runs the transaction-level experiments of ``sim_models.omni.experiments`` and writes to
``build/drift/``:

* ``at5_offset.png``: slave offset t_dif(n) for the thesis' AT-5 case (T_s 5 ms, +3618 ppm,
  1.74 ms initial offset, 1 Mbit/s) without sync and with the thesis re-phase (K = 10);
* ``four_slaves_offset.png``: sample offset s_n - (m_n + D) of four slaves at -100..+100 ppm,
  T_s 1 ms, 1 Mbit/s, with Omni SYNC every 100 cycles and without sync;
* ``dropout_sweep.png``: dropout vs data length per bit rate, T_s 5 ms and 1 ms, without and
  with sync (the thesis' Figs 2-18/2-19 and 3-24..3-28); infeasible cells marked;
* ``dropout_table.md`` / ``dropout_table.json``: the per-cell numbers (p, onset, K; table code
  in ``sim_models/omni/report.py``), plus ``summary.json``.

``--docs`` also copies the three plots (small PNGs) to ``docs/img/`` and rewrites the table
block of ``docs/omni_drift.md`` (between its markers; nothing else in the file). ``--cycles``
shortens the sweeps (default 3000, the thesis' N; ``--docs`` needs the default), ``--out``
writes elsewhere, ``--at9-cycles`` / ``--at10-cycles`` shorten the other runs (tests).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_models.omni import experiments as E  # noqa: E402
from sim_models.omni import report  # noqa: E402
from sim_models.sim_time import PS_PER_MS, PS_PER_US  # noqa: E402

OUT = ROOT / "build" / "drift"
DOCS_IMG = ROOT / "docs" / "img"
DOCS_MD = ROOT / "docs" / "omni_drift.md"
DOCS_CYCLES = 3000  #: N of the table in the docs
PLOTS = ("at5_offset.png", "four_slaves_offset.png", "dropout_sweep.png")


def plot_at5(path: Path) -> dict:
    free = E.at5_drift_reproduction(300)
    sync = E.at6_sync_removes_drift(2, n_cycles=300, k=10)
    fig, ax = plt.subplots(figsize=(6.4, 3.4), dpi=90)
    off_free = [o / PS_PER_MS for o in free["offsets_ps"]]
    off_sync = [o / PS_PER_MS for o in sync["run"].result.offsets_ps]
    ax.plot(off_free, label="no sync (free-running)", lw=1.2)
    ax.plot(off_sync, label="thesis re-phase, K = 10", lw=1.2)
    ax.axhline(5 + free["run"].d_min_ps / PS_PER_MS, color="grey", ls=":", lw=1,
               label="T_s + D: next command overwrites")
    ax.axvline(free["onset_measured"], color="red", ls="--", lw=1,
               label=f"dropout onset n = {free['onset_measured']}")
    ax.plot([0, 40], [off_free[0], off_free[40]], "ko", ms=3)
    ax.annotate(f"{off_free[0]:.2f} -> {off_free[40]:.2f} ms after 40 periods", (40, off_free[40]),
                xytext=(60, 1.0), fontsize=8, arrowprops={"arrowstyle": "->", "lw": 0.6})
    ax.set_xlabel("sample n (T_s = 5 ms)")
    ax.set_ylabel("offset t_dif(n) = s_n - m_n [ms]")
    ax.set_title("AT-5/AT-6: slave +3618 ppm, 1 Mbit/s, 2-byte command", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return {k: v for k, v in free.items() if k not in ("offsets_ps", "run")} | {
        "sync_offset_band_ms": (sync["offset_min_ps"] / PS_PER_MS,
                                sync["offset_max_ps"] / PS_PER_MS),
        "sync_p_pct": sync["p_pct"]}


def plot_four(path: Path, n_cycles: int = 10_000) -> dict:
    res = {}
    fig, axes = plt.subplots(1, 2, figsize=(8.0, 3.2), dpi=90)
    for ax, sync in zip(axes, (False, True)):
        r = E.at9_four_slaves(n_cycles, sync=sync, feedback=True)
        for s in r["slaves"]:
            y = [(o - s.nominal_latency_ps) / PS_PER_US for o in s.offsets_ps]
            ax.plot(y, lw=0.8, label=f"{s.name} {s.rho_ppm:+.0f} ppm")
        if sync:
            ax.set_xlim(0, min(500, n_cycles))  # the pattern repeats every K = 100 samples
        n_txt = f"{n_cycles:_}".replace("_", " ")
        ax.set_title((f"Omni SYNC every 100 cycles (first 500 of {n_txt})" if sync
                      else "no sync") + ", T_s 1 ms", fontsize=9)
        ax.set_xlabel("sample n")
        ax.grid(alpha=0.3)
        res["sync" if sync else "nosync"] = {
            "skew_max_us": r["skew_max_ps"] / PS_PER_US,
            "inter_slave_skew_max_us": r["inter_slave_skew_max_ps"] / PS_PER_US,
            "dropout_pct": r["dropout_pct"],
            "per_slave": [s.summary() for s in r["slaves"]],
            "bus_load": r["bus_load"]}
    axes[0].set_ylabel("s_n - (m_n + D) [us]")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return res


def plot_sweep(cells: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(8.0, 6.0), dpi=90, sharex=True)
    for row, period_ms in enumerate((5, 1)):
        for col, sync in enumerate((False, True)):
            ax = axes[row][col]
            for rate in E.RATES:
                sel = [c for c in cells if c["period_ms"] == period_ms and c["sync"] == sync
                       and c["bitrate_bps"] == rate]
                x = [c["dlc"] for c in sel]
                ax.plot(x, [c["p_pct"] for c in sel], marker="o", ms=3, lw=1,
                        label=f"{rate // 1000} kbit/s")
                bad = [c for c in sel if not c["feasible"]]
                if bad:
                    ax.plot([c["dlc"] for c in bad], [c["p_pct"] for c in bad], "kx", ms=7)
            ax.set_title(f"T_s {period_ms} ms, " + ("thesis re-phase" if sync else "no sync"),
                         fontsize=9)
            ax.set_ylim(-3, 103)
            ax.grid(alpha=0.3)
            if row == 1:
                ax.set_xlabel("command data length [bytes]")
            if col == 0:
                ax.set_ylabel("dropout p [%] (Eq 2-2)")
    axes[0][0].legend(fontsize=7)
    axes[1][1].text(2, 80, "x = flagged infeasible (AT-8)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=DOCS_CYCLES, help="N of the sweeps")
    ap.add_argument("--at9-cycles", type=int, default=10_000, help="N of the AT-9 runs")
    ap.add_argument("--at10-cycles", type=int, default=2000, help="N of the AT-10 runs")
    ap.add_argument("--out", type=Path, default=OUT, help="output directory")
    ap.add_argument("--docs", action="store_true",
                    help="copy the plots to docs/img/ and the table into docs/omni_drift.md")
    args = ap.parse_args(argv)
    if args.docs and args.cycles != DOCS_CYCLES:
        ap.error(f"--docs writes the documented N = {DOCS_CYCLES}; drop --cycles")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    summary = {"at5": plot_at5(out / PLOTS[0])}
    summary["at9"] = plot_four(out / PLOTS[1], args.at9_cycles)
    cells = report.sweep_cells(args.cycles)
    plot_sweep(cells, out / PLOTS[2])
    table = report.dropout_table_md(cells, args.cycles)
    (out / "dropout_table.json").write_text(json.dumps(cells, indent=1) + "\n")
    (out / "dropout_table.md").write_text(
        "# Dropout per cell, bit-rate x data-length sweeps\n\n"
        + report.dropout_table_md(cells, args.cycles, heading="##"))
    summary["at10"] = {f"{rho:+.0f}_{'sync' if s else 'nosync'}":
                       {k: v for k, v in E.at10_stress(rho, sync=s, n_cycles=args.at10_cycles)
                        .items() if k != "run"}
                       for rho in (3618.0, -3618.0) for s in (True, False)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str) + "\n")
    if args.docs:
        DOCS_IMG.mkdir(parents=True, exist_ok=True)
        for name in PLOTS:
            shutil.copy(out / name, DOCS_IMG / f"omni_{name}")
        DOCS_MD.write_text(report.replace_docs_block(DOCS_MD.read_text(), table))
    a5, a9 = summary["at5"], summary["at9"]
    print(f"AT-5: offset {a5['t_dif0_ms']:.3f} -> {a5['offset_after_40_ms']:.4f} ms after 40 "
          f"periods; N_drift model {a5['n_drift_model']}, measured onset "
          f"{a5['onset_measured']}, p = {a5['p_pct']:.2f} %")
    for key in ("sync", "nosync"):
        print(f"AT-9 {key}: skew max {a9[key]['skew_max_us']:.2f} us, inter-slave "
              f"{a9[key]['inter_slave_skew_max_us']:.2f} us, dropout "
              f"{a9[key]['dropout_pct']:.3f} %")
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
