"""Minimal CiA 402 device control state machine (controlword 6040h -> statusword 6041h).

Enough of a drive for a master to walk the usual power-up sequence (shutdown 0x06, switch on
0x07, enable operation 0x0F), read back the statusword, provoke and reset a fault. No motion
profile is modelled: in *operation enabled* the slave copies the targets to the actual values
when :meth:`CanopenSlave.drive_update` runs (at every SYNC).
"""

from __future__ import annotations

from enum import Enum

__all__ = ["DriveState", "STATUSWORD", "next_state"]


class DriveState(Enum):
    NOT_READY_TO_SWITCH_ON = "not_ready_to_switch_on"
    SWITCH_ON_DISABLED = "switch_on_disabled"
    READY_TO_SWITCH_ON = "ready_to_switch_on"
    SWITCHED_ON = "switched_on"
    OPERATION_ENABLED = "operation_enabled"
    QUICK_STOP_ACTIVE = "quick_stop_active"
    FAULT_REACTION_ACTIVE = "fault_reaction_active"
    FAULT = "fault"


#: Statusword of each state (bits 0-3, 5, 6 per CiA 402; other bits 0). Bit 4 "voltage
#: enabled" is set from *switched on* up; bit 5 (quick stop, active low) is 1 except in
#: *quick stop active*.
STATUSWORD: dict[DriveState, int] = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x0000,
    DriveState.SWITCH_ON_DISABLED: 0x0040,
    DriveState.READY_TO_SWITCH_ON: 0x0021,
    DriveState.SWITCHED_ON: 0x0033,
    DriveState.OPERATION_ENABLED: 0x0037,
    DriveState.QUICK_STOP_ACTIVE: 0x0017,
    DriveState.FAULT_REACTION_ACTIVE: 0x001F,
    DriveState.FAULT: 0x0008,
}

_S = DriveState


def next_state(state: DriveState, cw: int, prev_cw: int) -> DriveState:
    """State after the controlword changed from ``prev_cw`` to ``cw``.

    Commands (bits 7, 3, 2, 1, 0): shutdown ``0xxx x110``, switch on ``0xxx 0111``, enable
    operation ``0xxx 1111``, disable voltage ``0xxx xx0x``, quick stop ``0xxx x01x``, fault
    reset = rising edge of bit 7. Enable operation from *ready to switch on* passes through
    *switched on* (transitions 3 + 4).
    """
    if state is _S.FAULT:
        if cw & 0x80 and not prev_cw & 0x80:
            return _S.SWITCH_ON_DISABLED
        return state
    if state in (_S.NOT_READY_TO_SWITCH_ON, _S.FAULT_REACTION_ACTIVE):
        return state
    if cw & 0x80:  # fault reset bit without fault: no transition
        return state
    disable_voltage = (cw & 0x02) == 0
    quick_stop = (cw & 0x06) == 0x02
    shutdown = (cw & 0x07) == 0x06
    switch_on = (cw & 0x0F) == 0x07
    enable_op = (cw & 0x0F) == 0x0F
    if disable_voltage:
        return _S.SWITCH_ON_DISABLED
    if state is _S.SWITCH_ON_DISABLED:
        return _S.READY_TO_SWITCH_ON if shutdown else state
    if state is _S.READY_TO_SWITCH_ON:
        if quick_stop:
            return _S.SWITCH_ON_DISABLED
        if switch_on:
            return _S.SWITCHED_ON
        if enable_op:
            return _S.OPERATION_ENABLED
        return state
    if state is _S.SWITCHED_ON:
        if quick_stop:
            return _S.SWITCH_ON_DISABLED
        if shutdown:
            return _S.READY_TO_SWITCH_ON
        if enable_op:
            return _S.OPERATION_ENABLED
        return state
    if state is _S.OPERATION_ENABLED:
        if quick_stop:
            return _S.QUICK_STOP_ACTIVE
        if shutdown:
            return _S.READY_TO_SWITCH_ON
        if switch_on:
            return _S.SWITCHED_ON
        return state
    if state is _S.QUICK_STOP_ACTIVE:
        if enable_op:
            return _S.OPERATION_ENABLED
        return state
    return state
