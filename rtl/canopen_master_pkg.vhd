-- =================================================================================================
-- Title    : canopen_master_pkg
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The master FSM's state type and its encoding.
-- Purpose:
--   The 14 states of the Hefei thesis' Moore machine (St0 .. St13, Table 4-1), declared once in
--   thesis order, so that state_t'pos(state) is the thesis state number. The 4-bit code exported
--   on state_o is that number; tb/tblib/fsm_states.py decodes it with an IntEnum in the same
--   order and docs/fsm.md documents it (tb/test_consistency.py keeps the three equal).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

package canopen_master_pkg is

    type state_t is (
        S_INIT,     -- St0  CAN controller (MCP2510) initialisation
        S_HUB,      -- St1  application-layer interface: dispatch, start and end of every loop
        S_SYNC_GEN, -- St2  new SYNC: prepare the next SYNC frame (fired later by TXnRTS)
        S_CAN_RX,   -- St3  CAN receive: take one frame from the controller's RX FIFO
        S_PARSE,    -- St4  parse and dispatch by COB-ID function code
        S_PDO_PROC, -- St5  PDO processing
        S_SDO_PROC, -- St6  SDO processing (response to the SDO client)
        S_NMT_PROC, -- St7  NMT processing: heartbeat, boot-up, guarding reply, EMCY
        S_PDO_GEN,  -- St8  new PDO
        S_SDO_GEN,  -- St9  new SDO
        S_NMT_GEN,  -- St10 new NMT: NMT command or guarding RTR
        S_ENCAP,    -- St11 encapsulation: frame into Transmit_Data, TX buffer and priority
        S_CAN_TX,   -- St12 CAN transmit: hand the frame to the MCP2510 controller
        S_ERROR     -- St13 error handling
    );

    subtype state_code_t is std_logic_vector(3 downto 0);

    function state_code (s : state_t) return state_code_t;

end package canopen_master_pkg;

package body canopen_master_pkg is

    function state_code (s : state_t) return state_code_t is
    begin

        return std_logic_vector(to_unsigned(state_t'pos(s), 4));

    end function state_code;

end package body canopen_master_pkg;
