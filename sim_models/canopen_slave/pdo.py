"""PDO helpers of the reference slave: CiA 301 constants, mapping codec, payload packing.

The python ``canopen`` library does not transmit TPDOs or apply RPDOs by itself on a
``LocalNode`` (its maintainers leave that to application code), so the slave implements the
PDO engine with these helpers on top of the library's object dictionary and data store.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from sim_models.canopen_slave.timers import LocalTimer

__all__ = [
    "COB_EXTENDED",
    "COB_INVALID",
    "COB_NO_RTR",
    "MAX_PDO_BITS",
    "N_PDO",
    "MapEntry",
    "RpdoLengthError",
    "RpdoRuntime",
    "TpdoRuntime",
    "decode_map_entry",
    "encode_map_entry",
    "is_dummy",
    "mapping_bits",
    "pack_pdo",
    "unpack_pdo",
]

#: COB-ID bit 31: PDO does not exist / is not valid.
COB_INVALID = 1 << 31
#: COB-ID bit 30: no RTR allowed on this PDO.
COB_NO_RTR = 1 << 30
#: COB-ID bit 29: 29-bit CAN-ID (not supported by the reference slave).
COB_EXTENDED = 1 << 29
#: Predefined connection set: four RPDOs and four TPDOs.
N_PDO = 4
#: Classical CAN payload limit.
MAX_PDO_BITS = 64

#: Transmission types (CiA 301).
TT_SYNC_ACYCLIC = 0
TT_SYNC_MAX = 240
TT_RTR_SYNC = 252
TT_RTR_EVENT = 253
TT_EVENT_MANUF = 254
TT_EVENT_PROFILE = 255

#: Data-type sizes of the dummy entries (index 0x0002..0x0007, sub-index 0).
DUMMY_BITS = {0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


@dataclass(frozen=True)
class MapEntry:
    """One PDO mapping entry: object ``index``/``subindex``, ``bits`` long."""

    index: int
    subindex: int
    bits: int


def decode_map_entry(value: int) -> MapEntry:
    """UNSIGNED32 mapping value ``index << 16 | sub << 8 | bits`` -> :class:`MapEntry`."""
    return MapEntry((value >> 16) & 0xFFFF, (value >> 8) & 0xFF, value & 0xFF)


def encode_map_entry(index: int, subindex: int, bits: int) -> int:
    """Inverse of :func:`decode_map_entry`."""
    return ((index & 0xFFFF) << 16) | ((subindex & 0xFF) << 8) | (bits & 0xFF)


def is_dummy(entry: MapEntry) -> bool:
    """A dummy entry (data-type index 0x0002..0x0007, sub-index 0) reserves space only."""
    return entry.index in DUMMY_BITS and entry.subindex == 0


def mapping_bits(entries: list[MapEntry]) -> int:
    return sum(e.bits for e in entries)


def pack_pdo(entries: list[MapEntry], fetch: Callable[[int, int], bytes]) -> bytes:
    """Payload of a TPDO: the mapped objects, least significant bit first, little endian.

    ``fetch(index, subindex)`` returns an object's raw (little-endian) bytes; only its low
    ``bits`` bits are used. Dummy entries give zeros.
    """
    value = 0
    offset = 0
    for e in entries:
        if not is_dummy(e):
            raw = int.from_bytes(fetch(e.index, e.subindex), "little")
            value |= (raw & ((1 << e.bits) - 1)) << offset
        offset += e.bits
    return value.to_bytes((offset + 7) // 8, "little")


def unpack_pdo(entries: list[MapEntry], data: bytes,
               object_bytes: Callable[[int, int], int]) -> list[tuple[int, int, bytes]]:
    """Split an RPDO payload into ``(index, subindex, raw bytes)`` per non-dummy entry.

    ``object_bytes(index, subindex)`` gives the object's size in bytes; a mapping shorter than
    the object is zero-extended.
    """
    value = int.from_bytes(bytes(data), "little")
    out: list[tuple[int, int, bytes]] = []
    offset = 0
    for e in entries:
        if not is_dummy(e):
            part = (value >> offset) & ((1 << e.bits) - 1)
            size = max(object_bytes(e.index, e.subindex), (e.bits + 7) // 8)
            out.append((e.index, e.subindex, part.to_bytes(size, "little")))
        offset += e.bits
    return out


@dataclass(frozen=True)
class RpdoLengthError:
    """An RPDO whose data length differed from its mapping (CiA 301 EMCY 0x8210 / 0x8220)."""

    t_ps: int
    pdo: int  #: 1..4
    cob_id: int
    received: int  #: bytes received
    expected: int  #: bytes mapped
    applied: bool  #: data used anyway (too long) or dropped (too short)


@dataclass
class TpdoRuntime:
    """Run-time state of one TPDO (not part of the object dictionary)."""

    sync_count: int = 0
    waiting_start: bool = False  #: SYNC start value in use, start SYNC not yet seen
    pending: bool = False  #: acyclic-synchronous / event transmission requested
    sampled: bytes | None = None  #: type 252: data sampled at the last SYNC
    last_tx_local_ps: int | None = None  #: local time the last frame was queued (inhibit)
    inhibit_timer: LocalTimer | None = None
    event_timer: LocalTimer | None = None
    sent: int = 0
    log: list[tuple[int, bytes]] = field(default_factory=list)  #: (t_ps queued, payload)


@dataclass
class RpdoRuntime:
    """Run-time state of one RPDO."""

    pending: tuple[bytes, int] | None = None  #: synchronous RPDO waiting for SYNC (data, t)
    length_error: bool = False  #: last frame had a wrong length (EMCY sent on transition)
    received: int = 0
    applied: int = 0
