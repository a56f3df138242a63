"""Identifier packing and acceptance filtering of the MCP2510 (DS21291 section 4).

An identifier register group (filter, mask, or the SIDH..EID0 bytes of a buffer) is four bytes:
``SIDH = SID10..SID3``, ``SIDL = SID2..SID0 | (SRR) | EXIDE/IDE | - | EID17..EID16``,
``EID8 = EID15..EID8``, ``EID0 = EID7..EID0``. An extended identifier is ``SID << 18 | EID``.

Acceptance (Table 4-? "filter/mask truth table"): a mask bit of 0 accepts the identifier bit
whatever the filter says; a mask bit of 1 requires identifier bit == filter bit. A filter whose
EXIDE bit is 1 applies only to extended frames, 0 only to standard frames. The MCP2510 has no
data-byte filtering (the MCP2515 applies EID15..0 to data bytes 0/1 of standard frames): for
standard frames only the 11 SID bits are compared.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim_models.mcp2510 import regs as R


@dataclass(frozen=True)
class IdRegs:
    """Decoded identifier register group."""

    sid: int  # 11 bits
    eid: int  # 18 bits
    exide: bool

    @property
    def id29(self) -> int:
        return (self.sid << 18) | self.eid


def decode_id_regs(sidh: int, sidl: int, eid8: int, eid0: int) -> IdRegs:
    sid = (sidh << 3) | (sidl >> 5)
    eid = ((sidl & 0x03) << 16) | (eid8 << 8) | eid0
    return IdRegs(sid=sid, eid=eid, exide=bool(sidl & R.TXBNSIDL_EXIDE))


def encode_id_regs(can_id: int, extended: bool) -> tuple[int, int, int, int]:
    """(SIDH, SIDL, EID8, EID0) for an identifier; SIDL carries EXIDE/IDE for extended ids."""
    if extended:
        sid = (can_id >> 18) & 0x7FF
        eid = can_id & 0x3FFFF
        sidl = ((sid & 0x07) << 5) | R.TXBNSIDL_EXIDE | ((eid >> 16) & 0x03)
        return (sid >> 3) & 0xFF, sidl, (eid >> 8) & 0xFF, eid & 0xFF
    sid = can_id & 0x7FF
    return (sid >> 3) & 0xFF, (sid & 0x07) << 5, 0, 0


def filter_matches(mask: IdRegs, filt: IdRegs, can_id: int, extended: bool) -> bool:
    """True when one filter (with its buffer's mask) accepts the frame identifier."""
    if filt.exide != extended:
        return False
    if extended:
        return ((can_id ^ filt.id29) & mask.id29 & 0x1FFFFFFF) == 0
    return ((can_id ^ filt.sid) & mask.sid & 0x7FF) == 0


def buffer_accepts(
    rxm: int, mask: IdRegs, filters: list[tuple[int, IdRegs]], can_id: int, extended: bool
) -> int | None:
    """Filter number that accepts the frame for a receive buffer, or None.

    ``rxm`` is the buffer's RXBnCTRL.RXM field. With RXM = 11 (masks/filters off) the frame is
    accepted and the lowest filter number of the buffer is reported (the data sheet leaves
    FILHIT undefined in that mode; see docs/mcp2510_model.md). When several filters match, the
    lowest-numbered one is reported, as FILHIT does on the chip.
    """
    if rxm == R.RXM_ANY:
        return filters[0][0]
    if rxm == R.RXM_STD_ONLY and extended:
        return None
    if rxm == R.RXM_EXT_ONLY and not extended:
        return None
    for number, filt in filters:
        if filter_matches(mask, filt, can_id, extended):
            return number
    return None
