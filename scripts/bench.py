#!/usr/bin/env python3
"""Run every benchmark (pytest marker ``bench``) and merge their metrics.

Writes ``build/bench/results.json``, one flat ``{"metric_name": number}`` object, and prints it
as a table. Also folds in the synthesis estimate of ``build/synth/report.json`` when present
(``make bench`` runs ``make synth`` first): per build (entity or variant of
``scripts/synth.py``) ``synth_<build>_luts`` / ``_ffs`` / ``_m9k`` / ``_levels``, the slopes
``synth_luts_per_extra_pdo_channel`` / ``synth_luts_per_extra_sdo_channel`` (and ``ffs_``),
and ``synth_max_lut_levels``, the deepest register-to-register path over all builds.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "build" / "bench"
FRAGMENTS = BENCH / "fragments"


def synth_metrics(report: dict) -> dict[str, float]:
    """The flat metrics of a ``scripts/synth.py`` report (see the module docstring)."""
    out: dict[str, float] = {}
    for build, r in report["builds"].items():
        for key in ("luts", "ffs", "m9k", "levels"):
            out[f"synth_{build}_{key}"] = r[key]
    for kind, s in report["slopes"].items():
        out[f"synth_luts_per_extra_{kind}_channel"] = s["luts_per_channel"]
        out[f"synth_ffs_per_extra_{kind}_channel"] = s["ffs_per_channel"]
    out["synth_max_lut_levels"] = report["max_lut_levels"]
    return out


def main() -> int:
    if FRAGMENTS.exists():
        shutil.rmtree(FRAGMENTS)
    rc = subprocess.call(
        [sys.executable, "-m", "pytest", "-m", "bench", "-n", "auto", "--maxschedchunk=1", "-q",
         "tb"], cwd=ROOT
    )
    if rc != 0:
        print("benchmarks failed", file=sys.stderr)
        return rc
    results: dict[str, float] = {}
    for frag in sorted(FRAGMENTS.glob("*.json")):
        for k, v in json.loads(frag.read_text()).items():
            if k in results:
                raise SystemExit(f"metric {k} reported twice ({frag.name})")
            results[k] = v
    synth = ROOT / "build" / "synth" / "report.json"
    if synth.exists():
        results.update(synth_metrics(json.loads(synth.read_text())))
    if not results:
        print("no metrics were written", file=sys.stderr)
        return 1
    BENCH.mkdir(parents=True, exist_ok=True)
    out = BENCH / "results.json"
    out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    width = max(len(k) for k in results)
    print(f"\n{'metric':{width}s}  value")
    for k in sorted(results):
        v = results[k]
        print(f"{k:{width}s}  {v:.6g}" if isinstance(v, float) else f"{k:{width}s}  {v}")
    print(f"\nwritten: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
