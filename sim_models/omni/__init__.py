"""Omni-ID protocol of the NCTU thesis and its clock-drift / re-synchronisation experiments.

* :mod:`~sim_models.omni.codec`: identifiers and frame layouts (Table 3-3, Table 4-2);
* :mod:`~sim_models.omni.slave`: :class:`OmniSlave`, a drifting sampled-data slave with the
  thesis' re-phase and the project's Omni SYNC re-phase;
* :mod:`~sim_models.omni.master_model`: :class:`OmniMaster`, the transaction-level reference
  master, and the feasibility check (AT-8, the RTL engine's rule);
* :mod:`~sim_models.omni.experiments`: the acceptance experiments AT-5..AT-10, AT-13 and the
  model formulas they are checked against.

See ``docs/omni_drift.md``.
"""

from sim_models.omni.master_model import (
    Feasibility,
    InfeasibleConfiguration,
    OmniMaster,
    broadcast_dlc,
    check_feasibility,
)
from sim_models.omni.slave import OmniSlave, OmniTick, clock_for_period_error, setpoint_value

__all__ = [
    "Feasibility",
    "InfeasibleConfiguration",
    "OmniMaster",
    "OmniSlave",
    "OmniTick",
    "broadcast_dlc",
    "check_feasibility",
    "clock_for_period_error",
    "setpoint_value",
]
