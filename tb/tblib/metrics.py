"""Benchmark metrics: each benchmark writes a flat ``{"metric": number}`` JSON fragment to
``build/bench/fragments/<name>.json``; ``scripts/bench.py`` merges them into
``build/bench/results.json``. Simulated-time figures are exact; wall-clock figures are labelled
``*_wall_*`` and only ever reported, never asserted.
"""

from __future__ import annotations

import json
from pathlib import Path

from tb.tblib.runner import ROOT

FRAGMENTS = ROOT / "build" / "bench" / "fragments"


def record(name: str, metrics: dict[str, float]) -> Path:
    """Merge ``metrics`` into the fragment ``name`` (created if missing)."""
    FRAGMENTS.mkdir(parents=True, exist_ok=True)
    path = FRAGMENTS / f"{name}.json"
    data: dict[str, float] = {}
    if path.exists():
        data = json.loads(path.read_text())
    for k, v in metrics.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise TypeError(f"metric {k} must be a number, got {v!r}")
        data[k] = v
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    return path
