"""The per-cell dropout table of the bit-rate x data-length sweeps (``make drift-report``).

One code path for the three places the table appears: ``build/drift/dropout_table.md`` and
the block between :data:`DOCS_BEGIN` / :data:`DOCS_END` in ``docs/omni_drift.md`` (both
written by ``scripts/drift_report.py``), and the test that checks the docs against the model
(``sim_models/tests/test_omni_report.py``).

A cell is one :func:`~sim_models.omni.experiments.sweep` run: bit rate x command DLC (the
broadcast's DLC on the wire, sender byte included: 1 sender + DLC - 1 slots) x T_s x sync
(none: free-running from t_dif(0) = 0.348·T_s; thesis: re-phase every K samples, K per cell
from :func:`~sim_models.omni.experiments.default_k`), slave +3618 ppm, N cycles.
"""

from __future__ import annotations

import re
from typing import Any

from sim_models.omni import experiments as E
from sim_models.sim_time import PS_PER_MS

__all__ = [
    "DLCS",
    "DOCS_BEGIN",
    "DOCS_END",
    "PERIODS_MS",
    "SYNCS",
    "cell_text",
    "docs_block",
    "dropout_table_md",
    "parse_table",
    "replace_docs_block",
    "sweep_cells",
]

PERIODS_MS = (5, 1)
SYNCS = (False, True)
DLCS = tuple(range(2, 9))
DOCS_BEGIN = "<!-- dropout-table: begin (scripts/drift_report.py --docs writes this block) -->"
DOCS_END = "<!-- dropout-table: end -->"

CellKey = tuple[int, bool, int, int]  #: (T_s ms, sync, bit rate, DLC)


def sweep_cells(n_cycles: int, *, periods_ms: tuple[int, ...] = PERIODS_MS,
                syncs: tuple[bool, ...] = SYNCS, rates: tuple[int, ...] = E.RATES,
                dlcs: tuple[int, ...] = DLCS) -> list[dict[str, Any]]:
    """Run the sweeps; every cell's summary gets ``period_ms`` and ``sync``."""
    cells = []
    for period_ms in periods_ms:
        for sync in syncs:
            for c in E.sweep(period_ms * PS_PER_MS, rates=rates, dlcs=dlcs, n_cycles=n_cycles,
                             sync=sync):
                c["period_ms"] = period_ms
                c["sync"] = sync
                cells.append(c)
    return cells


def cell_text(c: dict[str, Any]) -> str:
    """``p / onset`` (no sync) or ``p / onset / K`` (thesis re-phase); p in % with two
    decimals (one sample of 3000 is 0.033 %), onset = index of the first dropout sample or
    ``–``; ``*`` = flagged infeasible by :func:`~sim_models.omni.check_feasibility`."""
    onset = "–" if c["onset"] is None else str(c["onset"])
    txt = f"{c['p_pct']:.2f}{'' if c['feasible'] else '*'} / {onset}"
    if c["sync"]:
        txt += f" / {c['k']}"
    return txt


def _title(period_ms: int, sync: bool) -> str:
    return (f"T_s = {period_ms} ms, " + ("thesis re-phase: p % / onset / K" if sync
                                         else "no sync: p % / onset"))


def dropout_table_md(cells: list[dict[str, Any]], n_cycles: int, heading: str = "####"
                     ) -> str:
    """The sub-tables (one per T_s x sync, rows = bit rate, columns = DLC) as markdown."""
    lines = [f"Dropout p (Eq 2-2: % of the samples whose command was sent; N = {n_cycles} "
             "master cycles, of which a free-running lagging slave samples about 99.7 %), "
             "onset (index of the first dropout sample, `–` = none) and, with the thesis "
             "re-phase, K per cell; two nodes, slave +3618 ppm, 1-byte slots, DLC = the "
             "broadcast's DLC on the wire (sender byte + DLC − 1 slots). `*` = flagged "
             "infeasible by the master's check (the RTL rule: worst-case bits · τ_bit > T_s, "
             "no margin).", ""]
    for period_ms in PERIODS_MS:
        for sync in SYNCS:
            sel = [c for c in cells if c["period_ms"] == period_ms and c["sync"] == sync]
            if not sel:
                continue
            lines += [f"{heading} {_title(period_ms, sync)}", "",
                      "| kbit/s | " + " | ".join(f"DLC {n}" for n in DLCS) + " |",
                      "|---|" + "---|" * len(DLCS)]
            for rate in E.RATES:
                row = {c["dlc"]: c for c in sel if c["bitrate_bps"] == rate}
                if row:
                    lines.append(f"| {rate // 1000} | "
                                 + " | ".join(cell_text(row[n]) if n in row else ""
                                              for n in DLCS) + " |")
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def parse_table(md: str) -> tuple[int | None, dict[CellKey, str]]:
    """Inverse of :func:`dropout_table_md`: (N, {(T_s ms, sync, bit rate, DLC): cell text})."""
    m = re.search(r"N = (\d+) master cycles", md)
    n_cycles = int(m.group(1)) if m else None
    cells: dict[CellKey, str] = {}
    key: tuple[int, bool] | None = None
    for line in md.splitlines():
        h = re.match(r"#+ T_s = (\d+) ms, (no sync|thesis re-phase)", line)
        if h:
            key = (int(h.group(1)), h.group(2) != "no sync")
            continue
        row = re.match(r"\| (\d+) \| (.*) \|$", line)
        if row and key is not None:
            rate = int(row.group(1)) * 1000
            for n, txt in zip(DLCS, row.group(2).split(" | ")):
                cells[(*key, rate, n)] = txt.strip()
    return n_cycles, cells


def docs_block(doc: str) -> str:
    """The text between the markers of ``docs/omni_drift.md``."""
    try:
        a = doc.index(DOCS_BEGIN) + len(DOCS_BEGIN)
        b = doc.index(DOCS_END, a)
    except ValueError as exc:
        raise ValueError("docs: dropout-table markers not found") from exc
    return doc[a:b]


def replace_docs_block(doc: str, table: str) -> str:
    """``doc`` with the block between the markers replaced by ``table`` (nothing else)."""
    old = docs_block(doc)
    a = doc.index(DOCS_BEGIN) + len(DOCS_BEGIN)
    return doc[:a] + "\n" + table.strip("\n") + "\n" + doc[a + len(old):]
