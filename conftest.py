"""Test ordering for `make test` (pytest -n auto on 2 cores).

pytest-xdist hands tests to its workers in collection order, so a long system simulation
collected last runs alone at the end while the other core idles. The system benches are
therefore moved to the front, longest first. The figures are wall times measured on the
project's 2-core machine (one simulation per core); they only order the run and are never
asserted. A test not listed keeps its place after these.
"""

from __future__ import annotations

#: pytest node-id prefix -> measured wall time in seconds (order only)
LONG_FIRST = {
    "tb/test_pdo_cycle.py::test_pdo_cycle_1000": 600,
    "tb/test_omni_system.py::test_omni_system ": 420,
    "tb/test_canopen_master_top.py::test_canopen_master_top": 270,
    "tb/test_canopen_drift.py": 240,
    "tb/test_omni_system.py::test_omni_system_grid": 200,
    "tb/test_sdo_channels_system.py": 180,
    "tb/test_canopen_autoconfig_system.py": 150,
    "tb/test_demo": 140,
    "tb/test_host_guide.py": 120,
    "tb/test_pdo_cycle.py": 110,
    "tb/test_omni_system.py": 100,
}


def _weight(nodeid: str) -> int:
    key = nodeid + " "
    return max((t for prefix, t in LONG_FIRST.items() if key.startswith(prefix)), default=0)


def pytest_collection_modifyitems(session, config, items) -> None:
    # stable sort: listed tests first (longest first), everything else in collection order
    items.sort(key=lambda item: -_weight(item.nodeid))
