"""The C HAL (``sw/canopen_master.{c,h}``) driven from a cocotb bench.

:func:`build` compiles the HAL with the host C compiler into a shared library under ``build/``
(warnings are errors: ``-std=c99 -Wall -Wextra -Werror -pedantic``). :class:`CHal` loads it with
:mod:`ctypes` and bridges its register callbacks into the simulation: a HAL function runs in a
thread started by cocotb's :func:`~cocotb.task.bridge`; each ``rd``/``wr`` callback of the C
code :func:`~cocotb.task.resume`\\ s one Avalon-MM transaction on the cocotb-bus Avalon master
of :class:`tb.tblib.host_driver.CanopenMasterHost` (the same driver every bench uses) and
blocks until it finished in simulated time; the ``idle`` callback between two polls waits
``poll_us`` of simulated time. Every access is logged (:attr:`CHal.log`) so a bench can compare
the HAL's register sequence with the documented one.
"""

from __future__ import annotations

import ctypes as C
import re
import shutil
import subprocess
from collections.abc import Callable, Sequence
from pathlib import Path

from cocotb.task import bridge, resume
from cocotb.triggers import NextTimeStep, Timer

from tb.tblib.host_driver import CanopenMasterHost
from tb.tblib.runner import ROOT

SW = ROOT / "sw"
SOURCES = (SW / "canopen_master.c",)
HEADERS = (SW / "canopen_master.h", SW / "include" / "canopen_master_regs.h")
CFLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
BUILD = ROOT / "build" / "c_hal"

#: status codes of canopen_master.h (cm_status_t)
CM_OK, CM_PENDING = 0, 1
CM_ERR_ARG, CM_ERR_ID, CM_ERR_VERSION, CM_ERR_TIMEOUT, CM_ERR_REFUSED = -1, -2, -3, -4, -5
CM_ERR_ABORT, CM_ERR_INIT, CM_ERR_EMPTY, CM_ERR_CONFIG, CM_ERR_SIZE = -6, -7, -8, -9, -10
CM_IRQ_SOURCES = 8


def compiler() -> str:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise RuntimeError("no C compiler (gcc): run scripts/setup.sh")
    return cc


def build(out: Path = BUILD / "libcanopen_master.so", *, include_dirs: Sequence[Path] = (),
          extra_flags: Sequence[str] = ()) -> Path:
    """Compile the HAL into the shared library ``out``; ``include_dirs`` come before
    ``sw/include`` (a doctored register header there replaces the generated one)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [compiler(), *CFLAGS, *extra_flags, "-O1", "-shared", "-fPIC",
           *(f"-I{d}" for d in include_dirs), f"-I{SW / 'include'}", f"-I{SW}",
           *map(str, SOURCES), "-o", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}\n{res.stdout}{res.stderr}")
    return out


def build_with_header_change(out: Path, pattern: str, repl: str) -> Path:
    """The HAL built against a copy of the generated register header with one ``#define``
    changed (``re.sub(pattern, repl)`` on it, which must match exactly once)."""
    inc = out.parent / f"{out.stem}_include"
    inc.mkdir(parents=True, exist_ok=True)
    text = (SW / "include" / "canopen_master_regs.h").read_text()
    doctored, n = re.subn(pattern, repl, text, flags=re.MULTILINE)
    if n != 1:
        raise ValueError(f"{pattern!r} matched {n} times in the register header")
    (inc / "canopen_master_regs.h").write_text(doctored)
    return build(out, include_dirs=[inc])


# ------------------------------------------------------------------------------ C types
class CmCtx(C.Structure):
    pass


WR_FN = C.CFUNCTYPE(None, C.POINTER(CmCtx), C.c_uint32, C.c_uint32)
RD_FN = C.CFUNCTYPE(C.c_uint32, C.POINTER(CmCtx), C.c_uint32)
IDLE_FN = C.CFUNCTYPE(None, C.POINTER(CmCtx))
IRQ_FN = C.CFUNCTYPE(None, C.POINTER(CmCtx), C.c_uint32)


class CmEmcy(C.Structure):
    _fields_ = [("node", C.c_uint8), ("data", C.c_uint8 * 8), ("error_code", C.c_uint16),
                ("error_register", C.c_uint8), ("lost", C.c_uint8), ("time_ms", C.c_uint32)]


EMCY_FN = C.CFUNCTYPE(None, C.POINTER(CmCtx), C.POINTER(CmEmcy))

CmCtx._fields_ = [
    ("wr", WR_FN), ("rd", RD_FN), ("idle", IDLE_FN), ("user", C.c_void_p),
    ("max_polls", C.c_uint32), ("version", C.c_uint32), ("n_sdo", C.c_uint8),
    ("n_tpdo", C.c_uint8), ("n_rpdo", C.c_uint8), ("sdo_chan", C.c_uint8),
    ("on_irq", IRQ_FN * CM_IRQ_SOURCES), ("on_emcy", EMCY_FN),
]


class CmSdoResult(C.Structure):
    _fields_ = [("size", C.c_uint32), ("abort_code", C.c_uint32), ("abort_sent", C.c_uint8)]


class CmAcfgEntry(C.Structure):
    _fields_ = [("node", C.c_uint8), ("index", C.c_uint16), ("sub", C.c_uint8),
                ("size", C.c_uint8), ("value", C.c_uint32)]


class CmAcfgResult(C.Structure):
    _fields_ = [("nodes_ok", C.c_uint8), ("nodes_fail", C.c_uint8)]


class CmRpdo(C.Structure):
    _fields_ = [("data", C.c_uint8 * 8), ("dlc", C.c_uint8), ("is_new", C.c_uint8),
                ("seq", C.c_uint16), ("sync_count", C.c_uint8), ("len_err", C.c_uint16),
                ("missed", C.c_uint16)]


class CmNodeStatus(C.Structure):
    _fields_ = [("nmt_state", C.c_uint8), ("alive", C.c_uint8), ("lost", C.c_uint8),
                ("toggle_err", C.c_uint8), ("bootup", C.c_uint8), ("last_ms", C.c_uint32)]


P = C.POINTER
u8, u16, u32, i32, sz = C.c_uint8, C.c_uint16, C.c_uint32, C.c_int, C.c_size_t
CTX = P(CmCtx)
#: name -> (restype, argtypes) of every HAL function
SIGNATURES: dict[str, tuple[object, list[object]]] = {
    "cm_setup": (None, [CTX, WR_FN, RD_FN, IDLE_FN, C.c_void_p]),
    "cm_ctx_size": (sz, []),
    "cm_identify": (i32, [CTX]),
    "cm_init": (i32, [CTX, u32]),
    "cm_nmt": (i32, [CTX, u8, u8]),
    "cm_sync_config": (i32, [CTX, u32, u8, u32, i32]),
    "cm_sdo_set_timeout": (None, [CTX, u16]),
    "cm_sdo_start_download": (i32, [CTX, u8, u8, u16, u8, P(u8), sz]),
    "cm_sdo_start_upload": (i32, [CTX, u8, u8, u16, u8]),
    "cm_sdo_poll": (i32, [CTX, u8, P(CmSdoResult)]),
    "cm_sdo_read_buf": (i32, [CTX, u8, P(u8), sz]),
    "cm_sdo_download": (i32, [CTX, u8, u8, u16, u8, P(u8), sz, P(CmSdoResult)]),
    "cm_sdo_upload": (i32, [CTX, u8, u8, u16, u8, P(u8), sz, P(sz), P(CmSdoResult)]),
    "cm_acfg_load": (i32, [CTX, P(CmAcfgEntry), sz, u8]),
    "cm_acfg_start": (i32, [CTX, i32]),
    "cm_acfg_poll": (i32, [CTX, P(CmAcfgResult)]),
    "cm_acfg_run": (i32, [CTX, i32, P(CmAcfgResult)]),
    "cm_acfg_failure": (i32, [CTX, u8, P(u8), P(u8), P(u32)]),
    "cm_tpdo_config": (i32, [CTX, u8, u16, u8, u8, u32, u16]),
    "cm_rpdo_config": (i32, [CTX, u8, u16, u8, u8, i32]),
    "cm_tpdo_set": (i32, [CTX, u8, P(u8), sz, i32, i32]),
    "cm_tpdo_pending": (i32, [CTX, u8]),
    "cm_rpdo_get": (i32, [CTX, u8, i32, P(CmRpdo)]),
    "cm_rpdo_new": (u32, [CTX]),
    "cm_node_config": (i32, [CTX, u8, u8, u8, u16, u8, u32]),
    "cm_node_status": (i32, [CTX, u8, P(CmNodeStatus)]),
    "cm_node_clear": (i32, [CTX, u8]),
    "cm_emcy_pop": (i32, [CTX, P(CmEmcy)]),
    "cm_irq_enable": (None, [CTX, u32]),
    "cm_irq_handler": (u32, [CTX]),
}


def load(path: Path) -> C.CDLL:
    lib = C.CDLL(str(path))
    for name, (res, args) in SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args
    if lib.cm_ctx_size() != C.sizeof(CmCtx):
        raise RuntimeError(f"cm_ctx_t is {lib.cm_ctx_size()} bytes in C, "
                           f"{C.sizeof(CmCtx)} in tb/tblib/c_hal.py")
    return lib


def u8_buf(data: bytes) -> C.Array:
    return (C.c_uint8 * max(1, len(data))).from_buffer_copy(bytes(data) or b"\0")


# ------------------------------------------------------------------------------ the bridge
class CHal:
    """One HAL context on the simulated core. ``await hal.call("cm_x", args...)`` runs the C
    function in a bridged thread (pass the context as :data:`CHal.CTX`, it is replaced by the
    pointer); the register callbacks go through ``host`` (Avalon master)."""

    CTX = object()

    def __init__(self, lib_path: Path, host: CanopenMasterHost, *, poll_us: float = 10,
                 max_polls: int = 20_000) -> None:
        self.lib = load(lib_path)
        self.host = host
        self.poll_us = poll_us
        #: every access: ("r" | "w", word address, value)
        self.log: list[tuple[str, int, int]] = []
        self.polls = 0
        self.errors: list[BaseException] = []
        #: reads that returned undefined bits: (address, bits MSB first)
        self.undefined_reads: list[tuple[int, str]] = []
        self.irq_calls: list[int] = []
        self.emcys: list[dict[str, object]] = []
        self.ctx = CmCtx()
        self._read = resume(self._aread)
        self._write = resume(self._awrite)
        self._sleep = resume(self._aidle)
        # keep the ctypes callbacks alive as long as the context
        self._cb_wr = WR_FN(self._wr)
        self._cb_rd = RD_FN(self._rd)
        self._cb_idle = IDLE_FN(self._idle)
        self._cb_irq = IRQ_FN(self._irq)
        self._cb_emcy = EMCY_FN(self._emcy)
        self.lib.cm_setup(C.byref(self.ctx), self._cb_wr, self._cb_rd, self._cb_idle, None)
        self.ctx.max_polls = max_polls

    # ---------------------------------------------------------------- callbacks (C thread)
    async def _aread(self, addr: int) -> int:
        value = await self.host.bus.read(addr)
        await NextTimeStep()  # as CanopenMasterHost.read: out of the read-only phase
        bits = str(value)
        if set(bits) <= {"0", "1"}:
            return int(bits, 2)
        # undefined bits (e.g. SDO_BUF bytes beyond the transfer, RAM never written): a real
        # bus returns something; 0 here, and the access is recorded for the bench to check
        self.undefined_reads.append((addr, bits))
        return int("".join(b if b in "01" else "0" for b in bits), 2)

    async def _awrite(self, addr: int, value: int) -> None:
        await self.host.write(addr, value)

    async def _aidle(self) -> None:
        await Timer(self.poll_us, "us")

    def _guard(self, fn: Callable[[], int | None]) -> int:
        # an exception must not unwind through C: record it, return 0, raise after the call
        try:
            return fn() or 0
        except BaseException as exc:  # noqa: BLE001 - re-raised by call()
            self.errors.append(exc)
            return 0

    def _wr(self, _ctx, addr: int, value: int) -> None:
        self.log.append(("w", addr, value))
        self._guard(lambda: self._write(addr, value))

    def _rd(self, _ctx, addr: int) -> int:
        value = self._guard(lambda: self._read(addr))
        self.log.append(("r", addr, value))
        return value

    def _idle(self, _ctx) -> None:
        self.polls += 1
        self._guard(self._sleep)

    def _irq(self, _ctx, mask: int) -> None:
        self.irq_calls.append(mask)

    def _emcy(self, _ctx, e) -> None:
        e = e.contents
        self.emcys.append({"node": e.node, "data": bytes(e.data), "error_code": e.error_code,
                           "error_register": e.error_register, "lost": e.lost,
                           "time_ms": e.time_ms})

    def dispatch(self, irq_bits: Sequence[int], emcy: bool) -> None:
        """Install the bench's callbacks for these IRQ_STATUS bit numbers (and on_emcy)."""
        for bit in range(CM_IRQ_SOURCES):
            self.ctx.on_irq[bit] = self._cb_irq if bit in irq_bits else IRQ_FN()
        self.ctx.on_emcy = self._cb_emcy if emcy else EMCY_FN()

    # ---------------------------------------------------------------- calls (cocotb side)
    async def call(self, name: str, *args):
        fn = getattr(self.lib, name)
        cargs = [C.byref(self.ctx) if a is self.CTX else a for a in args]

        def run():  # a Python function for bridge() (it names the thread after it)
            return fn(*cargs)

        run.__qualname__ = f"c_hal.{name}"
        result = await bridge(run)()
        if self.errors:
            raise self.errors[0]
        return result

    def writes(self, since: int = 0) -> list[tuple[int, int]]:
        """(address, value) of every write logged from index ``since`` on."""
        return [(a, v) for kind, a, v in self.log[since:] if kind == "w"]
