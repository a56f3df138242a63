-- =================================================================================================
-- Title    : canopen_pkg
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   CANopen (CiA 301) protocol constants.
-- Purpose:
--   COB-ID function codes of the predefined connection set, NMT command specifiers, NMT state
--   bytes of heartbeat/boot-up/guarding messages, SDO command specifiers and abort codes, and the
--   frame record exchanged between the master's blocks. Each constant names the CiA 301 clause
--   it comes from (docs/canopen.md repeats the table). Helpers: COB-ID from function code and
--   node, the effective COB-ID of an SDO channel (eff_cob) and the SDO client's abort code by
--   a 3-bit select (abort_code_of).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

package canopen_pkg is

    -- ---------------------------------------------------------------------------------------------
    -- Predefined connection set, 11-bit COB-ID = function code (4 bits) & node-ID (7 bits)
    -- (CiA 301 7.3.3, Table 70 "broadcast / peer-to-peer objects")
    -- ---------------------------------------------------------------------------------------------

    subtype cob_id_t is std_logic_vector(10 downto 0);

    subtype node_id_t is std_logic_vector(6 downto 0);

    subtype func_code_t is std_logic_vector(3 downto 0);

    constant FC_NMT_C       : func_code_t := "0000"; -- 000h NMT (node-ID 0)
    constant FC_SYNC_EMCY_C : func_code_t := "0001"; -- 080h SYNC, 081h..0FFh EMCY
    constant FC_TIME_C      : func_code_t := "0010"; -- 100h TIME
    constant FC_TPDO1_C     : func_code_t := "0011"; -- 180h + node
    constant FC_RPDO1_C     : func_code_t := "0100"; -- 200h + node
    constant FC_TPDO2_C     : func_code_t := "0101"; -- 280h + node
    constant FC_RPDO2_C     : func_code_t := "0110"; -- 300h + node
    constant FC_TPDO3_C     : func_code_t := "0111"; -- 380h + node
    constant FC_RPDO3_C     : func_code_t := "1000"; -- 400h + node
    constant FC_TPDO4_C     : func_code_t := "1001"; -- 480h + node
    constant FC_RPDO4_C     : func_code_t := "1010"; -- 500h + node
    constant FC_SDO_TX_C    : func_code_t := "1011"; -- 580h + node: server -> client (response)
    constant FC_SDO_RX_C    : func_code_t := "1100"; -- 600h + node: client -> server (request)
    constant FC_NMT_EC_C    : func_code_t := "1110"; -- 700h + node: heartbeat, boot-up, guarding

    constant COB_NMT_C  : cob_id_t := "000" & x"00"; -- NMT command (CiA 301 7.2.8.3.1)
    constant COB_SYNC_C : cob_id_t := "000" & x"80"; -- default SYNC COB-ID (1005h)

    -- ---------------------------------------------------------------------------------------------
    -- NMT (CiA 301 7.2.8.3.1): command frame [cs, node-ID], node-ID 0 = all nodes
    -- ---------------------------------------------------------------------------------------------
    constant NMT_CS_START_C      : std_logic_vector(7 downto 0) := x"01";
    constant NMT_CS_STOP_C       : std_logic_vector(7 downto 0) := x"02";
    constant NMT_CS_PREOP_C      : std_logic_vector(7 downto 0) := x"80";
    constant NMT_CS_RESET_NODE_C : std_logic_vector(7 downto 0) := x"81";
    constant NMT_CS_RESET_COMM_C : std_logic_vector(7 downto 0) := x"82";

    -- NMT state byte of heartbeat / boot-up / guarding replies (CiA 301 7.2.8.3.2, Table 58)
    constant NMT_ST_BOOTUP_C      : std_logic_vector(6 downto 0) := "0000000"; -- 00h
    constant NMT_ST_STOPPED_C     : std_logic_vector(6 downto 0) := "0000100"; -- 04h
    constant NMT_ST_OPERATIONAL_C : std_logic_vector(6 downto 0) := "0000101"; -- 05h
    constant NMT_ST_PREOP_C       : std_logic_vector(6 downto 0) := "1111111"; -- 7Fh

    -- ---------------------------------------------------------------------------------------------
    -- SDO (CiA 301 7.2.4.3): command specifier in bits 7..5 of byte 0
    -- ---------------------------------------------------------------------------------------------
    constant SDO_CCS_DL_SEG_C  : std_logic_vector(2 downto 0) := "000"; -- download segment
    constant SDO_CCS_DL_INIT_C : std_logic_vector(2 downto 0) := "001"; -- initiate download
    constant SDO_CCS_UL_INIT_C : std_logic_vector(2 downto 0) := "010"; -- initiate upload
    constant SDO_CCS_UL_SEG_C  : std_logic_vector(2 downto 0) := "011"; -- upload segment
    constant SDO_CS_ABORT_C    : std_logic_vector(2 downto 0) := "100"; -- abort transfer
    constant SDO_SCS_UL_SEG_C  : std_logic_vector(2 downto 0) := "000"; -- upload segment resp
    constant SDO_SCS_DL_SEG_C  : std_logic_vector(2 downto 0) := "001"; -- download segment resp
    constant SDO_SCS_UL_INIT_C : std_logic_vector(2 downto 0) := "010"; -- initiate upload resp
    constant SDO_SCS_DL_INIT_C : std_logic_vector(2 downto 0) := "011"; -- initiate download resp

    -- SDO abort codes used by the client (CiA 301 7.2.4.3.17, Table 22)
    constant SDO_ABORT_TOGGLE_C     : std_logic_vector(31 downto 0) := x"05030000";
    constant SDO_ABORT_TIMEOUT_C    : std_logic_vector(31 downto 0) := x"05040000";
    constant SDO_ABORT_CS_C         : std_logic_vector(31 downto 0) := x"05040001";
    constant SDO_ABORT_GENERAL_C    : std_logic_vector(31 downto 0) := x"08000000";
    constant SDO_ABORT_LENGTH_C     : std_logic_vector(31 downto 0) := x"06070010";
    constant SDO_ABORT_OUT_OF_MEM_C : std_logic_vector(31 downto 0) := x"05040005";

    -- ---------------------------------------------------------------------------------------------
    -- Frame record exchanged between the master's blocks (never on an entity with its own bench:
    -- those use the flattened std_logic_vector ports)
    -- ---------------------------------------------------------------------------------------------

    type can_frame_t is record
        id   : cob_id_t;                      -- 11-bit identifier (CANopen uses base frames)
        rtr  : std_logic;                     -- remote frame
        dlc  : std_logic_vector(3 downto 0);  -- data length code
        data : std_logic_vector(63 downto 0); -- byte k at bits 8k+7..8k (byte 0 first on CAN)
    end record can_frame_t;

    constant CAN_FRAME_NONE_C : can_frame_t :=
    (
        id   => (others => '0'),
        rtr  => '0',
        dlc  => (others => '0'),
        data => (others => '0')
    );

    function cob_id (fc : func_code_t; node : node_id_t) return cob_id_t;

    function func_code (id : cob_id_t) return func_code_t;

    function node_of (id : cob_id_t) return node_id_t;

    -- effective COB-ID: the configured one, or the default function code + node

    function eff_cob (cfg : std_logic_vector(10 downto 0); fc : func_code_t;
        node : std_logic_vector(6 downto 0)) return std_logic_vector;

    -- the abort codes of the SDO client (canopen_sdo_channels' decision on a received frame:
    -- csel 1..5; 0 selects rx_code, the code of a received abort)

    function abort_code_of (csel : natural range 0 to 5; rx_code : std_logic_vector(31 downto 0))
        return std_logic_vector;

end package canopen_pkg;

package body canopen_pkg is

    function cob_id (fc : func_code_t; node : node_id_t) return cob_id_t is
    begin

        return fc & node;

    end function cob_id;

    function func_code (id : cob_id_t) return func_code_t is
    begin

        return id(10 downto 7);

    end function func_code;

    function node_of (id : cob_id_t) return node_id_t is
    begin

        return id(6 downto 0);

    end function node_of;

    function eff_cob (cfg : std_logic_vector(10 downto 0); fc : func_code_t;
        node : std_logic_vector(6 downto 0)) return std_logic_vector is
    begin

        if unsigned(cfg) = 0 then
            return cob_id(fc, node);
        end if;

        return cfg;

    end function eff_cob;

    function abort_code_of (csel : natural range 0 to 5; rx_code : std_logic_vector(31 downto 0))
        return std_logic_vector is
    begin

        case csel is

            when 1 =>

                return SDO_ABORT_CS_C;

            when 2 =>

                return SDO_ABORT_GENERAL_C;

            when 3 =>

                return SDO_ABORT_TOGGLE_C;

            when 4 =>

                return SDO_ABORT_OUT_OF_MEM_C;

            when 5 =>

                return SDO_ABORT_LENGTH_C;

            when others =>

                return rx_code;

        end case;

    end function abort_code_of;

end package body canopen_pkg;
