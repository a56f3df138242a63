"""Test ordering for `make test` (pytest -n auto --maxschedchunk=1 on 2 cores).

pytest-xdist hands tests to its workers in collection order, so a long system simulation
collected last runs alone at the end while the other core idles. The system benches are
therefore moved to the front, longest first; ``--maxschedchunk=1`` (Makefile) makes xdist hand
them out a test at a time instead of in one consecutive chunk per worker, so the long ones
spread over both workers. The figures are wall times measured on the project's 2-core machine
(one simulation per core); they only order the run and are never asserted. A test not listed
keeps its place after these.
"""

from __future__ import annotations

#: pytest node-id prefix -> measured wall time in seconds (order only)
LONG_FIRST = {
    "tb/test_pdo_cycle.py::test_pdo_cycle_1000": 810,
    "tb/test_omni_system.py::test_omni_system ": 507,
    "tb/test_pdo_cycle.py::test_pdo_cycle_rtr_and_missing": 346,
    "tb/test_canopen_master_top.py::test_canopen_master_top": 273,
    "tb/test_omni_system.py::test_omni_system_125k": 238,
    "tb/test_canopen_drift.py": 195,
    "tb/test_demo.py": 179,
    "tb/test_demo_omni.py": 136,
    "tb/test_sdo_channels_system.py::test_sdo_channels_system[4]": 131,
    "tb/test_omni_system.py::test_omni_system_grid[500k]": 130,
    "tb/test_c_hal.py::test_c_hal ": 92,
    "tb/test_canopen_autoconfig_system.py": 86,
    "tb/test_omni_system.py::test_omni_system_grid[100k]": 82,
    "tb/test_sdo_channels_system.py::test_sdo_channels_system[2]": 58,
    "tb/test_host_guide.py": 46,
    "tb/test_fuzz_system.py::test_fuzz_short": 60,
}


def _weight(nodeid: str) -> int:
    key = nodeid + " "
    return max((t for prefix, t in LONG_FIRST.items() if key.startswith(prefix)), default=0)


def pytest_collection_modifyitems(session, config, items) -> None:
    # stable sort: listed tests first (longest first), everything else in collection order
    items.sort(key=lambda item: -_weight(item.nodeid))
