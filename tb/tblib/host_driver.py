"""Python driver of the CANopen master's host registers (``canopen_host_regs``).

:class:`CanopenMasterHost` talks to the Avalon-MM slave through cocotb-bus's
:class:`~cocotb_bus.drivers.avalon.AvalonMaster` and names every register and field by the
generated map :mod:`tb.tblib.regmap` (source: ``scripts/regmap.py``). It is what a user's
bench (or a system test) calls to configure the master, send NMT commands, run SDO transfers,
read node states, EMCY messages, counters and interrupts, and configure, write and read PDOs.

The slave has the IP core's port names (``avs_address_i``, ``avs_readdata_o``, ...):
:class:`AvalonSuffixMaster` maps the Avalon roles to those names. ``waitrequest`` is optional
(the core has none), ``readdatavalid`` is used, so the read latency is taken from the slave.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from cocotb.handle import SimHandleBase
from cocotb.triggers import ClockCycles, Lock, NextTimeStep, RisingEdge, Timer
from cocotb.types import LogicArray
from cocotb.utils import get_sim_time
from cocotb_bus.drivers.avalon import AvalonMaster

from tb.tblib import regmap as R

NODE_MODES = {"off": 0, "heartbeat": 1, "guarding": 2}
#: NMT command specifiers (CiA 301), the CS field of NMT_CMD and byte 0 of the NMT frame
NMT_START, NMT_STOP, NMT_PREOP, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
COUNTER_NAMES = ("RX_FRAMES", "TX_FRAMES", "UNEXPECTED", "MALFORMED", "RX_OVERFLOW",
                 "TX_ERROR", "SDO_ABORT", "HB_LOSS", "GUARD_ERR", "CAN_ERROR", "EMCY")
IRQ_NAMES = tuple(R.REGISTERS["IRQ_STATUS"].fields)
PDO_COUNTER_NAMES = ("RX", "TX", "RTR", "LEN_ERR", "MISSED", "LATE", "UNEXPECTED")
#: CiA 301 transmission types (PDO_CFG.TT)
TT_SYNC_ACYCLIC = 0
TT_SYNC_MAX = 240
TT_RTR_SYNC = 252
TT_RTR_EVENT = 253
TT_EVENT_MANUF = 254
TT_EVENT = 255


class SdoAbort(Exception):
    """An SDO transfer ended with an abort (``code``: CiA 301 abort code)."""

    def __init__(self, code: int, sent_by_client: bool) -> None:
        who = "the master (client)" if sent_by_client else "the node (server)"
        super().__init__(f"SDO abort 0x{code:08X} sent by {who}")
        self.code = code
        self.sent_by_client = sent_by_client


class SdoTimeout(TimeoutError):
    """SDO_CMD.DONE did not come within the driver's poll budget."""


class Refused(Exception):
    """The core refused a write (the register's REFUSED bit): nothing was sent or changed.

    REFUSED describes the last write to its register only (docs/register_map.md): the driver
    reads it once, right after its own write, and never while it polls BUSY/DONE.
    """


class SdoRefused(Refused):
    """The master refused an SDO_CMD write (SDO_CMD.REFUSED): nothing was sent."""


class NmtRefused(Refused):
    """The master refused an NMT_CMD write (NMT_CMD.REFUSED): nothing was sent."""


class AvalonSuffixMaster(AvalonMaster):
    """:class:`AvalonMaster` on a slave whose ports end in ``_i``/``_o``.

    Adds ``write(..., byteenable=...)`` for partial writes (cocotb-bus always enables every
    byte lane).
    """

    _signals = {"address": "address_i"}
    _optional_signals = {
        "read": "read_i",
        "write": "write_i",
        "writedata": "writedata_i",
        "byteenable": "byteenable_i",
        "readdata": "readdata_o",
        "readdatavalid": "readdatavalid_o",
        "waitrequest": "waitrequest_o",
    }

    async def _acquire_lock(self) -> None:
        # cocotb-bus's lock does not check ``busy`` again after waking: when one coroutine
        # releases the bus and takes it again at once (a poll loop), a second one that was
        # waiting wakes up and drives the bus in the same cycle, and one of the two reads
        # the other's register (found by the fuzz bench: a PDO_CFG read returned the SDO_CMD
        # word of a concurrent SDO poll). Wait until the bus is really free.
        while self.busy:
            await self.busy_event.wait()
        self.busy_event.clear()
        self.busy = True

    async def write(self, address: int, value: int, byteenable: int | None = None) -> None:
        if byteenable is None or not hasattr(self.bus, "byteenable"):
            await super().write(address, value)
            return
        await self._acquire_lock()
        await RisingEdge(self.clock)
        self.bus.address.value = address
        self.bus.writedata.value = value
        self.bus.byteenable.value = byteenable
        self.bus.write.value = 1
        if hasattr(self.bus, "waitrequest"):
            await self._wait_for_nsignal(self.bus.waitrequest)
        await RisingEdge(self.clock)
        self.bus.write.value = 0
        self.bus.byteenable.value = 0
        self.bus.address.value = LogicArray("x" * len(self.bus.address))
        self.bus.writedata.value = LogicArray("x" * len(self.bus.writedata))
        self._release_lock()


def _bits(bits: int | str | Iterable[str]) -> int:
    """Interrupt bits as a mask: an int, one name or several names of IRQ_STATUS fields."""
    if isinstance(bits, int):
        return bits
    names = [bits] if isinstance(bits, str) else list(bits)
    mask = 0
    for name in names:
        f = R.REGISTERS["IRQ_STATUS"].fields[name.upper()]
        mask |= 1 << f.lo
    return mask


class CanopenMasterHost:
    """Register-level driver of the CANopen master.

    ``max_polls`` bounds every wait on SDO_CMD.DONE (``poll_cycles`` clock cycles apart);
    exceeding it raises :class:`SdoTimeout`. ``bus`` replaces the Avalon master by any object
    with ``async read(address) -> int`` and ``async write(address, value, byteenable=None)``
    (word addresses of the map), e.g. a bench that drives one block's port directly.
    """

    def __init__(self, dut: SimHandleBase, clock: SimHandleBase, name_prefix: str = "avs", *,
                 max_polls: int = 10_000, poll_cycles: int = 10, bus: Any = None) -> None:
        self.dut = dut
        self.clock = clock
        self.bus = AvalonSuffixMaster(dut, name_prefix, clock) if bus is None else bus
        self.max_polls = max_polls
        self.poll_cycles = poll_cycles
        #: PDO_SEL is shared by every register of the PDO window: one sequence at a time
        self._pdo_lock = Lock()
        #: SDO_SEL likewise for SDO_OBJ .. SDO_BUF; transfers on different channels run
        #: concurrently, their register sequences take turns (the last SDO_SEL value is cached)
        self._sdo_lock = Lock()
        self._sdo_chan: int | None = None

    # ------------------------------------------------------------------ raw access
    @staticmethod
    def address(name_or_addr: int | str, slot: int | None = None) -> int:
        if isinstance(name_or_addr, int):
            if slot is not None:
                return R.node_addr(name_or_addr, slot)
            return name_or_addr
        return R.addr(name_or_addr.upper(), slot)

    async def read(self, name_or_addr: int | str, slot: int | None = None) -> int:
        """One 32-bit read; ``slot`` selects the node slot of a per-node register.

        Returns in the next time step after the data was taken (not in the read-only phase).
        """
        value = await self.bus.read(self.address(name_or_addr, slot))
        # AvalonMaster returns in the read-only phase: leave it so the caller may drive signals
        await NextTimeStep()
        return int(value)

    async def write(self, name_or_addr: int | str, value: int, slot: int | None = None, *,
                    byteenable: int | None = None) -> None:
        """One 32-bit write (``byteenable`` for a partial one)."""
        await self.bus.write(self.address(name_or_addr, slot), value, byteenable)

    async def read_fields(self, reg: str, slot: int | None = None) -> dict[str, int]:
        """Every readable field of ``reg`` as ``{field: value}``."""
        word = await self.read(reg, slot)
        info = R._info(reg)
        return {name: R.get_field(reg, name, word)
                for name, f in info.fields.items() if f.access in ("RO", "RW", "W1C")}

    # ------------------------------------------------------------------ NMT and SYNC
    async def nmt(self, cs: int, node: int = 0) -> None:
        """Send NMT command ``cs`` to ``node`` (0 = all nodes), after the previous one left
        (a write while NMT_BUSY is refused by the core: NMT_CMD.REFUSED)."""
        for _ in range(self.max_polls):
            if not await self.read("NMT_CMD") & R.NMT_CMD_NMT_BUSY:
                break
            await ClockCycles(self.clock, self.poll_cycles)
        else:
            raise TimeoutError(f"NMT_CMD.NMT_BUSY still set after {self.max_polls} polls")
        await self.write("NMT_CMD", R.make("NMT_CMD", CS=cs, NODE=node))
        word = await self.read("NMT_CMD")
        if word & R.NMT_CMD_REFUSED:
            raise NmtRefused(f"NMT_CMD cs={cs:#04x} node={node} refused (NMT_CMD = {word:#010x})")

    async def nmt_busy(self) -> bool:
        return bool(await self.read("NMT_CMD") & R.NMT_CMD_NMT_BUSY)

    async def sync_config(self, period_us: int, overflow: int = 0, window_us: int = 0,
                          enable: bool = True) -> None:
        """SYNC period (0 = off), counter overflow (0 or 2..240) and window, then SYNC_EN."""
        if overflow not in (0, *range(2, 241)):
            raise ValueError(f"SYNC overflow {overflow}: 0 or 2..240 (CiA 301 1019h)")
        await self.write("SYNC_PERIOD_US", R.make("SYNC_PERIOD_US", VALUE=period_us))
        await self.write("SYNC_OVERFLOW", R.make("SYNC_OVERFLOW", VALUE=overflow))
        if await self.read("SYNC_OVERFLOW") & R.SYNC_OVERFLOW_REFUSED:
            raise Refused(f"SYNC_OVERFLOW = {overflow} refused: 1019h changes only while the "
                          "SYNC producer is stopped")
        await self.write("SYNC_WINDOW_US", R.make("SYNC_WINDOW_US", VALUE=window_us))
        await self.write("CTRL", R.make("CTRL", SYNC_EN=int(enable)))

    async def sync_stop(self) -> None:
        """Stop the SYNC producer (period 0, SYNC_EN = 0) and leave SYNC_OVERFLOW and
        SYNC_WINDOW_US as they are: rewriting SYNC_OVERFLOW with another value restarts the
        counter at 1 (CiA 301 1019h), which a later restart with the old value would then show."""
        await self.write("SYNC_PERIOD_US", R.make("SYNC_PERIOD_US", VALUE=0))
        await self.write("CTRL", R.make("CTRL", SYNC_EN=0))

    async def reinit(self) -> None:
        """Re-initialise the CAN controller (CTRL.REINIT pulse; SYNC_EN kept)."""
        ctrl = await self.read("CTRL")
        await self.write("CTRL", ctrl | R.CTRL_REINIT)

    # ------------------------------------------------------------------ node supervision
    async def node_config(self, slot: int, node_id: int, mode: int | str, time_ms: int,
                          life: int = 0, autostart: bool = False,
                          reset_on_loss: bool = False) -> None:
        """Configure supervision slot ``slot`` (mode: 0/"off", 1/"heartbeat", 2/"guarding")."""
        mode_v = NODE_MODES[mode] if isinstance(mode, str) else mode
        await self.write("NODE_TIME", R.make("NODE_TIME", TIME_MS=time_ms, LIFE_FACTOR=life),
                         slot)
        await self.write("NODE_CFG", R.make("NODE_CFG", NODE_ID=node_id, MODE=mode_v,
                                            AUTOSTART=int(autostart),
                                            RESET_ON_LOSS=int(reset_on_loss)), slot)

    async def node_status(self, slot: int) -> dict[str, int | bool]:
        """State of slot ``slot``: NMT state, flags and time of the last message."""
        f = await self.read_fields("NODE_STATUS", slot)
        return {
            "nmt_state": f["NMT_STATE"],
            "alive": bool(f["ALIVE"]),
            "lost": bool(f["LOST"]),
            "toggle_err": bool(f["TOGGLE_ERR"]),
            "bootup": bool(f["BOOTUP"]),
            "last_ms": await self.read("NODE_LAST_MS", slot),
        }

    async def clear_node(self, slot: int) -> None:
        """Clear the sticky LOST / TOGGLE_ERR / BOOTUP flags of slot ``slot``."""
        await self.write("NODE_STATUS", R.NODE_STATUS_LOST | R.NODE_STATUS_TOGGLE_ERR
                         | R.NODE_STATUS_BOOTUP, slot)

    # ------------------------------------------------------------------ EMCY
    async def emcy_pop(self) -> dict[str, int | bytes | bool] | None:
        """Read and drop the EMCY FIFO head; ``None`` when the FIFO is empty."""
        status = await self.read_fields("EMCY_STATUS")
        if status["COUNT"] == 0:
            return None
        node = R.get_field("EMCY_NODE", "NODE", await self.read("EMCY_NODE"))
        lo = await self.read("EMCY_DATA_LO")
        hi = await self.read("EMCY_DATA_HI")
        time_ms = await self.read("EMCY_TIME_MS")
        await self.write("EMCY_POP", 0)
        data = (lo | hi << 32).to_bytes(8, "little")
        return {"node": node, "data": data, "error_code": int.from_bytes(data[:2], "little"),
                "error_register": data[2], "time_ms": time_ms, "lost": bool(status["LOST"])}

    async def emcy_clear_lost(self) -> None:
        await self.write("EMCY_STATUS", R.EMCY_STATUS_LOST)

    # ------------------------------------------------------------------ counters, interrupts
    async def counters(self) -> dict[str, int]:
        """Every CNT_* register, keyed by its lower-case name without ``CNT_``."""
        return {name.lower(): await self.read(f"CNT_{name}") for name in COUNTER_NAMES}

    async def clear_counters(self) -> None:
        ctrl = await self.read("CTRL")
        await self.write("CTRL", ctrl | R.CTRL_CLR_COUNTERS)

    async def irq_status(self) -> int:
        return await self.read("IRQ_STATUS")

    async def irq_clear(self, bits: int | str | Iterable[str]) -> None:
        """Clear IRQ_STATUS bits (mask or field names)."""
        await self.write("IRQ_STATUS", _bits(bits))

    async def irq_enable(self, bits: int | str | Iterable[str]) -> None:
        """Set IRQ_ENABLE to exactly ``bits`` (mask or field names)."""
        await self.write("IRQ_ENABLE", _bits(bits))

    # ------------------------------------------------------------------ SDO
    async def sdo_cob(self, request: int = 0, response: int = 0) -> None:
        """SDO COB-IDs; 0 selects the default 600h/580h + node."""
        await self.write("SDO_COB", R.make("SDO_COB", REQUEST=request, RESPONSE=response))

    async def _sdo_select(self, chan: int) -> None:
        """SDO_SEL.CHAN = ``chan`` (call with the SDO lock held)."""
        if self._sdo_chan != chan:
            await self.write("SDO_SEL", R.make("SDO_SEL", CHAN=chan))
            self._sdo_chan = chan

    async def sdo_channels(self) -> int:
        """Number of SDO client channels of the core (SDO_SEL.CHANNELS)."""
        return R.get_field("SDO_SEL", "CHANNELS", await self.read("SDO_SEL"))

    async def _sdo_start(self, node: int, index: int, sub: int, upload: bool,
                         size: int, chan: int = 0, data: bytes = b"") -> None:
        async with self._sdo_lock:
            await self._sdo_select(chan)
            padded = bytes(data) + bytes(-len(data) % 4)
            for w in range(len(padded) // 4):
                await self.write(R.REG_SDO_BUF + w,
                                 int.from_bytes(padded[4 * w:4 * w + 4], "little"))
            await self.write("SDO_OBJ", R.make("SDO_OBJ", INDEX=index, SUBINDEX=sub))
            await self.write("SDO_CMD", R.make("SDO_CMD", NODE=node, UPLOAD=int(upload),
                                               SIZE=size))
            # REFUSED describes this write: read it once now, never while polling DONE
            word = await self.read("SDO_CMD")
        if word & R.SDO_CMD_REFUSED:
            raise SdoRefused(f"SDO_CMD on channel {chan} refused (SDO_CMD = {word:#010x})")

    async def sdo_command(self, chan: int = 0) -> int:
        """SDO_CMD of channel ``chan``."""
        async with self._sdo_lock:
            await self._sdo_select(chan)
            return await self.read("SDO_CMD")

    async def _sdo_wait(self, chan: int = 0) -> int:
        """Poll SDO_CMD of ``chan`` until DONE; raise :class:`SdoAbort` on ERROR; return the
        size. REFUSED is not looked at here: it describes the channel's last SDO_CMD write,
        which may be someone else's (``_sdo_start`` checked this transfer's own write)."""
        for _ in range(self.max_polls):
            async with self._sdo_lock:
                await self._sdo_select(chan)
                word = await self.read("SDO_CMD")
                code = await self.read("SDO_ABORT") if word & R.SDO_CMD_ERROR else 0
            if word & R.SDO_CMD_DONE:
                if word & R.SDO_CMD_ERROR:
                    raise SdoAbort(code, bool(word & R.SDO_CMD_ABORT_SENT))
                return R.get_field("SDO_CMD", "XFER_SIZE", word)
            await ClockCycles(self.clock, self.poll_cycles)
        raise SdoTimeout(f"SDO_CMD.DONE not seen within {self.max_polls} polls")

    async def sdo_download(self, node: int, index: int, sub: int, data: bytes,
                           timeout_ms: int | None = None, chan: int = 0) -> None:
        """Write ``data`` to object ``index``:``sub`` of ``node`` through SDO channel
        ``chan``."""
        if len(data) > 4 * R.SDO_BUF_WORDS:
            raise ValueError(f"SDO download of {len(data)} bytes: 0..{4 * R.SDO_BUF_WORDS}")
        if timeout_ms is not None:
            await self.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=timeout_ms))
        await self._sdo_start(node, index, sub, False, len(data), chan, data)
        await self._sdo_wait(chan)

    async def sdo_upload(self, node: int, index: int, sub: int,
                         timeout_ms: int | None = None, chan: int = 0) -> bytes:
        """Read object ``index``:``sub`` of ``node`` through SDO channel ``chan``."""
        if timeout_ms is not None:
            await self.write("SDO_TIMEOUT_MS", R.make("SDO_TIMEOUT_MS", VALUE=timeout_ms))
        await self._sdo_start(node, index, sub, True, 0, chan)
        size = await self._sdo_wait(chan)
        if size > 4 * R.SDO_BUF_WORDS:
            raise ValueError(f"SDO upload reports {size} bytes, the buffer holds "
                             f"{4 * R.SDO_BUF_WORDS}")
        raw = bytearray()
        async with self._sdo_lock:
            await self._sdo_select(chan)
            for w in range((size + 3) // 4):
                raw += await self._read_buf_word(w, min(4, size - 4 * w))
        return bytes(raw[:size])

    async def _read_buf_word(self, w: int, n_valid: int) -> bytes:
        """Word ``w`` of SDO_BUF; only its first ``n_valid`` bytes were transferred (the rest
        of the last word is whatever the buffer RAM held: undefined in simulation)."""
        value = await self.bus.read(R.REG_SDO_BUF + w)
        await NextTimeStep()
        bits = str(value)  # MSB first, 32 characters
        out = bytearray()
        for k in range(4):
            byte = bits[len(bits) - 8 * (k + 1):len(bits) - 8 * k]
            if k < n_valid:
                out.append(int(byte, 2))  # a transferred byte must be defined
            else:
                out.append(int(byte, 2) if set(byte) <= {"0", "1"} else 0)
        return bytes(out)

    # ------------------------------------------------------------------ PDOs
    # The window registers PDO_CFG .. PDO_LATE show the channel chosen by PDO_SEL, so every
    # method below selects its channel first and holds a lock over the whole sequence.
    async def _pdo_sel(self, rpdo: bool, ch: int, ack: bool = False) -> None:
        await self.write("PDO_SEL", R.make("PDO_SEL", CH=ch, RPDO=int(rpdo), ACK=int(ack)))

    async def pdo_refused(self) -> bool:
        """PDO_SEL.REFUSED: the last PDO_SEL / PDO_CFG write was refused (a channel that does
        not exist, DLC > 8 or a reserved TT; the driver's own methods range-check DLC and TT
        before writing). Read it right after the write in question."""
        return bool(await self.read("PDO_SEL") & R.PDO_SEL_REFUSED)

    async def pdo_info(self) -> tuple[int, int]:
        """(N_TPDO, N_RPDO) of the PDO engine."""
        f = await self.read_fields("PDO_INFO")
        return f["N_TPDO"], f["N_RPDO"]

    async def tpdo_config(self, ch: int, cob_id: int, dlc: int, tt: int, *, valid: bool = True,
                          rtr_allowed: bool | None = None, inhibit_100us: int = 0) -> None:
        """Configure TPDO ``ch`` (the master transmits). ``rtr_allowed`` defaults to True for
        the RTR-only types 252/253. Resets the channel's SYNC count and drops a frame not yet
        started."""
        if not 0 <= dlc <= 8:
            raise ValueError(f"DLC {dlc}: 0..8")
        if 241 <= tt <= 251:
            raise ValueError(f"transmission type {tt} is reserved (CiA 301)")
        rtr = tt in (TT_RTR_SYNC, TT_RTR_EVENT) if rtr_allowed is None else rtr_allowed
        async with self._pdo_lock:
            await self._pdo_sel(False, ch)
            await self.write("PDO_INHIBIT", R.make("PDO_INHIBIT", TIME_100US=inhibit_100us))
            await self.write("PDO_CFG", R.make("PDO_CFG", COB_ID=cob_id, RTR=int(rtr),
                                               VALID=int(valid), DLC=dlc, TT=tt))

    async def tpdo_write(self, ch: int, data: bytes, commit: bool = True,
                         trigger: bool = False) -> None:
        """Write up to 8 bytes to TPDO ``ch``'s staging register (missing bytes are 0) and,
        by default, commit them: at the next SYNC for TT 0..252, at once for 253..255.
        ``trigger`` also requests a transmission (TT 254/255 now, TT 0 after the next SYNC)."""
        if len(data) > 8:
            raise ValueError(f"{len(data)} bytes: a PDO has at most 8")
        raw = bytes(data).ljust(8, b"\0")
        async with self._pdo_lock:
            await self._pdo_sel(False, ch)
            await self.write("PDO_DATA_LO", int.from_bytes(raw[:4], "little"))
            await self.write("PDO_DATA_HI", int.from_bytes(raw[4:], "little"))
            if commit or trigger:
                await self.write("PDO_CMD", R.make("PDO_CMD", COMMIT=int(commit),
                                                   TRIGGER=int(trigger)))

    async def tpdo_trigger(self, ch: int) -> None:
        """Request a transmission of TPDO ``ch`` (TT 254/255: now; TT 0: after the next
        SYNC) with its current data."""
        async with self._pdo_lock:
            await self._pdo_sel(False, ch)
            await self.write("PDO_CMD", R.PDO_CMD_TRIGGER)

    async def tpdo_status(self, ch: int) -> dict[str, Any]:
        """State of TPDO ``ch``: configuration, latest committed data, flags and counters."""
        async with self._pdo_lock:
            await self._pdo_sel(False, ch)
            cfg = await self.read_fields("PDO_CFG")
            lo = await self.read("PDO_DATA_LO")
            hi = await self.read("PDO_DATA_HI")
            cmd = await self.read_fields("PDO_CMD")
            seq = await self.read_fields("PDO_SEQ")
            late = await self.read_fields("PDO_LATE")
            inhibit = await self.read_fields("PDO_INHIBIT")
        return {"cob_id": cfg["COB_ID"], "valid": bool(cfg["VALID"]), "rtr": bool(cfg["RTR"]),
                "dlc": cfg["DLC"], "tt": cfg["TT"], "inhibit_100us": inhibit["TIME_100US"],
                "data": (lo | hi << 32).to_bytes(8, "little"), "pending": bool(cmd["PENDING"]),
                "due": bool(cmd["DUE"]), "inhibited": bool(cmd["INHIBITED"]),
                "seq": seq["SEQ"], "late": late["LATE"]}

    async def rpdo_config(self, ch: int, cob_id: int, dlc: int, tt: int = TT_EVENT, *,
                          valid: bool = True, rtr_poll: bool = False) -> None:
        """Configure RPDO ``ch`` (the master receives): expected DLC, transmission type of the
        producer (0..240 synchronous, 254/255 event), RTR poll after every SYNC. Restarts the
        missed-cycle monitor."""
        if not 0 <= dlc <= 8:
            raise ValueError(f"DLC {dlc}: 0..8")
        async with self._pdo_lock:
            await self._pdo_sel(True, ch)
            await self.write("PDO_CFG", R.make("PDO_CFG", COB_ID=cob_id, RTR=int(rtr_poll),
                                               VALID=int(valid), DLC=dlc, TT=tt))

    async def rpdo_read(self, ch: int, ack: bool = True) -> dict[str, Any]:
        """Snapshot of RPDO ``ch``: ``data`` (DLC bytes), ``seq``, ``sync_count``, ``new`` (data
        not acknowledged before this read), ``len_err``, ``missed``. ``ack`` clears NEW in the
        same cycle as the snapshot (a PDO arriving later sets it again)."""
        async with self._pdo_lock:
            await self._pdo_sel(True, ch, ack)
            cfg = await self.read_fields("PDO_CFG")
            lo = await self.read("PDO_DATA_LO")
            hi = await self.read("PDO_DATA_HI")
            cmd = await self.read_fields("PDO_CMD")
            seq = await self.read_fields("PDO_SEQ")
            err = await self.read_fields("PDO_ERR")
        data = (lo | hi << 32).to_bytes(8, "little")
        return {"data": data[:min(cfg["DLC"], 8)], "seq": seq["SEQ"],
                "sync_count": seq["SYNC_COUNT"], "new": bool(cmd["NEW"]),
                "poll_due": bool(cmd["POLL_DUE"]), "len_err": err["LEN_ERR"],
                "missed": err["MISSED"]}

    async def rpdo_new(self) -> int:
        """NEW flags of every RPDO channel (bit k = channel k)."""
        return await self.read("PDO_RX_NEW")

    async def rpdo_ack(self, mask: int) -> None:
        """Clear the NEW flags of the channels in ``mask``."""
        await self.write("PDO_RX_NEW", mask)

    async def pdo_counters(self) -> dict[str, int]:
        """Every PDO_CNT_* register, keyed by its lower-case name without ``PDO_CNT_``."""
        return {name.lower(): await self.read(f"PDO_CNT_{name}") for name in PDO_COUNTER_NAMES}

    async def pdo_clear_counters(self) -> None:
        """Clear PDO_CNT_* and every channel's LATE / LEN_ERR / MISSED counter."""
        await self.write("PDO_CTRL", R.PDO_CTRL_CLR_COUNTERS)

    # ------------------------------------------------------------ automatic configuration
    async def acfg_load(self, entries: Iterable[tuple[int, int, int, int, int]],
                        first: int = 0, terminate: bool = True) -> int:
        """Write the configuration list: ``(node, index, sub, size, value)`` per entry from
        entry ``first`` on (ACFG_ENTRY counts up after each ACFG_VALUE write); ``terminate``
        appends the node-0 end marker. Returns the number of entries written."""
        n = 0
        await self.write("ACFG_ENTRY", R.make("ACFG_ENTRY", ENTRY=first))
        rows = list(entries) + ([(0, 0, 0, 0, 0)] if terminate else [])
        for node, index, sub, size, value in rows:
            await self.write("ACFG_ENTRY", R.make("ACFG_ENTRY", ENTRY=first + n, NODE=node,
                                                  SIZE=size))
            await self.write("ACFG_OBJ", R.make("ACFG_OBJ", INDEX=index, SUBINDEX=sub))
            await self.write("ACFG_VALUE", value & 0xFFFFFFFF)
            n += 1
        return n

    async def acfg_start(self, start_nodes: bool = True) -> None:
        """Run the configuration list (ACFG_CTRL.START), optionally NMT-starting each node
        whose entries all succeeded."""
        nodes = R.ACFG_CTRL_START_NODES if start_nodes else 0
        await self.write("ACFG_CTRL", R.ACFG_CTRL_START | nodes)

    async def acfg_status(self) -> dict[str, int | bool]:
        """ACFG_STATUS decoded, with the first failure of the run (ACFG_FAIL_SEL = 0)."""
        st = await self.read_fields("ACFG_STATUS")
        first = await self.acfg_failure(0)
        return {"busy": bool(st["BUSY"]), "done": bool(st["DONE"]),
                "nodes_ok": st["NODES_OK"], "nodes_fail": st["NODES_FAIL"],
                "fail_node": first[0], "fail_entry": first[1], "fail_abort": first[2]}

    async def acfg_failure(self, k: int) -> tuple[int, int, int]:
        """(node, entry, abort code) of the k-th failing node of the last run (ACFG_FAIL_SEL
        = k, then ACFG_FAIL and ACFG_ABORT); (0, 0, 0) beyond the run's failures."""
        await self.write("ACFG_FAIL_SEL", R.make("ACFG_FAIL_SEL", INDEX=k))
        fail = await self.read_fields("ACFG_FAIL")
        return fail["NODE"], fail["ENTRY"], await self.read("ACFG_ABORT")

    async def acfg_failures(self) -> list[tuple[int, int, int]]:
        """Every logged failure of the last run (at most 16), in table order."""
        n = min((await self.read_fields("ACFG_STATUS"))["NODES_FAIL"], 16)
        return [await self.acfg_failure(k) for k in range(n)]

    async def acfg_run(self, start_nodes: bool = True, timeout_us: float = 1_000_000,
                       poll_us: float = 50) -> dict[str, int | bool]:
        """Start the list and wait (polling ACFG_STATUS.DONE) until it finished."""
        await self.acfg_start(start_nodes)
        t_end = get_sim_time("us") + timeout_us
        while True:
            st = await self.acfg_status()
            if st["done"] and not st["busy"]:
                return st
            if get_sim_time("us") > t_end:
                raise TimeoutError(f"configuration list not finished in {timeout_us} us: {st}")
            await Timer(poll_us, "us")

    # ------------------------------------------------------------------ Omni-ID mode
    # CTRL.OMNI banks the window C0h..FFh to the Omni-ID engine (OMNI_* registers); OMNI_SEL is
    # shared by the slot registers, so slot sequences hold the same lock as the PDO ones.
    async def omni_mode(self, on: bool) -> None:
        """CTRL.OMNI (with SYNC_EN = 0: change the protocol only while the cycle is stopped)."""
        await self.write("CTRL", R.CTRL_OMNI if on else 0)

    async def omni_config(self, *, master_id: int = 2, n_axes: int = 4, bcast_4x2: bool = False,
                          sender: bool = True, sync_mode: int = 0, sync_k: int = 1,
                          poll_m: int = 0, query_win_us: int = 1000,
                          stop_on_missing: bool = False) -> None:
        """OMNI_CFG, OMNI_SYNC_K, OMNI_POLL and OMNI_QUERY_WIN."""
        await self.write("OMNI_CFG", R.make(
            "OMNI_CFG", MASTER_ID=master_id, N_AXES=n_axes, BCAST_4X2=int(bcast_4x2),
            SENDER=int(sender), SYNC_MODE=sync_mode, STOP_ON_MISSING=int(stop_on_missing)))
        await self.write("OMNI_SYNC_K", R.make("OMNI_SYNC_K", K=sync_k))
        await self.write("OMNI_POLL", R.make("OMNI_POLL", M=poll_m))
        await self.write("OMNI_QUERY_WIN", R.make("OMNI_QUERY_WIN", US=query_win_us))

    async def omni_slot(self, slot: int, node: int, fc: int, dlc: int,
                        valid: bool = True) -> None:
        """Node table slot: the node, its feedback function code and DLC."""
        async with self._pdo_lock:
            await self.write("OMNI_SEL", R.make("OMNI_SEL", SLOT=slot))
            await self.write("OMNI_SLOT_CFG", R.make("OMNI_SLOT_CFG", NODE=node, FC=fc,
                                                     VALID=int(valid), DLC=dlc))

    async def omni_setpoints(self, values: Iterable[int], commit: bool = True) -> None:
        """Staging set-points of axes 0.. (16-bit two's complement; 1-byte slots send the low
        byte) and, by default, COMMIT: they go out in the cycle frame taken next."""
        vals = [v & 0xFFFF for v in values]
        vals += [0] * (-len(vals) % 2)
        for i in range(0, len(vals), 2):
            await self.write(R.REG_OMNI_SP01 + i // 2, vals[i] | vals[i + 1] << 16)
        if commit:
            await self.write("OMNI_CTRL", R.OMNI_CTRL_COMMIT)

    async def omni_nmt(self, node: int, start: bool) -> None:
        """Omni-ID NMT frame [node (0 = all)][1 start / 0 stop]."""
        await self.write("OMNI_NMT", R.make("OMNI_NMT", NODE=node, STATE=int(start)))

    async def omni_param(self, node: int, dtype: int, content: bytes) -> None:
        """Parameter frame 700h + node: [master][type][content] (content 0..6 bytes)."""
        if len(content) > 6:
            raise ValueError("a parameter frame carries at most 6 content bytes")
        raw = bytes(content).ljust(6, b"\0")
        await self.write("OMNI_PARAM_HDR", R.make("OMNI_PARAM_HDR", NODE=node, TYPE=dtype,
                                                  DLC=2 + len(content)))
        await self.write("OMNI_PARAM_LO", int.from_bytes(raw[:4], "little"))
        await self.write("OMNI_PARAM_HI", int.from_bytes(raw[4:], "little"))
        await self.write("OMNI_CTRL", R.OMNI_CTRL_PARAM_SEND)

    async def omni_status(self) -> dict[str, int]:
        """OMNI_STATUS fields plus OMNI_CYCLE, OMNI_ALIVE, OMNI_MISSING (slot bitmap
        ``missing``, lowest missing node-ID ``missing_node``), OMNI_BUS_BITS."""
        st = await self.read_fields("OMNI_STATUS")
        st["cycle"] = await self.read("OMNI_CYCLE")
        st["alive"] = await self.read("OMNI_ALIVE")
        miss = await self.read_fields("OMNI_MISSING")
        st["missing"], st["missing_node"] = miss["MISSING"], miss["NODE"]
        st["bus_bits"] = await self.read("OMNI_BUS_BITS")
        return st

    async def omni_feedback(self, slot: int, ack: bool = True) -> dict[str, Any]:
        """Snapshot of slot ``slot``'s last feedback frame: data, seq, cycle, new, errors."""
        async with self._pdo_lock:
            await self.write("OMNI_SEL", R.make("OMNI_SEL", SLOT=slot, ACK=int(ack)))
            sel = await self.read_fields("OMNI_SEL")
            lo = await self.read("OMNI_FB_LO")
            hi = await self.read("OMNI_FB_HI")
            info = await self.read_fields("OMNI_FB_INFO")
            err = await self.read_fields("OMNI_SLOT_ERR")
        return {"data": (lo | hi << 32).to_bytes(8, "little"), "seq": info["SEQ"],
                "cycle": info["CYCLE"], "new": bool(sel["NEW"]), "len_err": err["LEN_ERR"],
                "missed": err["MISSED"]}

    async def omni_counters(self) -> dict[str, int]:
        """Every OMNI_CNT_* register, keyed by its lower-case name without ``OMNI_CNT_``."""
        names = [n for n in R.OMNI_REGISTERS if n.startswith("OMNI_CNT_")]
        return {n[len("OMNI_CNT_"):].lower(): await self.read(n) for n in names}
