"""CiA 301 reference slaves (CiA 402 drive subset) for the simulated CAN bus.

Built on the python ``canopen`` library's ``LocalNode`` (object dictionary, SDO server, EMCY
encoding); NMT, heartbeat, guarding, SYNC, PDOs and timing are implemented on the simulation
scheduler. See ``docs/reference_slaves.md``.
"""

from sim_models.canopen_slave.cia402 import STATUSWORD, DriveState
from sim_models.canopen_slave.network import SimNetwork, SimPeriodicTask, make_message
from sim_models.canopen_slave.pdo import MapEntry, RpdoLengthError, encode_map_entry
from sim_models.canopen_slave.slave import (
    CONTROL_RESYNC_MODES,
    DEFAULT_BOOT_TIME_PS,
    DEFAULT_EDS,
    CanopenSlave,
    ControlTick,
    EmcyRecord,
    NmtState,
    build_slaves,
)
from sim_models.canopen_slave.timers import LocalTimer, true_after_local

__all__ = [
    "CONTROL_RESYNC_MODES",
    "DEFAULT_BOOT_TIME_PS",
    "DEFAULT_EDS",
    "STATUSWORD",
    "CanopenSlave",
    "ControlTick",
    "DriveState",
    "EmcyRecord",
    "LocalTimer",
    "MapEntry",
    "NmtState",
    "RpdoLengthError",
    "SimNetwork",
    "SimPeriodicTask",
    "build_slaves",
    "encode_map_entry",
    "make_message",
    "true_after_local",
]
