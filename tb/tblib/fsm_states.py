"""The master FSM's states and transitions, as the benches see them.

``State`` decodes ``state_o`` (the VHDL ``state_t'pos``, i.e. the thesis' St number).
``TRANSITIONS`` is Table 4-1 of the Hefei thesis (T1..T28, typos of rows 3 and 5 corrected) plus
the gap closures G1..G5. ``reference_next()`` is an independent Python model of the FSM's
next-state function, written from this table; the FSM bench compares the RTL against it cycle
by cycle and reports coverage. ``tb/test_consistency.py`` keeps this file, the VHDL enum in
``rtl/canopen_master_pkg.vhd`` and the tables in ``docs/fsm.md`` equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class State(IntEnum):
    S_INIT = 0
    S_HUB = 1
    S_SYNC_GEN = 2
    S_CAN_RX = 3
    S_PARSE = 4
    S_PDO_PROC = 5
    S_SDO_PROC = 6
    S_NMT_PROC = 7
    S_PDO_GEN = 8
    S_SDO_GEN = 9
    S_NMT_GEN = 10
    S_ENCAP = 11
    S_CAN_TX = 12
    S_ERROR = 13


S = State


@dataclass(frozen=True)
class Transition:
    tid: str
    src: State
    dst: State
    condition: str


TRANSITIONS: tuple[Transition, ...] = (
    Transition("T1", S.S_INIT, S.S_INIT, "init_fail_i: controller initialisation failed (retried)"),
    Transition("T2", S.S_INIT, S.S_HUB, "init_done_i: controller initialisation complete"),
    Transition("T3", S.S_HUB, S.S_SYNC_GEN, "sync_due_i: first entry into St1 / next SYNC due"),
    Transition("T4", S.S_SYNC_GEN, S.S_ENCAP, "frame_ready_i: SYNC generated"),
    Transition("T5", S.S_HUB, S.S_CAN_RX, "rx_avail_i: receive interrupt"),
    Transition("T6", S.S_CAN_RX, S.S_CAN_RX, "rx_avail_i and not rx_head_ok_i: reception failed"),
    Transition("T7", S.S_CAN_RX, S.S_PARSE, "rx_avail_i and rx_head_ok_i: reception successful"),
    Transition("T8", S.S_PARSE, S.S_PDO_PROC, "cls_pdo_i: PDO"),
    Transition("T9", S.S_PARSE, S.S_SDO_PROC, "cls_sdo_i: SDO"),
    Transition("T10", S.S_PARSE, S.S_NMT_PROC, "cls_nmt_i: NMT error control / EMCY"),
    Transition("T11", S.S_PDO_PROC, S.S_PDO_GEN, "pdo_done_i and pdo_reply_i"),
    Transition("T12", S.S_PDO_GEN, S.S_ENCAP, "frame_ready_i: PDO generated"),
    Transition("T13", S.S_SDO_PROC, S.S_SDO_GEN, "sdo_done_i and sdo_reply_i"),
    Transition("T14", S.S_SDO_GEN, S.S_ENCAP, "frame_ready_i: SDO generated"),
    Transition("T15", S.S_NMT_PROC, S.S_NMT_GEN, "nmt_done_i and nmt_reply_i"),
    Transition("T16", S.S_NMT_GEN, S.S_ENCAP, "frame_ready_i: NMT generated"),
    Transition("T17", S.S_ENCAP, S.S_CAN_TX, "encap_ok_i: encapsulated"),
    Transition("T18", S.S_CAN_TX, S.S_CAN_TX, "not tx_loaded_i: not sent yet, retry"),
    Transition("T19", S.S_CAN_TX, S.S_HUB, "tx_loaded_i: sent"),
    Transition("T20", S.S_HUB, S.S_PDO_GEN, "pdo_req_i: master produces PDO data"),
    Transition("T21", S.S_HUB, S.S_SDO_GEN, "sdo_req_i: master produces SDO data"),
    Transition("T22", S.S_HUB, S.S_NMT_GEN, "nmt_req_i: master produces NMT data"),
    Transition("T23", S.S_HUB, S.S_ERROR, "err_pending_i: error interrupt"),
    Transition("T24", S.S_PDO_PROC, S.S_HUB, "pdo_done_i and not pdo_reply_i"),
    Transition("T25", S.S_SDO_PROC, S.S_HUB, "sdo_done_i and not sdo_reply_i"),
    Transition("T26", S.S_NMT_PROC, S.S_HUB, "nmt_done_i and not nmt_reply_i"),
    Transition("T27", S.S_ERROR, S.S_HUB, "not err_fatal_i and not err_nmt_i: handled"),
    Transition("T28", S.S_ERROR, S.S_NMT_GEN, "err_nmt_i: error needs an NMT message"),
    Transition("G1", S.S_ERROR, S.S_INIT, "err_fatal_i: re-initialise the controller"),
    Transition("G2", S.S_CAN_RX, S.S_HUB, "not rx_avail_i: nothing (valid) left to read"),
    Transition("G3", S.S_PARSE, S.S_HUB, "no class: frame of no service (counted)"),
    Transition("G4", S.S_PDO_PROC, S.S_ERROR, "watchdog_i in any waiting state (St2, St5-St12)"),
    Transition("G5", S.S_HUB, S.S_HUB, "no request: idle"),
)

THESIS_IDS = tuple(f"T{i}" for i in range(1, 29))
BY_ID = {t.tid: t for t in TRANSITIONS}

#: states in which the watchdog ends a wait (G4)
WATCHDOG_STATES = (S.S_SYNC_GEN, S.S_PDO_PROC, S.S_SDO_PROC, S.S_NMT_PROC, S.S_PDO_GEN,
                   S.S_SDO_GEN, S.S_NMT_GEN, S.S_ENCAP, S.S_CAN_TX)

#: Moore output asserted in each state (None: the hub asserts none)
STATE_OUTPUT = {
    S.S_INIT: "in_init_o", S.S_HUB: None, S.S_SYNC_GEN: "in_sync_gen_o", S.S_CAN_RX: "in_rx_o",
    S.S_PARSE: "in_parse_o", S.S_PDO_PROC: "in_pdo_proc_o", S.S_SDO_PROC: "in_sdo_proc_o",
    S.S_NMT_PROC: "in_nmt_proc_o", S.S_PDO_GEN: "in_pdo_gen_o", S.S_SDO_GEN: "in_sdo_gen_o",
    S.S_NMT_GEN: "in_nmt_gen_o", S.S_ENCAP: "in_encap_o", S.S_CAN_TX: "in_tx_o",
    S.S_ERROR: "in_error_o",
}


def reference_next(state: State, i: dict[str, int]) -> tuple[State, str | None]:
    """Next state and transition id for the inputs ``i`` (names as the VHDL ports, no ``_i``).

    Returns (state, None) when the FSM waits in a state without a table row for it
    (e.g. St0 while the controller is still initialising, St2/St5-St12 waiting for a result).
    """
    s = state
    if s == S.S_INIT:
        if i["init_done"]:
            return S.S_HUB, "T2"
        return S.S_INIT, "T1" if i["init_fail"] else None
    if s == S.S_HUB:
        for name, tid in (("err_pending", "T23"), ("rx_avail", "T5"), ("sync_due", "T3"),
                          ("nmt_req", "T22"), ("sdo_req", "T21"), ("pdo_req", "T20")):
            if i[name]:
                return BY_ID[tid].dst, tid
        return S.S_HUB, "G5"
    if s == S.S_CAN_RX:
        if not i["rx_avail"]:
            return S.S_HUB, "G2"
        return (S.S_PARSE, "T7") if i["rx_head_ok"] else (S.S_CAN_RX, "T6")
    if s == S.S_PARSE:
        for name, tid in (("cls_pdo", "T8"), ("cls_sdo", "T9"), ("cls_nmt", "T10")):
            if i[name]:
                return BY_ID[tid].dst, tid
        return S.S_HUB, "G3"
    if s == S.S_ERROR:
        if i["err_fatal"]:
            return S.S_INIT, "G1"
        return (S.S_NMT_GEN, "T28") if i["err_nmt"] else (S.S_HUB, "T27")
    proc = {S.S_PDO_PROC: ("pdo", "T11", "T24"), S.S_SDO_PROC: ("sdo", "T13", "T25"),
            S.S_NMT_PROC: ("nmt", "T15", "T26")}
    if s in proc:
        svc, t_reply, t_done = proc[s]
        if i[f"{svc}_done"]:
            return (BY_ID[t_reply].dst, t_reply) if i[f"{svc}_reply"] else (S.S_HUB, t_done)
    gen = {S.S_SYNC_GEN: "T4", S.S_PDO_GEN: "T12", S.S_SDO_GEN: "T14", S.S_NMT_GEN: "T16"}
    if s in gen and i["frame_ready"]:
        return S.S_ENCAP, gen[s]
    if s == S.S_ENCAP and i["encap_ok"]:
        return S.S_CAN_TX, "T17"
    if s == S.S_CAN_TX and i["tx_loaded"]:
        return S.S_HUB, "T19"
    if s in WATCHDOG_STATES and i["watchdog"]:
        return S.S_ERROR, "G4"
    if s == S.S_CAN_TX:
        return S.S_CAN_TX, "T18"
    return s, None


INPUTS = ("init_done", "init_fail", "err_pending", "rx_avail", "sync_due", "nmt_req", "sdo_req",
          "pdo_req", "rx_head_ok", "cls_pdo", "cls_sdo", "cls_nmt", "pdo_done", "pdo_reply",
          "sdo_done", "sdo_reply", "nmt_done", "nmt_reply", "frame_ready", "encap_ok",
          "tx_loaded", "err_fatal", "err_nmt", "watchdog")


def coverage_report(covered: dict[str, int]) -> str:
    """A readable table of which transitions were taken how often."""
    lines = [f"{'id':4s} {'from':12s} {'to':12s} {'count':>7s}"]
    for t in TRANSITIONS:
        lines.append(f"{t.tid:4s} {t.src.name:12s} {t.dst.name:12s} {covered.get(t.tid, 0):7d}")
    n = sum(1 for tid in THESIS_IDS if covered.get(tid))
    lines.append(f"thesis transitions covered: {n}/28")
    return "\n".join(lines)
