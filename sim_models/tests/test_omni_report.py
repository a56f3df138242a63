"""The drift report: the per-cell dropout table in docs/omni_drift.md against the model, and
``scripts/drift_report.py`` end to end with a tiny N.

Regenerating the whole table at the documented N = 3000 takes about 130 s on one core (140
cells), too long for ``make test``; so here every cell's feasibility flag and K are checked
exactly (they need no simulation), and nine cells of the three sub-tables not covered by
``test_omni_drift.py::test_at7_bitrate_sweep_with_sync_5ms`` (which compares all 35 cells of
the 5 ms / thesis re-phase sub-table at N = 3000) are re-simulated at N = 3000.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import pytest

from sim_models.omni import check_feasibility, report
from sim_models.omni import experiments as E
from sim_models.sim_time import PS_PER_MS

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs" / "omni_drift.md"
ALL_KEYS = {(pm, sync, rate, dlc) for pm in report.PERIODS_MS for sync in report.SYNCS
            for rate in E.RATES for dlc in report.DLCS}
CELL_RE = re.compile(r"(\d+\.\d\d)(\*?) / (–|\d+)(?: / (\d+))?")

#: re-simulated at the documented N: (T_s ms, sync, bit rate, DLC)
SAMPLE_CELLS = [(5, False, 1_000_000, 2), (5, False, 100_000, 8), (5, False, 250_000, 5),
                (1, False, 1_000_000, 8), (1, False, 125_000, 4), (1, False, 250_000, 2),
                (1, True, 100_000, 8), (1, True, 125_000, 8), (1, True, 500_000, 3)]


def docs_table() -> tuple[int | None, dict]:
    return report.parse_table(report.docs_block(DOCS.read_text()))


def test_docs_table_complete_flags_and_k() -> None:
    n, cells = docs_table()
    assert n == 3000
    assert set(cells) == ALL_KEYS
    for (pm, sync, rate, dlc), txt in cells.items():
        m = CELL_RE.fullmatch(txt)
        assert m, txt
        period = pm * PS_PER_MS
        # the sweeps' master sends no Omni SYNC (thesis re-phase or none)
        assert (m[2] == "") == check_feasibility(rate, dlc, period).ok, (pm, rate, dlc, txt)
        if sync:
            k = E.default_k(rate, dlc, period, E.THESIS_RHO_PPM, E.stuff_jitter_ps(rate, dlc))
            assert int(m[4]) == k, (pm, rate, dlc, txt)
        else:
            assert m[4] is None


@pytest.mark.parametrize("key", SAMPLE_CELLS, ids=lambda k: f"{k[0]}ms-{k[1]}-{k[2]}-{k[3]}")
def test_docs_table_cells_match_model(key: tuple[int, bool, int, int]) -> None:
    pm, sync, rate, dlc = key
    n, cells = docs_table()
    (c,) = report.sweep_cells(n, periods_ms=(pm,), syncs=(sync,), rates=(rate,), dlcs=(dlc,))
    assert cells[key] == report.cell_text(c), "docs stale: run scripts/drift_report.py --docs"


def test_docs_block_replacement_touches_only_the_block() -> None:
    doc = f"head\n{report.DOCS_BEGIN}\nold\n{report.DOCS_END}\ntail (other agents)\n"
    new = report.replace_docs_block(doc, "| new |\n")
    assert new == f"head\n{report.DOCS_BEGIN}\n| new |\n{report.DOCS_END}\ntail (other agents)\n"
    assert report.replace_docs_block(new, "| new |") == new
    with pytest.raises(ValueError, match="markers"):
        report.docs_block("no markers")


def _load_script():
    spec = importlib.util.spec_from_file_location("drift_report", ROOT / "scripts"
                                                  / "drift_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_drift_report_script_writes_plots_and_tables(tmp_path: Path) -> None:
    """``scripts/drift_report.py`` main() with N = 12 (sweeps), 150 (AT-9), 100 (AT-10)."""
    mod = _load_script()
    assert mod.main(["--cycles", "12", "--at9-cycles", "150", "--at10-cycles", "100",
                     "--out", str(tmp_path)]) == 0
    for name in mod.PLOTS:
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    md = (tmp_path / "dropout_table.md").read_text()
    n, cells = report.parse_table(md)
    assert n == 12 and set(cells) == ALL_KEYS
    assert all(CELL_RE.fullmatch(t) for t in cells.values())
    rows = json.loads((tmp_path / "dropout_table.json").read_text())
    assert len(rows) == len(ALL_KEYS) and all(r["n_cycles"] == 12 for r in rows)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert set(summary) == {"at5", "at9", "at10"} and summary["at5"]["onset_measured"] == 184
    # the docs are written only at the documented N
    with pytest.raises(SystemExit):
        mod.main(["--docs", "--cycles", "12", "--out", str(tmp_path)])
