-- =================================================================================================
-- Title    : canopen_master_fsm
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The CANopen master scheduler: the 14-state Moore FSM of the Hefei thesis.
-- Purpose:
--   Exactly the thesis' states St0..St13 and the 28 transitions of its Table 4-1 (T1..T28),
--   with the table's typos corrected (rows 3 and 5 name St0 where St1 is meant) and the gaps it
--   leaves closed by five documented transitions:
--     G1  St13 -> St0  fatal controller error: re-initialise the MCP2510
--     G2  St3  -> St1  nothing (valid) left to read
--     G3  St4  -> St1  frame of no service (unknown COB-ID; counted by the datapath)
--     G4  any waiting state -> St13  the datapath's state watchdog expired (no unbounded wait)
--     G5  St1  -> St1  idle (implicit in the thesis' VHDL default)
--   It contains no counters, timers or frame buffers: its inputs are conditions computed by the
--   datapath around it, its outputs are a function of the state only (output_proc is sensitive
--   to the state alone). The full table with the conditions is in docs/fsm.md.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_master_pkg.all;

entity canopen_master_fsm is
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- St0: controller initialisation
        init_done_i : in    std_logic; -- MCP2510 controller initialised (T2)
        init_fail_i : in    std_logic; -- initialisation failed, retried by the datapath (T1)
        -- St1: dispatch requests, in priority order
        err_pending_i : in    std_logic; -- an error needs handling (T23)
        rx_avail_i    : in    std_logic; -- a received frame waits in the controller (T5)
        sync_due_i    : in    std_logic; -- the next SYNC frame must be prepared (T3)
        nmt_req_i     : in    std_logic; -- an NMT command or guarding RTR is requested (T22)
        sdo_req_i     : in    std_logic; -- the SDO client has a frame to send (T21)
        pdo_req_i     : in    std_logic; -- a PDO is to be sent (T20)
        -- St3: receive
        rx_head_ok_i : in    std_logic; -- the frame at the FIFO head is a CANopen frame (T7)
        -- St4: parse
        cls_pdo_i : in    std_logic; -- parsed as PDO (T8)
        cls_sdo_i : in    std_logic; -- parsed as SDO response (T9)
        cls_nmt_i : in    std_logic; -- parsed as NMT error control or EMCY (T10)
        -- St5..St7: processing results (1-cycle strobes from the service blocks)
        pdo_done_i  : in    std_logic; -- PDO processed (T11 with pdo_reply_i, else T24)
        pdo_reply_i : in    std_logic; -- a new PDO must be produced
        sdo_done_i  : in    std_logic; -- SDO processed (T13 with sdo_reply_i, else T25)
        sdo_reply_i : in    std_logic; -- a new SDO must be produced
        nmt_done_i  : in    std_logic; -- NMT processed (T15 with nmt_reply_i, else T26)
        nmt_reply_i : in    std_logic; -- a new NMT must be produced
        -- St2, St8..St10: the selected source presents its frame
        frame_ready_i : in    std_logic; -- generated frame available (T4, T12, T14, T16)
        -- St11, St12
        encap_ok_i  : in    std_logic; -- Transmit_Data holds the frame (T17)
        tx_loaded_i : in    std_logic; -- controller loaded (and started) the frame (T19)
        -- St13
        err_fatal_i : in    std_logic; -- the controller must be re-initialised (G1)
        err_nmt_i   : in    std_logic; -- the error needs an NMT message (T28)
        -- any waiting state
        watchdog_i : in    std_logic; -- datapath: too long in this state (G4)
        -- outputs (Moore)
        state_o        : out   std_logic_vector(3 downto 0); -- St number, for debug and benches
        state_change_o : out   std_logic;                    -- strobe: a new state was entered
        in_init_o      : out   std_logic;                    -- St0
        in_sync_gen_o  : out   std_logic;                    -- St2
        in_rx_o        : out   std_logic;                    -- St3: pop the FIFO head
        in_parse_o     : out   std_logic;                    -- St4
        in_pdo_proc_o  : out   std_logic;                    -- St5
        in_sdo_proc_o  : out   std_logic;                    -- St6
        in_nmt_proc_o  : out   std_logic;                    -- St7
        in_pdo_gen_o   : out   std_logic;                    -- St8
        in_sdo_gen_o   : out   std_logic;                    -- St9
        in_nmt_gen_o   : out   std_logic;                    -- St10
        in_encap_o     : out   std_logic;                    -- St11
        in_tx_o        : out   std_logic;                    -- St12
        in_error_o     : out   std_logic                     -- St13
    );
end entity canopen_master_fsm;

architecture rtl of canopen_master_fsm is

    function check_states return boolean is
    begin

        assert state_t'pos(state_t'high) = 13
            report "canopen_master_fsm: the thesis FSM has exactly 14 states"
            severity failure;
        return true;

    end function check_states;

    constant states_ok_c : boolean := check_states;

    -- current and next state
    signal state      : state_t;
    signal next_state : state_t;
    -- previous state, for the entry strobe
    signal prev_state : state_t;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Next-state logic: one arm per state, every transition named after its table row
    -- ---------------------------------------------------------------------------------------------
    next_state_proc : process (cls_nmt_i, cls_pdo_i, cls_sdo_i, encap_ok_i, err_fatal_i, err_nmt_i,
                               err_pending_i, frame_ready_i, init_done_i, nmt_done_i, nmt_reply_i,
                               nmt_req_i, pdo_done_i, pdo_reply_i, pdo_req_i, rx_avail_i,
                               rx_head_ok_i, sdo_done_i, sdo_reply_i, sdo_req_i, state, sync_due_i,
                               tx_loaded_i, watchdog_i) is
    begin

        next_state <= state;

        case state is

            when S_INIT =>

                if init_done_i = '1' then
                    next_state <= S_HUB;                       -- T2  initialisation complete
                else
                    next_state <= S_INIT;                      -- T1  failed (retried) / running
                end if;

            when S_HUB =>

                if err_pending_i = '1' then
                    next_state <= S_ERROR;                     -- T23 error interrupt
                elsif rx_avail_i = '1' then
                    next_state <= S_CAN_RX;                    -- T5  receive interrupt
                elsif sync_due_i = '1' then
                    next_state <= S_SYNC_GEN;                  -- T3  first entry / next SYNC
                elsif nmt_req_i = '1' then
                    next_state <= S_NMT_GEN;                   -- T22 raw NMT data
                elsif sdo_req_i = '1' then
                    next_state <= S_SDO_GEN;                   -- T21 raw SDO data
                elsif pdo_req_i = '1' then
                    next_state <= S_PDO_GEN;                   -- T20 raw PDO data
                else
                    next_state <= S_HUB;                       -- G5  idle
                end if;

            when S_SYNC_GEN =>

                if frame_ready_i = '1' then
                    next_state <= S_ENCAP;                     -- T4  SYNC generated
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_CAN_RX =>

                if rx_avail_i = '0' then
                    next_state <= S_HUB;                       -- G2  nothing left to read
                elsif rx_head_ok_i = '1' then
                    next_state <= S_PARSE;                     -- T7  reception successful
                else
                    next_state <= S_CAN_RX;                    -- T6  reception failed: read again
                end if;

            when S_PARSE =>

                if cls_pdo_i = '1' then
                    next_state <= S_PDO_PROC;                  -- T8  PDO
                elsif cls_sdo_i = '1' then
                    next_state <= S_SDO_PROC;                  -- T9  SDO
                elsif cls_nmt_i = '1' then
                    next_state <= S_NMT_PROC;                  -- T10 NMT
                else
                    next_state <= S_HUB;                       -- G3  no service for this frame
                end if;

            when S_PDO_PROC =>

                if pdo_done_i = '1' and pdo_reply_i = '1' then
                    next_state <= S_PDO_GEN;                   -- T11 new PDO needed
                elsif pdo_done_i = '1' then
                    next_state <= S_HUB;                       -- T24 no reply
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_SDO_PROC =>

                if sdo_done_i = '1' and sdo_reply_i = '1' then
                    next_state <= S_SDO_GEN;                   -- T13 new SDO needed
                elsif sdo_done_i = '1' then
                    next_state <= S_HUB;                       -- T25 no reply
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_NMT_PROC =>

                if nmt_done_i = '1' and nmt_reply_i = '1' then
                    next_state <= S_NMT_GEN;                   -- T15 new NMT needed
                elsif nmt_done_i = '1' then
                    next_state <= S_HUB;                       -- T26 no reply
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_PDO_GEN =>

                if frame_ready_i = '1' then
                    next_state <= S_ENCAP;                     -- T12 PDO generated
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_SDO_GEN =>

                if frame_ready_i = '1' then
                    next_state <= S_ENCAP;                     -- T14 SDO generated
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_NMT_GEN =>

                if frame_ready_i = '1' then
                    next_state <= S_ENCAP;                     -- T16 NMT generated
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_ENCAP =>

                if encap_ok_i = '1' then
                    next_state <= S_CAN_TX;                    -- T17 encapsulated
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                end if;

            when S_CAN_TX =>

                if tx_loaded_i = '1' then
                    next_state <= S_HUB;                       -- T19 sent (handed to the chip)
                elsif watchdog_i = '1' then
                    next_state <= S_ERROR;                     -- G4
                else
                    next_state <= S_CAN_TX;                    -- T18 not yet: retry
                end if;

            when S_ERROR =>

                if err_fatal_i = '1' then
                    next_state <= S_INIT;                      -- G1  re-initialise the controller
                elsif err_nmt_i = '1' then
                    next_state <= S_NMT_GEN;                   -- T28 error needs an NMT message
                else
                    next_state <= S_HUB;                       -- T27 handled
                end if;

        end case;

    end process next_state_proc;

    -- ---------------------------------------------------------------------------------------------
    -- State register
    -- ---------------------------------------------------------------------------------------------
    state_reg_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            state      <= S_INIT;
            prev_state <= S_INIT;
        elsif rising_edge(clk_i) then
            state      <= next_state;
            prev_state <= state;
        end if;

    end process state_reg_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Moore outputs: a function of the state alone
    -- ---------------------------------------------------------------------------------------------
    output_proc : process (state) is
    begin

        in_init_o     <= '0';
        in_sync_gen_o <= '0';
        in_rx_o       <= '0';
        in_parse_o    <= '0';
        in_pdo_proc_o <= '0';
        in_sdo_proc_o <= '0';
        in_nmt_proc_o <= '0';
        in_pdo_gen_o  <= '0';
        in_sdo_gen_o  <= '0';
        in_nmt_gen_o  <= '0';
        in_encap_o    <= '0';
        in_tx_o       <= '0';
        in_error_o    <= '0';

        case state is

            when S_INIT =>

                in_init_o <= '1';

            when S_HUB =>

                null;  -- the hub only dispatches

            when S_SYNC_GEN =>

                in_sync_gen_o <= '1';

            when S_CAN_RX =>

                in_rx_o <= '1';

            when S_PARSE =>

                in_parse_o <= '1';

            when S_PDO_PROC =>

                in_pdo_proc_o <= '1';

            when S_SDO_PROC =>

                in_sdo_proc_o <= '1';

            when S_NMT_PROC =>

                in_nmt_proc_o <= '1';

            when S_PDO_GEN =>

                in_pdo_gen_o <= '1';

            when S_SDO_GEN =>

                in_sdo_gen_o <= '1';

            when S_NMT_GEN =>

                in_nmt_gen_o <= '1';

            when S_ENCAP =>

                in_encap_o <= '1';

            when S_CAN_TX =>

                in_tx_o <= '1';

            when S_ERROR =>

                in_error_o <= '1';

        end case;

    end process output_proc;

    state_o <= state_code(state);
    -- entry strobe: the state differs from the one of the previous cycle (self-loops T1, T6,
    -- T18 and G5 do not re-enter)
    state_change_o <= '1' when state /= prev_state else '0';

end architecture rtl;
