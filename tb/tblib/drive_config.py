"""The configuration list the benches and the demo give the master's ``canopen_autoconfig`` for
one CiA 402 reference drive: entries ``(node, index, sub, size, value)`` as
:meth:`tb.tblib.host_driver.CanopenMasterHost.acfg_load` takes them."""

from __future__ import annotations

Entry = tuple[int, int, int, int, int]


def map_entry(index: int, sub: int, bits: int) -> int:
    """CiA 301 PDO mapping entry: index << 16 | sub-index << 8 | length in bits."""
    return index << 16 | sub << 8 | bits


def drive_entries(node: int, hb_ms: int = 10, tpdo_type: int = 1) -> list[Entry]:
    """RPDO1 = controlword (6040h) + target position (607Ah), TPDO1 = statusword (6041h) +
    position actual value (6064h) with transmission type ``tpdo_type``, heartbeat producer
    ``hb_ms``. Mappings are written the CiA 301 way: invalidate the PDO (COB-ID bit 31),
    clear the count, write the entries, set the count, validate."""
    rpdo, tpdo = 0x200 + node, 0x180 + node
    return [
        (node, 0x1400, 1, 4, 0x8000_0000 | rpdo),
        (node, 0x1600, 0, 1, 0),
        (node, 0x1600, 1, 4, map_entry(0x6040, 0, 16)),
        (node, 0x1600, 2, 4, map_entry(0x607A, 0, 32)),
        (node, 0x1600, 0, 1, 2),
        (node, 0x1400, 1, 4, rpdo),
        (node, 0x1800, 1, 4, 0x8000_0000 | tpdo),
        (node, 0x1A00, 0, 1, 0),
        (node, 0x1A00, 1, 4, map_entry(0x6041, 0, 16)),
        (node, 0x1A00, 2, 4, map_entry(0x6064, 0, 32)),
        (node, 0x1A00, 0, 1, 2),
        (node, 0x1800, 2, 1, tpdo_type),
        (node, 0x1800, 1, 4, tpdo),
        (node, 0x1017, 0, 2, hb_ms),
    ]
