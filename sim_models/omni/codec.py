"""Omni-ID codec: identifiers and frame layouts of the NCTU thesis' application protocol.

The thesis (digest ``shared/spec/nctu_omni_sync.md`` sections 2.1-2.5) splits the 11-bit CAN
identifier into a 3-bit function code and an 8-bit node field: ``id = fc << 8 | node``. This
module builds and parses every frame the protocol uses as python-can ``can.Message`` objects.
Where the thesis is ambiguous the choice made here carries the digest's ambiguity number:

* A1  broadcast layout: an optional sender byte first (the Fig 4-20 trace form, default for
  fc 001), then the slots with the highest axis first: ``[axis N] ... [axis 1]`` (the text
  "最高位元組為第四軸速度命令"). fc 100 (4 x 2 bytes) has no sender byte.
* A2  command and content values are signed (slots) / opaque (content) big-endian integers.
* A3  NMT state byte: 1 = start, 0 = stop; other values are rejected.
* A4  data-type byte: a table (``DTYPE_*``); unknown types are accepted and stored as given.
* A6  option (ii) sync: the project's **Omni SYNC** frame, data frame id 0x080 with DLC 0.
  Its content is fixed, so its length on the wire is fixed (51 bits), hence no stuffing jitter.
  It cannot collide with Omni traffic: every fc-000 frame except id 0 is a *remote* frame (a
  node-query reply), and a data frame differs from a remote frame in the RTR bit (a node 0x80
  answering a query sends RTR 0x080, which loses arbitration against the data frame).
* A12 node query and its reply are remote frames with DLC 0.
* A13 node ids 1..255 are accepted; the thesis' one-hot ids are only the defaults.
"""

from __future__ import annotations

from dataclasses import dataclass

import can

from sim_models.canopen_slave.network import make_message

__all__ = [
    "BROADCAST_FCS",
    "DTYPE_CONTROLLER_SETTING",
    "DTYPE_FEEDBACK",
    "DTYPE_PARAMETER",
    "FC_BCAST_4X2",
    "FC_BCAST_8X1",
    "FC_NMT",
    "FC_PARAM",
    "FC_PD_010",
    "FC_PD_011",
    "FC_PD_101",
    "FC_PD_110",
    "NMT_START",
    "NMT_STOP",
    "OMNI_SYNC_ID",
    "PROCESS_DATA_FCS",
    "THESIS_FEEDBACK_FC",
    "THESIS_MASTER_ID",
    "THESIS_PC_ID",
    "THESIS_SLAVE_IDS",
    "Broadcast",
    "DataFrame",
    "OmniFrameError",
    "broadcast_frame",
    "data_frame",
    "decode_id",
    "fc_id_range",
    "is_node_query",
    "is_omni_sync",
    "nmt_frame",
    "node_query_frame",
    "omni_id",
    "omni_sync_frame",
    "parse_broadcast",
    "parse_data_frame",
    "parse_nmt",
    "query_reply_frame",
    "slot_layout",
    "valid_omni_id",
]

# --- function codes (Table 3-3) -----------------------------------------------------------
FC_NMT = 0b000  #: NMT: id 0 = command / query, id 1..255 = query reply (remote)
FC_BCAST_8X1 = 0b001  #: broadcast, up to 8 nodes x 1 byte; node field = sender
FC_PD_010 = 0b010  #: process data; node field = receiver
FC_PD_011 = 0b011  #: process data; node field = receiver
FC_BCAST_4X2 = 0b100  #: broadcast, up to 4 nodes x 2 bytes; node field = sender
FC_PD_101 = 0b101  #: process data; node field = receiver
FC_PD_110 = 0b110  #: process data; node field = receiver
FC_PARAM = 0b111  #: parameter setup (lowest priority); node field = receiver

BROADCAST_FCS = (FC_BCAST_8X1, FC_BCAST_4X2)
PROCESS_DATA_FCS = (FC_PD_010, FC_PD_011, FC_PD_101, FC_PD_110)

# --- node ids and assignments of the platform (Table 4-2) ---------------------------------
THESIS_PC_ID = 0x01
THESIS_MASTER_ID = 0x02
THESIS_SLAVE_IDS = (0x04, 0x08, 0x10, 0x20)
#: feedback function code per slave (Table 4-2: 0x202, 0x302, 0x502, 0x602 to the master)
THESIS_FEEDBACK_FC = {0x04: FC_PD_010, 0x08: FC_PD_011, 0x10: FC_PD_101, 0x20: FC_PD_110}

# --- NMT (A3) ------------------------------------------------------------------------------
NMT_START = 1
NMT_STOP = 0

# --- data types (A4): the only codes the thesis shows, plus the feedback type of Fig 4-20 ---
DTYPE_FEEDBACK = 0x00  #: velocity feedback, slave -> master (trace: ``04 00 ...``)
DTYPE_PARAMETER = 0x01  #: per-axis control parameter, master -> slave (Fig 4-19)
DTYPE_CONTROLLER_SETTING = 0x0C  #: "slave controller setting", PC -> master (Fig 4-19)

#: Omni SYNC (sync option ii, A6): data frame, id 0x080, DLC 0
OMNI_SYNC_ID = 0x080

#: bytes per broadcast slot and maximum slots, per broadcast function code
_SLOT_WIDTH = {FC_BCAST_8X1: 1, FC_BCAST_4X2: 2}
_MAX_SLOTS = {FC_BCAST_8X1: 8, FC_BCAST_4X2: 4}


class OmniFrameError(ValueError):
    """A frame or a field does not follow the Omni layout."""


# ==========================================================================================
# Identifier
# ==========================================================================================


def omni_id(fc: int, node: int) -> int:
    """``fc << 8 | node`` (pure arithmetic; see :func:`valid_omni_id` for Table 3-3)."""
    if not 0 <= fc <= 7:
        raise OmniFrameError(f"function code {fc} out of range 0..7")
    if not 0 <= node <= 255:
        raise OmniFrameError(f"node id {node} out of range 0..255")
    return fc << 8 | node


def decode_id(can_id: int) -> tuple[int, int]:
    """Inverse of :func:`omni_id`: ``(fc, node)``."""
    if not 0 <= can_id <= 0x7FF:
        raise OmniFrameError(f"0x{can_id:X} is not an 11-bit identifier")
    return can_id >> 8, can_id & 0xFF


def fc_id_range(fc: int) -> range:
    """Identifiers Table 3-3 lists for ``fc``: 0..255 for NMT, ``fc·256 + 1 .. fc·256 + 255``
    otherwise (node 0 only exists as the NMT command/query id)."""
    if fc == FC_NMT:
        return range(0, 256)
    base = omni_id(fc, 0)
    return range(base + 1, base + 256)


def valid_omni_id(can_id: int) -> bool:
    """``can_id`` lies in one of the ranges of Table 3-3."""
    if not 0 <= can_id <= 0x7FF:
        return False
    return can_id in fc_id_range(can_id >> 8)


# ==========================================================================================
# NMT: node operation and node query
# ==========================================================================================


def nmt_frame(target: int, state: int) -> can.Message:
    """Node operation: id 0, DLC 2, ``[target (0 = all)][state: 1 start, 0 stop]``."""
    if not 0 <= target <= 255:
        raise OmniFrameError(f"target {target} out of range 0..255")
    if state not in (NMT_START, NMT_STOP):
        raise OmniFrameError(f"NMT state {state} is neither start (1) nor stop (0) (A3)")
    return make_message(0x000, bytes([target, state]))


def parse_nmt(msg: can.Message) -> tuple[int, int]:
    """``(target, state)`` of a node-operation frame; raises on anything else."""
    if msg.arbitration_id != 0 or msg.is_remote_frame or msg.is_extended_id or msg.dlc != 2:
        raise OmniFrameError(f"not an Omni NMT command: {msg}")
    target, state = msg.data[0], msg.data[1]
    if state not in (NMT_START, NMT_STOP):
        raise OmniFrameError(f"NMT state {state} is neither start (1) nor stop (0) (A3)")
    return target, state


def node_query_frame() -> can.Message:
    """Node query: remote frame, id 0, DLC 0 (A12)."""
    return make_message(0x000, None, remote=True, dlc=0)


def is_node_query(msg: can.Message) -> bool:
    return msg.arbitration_id == 0 and msg.is_remote_frame and not msg.is_extended_id


def query_reply_frame(node: int) -> can.Message:
    """Reply to a node query: remote frame, id = own node id (fc 000), DLC 0 (A12)."""
    if not 1 <= node <= 255:
        raise OmniFrameError(f"node id {node} out of range 1..255")
    return make_message(node, None, remote=True, dlc=0)


# ==========================================================================================
# Omni SYNC (option ii)
# ==========================================================================================


def omni_sync_frame() -> can.Message:
    """The project's Omni SYNC: data frame, id 0x080, DLC 0 (fixed length, A6)."""
    return make_message(OMNI_SYNC_ID, b"")


def is_omni_sync(msg: can.Message) -> bool:
    return (msg.arbitration_id == OMNI_SYNC_ID and not msg.is_remote_frame
            and not msg.is_extended_id and msg.dlc == 0)


# ==========================================================================================
# Broadcast (fc 001: 8 x 1 byte, fc 100: 4 x 2 bytes)
# ==========================================================================================


@dataclass(frozen=True)
class Broadcast:
    """A decoded broadcast frame; ``values[0]`` is axis 1."""

    fc: int
    sender: int  #: node field of the id (the sender)
    sender_byte: int | None  #: byte 0 when the frame carries one (A1), else None
    values: tuple[int, ...]


def slot_layout(fc: int, with_sender: bool | None = None) -> tuple[int, int, int]:
    """``(offset of the first slot, slot width, max slots)`` for broadcast ``fc``.

    ``with_sender`` defaults to True for fc 001 (trace form, A1) and is never allowed for
    fc 100 (4 x 2 bytes fill the frame)."""
    if fc not in BROADCAST_FCS:
        raise OmniFrameError(f"function code {fc:03b} is not a broadcast")
    if with_sender is None:
        with_sender = fc == FC_BCAST_8X1
    if with_sender and fc == FC_BCAST_4X2:
        raise OmniFrameError("fc 100 (4 x 2 bytes) has no room for a sender byte")
    offset = 1 if with_sender else 0
    return offset, _SLOT_WIDTH[fc], _MAX_SLOTS[fc] - offset


def broadcast_frame(fc: int, sender: int, values: list[int] | tuple[int, ...],
                    with_sender: bool | None = None) -> can.Message:
    """Broadcast of ``values`` (``values[0]`` = axis 1) from node ``sender``.

    Byte order: ``[sender]? [axis N] ... [axis 1]``, each slot signed big-endian (A1, A2)."""
    offset, width, max_slots = slot_layout(fc, with_sender)
    if not 1 <= len(values) <= max_slots:
        raise OmniFrameError(f"{len(values)} slots, fc {fc:03b} holds 1..{max_slots}")
    if not 1 <= sender <= 255:
        raise OmniFrameError(f"sender {sender} out of range 1..255")
    data = bytearray([sender]) if offset else bytearray()
    lo, hi = -(1 << (8 * width - 1)), (1 << (8 * width - 1)) - 1
    for v in reversed(values):
        if not lo <= v <= hi:
            raise OmniFrameError(f"value {v} does not fit a signed {width}-byte slot")
        data += int(v).to_bytes(width, "big", signed=True)
    return make_message(omni_id(fc, sender), bytes(data))


def parse_broadcast(msg: can.Message, with_sender: bool | None = None) -> Broadcast:
    """Decode a broadcast frame; the number of slots follows from the DLC."""
    if msg.is_remote_frame or msg.is_extended_id:
        raise OmniFrameError(f"not a broadcast data frame: {msg}")
    fc, sender = decode_id(msg.arbitration_id)
    offset, width, _ = slot_layout(fc, with_sender)
    data = bytes(msg.data[:msg.dlc])
    n_slots, rest = divmod(len(data) - offset, width)
    if n_slots < 1 or rest:
        raise OmniFrameError(f"DLC {msg.dlc} does not hold whole {width}-byte slots")
    slots = [int.from_bytes(data[offset + i * width: offset + (i + 1) * width], "big",
                            signed=True) for i in range(n_slots)]
    return Broadcast(fc, sender, data[0] if offset else None, tuple(reversed(slots)))


# ==========================================================================================
# Process data and parameter frames
# ==========================================================================================


@dataclass(frozen=True)
class DataFrame:
    """A decoded process-data or parameter frame."""

    fc: int
    receiver: int  #: node field of the id
    sender: int  #: byte 0
    dtype: int  #: byte 1
    content: bytes  #: bytes 2.. (big-endian value)

    def value(self, signed: bool = True) -> int:
        return int.from_bytes(self.content, "big", signed=signed)


def data_frame(fc: int, receiver: int, sender: int, dtype: int, content: int | bytes,
               size: int = 4, signed: bool = True) -> can.Message:
    """``id = fc << 8 | receiver``, data ``[sender][dtype][content, big-endian]``.

    ``content`` is an integer packed into ``size`` bytes (0..6) or raw bytes."""
    if fc not in (*PROCESS_DATA_FCS, FC_PARAM):
        raise OmniFrameError(f"function code {fc:03b} is not process data / parameter")
    if not 1 <= receiver <= 255 or not 1 <= sender <= 255:
        raise OmniFrameError("receiver and sender must be node ids 1..255")
    if not 0 <= dtype <= 255:
        raise OmniFrameError(f"data type {dtype} is not a byte")
    if isinstance(content, bytes | bytearray):
        body = bytes(content)
    else:
        body = int(content).to_bytes(size, "big", signed=signed)
    if len(body) > 6:
        raise OmniFrameError(f"content of {len(body)} bytes > 6")
    return make_message(omni_id(fc, receiver), bytes([sender, dtype]) + body)


def parse_data_frame(msg: can.Message) -> DataFrame:
    if msg.is_remote_frame or msg.is_extended_id or msg.dlc < 2:
        raise OmniFrameError(f"not an Omni data frame: {msg}")
    fc, receiver = decode_id(msg.arbitration_id)
    if fc not in (*PROCESS_DATA_FCS, FC_PARAM):
        raise OmniFrameError(f"function code {fc:03b} is not process data / parameter")
    data = bytes(msg.data[:msg.dlc])
    return DataFrame(fc, receiver, data[0], data[1], data[2:])
