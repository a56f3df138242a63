-- =================================================================================================
-- Title    : canopen_tx_path
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The transmit side of the master's datapath (part of canopen_master_core): the generation
--   sources of St2 and St8..St10, Transmit_Data (St11) with the MCP2510 TX buffer plan, the
--   controller request (St12) and the withdrawal of frames that must not go out any more.
-- Purpose:
--   * Sources: 0 SYNC (or the Omni-ID cycle frame), 1 host NMT command, 5 NMT start of the
--     configuration list, 2 node monitor (NMT, guarding RTR), 3 SDO channels, 4 PDO / Omni-ID
--     engine. The host NMT command and the configuration list's NMT start wait in their own
--     registers (a host command is refused while one waits, never overwritten).
--   * FSM conditions: a generation is requested only while its TX buffer is free (TXB1 for NMT
--     and SDO, TXB0 for PDOs); frame_ready_o in St2, St8..St10 when the selected source has a
--     frame.
--   * Buffer plan: TXB2 (TXP 3) the SYNC, preloaded and started by TX2RTS (send = 0); TXB1
--     (TXP 2) SDO and NMT; TXB0 (TXP 1) PDOs.
--   * An SDO transfer that ended while its request waits in TXB1 has it cancelled (once, until
--     TXB1 is free); the transfer's withdrawal is acknowledged when no request of it is left.
--   * A synchronous TPDO still waiting in (or being loaded into) TXB0 when the next SYNC fires
--     is cancelled; pdo_cancel_sent_o tells the PDO engine that an abort report is its frame.
--   Decisions: docs/canopen_master_top.md (TX buffer plan, fault reactions).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;

entity canopen_tx_path is
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- FSM states
        in_sync_gen_i : in    std_logic; -- St2: SYNC generation
        in_nmt_gen_i  : in    std_logic; -- St10: NMT generation
        in_sdo_gen_i  : in    std_logic; -- St9: SDO generation
        in_pdo_gen_i  : in    std_logic; -- St8: PDO generation
        in_encap_i    : in    std_logic; -- St11: encapsulation
        in_tx_i       : in    std_logic; -- St12: request to the controller
        -- protocol mode
        omni_en_i : in    std_logic; -- Omni-ID mode: no host NMT, no monitor frames
        -- host NMT command (NMT_CMD)
        nmt_req_i     : in    std_logic;                    -- strobe: NMT_CMD written
        nmt_cs_i      : in    std_logic_vector(7 downto 0); -- command specifier
        nmt_node_i    : in    std_logic_vector(7 downto 0); -- node-ID, 0 = all
        nmt_pending_o : out   std_logic;                    -- a command waits
        nmt_refused_o : out   std_logic;                    -- NMT_STATUS.REFUSED as read
        -- NMT start of a node the configuration list configured
        acfg_nmt_req_i     : in    std_logic;                    -- strobe: queue a start
        acfg_nmt_node_i    : in    std_logic_vector(6 downto 0); -- its node-ID
        acfg_nmt_pending_o : out   std_logic;                    -- a start waits
        -- source 0: SYNC (counter byte with SYNC_OVERFLOW >= 2) or the Omni-ID cycle frame
        sync_overflow_i : in    std_logic_vector(7 downto 0);  -- 1019h
        sync_counter_i  : in    std_logic_vector(7 downto 0);  -- the counter byte
        cyc_id_i        : in    std_logic_vector(10 downto 0); -- Omni-ID cycle frame
        cyc_dlc_i       : in    std_logic_vector(3 downto 0);  -- its DLC
        cyc_data_i      : in    std_logic_vector(63 downto 0); -- its data
        sync_encap_o    : out   std_logic;                     -- St11 takes the SYNC source
        sync_loaded_o   : out   std_logic;                     -- strobe: TXB2 loaded (St12)
        -- source 2: node monitor
        mon_tx_req_i  : in    std_logic;                     -- frame waiting
        mon_tx_id_i   : in    std_logic_vector(10 downto 0); -- its id
        mon_tx_rtr_i  : in    std_logic;                     -- remote frame
        mon_tx_dlc_i  : in    std_logic_vector(3 downto 0);  -- DLC
        mon_tx_data_i : in    std_logic_vector(63 downto 0); -- data
        mon_tx_ack_o  : out   std_logic;                     -- strobe: taken
        -- source 3: SDO channels
        sdo_tx_req_i   : in    std_logic;                     -- frame waiting
        sdo_tx_id_i    : in    std_logic_vector(10 downto 0); -- its id
        sdo_tx_dlc_i   : in    std_logic_vector(3 downto 0);  -- DLC
        sdo_tx_data_i  : in    std_logic_vector(63 downto 0); -- data
        sdo_tx_abort_i : in    std_logic;                     -- it is an abort frame
        sdo_tx_ack_o   : out   std_logic;                     -- strobe: taken
        sdo_wdr_req_i  : in    std_logic;                     -- a transfer ended: withdraw
        sdo_wdr_id_i   : in    std_logic_vector(10 downto 0); -- its request COB-ID
        sdo_wdr_ack_o  : out   std_logic;                     -- strobe: nothing of it left
        -- source 4: the active protocol engine (PDO or Omni-ID)
        pdo_tx_req_i      : in    std_logic;                     -- frame waiting
        pdo_tx_id_i       : in    std_logic_vector(10 downto 0); -- its id
        pdo_tx_rtr_i      : in    std_logic;                     -- remote frame
        pdo_tx_dlc_i      : in    std_logic_vector(3 downto 0);  -- DLC
        pdo_tx_data_i     : in    std_logic_vector(63 downto 0); -- data
        pdo_tx_sync_i     : in    std_logic;                     -- a synchronous TPDO
        pdo_tx_ack_o      : out   std_logic;                     -- strobe: taken
        sync_fire_i       : in    std_logic;                     -- strobe: a SYNC fires
        pdo_cancel_sent_o : out   std_logic;                     -- TXB0's frame was cancelled
        -- FSM conditions
        nmt_gen_req_o : out   std_logic; -- an NMT-source frame, TXB1 free
        sdo_gen_req_o : out   std_logic; -- an SDO frame, TXB1 free
        pdo_gen_req_o : out   std_logic; -- a PDO frame, TXB0 free
        frame_ready_o : out   std_logic; -- St2, St8..St10: the selected source has a frame
        -- mcp2510_ctrl transmit interface
        ctl_tx_ready_i   : in    std_logic;                     -- request taken
        ctl_tx_loaded_i  : in    std_logic;                     -- strobe: executed
        ctl_tx_pending_i : in    std_logic_vector(2 downto 0);  -- TXREQ per buffer
        ctl_init_done_i  : in    std_logic;                     -- chip in normal mode
        ctl_tx_valid_o   : out   std_logic;                     -- request
        ctl_tx_buf_o     : out   std_logic_vector(1 downto 0);  -- TX buffer
        ctl_tx_txp_o     : out   std_logic_vector(1 downto 0);  -- priority
        ctl_tx_send_o    : out   std_logic;                     -- RTS after load
        ctl_tx_id_o      : out   std_logic_vector(28 downto 0); -- identifier
        ctl_tx_rtr_o     : out   std_logic;                     -- remote frame
        ctl_tx_dlc_o     : out   std_logic_vector(3 downto 0);  -- DLC
        ctl_tx_data_o    : out   std_logic_vector(63 downto 0); -- data
        ctl_tx_cancel_o  : out   std_logic_vector(2 downto 0)   -- pulse: cancel a buffer
    );
end entity canopen_tx_path;

architecture rtl of canopen_tx_path is

    -- MCP2510 buffer plan
    constant txb_pdo_c  : std_logic_vector(1 downto 0) := "00";
    constant txb_cmd_c  : std_logic_vector(1 downto 0) := "01";
    constant txb_sync_c : std_logic_vector(1 downto 0) := "10";

    -- source of the frame being generated: 0 SYNC, 1 NMT host, 2 NMT monitor, 3 SDO, 4 PDO,
    -- 5 NMT start of the configuration list

    subtype gen_src_t is natural range 0 to 5;

    -- the buffer plan per source: TX buffer, TXP priority, RTS right after the load (the SYNC
    -- in TXB2 is only loaded; the SYNC timebase requests its send)

    type tx_plan_t is record
        buf  : std_logic_vector(1 downto 0);
        txp  : std_logic_vector(1 downto 0);
        send : std_logic;
    end record tx_plan_t;

    type tx_plan_arr_t is array (gen_src_t) of tx_plan_t;

    constant tx_plan_c : tx_plan_arr_t :=
    (
        0      => (buf => txb_sync_c, txp => "11", send => '0'),
        4      => (buf => txb_pdo_c,  txp => "01", send => '1'),
        others => (buf => txb_cmd_c,  txp => "10", send => '1')
    );

    -- Transmit_Data (thesis: frame register filled in St11); its buffer plan follows gen_src,
    -- which holds from the generation state through St11 and St12
    signal gen_src      : gen_src_t;
    signal tx_frame     : can_frame_t;
    signal tx_buf       : std_logic_vector(1 downto 0);
    signal tx_requested : std_logic;
    -- host NMT command waiting; refused; its fields
    signal nmt_pending  : std_logic;
    signal nmt_refused  : std_logic;
    signal nmt_cmd_cs   : std_logic_vector(7 downto 0);
    signal nmt_cmd_node : std_logic_vector(6 downto 0);
    signal nmt_cmd_ok   : std_logic;
    signal nmt_accept   : std_logic;
    -- the configuration list's NMT start waiting (apart from the host's, so neither is lost)
    signal acfg_nmt_pending : std_logic;
    signal acfg_nmt_cmd     : std_logic_vector(6 downto 0);
    -- TXB1 holds a request of an SDO transfer (not an abort frame), with this COB-ID; the frame
    -- in St11/St12 is an SDO request (the SDO source's tx_abort = 0 when it was taken)
    signal txb1_sdo_req : std_logic;
    signal txb1_id      : std_logic_vector(10 downto 0);
    signal tx_sdo_req   : std_logic;
    -- an SDO transfer ended: its request waits in TXB1 (cancel it), or an SDO frame is between
    -- St11 and TXB1 (wait), else withdrawn (ack)
    signal sdo_cancel : std_logic;
    signal sdo_flight : std_logic;
    -- the cancel of TXB1 was asked for (until TXB1 is free), and the pulse towards the chip
    signal cancel_sent  : std_logic;
    signal cancel_pulse : std_logic;
    -- TXB0 holds, or is being loaded with, a synchronous TPDO: if a SYNC fires before it
    -- started it would go out after that SYNC, in the next cycle, so it is cancelled
    -- (pdo_cancel_req until TXB0 is pending, then one pulse) and, if the controller reports it
    -- cancelled, the engine counts it late
    signal txb0_sync        : std_logic;
    signal txb0_loading     : std_logic;
    signal pdo_cancel_req   : std_logic;
    signal pdo_cancel_sent  : std_logic;
    signal pdo_cancel_pulse : std_logic;
    -- acknowledges to the sources
    signal sdo_tx_ack : std_logic;
    signal mon_tx_ack : std_logic;
    signal pdo_tx_ack : std_logic;

begin

    -- host NMT command admission: CS is one of the five CiA 301 commands and NODE is 0..127;
    -- REFUSED as the host reads it (the decision already in the cycle of the request)
    nmt_cmd_ok    <= '1' when (nmt_cs_i = NMT_CS_START_C or nmt_cs_i = NMT_CS_STOP_C
                                  or nmt_cs_i = NMT_CS_PREOP_C or nmt_cs_i = NMT_CS_RESET_NODE_C
                                  or nmt_cs_i = NMT_CS_RESET_COMM_C) and nmt_node_i(7) = '0' else
                     '0';
    nmt_accept    <= nmt_cmd_ok and not nmt_pending and not omni_en_i;
    nmt_refused_o <= not nmt_accept when nmt_req_i = '1' else
                     nmt_refused;

    -- a generation is only dispatched when its TX buffer is free
    nmt_gen_req_o <= (nmt_pending or acfg_nmt_pending or (mon_tx_req_i and not omni_en_i))
                     and not ctl_tx_pending_i(1);
    sdo_gen_req_o <= sdo_tx_req_i and not ctl_tx_pending_i(1);
    pdo_gen_req_o <= pdo_tx_req_i and not ctl_tx_pending_i(0);

    -- St2, St8..St10: the selected source presents its frame
    frame_ready_o <= '1' when in_sync_gen_i = '1' else
                     '1' when in_nmt_gen_i = '1'
                              and (nmt_pending = '1' or acfg_nmt_pending = '1'
                             or (mon_tx_req_i = '1' and omni_en_i = '0')) else
                     '1' when in_sdo_gen_i = '1' and sdo_tx_req_i = '1' else
                     '1' when in_pdo_gen_i = '1' and pdo_tx_req_i = '1' else
                     '0';

    -- St12 loaded TXB2 with the SYNC; St11 takes the SYNC source (generation source 0)
    sync_loaded_o <= '1' when in_tx_i = '1' and ctl_tx_loaded_i = '1' and tx_buf = txb_sync_c else
                     '0';
    sync_encap_o  <= '1' when in_encap_i = '1' and gen_src = 0 else
                     '0';

    -- an ended SDO transfer (any end: client abort, server abort, timeout, ...) withdraws its
    -- request still waiting in TXB1: cancelled (a frame already on the wire completes); the
    -- transfer's DONE waits for the withdraw (fuzz finding 3)
    sdo_cancel    <= '1' when sdo_wdr_req_i = '1' and ctl_tx_pending_i(1) = '1'
                              and txb1_sdo_req = '1' and txb1_id = sdo_wdr_id_i else
                     '0';
    sdo_flight    <= '1' when (in_encap_i = '1' or in_tx_i = '1') and gen_src = 3 else
                     '0';
    sdo_wdr_ack_o <= sdo_wdr_req_i and not sdo_cancel and not sdo_flight;

    tx_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            tx_frame         <= CAN_FRAME_NONE_C;
            tx_requested     <= '0';
            txb1_sdo_req     <= '0';
            txb1_id          <= (others => '0');
            tx_sdo_req       <= '0';
            cancel_sent      <= '0';
            cancel_pulse     <= '0';
            txb0_sync        <= '0';
            txb0_loading     <= '0';
            pdo_cancel_req   <= '0';
            pdo_cancel_sent  <= '0';
            pdo_cancel_pulse <= '0';
            gen_src          <= 0;
            nmt_pending      <= '0';
            nmt_refused      <= '0';
            nmt_cmd_cs       <= (others => '0');
            nmt_cmd_node     <= (others => '0');
            acfg_nmt_pending <= '0';
            acfg_nmt_cmd     <= (others => '0');
            sdo_tx_ack       <= '0';
            mon_tx_ack       <= '0';
            pdo_tx_ack       <= '0';
        elsif rising_edge(clk_i) then
            sdo_tx_ack <= '0';
            mon_tx_ack <= '0';
            pdo_tx_ack <= '0';

            -- host NMT command --------------------------------------------------------------
            -- a write while one is pending (or in Omni-ID mode, or with a command specifier
            -- CiA 301 does not define, or a node-ID above 127) is refused, never overwrites
            if nmt_req_i = '1' and nmt_accept = '0' then
                nmt_refused <= '1';
            elsif nmt_req_i = '1' then
                nmt_refused  <= '0';
                nmt_pending  <= '1';
                nmt_cmd_cs   <= nmt_cs_i;
                nmt_cmd_node <= nmt_node_i(6 downto 0);
            end if;

            -- NMT start of a configured node (canopen_autoconfig) -----------------------------
            if acfg_nmt_req_i = '1' then
                acfg_nmt_pending <= '1';
                acfg_nmt_cmd     <= acfg_nmt_node_i;
            end if;

            -- St2, St8..St10: remember the generation source ---------------------------------
            if in_sync_gen_i = '1' then
                gen_src <= 0;
            elsif in_nmt_gen_i = '1' and nmt_pending = '1' then
                gen_src <= 1;
            elsif in_nmt_gen_i = '1' and acfg_nmt_pending = '1' then
                gen_src <= 5;
            elsif in_nmt_gen_i = '1' then
                gen_src <= 2;
            elsif in_sdo_gen_i = '1' then
                gen_src <= 3;
            elsif in_pdo_gen_i = '1' then
                gen_src <= 4;
            end if;

            -- St11: encapsulation into Transmit_Data, TX buffer and priority ----------------
            if in_encap_i = '1' then
                tx_frame     <= CAN_FRAME_NONE_C;
                tx_requested <= '0';

                case gen_src is

                    when 0 =>

                        -- SYNC (COB-ID 080h), with the counter byte when 1019h is set
                        tx_frame.id <= COB_SYNC_C;
                        if omni_en_i = '1' then
                            -- Omni-ID mode: the engine's cycle frame
                            tx_frame.id   <= cyc_id_i;
                            tx_frame.dlc  <= cyc_dlc_i;
                            tx_frame.data <= cyc_data_i;
                        elsif unsigned(sync_overflow_i) >= 2 then
                            tx_frame.dlc              <= x"1";
                            tx_frame.data(7 downto 0) <= sync_counter_i;
                        end if;

                    when 1 | 5 =>

                        -- NMT command [cs, node]: the host's, or the start of a node the
                        -- configuration list configured
                        tx_frame.id  <= COB_NMT_C;
                        tx_frame.dlc <= x"2";
                        if gen_src = 1 then
                            tx_frame.data(15 downto 0) <= '0' & nmt_cmd_node & nmt_cmd_cs;
                            nmt_pending                <= '0';
                        else
                            tx_frame.data(15 downto 0) <= '0' & acfg_nmt_cmd & NMT_CS_START_C;
                            acfg_nmt_pending           <= '0';
                        end if;

                    when 2 =>

                        tx_frame.id   <= mon_tx_id_i;
                        tx_frame.rtr  <= mon_tx_rtr_i;
                        tx_frame.dlc  <= mon_tx_dlc_i;
                        tx_frame.data <= mon_tx_data_i;
                        mon_tx_ack    <= '1';

                    when 3 =>

                        tx_frame.id   <= sdo_tx_id_i;
                        tx_frame.dlc  <= sdo_tx_dlc_i;
                        tx_frame.data <= sdo_tx_data_i;
                        tx_sdo_req    <= not sdo_tx_abort_i;
                        sdo_tx_ack    <= '1';

                    when 4 =>

                        tx_frame.id   <= pdo_tx_id_i;
                        tx_frame.rtr  <= pdo_tx_rtr_i;
                        tx_frame.dlc  <= pdo_tx_dlc_i;
                        tx_frame.data <= pdo_tx_data_i;
                        pdo_tx_ack    <= '1';

                end case;

            end if;

            -- St12: the request stays up until the controller takes it -------------------
            if in_tx_i = '1' and ctl_tx_ready_i = '1' then
                tx_requested <= '1';
            end if;
            if in_tx_i = '1' and ctl_tx_loaded_i = '1' and tx_buf = txb_cmd_c then
                txb1_id <= tx_frame.id;
                if gen_src = 3 and tx_sdo_req = '1' then
                    txb1_sdo_req <= '1';
                else
                    txb1_sdo_req <= '0';
                end if;
            end if;
            -- an SDO transfer ended while its last request still waits in TXB1: the request is
            -- cancelled once (again only after TXB1 was free) (fuzz finding 3)
            cancel_pulse <= sdo_cancel and not cancel_sent;
            if sdo_cancel = '1' then
                cancel_sent <= '1';
            end if;
            if ctl_tx_pending_i(1) = '0' then
                cancel_sent <= '0';
            end if;
            -- a synchronous TPDO not started when the next SYNC fires is withdrawn from TXB0
            if pdo_tx_ack = '1' and omni_en_i = '0' then
                txb0_sync    <= pdo_tx_sync_i;
                txb0_loading <= '1';
            end if;
            if (in_tx_i = '1' and ctl_tx_loaded_i = '1' and tx_buf = txb_pdo_c)
               or ctl_init_done_i = '0' then
                txb0_loading <= '0';
            end if;
            pdo_cancel_pulse <= pdo_cancel_req and ctl_tx_pending_i(0);
            if pdo_cancel_req = '1' and ctl_tx_pending_i(0) = '1' then
                pdo_cancel_req  <= '0';
                pdo_cancel_sent <= '1';
            end if;
            if ctl_tx_pending_i(0) = '0' and txb0_loading = '0' then
                -- TXB0 free: nothing to cancel, the outcome of a cancel is known
                pdo_cancel_req  <= '0';
                pdo_cancel_sent <= '0';
            elsif sync_fire_i = '1' and txb0_sync = '1' and omni_en_i = '0' then
                pdo_cancel_req <= not pdo_cancel_sent;
            end if;
        end if;

    end process tx_proc;

    tx_buf <= tx_plan_c(gen_src).buf;

    nmt_pending_o      <= nmt_pending;
    acfg_nmt_pending_o <= acfg_nmt_pending;
    mon_tx_ack_o       <= mon_tx_ack;
    sdo_tx_ack_o       <= sdo_tx_ack;
    pdo_tx_ack_o       <= pdo_tx_ack;
    pdo_cancel_sent_o  <= pdo_cancel_sent;

    -- St12: request towards mcp2510_ctrl
    ctl_tx_valid_o  <= in_tx_i and not tx_requested;
    ctl_tx_buf_o    <= tx_buf;
    ctl_tx_txp_o    <= tx_plan_c(gen_src).txp;
    ctl_tx_send_o   <= tx_plan_c(gen_src).send;
    ctl_tx_id_o     <= (28 downto 11 => '0') & tx_frame.id;
    ctl_tx_rtr_o    <= tx_frame.rtr;
    ctl_tx_dlc_o    <= tx_frame.dlc;
    ctl_tx_data_o   <= tx_frame.data;
    ctl_tx_cancel_o <= (0 => pdo_cancel_pulse, 1 => cancel_pulse, others => '0');

end architecture rtl;
